"""The commands' options as typed objects: one frozen dataclass per concern.

* :class:`ReadOptions` — how a rig's own data files are read (``--columns``, ...);
* :class:`ProblemOptions` — the estimation problem: configuration, data, what is free or
  fixed, effects switched on and off, channels and weights, the integrator's step;
* :class:`SolverOptions` — the least-squares budget and tolerances;
* :class:`ExecutorOptions` — where independent tasks run (``--backend``, ...);
* :class:`FitFolderOptions` — how an earlier fit folder is read again;
* one class per command that composes them (:class:`FitOptions`,
  :class:`MultistartOptions`, :class:`SampleOptions`, :class:`IdentifyOptions`).

The command line, the Python functions (``rotorbayes.commands.fit.fit`` and the others)
and the study (:mod:`rotorbayes.study`) all build these objects, and each command's work
reads them alone.  A command's keyword arguments are the flattened fields of its class
(:func:`keyword_fields`; ``--max-nfev`` is ``solver.max_nfev``), so the command line, the
Python signature and the objects cannot drift apart (``tests/test_architecture.py``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import typing
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

#: Names given as one comma-separated string (the command line's form) or as a list.
Names = str | Sequence[str] | None


def _paths(value) -> tuple[str, ...] | None:
    """One path or several, as a tuple; None stays None."""
    if value is None:
        return None
    return (value,) if isinstance(value, str) else tuple(value)


@dataclass(frozen=True)
class ReadOptions:
    """How to read a rig's own data files (:class:`rotorbayes.rigfiles.ReadSpec`): the
    file's names of the signals (``columns``), the unit of its time (``time_unit``: s or
    ms) and angles (``angle_unit``: rad, deg or counts) and the encoders' counts per
    revolution (``counts_per_rev``).  Checked where it is built: a bad value is refused
    (:class:`~rotorbayes.exitcodes.Refused`) naming the option."""

    columns: str | Mapping[str, str] | None = None
    time_unit: str | None = None
    angle_unit: str | None = None
    counts_per_rev: str | float | Mapping[str, float] | None = None
    spec: Any = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        from .options import read_spec

        object.__setattr__(
            self,
            "spec",
            read_spec(self.columns, self.time_unit, self.angle_unit, self.counts_per_rev),
        )


@dataclass(frozen=True)
class ProblemOptions:
    """The estimation problem of ``fit`` and ``multistart``.

    ``model`` is the configuration ("upper", "coupled" or "brake") and ``data`` the
    measurement files (one path or several; ``example:NAME`` for a bundled one).
    ``free``/``fixed``/``channels`` are names (a list or comma-separated), ``base`` the
    values of the parameters not estimated, ``add``/``without`` effects switched on and
    off, ``weights`` channel weights ("theta_l=1,theta_u=0.1"), ``prescribed_upper``
    drives the lower disc with the measured theta_u, ``step`` the largest Runge-Kutta step
    [s] (None: the default), ``keep_glitches`` fits encoder spikes as measured,
    ``trust_effects`` imports user effect files a start names without their hash check,
    ``read`` says how the data files are read.
    """

    model: str
    data: tuple[str, ...]
    free: Names = None
    fixed: Names = None
    base: str | None = None
    add: Sequence[str] | None = None
    without: Sequence[str] | None = None
    channels: Names = None
    weights: str | None = None
    prescribed_upper: bool = False
    step: float | None = None
    keep_glitches: bool = False
    trust_effects: bool = False
    read: ReadOptions = field(default_factory=ReadOptions)

    def __post_init__(self):
        object.__setattr__(self, "data", _paths(self.data))


@dataclass(frozen=True)
class SolverOptions:
    """The budget and tolerances of each least-squares fit
    (:func:`scipy.optimize.least_squares`): at most ``max_nfev`` residual evaluations,
    ``ftol``/``xtol``/``gtol`` relative convergence tolerances, and how its Jacobian is
    computed (``jacobian``)."""

    max_nfev: int = 200
    ftol: float = 1e-10
    xtol: float = 1e-10
    gtol: float = 1e-10
    #: 'differences' or 'sensitivity' (None: :data:`rotorbayes.inference.problem.
    #: JACOBIAN_DEFAULT`).
    jacobian: str | None = None

    def keywords(self) -> dict[str, Any]:
        """The keywords of :func:`rotorbayes.inference.fit` and its relatives (the
        Jacobian's method only where one was chosen: a multistart's resume record of the
        default stays as it was)."""
        kw = dataclasses.asdict(self)
        if kw["jacobian"] is None:
            del kw["jacobian"]
        return kw


@dataclass(frozen=True)
class ExecutorOptions:
    """Where independent tasks run (:mod:`rotorbayes.inference.parallel`): ``backend``
    (serial, threads, processes or dask), ``workers`` and a Dask ``scheduler`` address;
    all None: the default (or the study's executor inside ``run``)."""

    backend: str | None = None
    workers: int | None = None
    scheduler: str | None = None

    @property
    def given(self) -> bool:
        """Whether any of the three was given."""
        return (self.backend, self.workers, self.scheduler) != (None, None, None)

    @contextlib.contextmanager
    def open(self, file: dict | None = None) -> Iterator[Any]:
        """The executor for the length of a command
        (:func:`rotorbayes.commands.common.executor`; ``file``: an analysis file's
        [parallel] table, used where these options say nothing)."""
        from .common import executor

        with executor(self.backend, self.workers, self.scheduler, file=file) as ex:
            yield ex


@dataclass(frozen=True)
class FitFolderOptions:
    """How an earlier fit folder is read again (:func:`rotorbayes.inference.results.load_fit`):
    ``trust_effects`` imports user effect files that changed since the fit (or were not
    hashed), ``accept_changed_data`` uses data files whose SHA-256 changed since."""

    trust_effects: bool = False
    accept_changed_data: bool = False

    def load(self, folder):
        """The fit in ``folder`` (a :class:`rotorbayes.results.FitResult`)."""
        from ..inference.results import load_fit

        return load_fit(
            folder, trust_effects=self.trust_effects, accept_changed_data=self.accept_changed_data
        )


@dataclass(frozen=True)
class FitOptions:
    """``rotorbayes fit``: the problem, the solver, the result folder ``out`` (``force``
    replaces an earlier one), the validation files ``validate`` with their initial string
    torsions ``validate_alpha0``, the start ``p0`` (None: from the data, with up to
    ``restarts`` restarts) and ``search`` over the starts of added effects' parameters."""

    problem: ProblemOptions
    out: str
    solver: SolverOptions = field(default_factory=SolverOptions)
    validate: tuple[str, ...] | None = None
    validate_alpha0: Any = None
    p0: str | None = None
    restarts: int = 6
    search: bool = True
    force: bool = False

    def __post_init__(self):
        object.__setattr__(self, "validate", _paths(self.validate))


@dataclass(frozen=True)
class MultistartOptions:
    """``rotorbayes multistart``: the problem, the solver of each start, where the starts
    run (``executor``), the result folder ``out``, ``starts`` fits from a Latin hypercube
    over the bounds or a log-normal ``spread`` around the set ``around``, ``seed``."""

    problem: ProblemOptions
    out: str
    solver: SolverOptions = field(default_factory=SolverOptions)
    executor: ExecutorOptions = field(default_factory=ExecutorOptions)
    starts: int = 32
    around: str | None = None
    spread: float = 0.3
    seed: int = 0
    force: bool = False


@dataclass(frozen=True)
class SampleOptions:
    """``rotorbayes sample``: emcee from the fit folder ``source`` into ``out`` (with
    ``resume``, ``source`` is a sample folder continued in place); the sizes, ``seed``,
    noise model, moves, priors, draws kept, where the ensembles run and how the fit
    folder is read."""

    source: str
    out: str | None = None
    resume: bool = False
    walkers: int = 32
    steps: int | None = None
    ensembles: int = 2
    seed: int = 0
    noise: str = "robust"
    ar1: bool = False
    moves: str | None = None
    priors: str | None = None
    max_draws: int = 100
    quiet: bool = False
    force: bool = False
    fit_folder: FitFolderOptions = field(default_factory=FitFolderOptions)
    executor: ExecutorOptions = field(default_factory=ExecutorOptions)


@dataclass(frozen=True)
class IdentifyOptions:
    """``rotorbayes identify``: the fit folder ``fit``, the result folder ``out``, the
    profiles (names, ``points`` each, run on ``executor``), a sample folder ``posterior``
    for the corner plot and a ``multistart`` folder whose end points go on it."""

    fit: str
    out: str
    profiles: Names = None
    points: int = 11
    posterior: str | None = None
    multistart: str | None = None
    force: bool = False
    fit_folder: FitFolderOptions = field(default_factory=FitFolderOptions)
    executor: ExecutorOptions = field(default_factory=ExecutorOptions)


def _nested(cls) -> dict[str, type]:
    """The fields of ``cls`` that are option objects themselves, with their classes."""
    hints = typing.get_type_hints(cls)
    return {
        f.name: hints[f.name]
        for f in dataclasses.fields(cls)
        if dataclasses.is_dataclass(hints[f.name])
    }


def keyword_fields(cls) -> dict[str, tuple[str, ...]]:
    """Every keyword of the options class ``cls``, flattened, with the path of the field
    it sets (``{"max_nfev": ("solver", "max_nfev"), ...}``)."""
    nested = _nested(cls)
    out: dict[str, tuple[str, ...]] = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.name in nested:
            out.update({k: (f.name, *p) for k, p in keyword_fields(nested[f.name]).items()})
        else:
            out[f.name] = (f.name,)
    return out


def keyword_defaults(cls) -> dict[str, Any]:
    """The default of every keyword of ``cls`` (absent: the keyword is required)."""
    nested = _nested(cls)
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.name in nested:
            out.update(keyword_defaults(nested[f.name]))
        elif f.default is not dataclasses.MISSING:
            out[f.name] = f.default
    return out


def from_keywords(cls, **keywords):
    """An options object of class ``cls`` from its flattened keywords (those of the
    command's function and of the command line); an unknown keyword is a TypeError."""
    known = keyword_fields(cls)
    unknown = sorted(set(keywords) - set(known))
    if unknown:
        raise TypeError(f"{cls.__name__}: unknown option(s) {', '.join(unknown)}")
    return _build(cls, keywords)


def _build(cls, keywords: dict):
    nested = _nested(cls)
    args = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.name in nested:
            sub = nested[f.name]
            args[f.name] = _build(
                sub, {k: v for k, v in keywords.items() if k in keyword_fields(sub)}
            )
        elif f.name in keywords:
            args[f.name] = keywords[f.name]
    return cls(**args)


def keywords(options) -> dict[str, Any]:
    """The flattened keywords of an options object (the reverse of :func:`from_keywords`)."""
    out = {}
    for name, path in keyword_fields(type(options)).items():
        value = options
        for p in path:
            value = getattr(value, p)
        out[name] = value
    return out
