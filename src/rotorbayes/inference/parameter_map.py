"""The free parameters of an estimation problem: names, bounds and the vector ``x``.

A :class:`ParameterMap` knows which parameters a fit moves (``names``, in the order of the
vector ``x``), their bounds, and how ``x`` becomes the full parameter set of one
experiment and back.  A per-experiment parameter has one entry per experiment,
``alpha0[0]``, ``alpha0[1]``, ... (thesis §5.3.2): each experiment starts with its own
string torsion, every other parameter is shared.  :class:`FillTemplate` is the fast way
from ``x`` to the kernel's vectors: the vectors at the fixed values, with the free values
put in place.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..kernel import layout as _layout
from ..model.parameters import ParameterError


def local_name(name: str) -> tuple[str, int | None]:
    """Split ``'alpha0[2]'`` into ``('alpha0', 2)``."""
    if name.endswith("]") and "[" in name:
        base, idx = name[:-1].split("[", 1)
        try:
            return base, int(idx)
        except ValueError:
            raise ParameterError(f"{name!r}: the index in brackets must be a number") from None
    return name, None


@dataclass(frozen=True, eq=False)
class FillTemplate:
    """How the kernel vectors ``(p, q)`` of one experiment follow from a free vector:
    copies of ``p0``, ``q0`` (the vectors at the fixed values) with ``x[pf]`` put at
    ``p[pa]`` and ``x[qf]`` at ``q[qa]``; ``ts_follows``: the static friction ``Ts_l``
    follows ``Tc_l`` (no Stribeck peak in the model)."""

    p0: np.ndarray
    q0: np.ndarray
    pa: np.ndarray
    pf: np.ndarray
    qa: np.ndarray
    qf: np.ndarray
    ts_follows: bool

    def vectors(self, x) -> tuple[np.ndarray, np.ndarray]:
        """The kernel vectors at the free vector ``x``."""
        x = np.asarray(x, dtype=float)
        p = self.p0.copy()
        p[self.pa] = x[self.pf]
        q = self.q0.copy()
        q[self.qa] = x[self.qf]
        if self.ts_follows or math.isnan(p[_layout.TS_L]):
            p[_layout.TS_L] = p[_layout.TC_L]
        return p, q


@dataclass(eq=False)
class ParameterMap:
    """The free parameters: ``names`` in vector order (per-experiment ones as
    ``alpha0[i]``), their ``lower`` and ``upper`` bounds, over ``n_experiments``
    experiments.

    Build one with :meth:`expand` from the free names as a user gives them.
    """

    names: list[str]
    lower: np.ndarray
    upper: np.ndarray
    n_experiments: int

    #: Parameters that take one value per experiment when there are several.
    PER_EXPERIMENT = ("alpha0",)

    @classmethod
    def expand(
        cls, free: Sequence[str], n_experiments: int, bounds: Callable[[str], tuple[float, float]]
    ) -> ParameterMap:
        """The map of the free names ``free``: a per-experiment parameter becomes one
        entry per experiment when there are several (``alpha0`` -> ``alpha0[0]``,
        ``alpha0[1]``, ...); ``bounds(base_name)`` gives ``(lower, upper)``.  A name listed
        twice is refused."""
        names: list[str] = []
        for n in free:
            if n in cls.PER_EXPERIMENT and n_experiments > 1:
                names += [f"{n}[{i}]" for i in range(n_experiments)]
            else:
                names.append(n)
        if len(set(names)) != len(names):
            raise ParameterError(f"a free parameter is listed twice: {names}")
        lower = np.array([bounds(local_name(n)[0])[0] for n in names])
        upper = np.array([bounds(local_name(n)[0])[1] for n in names])
        return cls(names, lower, upper, n_experiments)

    def __len__(self) -> int:
        return len(self.names)

    def names_base(self) -> list[str]:
        """Free parameter names with per-experiment names folded (``alpha0``)."""
        out: list[str] = []
        for n in self.names:
            b, _ = local_name(n)
            if b not in out:
                out.append(b)
        return out

    def point(self, x) -> np.ndarray:
        """``x`` as a free-parameter vector: a 1-D float array with one value per free
        parameter; :class:`ValueError` naming what is wrong otherwise."""
        try:
            out = np.asarray(x, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"x must hold one number per free parameter ({exc}); make it "
                "with problem.x_from(values) or problem.start_vector(values)"
            ) from None
        k = len(self.names)
        if out.shape != (k,):
            what = f"{out.size} value(s)" if out.ndim == 1 else f"shape {out.shape}"
            raise ValueError(
                f"x has {what}, but this problem has {k} free parameter(s) "
                f"({', '.join(self.names) or 'none'}); make x with problem.x_from(values) or "
                "problem.start_vector(values)"
            )
        return out

    def x_from(self, params: Mapping[str, float]) -> np.ndarray:
        """Free-parameter vector from a mapping (``alpha0[i]`` falls back to ``alpha0``)."""
        out = []
        for n in self.names:
            base, _ = local_name(n)
            out.append(float(params[n] if n in params else params[base]))
        return np.array(out)

    def values(self, x) -> dict[str, float]:
        """``{name: value}`` of the free parameters."""
        return {n: float(v) for n, v in zip(self.names, self.point(x), strict=True)}

    def params_for(self, x, i: int, fixed: Mapping[str, float]) -> dict[str, float]:
        """The full parameter set of experiment ``i``: the ``fixed`` values with the free
        ones of ``x`` (experiment ``i``'s entry of a per-experiment parameter) in place."""
        x = self.point(x)
        p = dict(fixed)
        for n, v in zip(self.names, x, strict=True):
            base, idx = local_name(n)
            if idx is None or idx == i:
                p[base] = float(v)
        return p

    def scale(self, x) -> np.ndarray:
        """Typical magnitudes of the free parameters at ``x``: ``|x|``, at least a
        thousandth of the bounds' width (the optimiser's variables, the steps of finite
        differences)."""
        width = self.upper - self.lower
        return np.maximum(np.abs(x), 1e-3 * width)

    def outside(self, x) -> list[tuple[str, float, float, float]]:
        """``(name, value, lower, upper)`` of every value of ``x`` outside its bounds."""
        return [
            (n, v, lo, hi)
            for n, v, lo, hi in zip(self.names, x, self.lower, self.upper, strict=True)
            if not (lo <= v <= hi)
        ]

    def fill_template(
        self,
        i: int,
        slot: Callable[[str], tuple[int, int] | None],
        p0: np.ndarray,
        q0: np.ndarray,
        ts_follows: bool,
    ) -> FillTemplate | None:
        """The :class:`FillTemplate` of experiment ``i`` from the kernel vectors ``p0``,
        ``q0`` at the fixed values; ``slot(base_name)`` is a parameter's place in them
        (``(0, index)`` in ``p``, ``(1, index)`` in ``q``), ``None`` where it has none (then
        no template either: the long way is the only right one)."""
        pa: list[int] = []
        pf: list[int] = []
        qa: list[int] = []
        qf: list[int] = []
        for j, n in enumerate(self.names):
            base, idx = local_name(n)
            if idx is not None and idx != i:
                continue
            s = slot(base)
            if s is None:
                return None
            (qa if s[0] else pa).append(s[1])
            (qf if s[0] else pf).append(j)
        return FillTemplate(
            p0,
            q0,
            np.array(pa, dtype=np.intp),
            np.array(pf, dtype=np.intp),
            np.array(qa, dtype=np.intp),
            np.array(qf, dtype=np.intp),
            ts_follows,
        )
