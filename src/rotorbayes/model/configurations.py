"""The rig's configurations and :class:`Model`: a configuration plus its active effects.

Everything that depends on the configuration is here: which base parameters enter it,
which effects its base model has switched on (the thesis's models: asymmetric upper
friction, eq. 4.2-4.3; the brake's Stribeck curve with asymmetric viscous friction,
eq. 5.18), which parameters a fit frees by default, and the kernel's configuration code.

A :class:`Model` turns ``{name: value}`` into the kernel's two parameter vectors, holding
the parameters of effects that are off at their null values (and refusing a non-null
value for one: no silent no-op), and compiles the hooks of user-defined effects.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
from numba import njit, types

from ..kernel import layout as _layout
from ..kernel.terms import CONSTRAINTS, HOOK_SIGNATURE, null_hook, violations
from . import effects as _effects
from .effects import Effect, EffectError
from .info import Parameter
from .parameters import INFO, ParameterError


@dataclass(frozen=True)
class Configuration:
    """One configuration of the rig."""

    name: str
    description: str
    parameters: tuple[str, ...]  # base parameters that enter its equations
    base_effects: tuple[str, ...]  # effects its base model has on
    # Base parameters a fit frees by default: every one the data determine.  J_u is
    # fixed (eq. 5.4): with it, the string's reaction on the measured upper disc sets the
    # scale of the lower disc's parameters.
    fitted: tuple[str, ...]
    has_lower: bool
    fitted_effects: tuple[str, ...] = ()  # base effects whose parameters a fit frees


CONFIGURATIONS: dict[str, Configuration] = {
    c.name: c
    for c in (
        Configuration(
            "upper",
            "string removed: the motor drives the upper disc alone (thesis eq. 4.1)",
            ("k_m", "J_u", "Tc_u", "b_u"),
            ("upper_asymmetric_coulomb", "upper_asymmetric_viscous"),
            ("k_m", "Tc_u", "b_u"),
            False,
            ("upper_asymmetric_coulomb", "upper_asymmetric_viscous"),
        ),
        Configuration(
            "coupled",
            "both discs and the string, no brake (thesis eqs. 4.5-4.9)",
            ("k_m", "J_u", "Tc_u", "b_u", "J_l", "k_alpha", "Tc_l", "b_l"),
            ("upper_asymmetric_coulomb", "upper_asymmetric_viscous"),
            ("k_m", "Tc_u", "b_u", "J_l", "k_alpha", "Tc_l", "b_l"),
            True,
            ("upper_asymmetric_coulomb", "upper_asymmetric_viscous"),
        ),
        Configuration(
            "brake",
            "both discs, the brake pressing on the lower disc (thesis eqs. 4.11-4.14, 5.18)",
            ("k_m", "J_u", "Tc_u", "b_u", "J_l", "k_alpha", "Tc_l", "b_l"),
            (
                "upper_asymmetric_coulomb",
                "upper_asymmetric_viscous",
                "lower_stribeck",
                "lower_asymmetric_viscous",
            ),
            ("k_m", "Tc_u", "b_u", "J_l", "k_alpha", "Tc_l", "b_l"),
            True,
            (
                "upper_asymmetric_coulomb",
                "upper_asymmetric_viscous",
                "lower_stribeck",
                "lower_asymmetric_viscous",
            ),
        ),
    )
}
CONFIGS = tuple(CONFIGURATIONS)


def check_config(config: str) -> str:
    """Return ``config`` or raise a ValueError listing the valid configurations."""
    if config not in CONFIGURATIONS:
        raise ValueError(f"unknown configuration {config!r}; choose one of {', '.join(CONFIGS)}")
    return config


def problems(values: Mapping[str, float], kernel_cfg: int) -> list[str]:
    """Sentences for every validity constraint the values break (empty if none).

    The flags come from the kernel's own check, so Python and the kernel agree.
    """
    p = np.array([float(values[n]) for n in _layout.NAMES])
    if math.isnan(p[_layout.TS_L]):
        p[_layout.TS_L] = p[_layout.TC_L]
    bad = violations(p, kernel_cfg)
    out = []
    for flag, (names, text, _) in zip(bad, CONSTRAINTS, strict=True):
        if flag:
            if names == ("*",):
                nf = [
                    f"{n} = {values[n]}"
                    for n in _layout.NAMES
                    if not math.isfinite(p[_layout.INDEX[n]])
                ]
                out.append(f"{text} ({', '.join(nf)})")
            else:
                vals = ", ".join(f"{n} = {values[n]:g}" for n in names)
                out.append(f"{text} (here {vals})")
    return out


class Model:
    """A configuration with its active effects.

    Parameters
    ----------
    config : {'upper', 'coupled', 'brake'}
    effects : iterable of str or Effect
        Effects switched on in addition to the configuration's base model: catalogue
        names, ``'FILE.py:NAME'`` user effects or :class:`Effect` objects.
    without : iterable of str
        Base-model effects to switch off (e.g. the upper friction asymmetry).
    prescribed_upper : bool
        The measured upper-disc angle drives the lower disc (the motor model is not used).
    """

    def __init__(
        self,
        config: str,
        effects: Iterable[str | Effect] = (),
        *,
        without: Iterable[str] = (),
        prescribed_upper: bool = False,
    ):
        self.config = check_config(config)
        self.configuration = CONFIGURATIONS[config]
        self.prescribed_upper = bool(prescribed_upper)
        if self.prescribed_upper and not self.configuration.has_lower:
            raise ValueError(
                "a prescribed upper-disc motion needs the 'coupled' or 'brake' configuration "
                "(the lower disc must be present)"
            )
        without = tuple(without)
        for w in without:
            if w not in self.configuration.base_effects:
                raise EffectError(
                    f"cannot switch off {w!r}: the {config} base model has "
                    f"{', '.join(self.configuration.base_effects) or 'no effects'} on"
                )
        base = [_effects.get(n) for n in self.configuration.base_effects if n not in without]
        added = list(_effects.resolve(effects))
        for e in added:
            if config not in e.configs:
                raise EffectError(
                    f"effect {e.name!r} does not apply to the {config} configuration (it "
                    f"applies to {', '.join(e.configs)})"
                )
            if self.prescribed_upper and e.motor:
                raise EffectError(
                    f"effect {e.name!r} acts through the motor or the upper disc, which the "
                    "measured theta_u replaces here (prescribed upper motion)"
                )
        self.base_effects = tuple(base)
        self.added = tuple(e for e in added if e not in base)
        self.effects = self.base_effects + self.added
        self.user_effects = tuple(e for e in self.effects if e.is_user)
        stateful = [e.name for e in self.effects if e.state]
        if len(stateful) > 1:
            raise EffectError(
                f"effects {', '.join(stateful)} each carry a state; a model holds at most one "
                "stateful effect (the kernel integrates one effect state)"
            )
        names = [e.name for e in self.effects]
        if len(set(names)) != len(names):
            raise EffectError(f"an effect is listed twice: {names}")
        # Parameter space: every built-in parameter plus the user effects' ones.
        self.info: dict[str, Parameter] = dict(INFO)
        for e in self.user_effects:
            for p in e.parameters:
                if p.name in self.info:
                    raise EffectError(f"effect {e.name!r}: parameter {p.name!r} is already defined")
                self.info[p.name] = p
        self.user_names = tuple(p.name for e in self.user_effects for p in e.parameters)
        replacing = [e for e in self.effects if e.replaces]
        if len(replacing) > 1:
            raise EffectError(
                f"effects {', '.join(e.name for e in replacing)} each replace the lower "
                "disc's friction; switch on one of them"
            )
        #: The effect that carries the lower disc's dry friction (``Effect.replaces``).
        self.replacing = replacing[0] if replacing else None
        #: The kernel's ``q``: the user effects' parameters, the replacing effect's followed
        #: by the levels it carries (:data:`BORROWED`).
        self.q_names = tuple(
            n
            for e in self.user_effects
            for n in (*e.names, *(BORROWED if e is self.replacing else ()))
        )
        on = set(self.configuration.parameters)
        for e in self.effects:
            on.update(e.names)
        if self.prescribed_upper:
            on -= {"k_m", "J_u", "Tc_u", "b_u"}
        #: Parameters that act in this model.
        self.active = tuple(n for n in self.info if n in on)
        #: Parameters of catalogue effects that are off (held at their null values).
        self.off = tuple(n for n in INFO if _effects.effect_of(n) is not None and n not in on)
        self.kernel_cfg = (
            _layout.CFG_PRESCRIBED
            if self.prescribed_upper
            else (_layout.CFG_COUPLED if self.configuration.has_lower else _layout.CFG_UPPER)
        )
        self.stribeck = "lower_stribeck" in names
        #: Whether it runs on the full kernel (the one with hook functions): user effects,
        #: or a catalogue effect whose code only that kernel has (``Effect.full_kernel``).
        self.full_kernel = bool(self.user_effects) or any(e.full_kernel for e in self.effects)
        self._hooks = None

    def __repr__(self) -> str:
        return f"Model({self.config!r}, effects={[e.name for e in self.effects]})"

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def with_effects(self, extra: Iterable[str | Effect]) -> Model:
        """The same model with more effects switched on."""
        without = [n for n in self.configuration.base_effects if n not in self.effect_names]
        return Model(
            self.config,
            [*self.added, *extra],
            without=without,
            prescribed_upper=self.prescribed_upper,
        )

    # ----------------------------------------------------------------------- values
    def null_values(self) -> dict[str, float]:
        """Null values of the user effects' parameters (built-ins come from the sets)."""
        return {n: self.info[n].null for n in self.user_names}

    def complete(self, values: Mapping[str, float]) -> dict[str, float]:
        """``values`` with missing user-effect parameters at their null values."""
        out = dict(self.null_values())
        out.update(values)
        return out

    def check_off(self, values: Mapping[str, float], *, where: str = "") -> None:
        """Refuse a non-null value for a parameter of an effect that is off."""
        for n in self.off:
            info = INFO[n]
            if info.nuisance or n not in values:
                continue
            v = float(values[n])
            null = info.null
            if n == "Ts_l":
                if math.isnan(v) or v == values["Tc_l"]:
                    continue
            elif v == null or (math.isnan(v) and math.isnan(null)):
                continue
            e = _effects.effect_of(n)
            prefix = f"{where}: " if where else ""
            raise ParameterError(
                f"{prefix}{n} = {v:g} {info.unit}, but the effect {e.name!r} is off in this "
                f"{self.config} model, so {n} would be ignored; switch the effect on (--add "
                f"{e.name}) or set {n} to its null value "
                + ("(Ts_l = Tc_l)" if n == "Ts_l" else f"({null:g})")
            )

    def kernel_vectors(self, values: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """``(p, q)``: built-in and user-effect parameter vectors for the kernel.

        Parameters of effects that are off must be at their null values (a non-null one
        is refused, see :meth:`check_off`); ``Ts_l`` is ``Tc_l`` without the Stribeck
        effect.
        """
        p, q = self._vectors(values)
        if self.replacing is not None:
            for n in BORROWED:  # the levels act through the effect alone
                p[_layout.INDEX[n]] = 0.0
        return p, q

    def _vectors(self, values: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`kernel_vectors` before the replacing effect takes the lower levels out of
        ``p`` (what the constraints are checked on)."""
        self.check_off(values)
        p = np.array([float(values[n]) for n in _layout.NAMES])
        for n in self.off:
            if n != "Ts_l" and not INFO[n].nuisance:
                p[_layout.INDEX[n]] = INFO[n].null
        if not self.stribeck or math.isnan(p[_layout.TS_L]):
            p[_layout.TS_L] = p[_layout.TC_L]
        q = np.array(
            [
                p[_layout.INDEX[n]] if n in BORROWED else float(values.get(n, self.info[n].null))
                for n in self.q_names
            ]
        )
        return p, q

    def kernel_slot(self, name: str) -> tuple[int, int] | None:
        """Where :meth:`kernel_vectors` puts the value of ``name`` unchanged: ``(0, i)`` for
        ``p[i]``, ``(1, i)`` for ``q[i]``; ``None`` when it does not (a parameter of an
        effect that is off, ``Ts_l`` without the Stribeck effect), or ``name`` is unknown.
        Without the Stribeck effect ``Ts_l`` also follows ``Tc_l``."""
        if name in self.off or (name == "Ts_l" and not self.stribeck):
            return None
        if self.replacing is not None and name in BORROWED:
            return None  # it moves from p into q
        if name in _layout.INDEX:
            return 0, _layout.INDEX[name]
        if name in self.user_names:
            return 1, self.q_names.index(name)
        return None

    def problems(self, values: Mapping[str, float]) -> list[str]:
        """Why ``values`` cannot be simulated in this model (empty if they can)."""
        p, q = self._vectors(values)
        out = problems(dict(zip(_layout.NAMES, p, strict=True)), self.kernel_cfg)
        for n, v in zip(self.q_names, q, strict=True):
            if not math.isfinite(v) and n not in BORROWED:
                out.append(f"{n} = {v} is not finite")
        if self.replacing is not None:
            tc, dtc, ts = (p[_layout.INDEX[n]] for n in BORROWED)
            if not min(tc, ts) > abs(dtc):
                out.append(
                    f"Tc_l = {tc:g} and Ts_l = {ts:g} must exceed |dTc_l| = {abs(dtc):g} with "
                    f"{self.replacing.name!r} (its bristles relax towards that level, which "
                    "must be positive)"
                )
        return out

    # ------------------------------------------------------------------------ hooks
    def hooks(self):
        """``(use, torque_hook, shift_hook, rate_hook, state_reset)`` for the kernel,
        compiled on first use (see :data:`rotorbayes.kernel.terms.HOOK_SIGNATURE`)."""
        if self._hooks is None:
            self._hooks = _compile_hooks(self.user_effects)
        return self._hooks

    @property
    def stateful(self) -> Effect | None:
        """The model's effect with a state (at most one), or None."""
        return next((e for e in self.effects if e.state), None)


#: The lower disc's levels that an effect replacing its friction carries (``q``, after the
#: effect's own parameters; zero in ``p``).
BORROWED = ("Tc_l", "dTc_l", "Ts_l")

_HOOK_CACHE: dict[tuple, tuple] = {}

#: A user's function without the state: ``(t, theta_u, omega_u, theta_l, omega_l, v, p, q)``.
_STATELESS_SIGNATURE = types.UniTuple(types.float64, 2)(
    types.float64, types.float64, types.float64, types.float64, types.float64,
    types.float64, types.float64[::1], types.float64[::1],
)  # fmt: skip
#: A stateful effect's rate: ``(t, theta_u, omega_u, theta_l, omega_l, v, z, p, q) -> dz/dt``.
_RATE_SIGNATURE = types.float64(
    types.float64, types.float64, types.float64, types.float64, types.float64,
    types.float64, types.float64, types.float64[::1], types.float64[::1],
)  # fmt: skip


def _compile_one(effect: Effect, fn, what: str):
    """The kernel's hook (:data:`HOOK_SIGNATURE`) for one function of a user effect: a
    stateful effect's functions take the state ``z`` after ``v`` (its rate returns one
    float), a stateless effect's do not (wrapped so that the kernel may pass ``z``)."""
    py = getattr(fn, "py_func", fn)
    if effect.state:
        sig = _RATE_SIGNATURE if what == "state_rate" else HOOK_SIGNATURE
        args = "(t, theta_u, omega_u, theta_l, omega_l, v, z, p, q)"
        ret = "one float" if what == "state_rate" else "two floats"
    else:
        sig, ret = _STATELESS_SIGNATURE, "two floats"
        args = "(t, theta_u, omega_u, theta_l, omega_l, v, p, q)"
    try:
        f = njit(sig, cache=True)(py)
    except Exception as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EffectError(
            f"{effect.source}: the {what} function of effect {effect.name!r} does not compile "
            f"with numba ({first}); it must take {args} and return {ret}, using only "
            "numpy/math (see docs/effects.md)"
        ) from None
    if effect.state and what != "state_rate":
        return f
    if what == "state_rate":

        @njit(HOOK_SIGNATURE)
        def rate(t, thu, wu, thl, wl, v, z, p, q):
            return f(t, thu, wu, thl, wl, v, z, p, q), 0.0

        return rate

    @njit(HOOK_SIGNATURE)
    def stateless(t, thu, wu, thl, wl, v, z, p, q):
        return f(t, thu, wu, thl, wl, v, p, q)

    return stateless


def _compile_hooks(user: tuple[Effect, ...]):
    if not user:
        return False, null_hook, null_hook, null_hook, -2
    key = tuple((e.source, e.name) for e in user)
    if key in _HOOK_CACHE:
        return _HOOK_CACHE[key]
    torques, shifts, rates = [], [], []
    reset = -2  # no state (-1: a state never reset; 0/1: reset when that disc sticks)
    off = 0
    for e in user:
        k = len(e.parameters) + (len(BORROWED) if e.replaces else 0)
        if e.torque is not None:
            torques.append((_compile_one(e, e.torque, "torque"), off, k))
        if e.friction_shift is not None:
            shifts.append((_compile_one(e, e.friction_shift, "friction_shift"), off, k))
        if e.state:
            rates.append((_compile_one(e, e.state_rate, "state_rate"), off, k))
            reset = {"": -1, "u": 0, "l": 1}[e.state_reset]
        off += k
    out = (True, _combine(torques), _combine(shifts), _combine(rates), reset)
    _HOOK_CACHE[key] = out
    return out


def _combine(parts):
    """One hook summing the given ``(hook, offset, size)`` parts over slices of ``q``."""
    if not parts:
        return null_hook
    if len(parts) == 1 and parts[0][1] == 0:
        f0, _, k0 = parts[0]

        @njit(HOOK_SIGNATURE)
        def one(t, thu, wu, thl, wl, v, z, p, q):
            return f0(t, thu, wu, thl, wl, v, z, p, q[:k0])

        return one
    head, rest = parts[0], parts[1:]
    f0, o0, k0 = head
    tail = _combine(rest)

    @njit(HOOK_SIGNATURE)
    def both(t, thu, wu, thl, wl, v, z, p, q):
        a, b = f0(t, thu, wu, thl, wl, v, z, p, q[o0 : o0 + k0])
        c, d = tail(t, thu, wu, thl, wl, v, z, p, q)
        return a + c, b + d

    return both
