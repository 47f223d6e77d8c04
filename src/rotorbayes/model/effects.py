"""The registry of physical effects: the catalogue, and effects users write themselves.

An effect is one :class:`Effect` entry: its name, one sentence of physics, its parameters
(unit, bounds, null value, typical start), the residual signature to look for, where it
applies, and the exact equivalences it has with other parameters of the model.  Switching
an effect on (``--add NAME`` or ``effects=[...]``) frees its parameters; an effect that is
off holds them at their null values, and a non-null value for one of them is refused.

Catalogue effects act through terms the compiled kernel already has (friction asymmetry,
Stribeck curve, string torsion and damping, motor input); ``kernel_term`` names them.
A **user effect** brings its own physics as two plain Python functions that numba
compiles, both with the signature

    f(t, theta_u, omega_u, theta_l, omega_l, v, p, q) -> (upper, lower)

* ``torque``: extra external torque on the upper and lower disc [N m];
* ``friction_shift``: an additive change of each disc's friction *levels* [N m] (Coulomb
  and static alike, so the static band moves too).

``v`` is the effective motor voltage [V], ``p`` the built-in parameter vector (positions
in :mod:`rotorbayes.kernel.layout`, e.g. ``p[TC_L]``) and ``q`` the effect's own
parameters in the order declared.  See ``docs/effects.md`` and
``examples/angle_friction.py``.
"""

from __future__ import annotations

import hashlib
import importlib.util
import math
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from ..kernel.layout import NAMES as BUILTIN_NAMES
from .info import Parameter
from .laws import lugre_rate, lugre_torque

#: Configurations with the lower disc.
LOWER = ("coupled", "brake")
ALL = ("upper", "coupled", "brake")


@dataclass(frozen=True)
class Resolution:
    """The smallest size of an effect that the data can tell from the model's other errors.

    A score test on thousands of samples detects effects far too small to mean anything
    (a delay of a thousandth of a sample is how the input's unknown shape between samples
    reads).  An effect is claimed only when its one-step size reaches its resolution:

    * ``kind="sample"``: the parameter [s] against ``factor`` sample intervals (below a
      tenth of a sample a delay cannot be told from how the input behaves between samples);
    * ``kind="torque"``: the torque the effect makes, ``|size| * per_unit``, against
      ``factor`` times the uncertainty of the friction level of ``disc`` ('u' or 'l'): the
      autocorrelation-robust (block) standard error of ``Tc_u`` / ``Tc_l`` at the fit.
      ``per_unit`` converts one unit of the parameter to N m: empty (already N m), a model
      parameter (``k_m``, ``k_alpha``), or an RMS speed of the fit's simulation
      (``omega_u``, ``omega_l``, ``dalpha`` = ``omega_l - omega_u``).
    """

    kind: str
    factor: float = 1.0
    disc: str = ""
    per_unit: str = ""
    words: str = ""

    def __post_init__(self):
        if self.kind not in ("sample", "torque"):
            raise ValueError(f"resolution kind {self.kind!r}: choose 'sample' or 'torque'")
        if self.kind == "torque" and self.disc not in ("u", "l"):
            raise ValueError("a torque resolution names its disc, 'u' or 'l'")


@dataclass(frozen=True)
class Effect:
    """One physical effect.

    Attributes
    ----------
    name : str
        Identifier used in the API and on the command line.
    physics : str
        What it models, in one sentence.
    parameters : tuple of Parameter
        The parameters it frees.
    signature : str
        What a residual looks like when the effect is missing.
    configs : tuple of str
        Configurations it applies to.
    motor : bool
        It acts through the motor or the upper disc (meaningless when the measured
        upper-disc angle drives the lower disc).
    per_experiment : bool
        Its parameter takes one value per experiment (the initial string torsion).
    kernel_term : str
        Where a catalogue effect's physics lives in the kernel.
    equivalences : tuple of str
        Exact equivalences with other parameters, in words.
    resolution : Resolution, optional
        What the data can resolve of it (the smallest size worth a claim); ``None``: only
        the size of its predicted fall of the error counts (user effects).
    full_kernel : bool
        Its physics lives only in the full kernel (built with hook functions): code that
        would slow every run if the plain kernel carried it (see
        :func:`rotorbayes.kernel.terms.full_kernel_only`).
    explains : tuple of str
        The missing-torque map's variables it can produce (``velocity``, ``direction``,
        ``torsion``, ``torsion_rate``, ``input``, ``input_rate``, ``input_history``; see
        :mod:`rotorbayes.diagnosis.torque`): a map that names only others speaks against
        it.
    torque, friction_shift : callable, optional
        A user effect's physics (see the module docstring).
    state : str
        The name of the effect's state variable (e.g. ``"heat"``); empty: no state.  A
        stateful effect's ``torque`` and ``friction_shift`` take the state ``z`` after
        ``v``; its ``state_rate`` gives ``dz/dt`` (a float) with the same arguments.  ``z``
        starts at 0 and is integrated with the rig's state (stick or slip).
    state_rate : callable, optional
        ``f(t, theta_u, omega_u, theta_l, omega_l, v, z, p, q) -> dz/dt``.
    state_reset : str
        ``"u"`` or ``"l"``: ``z`` is set to 0 whenever that disc starts to stick (e.g. a
        bristle deflection that a stop releases); empty: never.
    replaces : str
        ``"l"``: the effect carries the lower disc's whole dry friction (a dynamic friction
        law such as :data:`LUGRE`).  The kernel then gives that disc
        no Coulomb or static level (it never sticks: its velocity passes zero like any
        other value; the viscous part stays), and the effect's functions find the levels
        in ``q`` after its own parameters, as ``(Tc_l, dTc_l, Ts_l)`` (``Ts_l = Tc_l``
        without the Stribeck effect).  Empty: the switch model's friction stays.
    source : str
        Where a user effect was loaded from.
    inverted : callable, optional
        ``f(values) -> (str, dict)``: given a fit's parameter values (a mapping by name,
        the model's and the effect's), a sentence where they turn the effect into the
        opposite of its physics (a static friction level below the Coulomb one: a friction
        that rises with speed), and the model's own parameters that keep what it fits
        where it is harmless (the friction at standstill: ``Tc_l`` at ``Ts_l``); ``("",
        {})`` where it is not inverted.  A fall of the error an inverted effect gives is
        not a claim for it: it stands in for something else, whose missing torque shows at
        the fit's point with those values instead.  ``None``: it cannot invert.
    """

    name: str
    physics: str
    parameters: tuple[Parameter, ...]
    signature: str
    configs: tuple[str, ...] = ALL
    motor: bool = False
    per_experiment: bool = False
    kernel_term: str = ""
    equivalences: tuple[str, ...] = ()
    resolution: Resolution | None = None
    explains: tuple[str, ...] = ()
    full_kernel: bool = False
    torque: Callable | None = field(default=None, compare=False, repr=False)
    friction_shift: Callable | None = field(default=None, compare=False, repr=False)
    state: str = ""
    state_rate: Callable | None = field(default=None, compare=False, repr=False)
    state_reset: str = ""
    replaces: str = ""
    source: str = "catalogue"
    inverted: Callable | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        if not self.name.isidentifier():
            raise ValueError(f"effect name {self.name!r} must be a Python identifier")
        if not self.parameters:
            raise ValueError(f"effect {self.name!r} declares no parameters")
        bad = [c for c in self.configs if c not in ALL]
        if bad:
            raise ValueError(f"effect {self.name!r}: unknown configuration(s) {bad}")
        if bool(self.state) != (self.state_rate is not None):
            raise ValueError(
                f"effect {self.name!r}: a state needs its state_rate, and a "
                "state_rate its state's name"
            )
        if self.state_reset not in ("", "u", "l"):
            raise ValueError(f"effect {self.name!r}: state_reset must be '', 'u' or 'l'")
        if self.replaces not in ("", "l"):
            raise ValueError(
                f"effect {self.name!r}: replaces must be '' or 'l' (the lower disc's friction)"
            )
        if self.replaces and any(c not in LOWER for c in self.configs):
            raise ValueError(
                f"effect {self.name!r} replaces the lower disc's friction, so "
                f"its configs must be among {LOWER}"
            )
        object.__setattr__(self, "parameters", tuple(self.parameters))
        object.__setattr__(self, "configs", tuple(self.configs))

    @property
    def is_user(self) -> bool:
        """A user-defined effect (brings its own compiled physics)."""
        return (
            self.torque is not None
            or self.friction_shift is not None
            or self.state_rate is not None
        )

    def __reduce_ex__(self, protocol):
        # A user effect loaded from a file travels with the file's code and its SHA-256:
        # process and Dask workers need not have the file, and run exactly what was hashed.
        code = _FILE_CODE.get(self.source) if self.is_user else None
        if code is None:
            return object.__reduce_ex__(self, protocol)
        return (_shipped_effect, (self.source, self.name, code, _FILE_SHA[self.source]))

    @property
    def names(self) -> tuple[str, ...]:
        """Its parameter names."""
        return tuple(p.name for p in self.parameters)

    @property
    def switches(self) -> tuple[Parameter, ...]:
        """The parameters whose null value switches the effect off (not the nuisance ones)."""
        return tuple(p for p in self.parameters if not p.nuisance)

    def describe(self) -> str:
        """A few lines for listings: parameters with units, bounds and null values."""
        rows = [f"{self.name}  ({self.source}; {', '.join(self.configs)})", f"    {self.physics}"]
        for p in self.parameters:
            null = "= Tc_l" if math.isnan(p.null) else f"{p.null:g}"
            extra = ", nuisance (meaningless at the null)" if p.nuisance else ""
            rows.append(
                f"    {p.name:<11} [{p.unit}]  bounds [{p.lower:g}, {p.upper:g}], "
                f"null {null}{extra}: {p.description}"
            )
        if self.replaces:
            rows.append(
                "    replaces the lower disc's dry friction (Tc_l, dTc_l, Ts_l act "
                "through it; the disc never sticks)"
            )
        if self.state:
            reset = {
                "u": ", reset when the upper disc sticks",
                "l": ", reset when the lower disc sticks",
            }.get(self.state_reset, "")
            rows.append(f"    state: {self.state} (starts at 0{reset})")
        rows.append(f"    missing when: {self.signature}")
        for eq in self.equivalences:
            rows.append(f"    equivalence: {eq}")
        if self.resolution is not None:
            r = self.resolution
            what = (
                f"{r.factor:g} sample interval(s)"
                if r.kind == "sample"
                else f"{r.factor:g}x the robust standard error of Tc_{r.disc}"
            )
            rows.append(f"    claimed only from {what}: {r.words}")
        return "\n".join(rows)


class Equivalence(str):
    """An exact equivalence: its words (the string itself) and what a tool can act on.

    It is a ``str``, so every listing, JSON file and message that shows an effect's
    ``equivalences`` shows its words; :mod:`rotorbayes.design` reads the attributes.

    Attributes
    ----------
    effects : tuple of str
        The effects it ties (each can stand in for the other).
    also_free : tuple of str
        Parameters that must be free for the tie to be exact (e.g. ``dTc_u``: the upper
        disc takes the string's reaction); parameters of the motor and the upper disc do not
        count when the measured upper angle drives the lower disc.
    scope : str
        Where it holds, in words ("any single experiment").
    max_experiments : int
        It holds for data of at most this many experiments (0: any number).
    input_can_break : bool
        Whether some input (within the scope) can tell the tied effects apart.
    procedure : str
        What separates them when no input can.
    """

    effects: tuple[str, ...]
    also_free: tuple[str, ...]
    scope: str
    max_experiments: int
    input_can_break: bool
    procedure: str

    def __new__(
        cls,
        words: str,
        *,
        effects=(),
        also_free=(),
        scope: str = "",
        max_experiments: int = 0,
        input_can_break: bool = True,
        procedure: str = "",
    ):
        obj = super().__new__(cls, words)
        obj.effects = tuple(effects)
        obj.also_free = tuple(also_free)
        obj.scope = scope
        obj.max_experiments = int(max_experiments)
        obj.input_can_break = bool(input_can_break)
        obj.procedure = procedure
        return obj

    def holds_for(self, n_experiments: int) -> bool:
        """Whether it holds for data of ``n_experiments`` experiments."""
        return self.max_experiments <= 0 or n_experiments <= self.max_experiments

    def __reduce__(self):  # pickled with its attributes (process and Dask workers)
        return (
            _equivalence,
            (
                str(self),
                self.effects,
                self.also_free,
                self.scope,
                self.max_experiments,
                self.input_can_break,
                self.procedure,
            ),
        )


def _equivalence(words, effects, also_free, scope, max_experiments, input_can_break, procedure):
    return Equivalence(
        words,
        effects=effects,
        also_free=also_free,
        scope=scope,
        max_experiments=max_experiments,
        input_can_break=input_can_break,
        procedure=procedure,
    )


#: A pre-wound string against a lower friction asymmetry (DESIGN.md, "one exact tie").
_TORSION_TIE = Equivalence(
    "in any single experiment a pre-wound string is a constant torque k_alpha*alpha0 on "
    "both discs, i.e. a shift of both discs' friction levels: initial_torsion cannot be "
    "told from lower_asymmetric_coulomb (with dTc_u free) by any input",
    effects=("initial_torsion", "lower_asymmetric_coulomb"),
    also_free=("dTc_u",),
    scope="any single experiment",
    max_experiments=1,
    input_can_break=False,
    procedure=(
        "unwind or re-zero the string (so that it starts with a torsion different from the "
        "first experiment's, ideally none), run a second experiment (the same input will "
        "do), and fit both experiments together with one alpha0 each (rotorbayes fit "
        "--model ... first.csv second.csv --add lower_asymmetric_coulomb: several "
        "experiments get alpha0[0], alpha0[1]). A friction asymmetry is the same in both "
        "experiments, a pre-wound string's torque is not: alpha0s that differ by the "
        "unwinding say the string was wound; the part common to both stays tied to dTc_l "
        "unless one torsion is known (an unwound string's is 0)"
    ),
)


def _p(name, unit, lo, hi, null, desc, start=math.nan, nuisance=False) -> Parameter:
    return Parameter(name, unit, lo, hi, null, desc, start, nuisance)


def _stribeck_inverted(values) -> tuple[str, dict[str, float]]:
    """lower_stribeck's parameters as thesis eqs. 4.11-4.14 write them allow a static level
    below the Coulomb one: the fitted friction then rises with speed from standstill
    (``Tc_l + (Ts_l - Tc_l) exp(-(w/ws_l)^delta_l)`` grows like ``(w/ws_l)^delta_l``).
    Measured: a quadratic air drag on the lower disc (reference data) was taken up so, Ts_l
    0.0274 (the true Coulomb level) below Tc_l 0.63, 697x -> 1.28x the floor on the
    estimation run and 36.6x on the validation run."""
    ts, tc = values.get("Ts_l", math.nan), values.get("Tc_l", math.nan)
    if not (math.isfinite(ts) and math.isfinite(tc)) or ts >= tc - 1e-3 * abs(tc):
        return "", {}
    return (
        f"Ts_l = {ts:.4g} below Tc_l = {tc:.4g} N m: a friction that rises with speed from "
        "standstill, the opposite of a Stribeck peak"
    ), {"Tc_l": ts}


_CATALOGUE: tuple[Effect, ...] = (
    Effect(
        "upper_asymmetric_coulomb",
        "Coulomb friction of the upper disc differs between the two directions (eq. 4.2).",
        (_p("dTc_u", "N m", -1.0, 1.0, 0.0, "upper Coulomb asymmetry (+ for positive slip)"),),
        "theta_u residual ramps one way in positive and the other way in negative slip",
        motor=True,
        kernel_term="friction.slip_torque (dTc), terms.bands",
        equivalences=(
            "with Coulomb + viscous upper friction, a motor voltage offset u_offset is exactly "
            "a change of dTc_u by -k_m*u_offset (a constant torque shifts the static band and "
            "both slip levels alike)",
        ),
        resolution=Resolution(
            "torque",
            1.0,
            "u",
            "",
            "an asymmetry below the upper friction level's uncertainty",
        ),
        explains=("direction", "velocity"),
    ),
    Effect(
        "upper_asymmetric_viscous",
        "viscous friction of the upper disc differs between the two directions (eq. 4.3).",
        (_p("db_u", "N m s/rad", -5.0, 5.0, 0.0, "upper viscous asymmetry"),),
        "theta_u residual grows with |omega_u|, with opposite sign per direction",
        motor=True,
        kernel_term="friction.slip_torque (db)",
        resolution=Resolution(
            "torque",
            1.0,
            "u",
            "omega_u",
            "an asymmetry whose torque at the RMS speed is below the upper friction"
            " level's uncertainty",
        ),
        explains=("direction", "velocity"),
    ),
    Effect(
        "lower_asymmetric_coulomb",
        "Coulomb friction of the lower disc differs between the two directions (§5.2.3).",
        (_p("dTc_l", "N m", -0.5, 0.5, 0.0, "lower Coulomb asymmetry (+ for positive slip)"),),
        "residual of theta_l drifts one way in positive slip and the other in negative "
        "slip; the error grows with each reversal",
        configs=LOWER,
        kernel_term="friction.slip_torque (dTc), terms.bands",
        equivalences=(
            "a common shift of every alpha0 is absorbed by dTc_l and dTc_u on estimation "
            "data (a constant string torque acts like a friction asymmetry); validation "
            "data expose it",
            _TORSION_TIE,
        ),
        resolution=Resolution(
            "torque",
            1.0,
            "l",
            "",
            "an asymmetry below the lower friction level's uncertainty",
        ),
        explains=("direction", "velocity"),
    ),
    Effect(
        "lower_asymmetric_viscous",
        "viscous friction of the lower disc differs between the two directions (eq. 5.18).",
        (_p("db_l", "N m s/rad", -0.5, 0.5, 0.0, "lower viscous asymmetry"),),
        "residual correlates with |omega_l| differently per direction of rotation",
        configs=LOWER,
        kernel_term="friction.slip_torque (db)",
        resolution=Resolution(
            "torque",
            1.0,
            "l",
            "omega_l",
            "an asymmetry whose torque at the RMS speed is below the lower friction"
            " level's uncertainty",
        ),
        explains=("direction", "velocity"),
    ),
    Effect(
        "lower_stribeck",
        "static friction above the Coulomb level, decaying with speed (negative damping, "
        "stick-slip; eqs. 4.11-4.14).",
        (
            _p("Ts_l", "N m", 0.0, 3.0, math.nan, "lower static friction level (Stribeck)"),
            _p("ws_l", "rad/s", 1e-3, 50.0, 1.0, "lower Stribeck velocity", 1.0, True),
            _p("delta_l", "-", 0.2, 5.0, 2.0, "lower Stribeck shape exponent", 2.0, True),
        ),
        "stick phases last longer than simulated; large errors right after break-away",
        configs=LOWER,
        kernel_term="friction.stribeck, terms.bands (static band from Ts_l)",
        resolution=Resolution(
            "torque",
            1.0,
            "l",
            "",
            "a static level above the Coulomb level by less than that level's uncertainty",
        ),
        explains=("velocity", "direction"),
        inverted=_stribeck_inverted,
    ),
    Effect(
        "upper_stribeck",
        "static friction of the upper disc above its Coulomb level, decaying with speed: "
        "the lower disc's Stribeck law (eqs. 4.11-4.14) on the upper disc, its static "
        "level Tc_u + dTs_u.",
        (
            _p(
                "dTs_u",
                "N m",
                0.0,
                3.0,
                0.0,
                "upper static friction above the Coulomb level (Stribeck excess)",
                0.1,
            ),
            _p("ws_u", "rad/s", 1e-3, 50.0, 1.0, "upper Stribeck velocity", 1.0, True),
            _p("delta_u", "-", 0.2, 5.0, 2.0, "upper Stribeck shape exponent", 2.0, True),
        ),
        "the upper disc stays at rest longer than simulated and then jumps; large theta_u "
        "errors right after each break-away and at slow speeds",
        motor=True,
        kernel_term="friction.slip_torque (Stribeck part), terms.bands (static band from "
        "Tc_u + dTs_u), terms.stribeck_step",
        resolution=Resolution(
            "torque",
            1.0,
            "u",
            "",
            "a static level above the upper Coulomb level by less than that level's uncertainty",
        ),
        explains=("velocity", "direction"),
        full_kernel=True,
    ),
    Effect(
        "initial_torsion",
        "the string is pre-wound at the start of an experiment, invisible to the zeroed "
        "encoders (§5.3.2); one value per experiment.",
        (_p("alpha0", "rad", -10.0, 10.0, 0.0, "initial string torsion (per experiment)"),),
        "repeats of the same input differ; the lower disc moves at t = 0 or breaks away "
        "earlier in one direction",
        configs=LOWER,
        per_experiment=True,
        kernel_term="terms.torques (k_alpha * (theta_l - theta_u + alpha0))",
        equivalences=(
            "a common shift of every alpha0 is absorbed by dTc_l and dTc_u on estimation data",
            _TORSION_TIE,
        ),
        resolution=Resolution(
            "torque",
            1.0,
            "l",
            "k_alpha",
            "a pre-wound torque k_alpha*alpha0 below the lower friction level's uncertainty",
        ),
        explains=("torsion", "direction", "velocity"),
    ),
    Effect(
        "string_damping",
        "viscous damping in the torsion of the string (§2.3 neglects it).",
        (_p("c_alpha", "N m s/rad", 0.0, 0.1, 0.0, "viscous damping in the string", 1e-3),),
        "simulated string oscillations decay too slowly; residual at the string's natural "
        "frequency",
        configs=LOWER,
        kernel_term="terms.torques (c_alpha * (omega_l - omega_u))",
        resolution=Resolution(
            "torque",
            1.0,
            "l",
            "dalpha",
            "a damping torque at the RMS twist rate below the lower friction level's uncertainty",
        ),
        explains=("torsion_rate", "torsion", "velocity"),
    ),
    Effect(
        "voltage_offset",
        "an offset in the amplifier's output voltage.",
        (_p("u_offset", "V", -0.5, 0.5, 0.0, "motor voltage offset"),),
        "theta_u residual drifts linearly while u is near zero",
        motor=True,
        kernel_term="terms.drive",
        equivalences=(
            "with Coulomb + viscous upper friction, u_offset is exactly a change of dTc_u by "
            "-k_m*u_offset (without a dead zone)",
        ),
        resolution=Resolution(
            "torque",
            1.0,
            "u",
            "k_m",
            "a motor torque k_m*u_offset below the upper friction level's uncertainty",
        ),
        explains=("input", "direction"),
    ),
    Effect(
        "input_delay",
        "a time delay between the commanded and the applied voltage.",
        (_p("t_delay", "s", 0.0, 0.1, 0.0, "input time delay", 5e-3),),
        "residual proportional to the derivative of the response; cross-correlation with u "
        "peaks at a positive lag",
        motor=True,
        kernel_term="terms.drive, terms.delay_samples (the step grid follows the delay)",
        resolution=Resolution(
            "sample",
            0.1,
            "",
            "",
            "a delay below a tenth of a sample cannot be told from how the input "
            "behaves between samples",
        ),
        explains=("input_rate", "input", "input_history"),
    ),
    Effect(
        "motor_deadzone",
        "the motor produces no torque while |u| is below a threshold.",
        (_p("u_deadzone", "V", 0.0, 1.0, 0.0, "motor dead zone half-width", 0.05),),
        "simulated upper disc moves where the measured one stays still at small |u|",
        motor=True,
        kernel_term="terms.drive, terms.next_kink (dead-zone edges)",
        resolution=Resolution(
            "torque",
            1.0,
            "u",
            "k_m",
            "a dead zone whose motor torque k_m*u_deadzone is below the upper "
            "friction level's uncertainty",
        ),
        explains=("input", "velocity"),
    ),
    Effect(
        "drive_lag",
        "the drive's electrical dynamics (amplifier and motor current): the voltage that "
        "makes the motor's torque follows the command through a first-order lag; for "
        "inputs slower than 1/tau_drive it acts like a delay of tau_drive, over fast "
        "transitions it smooths them as a delay does not.",
        (_p("tau_drive", "s", 0.0, 0.1, 0.0, "time constant of the drive's lag", 5e-3),),
        "theta_u residual spikes of alternating sign at every fast input transition, "
        "which an input delay reduces but does not remove",
        motor=True,
        kernel_term="terms.lagged, terms.input_source (the lag's exact solution for the "
        "interpolated input: no state, no stiffness)",
        resolution=Resolution(
            "sample",
            0.1,
            "",
            "",
            "a lag below a tenth of a sample cannot be told from how the input behaves "
            "between samples",
        ),
        explains=("input_rate", "input_history", "input"),
        full_kernel=True,
    ),
)

#: The catalogue of built-in effects by name.
CATALOGUE: dict[str, Effect] = {e.name: e for e in _CATALOGUE}


#: LuGre dynamic friction on the lower disc; its equations are in :mod:`rotorbayes.model.laws`.
LUGRE = Effect(
    name="lugre",
    physics="LuGre dynamic friction on the lower disc: the contact's bristles deflect "
    "before it slides (pre-sliding, a spring of stiffness sigma0_l), so the disc creeps "
    "under a torque below the static level instead of sticking, and the friction lags "
    "the velocity (frictional memory); steady sliding follows the switch model's "
    "Stribeck curve.",
    parameters=(
        Parameter(
            "sigma0_l",
            "N m/rad",
            5.0,
            700.0,
            700.0,
            "bristle stiffness (pre-sliding displacement Ts_l/sigma0_l)",
            start=300.0,
        ),
        Parameter("sigma1_l", "N m s/rad", 0.0, 10.0, 0.0, "bristle damping", start=0.5),
    ),
    signature="theta_l residual at every lower stop and break-away (the disc creeps by "
    "about Ts_l/sigma0_l where the model holds it still), with the residual's sign "
    "following the torque's history",
    configs=("coupled", "brake"),
    kernel_term="the effect state (terms.state_step substeps the stiff bristles); the "
    "lower disc's levels reach the law through q (Effect.replaces)",
    explains=("velocity", "direction", "torsion", "input_history"),
    torque=lugre_torque,
    state="bristle",
    state_rate=lugre_rate,
    replaces="l",
)

#: Friction laws shipped to hold against the switch model, by name (``--add NAME`` like a
#: catalogue effect; not nested in the model, so the diagnosis never tries them).
LAWS: dict[str, Effect] = {LUGRE.name: LUGRE}


class EffectError(ValueError):
    """An effect name, file or definition is invalid."""


def get(name: str) -> Effect:
    """Look a catalogue effect or a shipped friction law (:data:`LAWS`) up by name, with
    an error that lists both."""
    if name in CATALOGUE:
        return CATALOGUE[name]
    if name in LAWS:
        return LAWS[name]
    raise EffectError(
        f"unknown effect {name!r}; the catalogue has: {', '.join(CATALOGUE)}; the friction "
        f"laws: {', '.join(LAWS)}; a user effect is given as FILE.py:NAME (see "
        "docs/effects.md)"
    )


def effect_of(parameter: str) -> Effect | None:
    """The catalogue effect a built-in parameter belongs to (``None`` for base ones)."""
    for e in CATALOGUE.values():
        if parameter in e.names:
            return e
    return None


def typical_start(effect: Effect, values: dict[str, float]) -> dict[str, float]:
    """Start values for an effect's parameters that sit at their null value.

    At the null, a switch parameter of an effect is often on a bound (damping, delay, dead
    zone >= 0) and its nuisance parameters have no gradient; the declared typical start
    moves them off it.  The static level ``Ts_l`` starts at twice the Coulomb level.
    """
    out = {}
    for p in effect.parameters:
        v = values.get(p.name, p.null)
        at_null = (math.isnan(v) and math.isnan(p.null)) or v == p.null
        if p.name == "Ts_l":
            at_null = math.isnan(v) or v == values.get("Tc_l")
            if at_null:
                out["Ts_l"] = 2.0 * values["Tc_l"] if values.get("Tc_l") else 0.05
            continue
        if at_null and not math.isnan(p.start):
            out[p.name] = p.start
    return out


_LOADED: dict[tuple[str, str], Effect] = {}
#: SHA-256 of each effect file as it was imported (results record it; see file_sha256).
_FILE_SHA: dict[str, str] = {}
#: The bytes of each effect file as it was imported (sent with the effect to workers).
_FILE_CODE: dict[str, bytes] = {}


def _shipped_effect(path: str, name: str, code: bytes, sha: str) -> Effect:
    """A user effect unpickled in a worker: its file's code, checked against the SHA-256
    the sending process recorded, run under the file's path (the file itself need not
    exist here)."""
    if hashlib.sha256(code).hexdigest() != sha:
        raise EffectError(
            f"{path}: the effect file's code arrived altered (its SHA-256 "
            f"differs from the recorded {sha[:12]}...); run the command again"
        )
    old = _FILE_SHA.get(str(Path(path)))
    if old is not None and old != sha:
        raise EffectError(
            f"{path}: this worker already runs another version of the effect file (SHA-256 "
            f"{old[:12]}..., the task's is {sha[:12]}...); restart the workers"
        )
    return load_user_effect(f"{path}:{name}", code=code)


def file_sha256(path: str | Path) -> str | None:
    """The SHA-256 of an effect file as this process imported it (None if not imported)."""
    return _FILE_SHA.get(str(Path(path).expanduser().resolve()))


def load_user_effect(spec: str, *, code: bytes | None = None) -> Effect:
    """Import a user effect from ``'path/to/file.py:NAME'``.

    The file is the user's own Python code, imported like a configuration file (nothing
    is unpickled) -- it runs, so an effect file, like a script, must come from someone you
    trust.  ``NAME`` is the variable holding an :class:`Effect` with a ``torque`` and/or
    ``friction_shift`` function (or, when no variable has that name, the effect whose
    ``name`` it is).  The functions are compiled by numba when a model uses them (see
    :mod:`rotorbayes.model.configurations`).  The effect's ``source`` is the file's
    absolute path; the SHA-256 of the bytes that were run is kept (:func:`file_sha256`).
    ``code``: the file's bytes, given (a worker gets them with the effect), not read.
    """
    path_s, sep, name = spec.rpartition(":")
    if not sep or not path_s.endswith(".py") or not name:
        raise EffectError(f"{spec!r}: a user effect is given as FILE.py:NAME")
    path = Path(path_s).expanduser().resolve()
    key = (str(path), name)
    if key in _LOADED:
        return _LOADED[key]
    if code is None and not path.is_file():
        raise EffectError(f"{path_s}: effect file not found")
    mod_name = "rotorbayes_user_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
    if mod_name in sys.modules:
        module = sys.modules[mod_name]
    else:
        try:
            code_bytes = path.read_bytes() if code is None else bytes(code)
        except OSError as exc:
            raise EffectError(f"{path_s}: cannot read the effect file ({exc.strerror})") from None
        spec_obj = importlib.util.spec_from_file_location(mod_name, path)
        module = importlib.util.module_from_spec(spec_obj)
        sys.modules[mod_name] = module
        try:
            # Run exactly the bytes that are hashed (not a second read of the file).
            exec(compile(code_bytes, str(path), "exec"), module.__dict__)  # noqa: S102
        except Exception as exc:
            del sys.modules[mod_name]
            raise EffectError(
                f"{path_s}: importing the effect file failed: {type(exc).__name__}: {exc}"
            ) from None
        _FILE_SHA[str(path)] = hashlib.sha256(code_bytes).hexdigest()
        _FILE_CODE[str(path)] = code_bytes
    eff = getattr(module, name, None)
    if not isinstance(eff, Effect):
        # A result records the effect's own name, which may differ from its variable's.
        by_name = [v for v in vars(module).values() if isinstance(v, Effect) and v.name == name]
        eff = by_name[0] if by_name else eff
    if eff is None:
        found = [k for k, v in vars(module).items() if isinstance(v, Effect)]
        raise EffectError(
            f"{path_s}: defines no effect {name!r}"
            + (f"; it defines: {', '.join(found)}" if found else "; it defines no Effect at all")
        )
    if not isinstance(eff, Effect) or not eff.is_user:
        raise EffectError(
            f"{path_s}:{name} must be a rotorbayes Effect with a torque, friction_shift or "
            "state_rate "
            "function (see docs/effects.md)"
        )
    if eff.name in CATALOGUE:
        raise EffectError(f"{path_s}:{name}: the name {eff.name!r} is taken by the catalogue")
    # The built-in parameters are the kernel's (the table in .parameters is built from
    # them and this catalogue).
    clash = [p.name for p in eff.parameters if p.name in BUILTIN_NAMES]
    if clash:
        raise EffectError(
            f"{path_s}:{name}: parameter name(s) {', '.join(clash)} are built-in parameters; "
            "choose other names"
        )
    eff = Effect(**{**eff.__dict__, "source": str(path)})
    _LOADED[key] = eff
    return eff


def resolve(specs: Iterable[str | Effect]) -> tuple[Effect, ...]:
    """Catalogue names, ``FILE.py:NAME`` specs or :class:`Effect` objects -> effects."""
    out: list[Effect] = []
    for s in specs:
        if isinstance(s, Effect):
            e = s
        elif ":" in s and s.rpartition(":")[0].endswith(".py"):
            e = load_user_effect(s)
        else:
            e = get(s)
        if any(o.name == e.name for o in out):
            continue
        out.append(e)
    return tuple(out)
