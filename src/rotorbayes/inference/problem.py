"""An estimation problem: a model, experiments, free parameters and fitted channels.

A :class:`Problem` maps a free-parameter vector ``x`` to

* :meth:`~Problem.simulate` — a :class:`~rotorbayes.Simulation` per experiment, each with
  its status;
* :meth:`~Problem.evaluate` — the residual vector and the status of every experiment
  (failed experiments give ``nan`` residuals: least squares may choose a penalty, a
  likelihood ``-inf``; nothing turns a failure into a plausible number silently);
* :meth:`~Problem.jacobian` — sensitivities to *any* parameters: the free ones, fixed ones,
  and those of effects that are off (evaluated at their null value, one-sided where the
  null is a bound) — what a score test for a missing effect needs.

The residual is ``r = concat over experiments e and channels c of w_c (y_ec - yhat_ec)``
(thesis eqs. 4.4, 4.10, 5.19).  ``alpha0`` takes one value per experiment
(``alpha0[0]``, ``alpha0[1]``, ...; thesis §5.3.2).  A validation experiment has its own
torsion too: :meth:`Problem.validation_params` decides it (fitted on that run alone, given,
or the model's fixed value), and every command that evaluates validation data goes through
it or through the value it stored.

The free parameters themselves -- their names, bounds and the map between the vector ``x``
and parameter values -- are a :class:`~rotorbayes.inference.parameter_map.ParameterMap`
the problem holds (:attr:`Problem.parameters`).
"""

from __future__ import annotations

import math
import threading
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..io.measurements import Experiment
from ..kernel import layout as _layout
from ..kernel.triangle import difference_quotients
from ..model import effects as _effects
from ..model.configurations import Model
from ..model.parameters import INFO, ParameterError, resolve, unknown_name_message
from ..model.simulate import DEFAULT_STEP, Simulation, Simulator, check_step
from .parallel import claim_kernel_threads
from .parameter_map import FillTemplate, ParameterMap, local_name

CHANNELS = ("theta_u", "theta_l")

#: How :meth:`Problem.jacobian` differentiates unless told: ``'differences'`` (finite
#: differences, every model), or ``'sensitivity'`` (the kernel's forward sensitivities where
#: the kernel has them, see :meth:`Problem.sensitivity_support`; differences elsewhere).
#: Differences stay the default while the sensitivities cost 8 to 9 residual
#: evaluations against differences' 12 or more on a 30 s brake Jacobian (not yet the 3
#: aimed at), leave every command measured end to end about as fast as before
#: (benchmarks/bench_end_to_end.py: the Jacobian is not what they wait for), add 33 s to a
#: cold start, and differ from the differences of the computed residuals where Stribeck
#: substeps move with the parameters (benchmarks/bench_sensitivity.py).
JACOBIAN_DEFAULT = "differences"


class SensitivityFallback(UserWarning):
    """:meth:`Problem.jacobian` was asked for sensitivities and used finite differences
    (the message says why)."""


#: How a validation experiment's initial torsion was chosen (:attr:`ValidationTorsion.how`).
FITTED_ALONE = "fitted on that run alone"
GIVEN = "given"
FIXED = "fixed"
#: Points of the scan that starts the nuisance fit of a validation run's alpha0.
VALIDATION_SCAN = 41
#: Range of a channel's weight.  Weights set how much one channel counts against the other
#: (the thesis weighs theta_u by 0.1); beyond a factor 1e4 either way a channel is ignored
#: in effect, or its squared residuals overflow (1e308) or vanish (1e-308) in the numbers
#: of the fit and its standard errors.  To leave a channel out, fit without it (channels).
MIN_WEIGHT, MAX_WEIGHT = 1e-4, 1e4
#: Residual [rad] for a parameter set the integrator rejects during that nuisance fit (as
#: ``least_squares.FAIL_RESIDUAL`` in a fit: a finite number the optimiser can leave).
_FAILED = 1e3


#: Parameters of the motor and the upper disc's friction: fitted from theta_u.
UPPER_PARAMETERS = (
    "k_m",
    "J_u",
    "Tc_u",
    "dTc_u",
    "b_u",
    "db_u",
    "u_offset",
    "u_deadzone",
    "dTs_u",
    "ws_u",
    "delta_u",
    "tau_drive",
)


def checked_experiments(experiments) -> list[Experiment]:
    """``experiments`` as a list of :class:`~rotorbayes.Experiment`; :class:`ValueError`
    naming the bad entry otherwise (a path is a file still to load)."""
    hint = "load each file with rotorbayes.load_experiment(path) first"
    if isinstance(experiments, Experiment):
        return [experiments]
    if isinstance(experiments, str | Path):
        raise ValueError(
            f"experiments is the path {str(experiments)!r}, not an Experiment; "
            f"{hint}: [rotorbayes.load_experiment({str(experiments)!r})]"
        )
    if experiments is None or isinstance(experiments, Mapping):
        raise ValueError(
            f"experiments is {experiments!r}; give a list of Experiment objects ({hint})"
        )
    try:
        out = list(experiments)
    except TypeError:
        raise ValueError(
            f"experiments is a {type(experiments).__name__}; give a list of "
            f"Experiment objects ({hint})"
        ) from None
    for i, ex in enumerate(out):
        if isinstance(ex, str | Path):
            raise ValueError(
                f"experiments[{i}] is the path {str(ex)!r}, not an Experiment; "
                f"{hint}: rotorbayes.load_experiment({str(ex)!r})"
            )
        if not isinstance(ex, Experiment):
            raise ValueError(
                f"experiments[{i}] is a {type(ex).__name__}, not an Experiment; {hint}"
            )
    return out


def default_channels(config: str, prescribed_upper: bool, free: Sequence[str]) -> tuple:
    """The channels a fit uses unless told: the upper configuration has only theta_u;
    otherwise theta_l, and theta_u as well whenever a parameter of the motor or the upper
    disc is free (the measured upper angle is what determines them)."""
    if config == "upper":
        return ("theta_u",)
    if not prescribed_upper and any(local_name(n)[0] in UPPER_PARAMETERS for n in free):
        return ("theta_u", "theta_l")
    return ("theta_l",)


def model_of(
    model: Model | str, effects: Iterable[str], prescribed_upper: bool, n_experiments: int
) -> Model:
    """The :class:`~rotorbayes.Model` of a problem: ``model`` itself, or the configuration
    named ``model`` with ``effects`` on (and ``initial_torsion`` too for several
    experiments on the lower disc: each starts with its own string torsion, thesis
    §5.3.2)."""
    if isinstance(model, Model):
        if tuple(effects):
            raise ValueError("give the effects with the Model, not to the Problem")
        return model
    effects = list(effects)
    if n_experiments > 1 and model != "upper" and "initial_torsion" not in effects:
        effects.append("initial_torsion")
    return Model(model, effects, prescribed_upper=prescribed_upper)


def checked_weights(channels: Sequence[str], given) -> dict[str, float]:
    """The weight of every fitted channel (default 1), each a number within
    [:data:`MIN_WEIGHT`, :data:`MAX_WEIGHT`]; a weight for a channel that does not exist is
    refused."""
    if given is not None and not isinstance(given, Mapping):
        raise ValueError(
            f"weights = {given!r}: give a mapping of channel to weight, "
            "e.g. {'theta_u': 0.1, 'theta_l': 1.0}"
        )
    given = dict(given or {})
    for c in given:
        if c not in CHANNELS:
            raise ValueError(f"weights: unknown channel {c!r}; choose from {', '.join(CHANNELS)}")
    out = {}
    for c in channels:
        w = given.get(c, 1.0)
        if isinstance(w, bool) or not isinstance(w, int | float | np.number):
            raise ValueError(
                f"the weight of channel {c} is {w!r}, not a number; give a "
                f"number between {MIN_WEIGHT:g} and {MAX_WEIGHT:g}"
            )
        w = float(w)
        if not (w > 0 and math.isfinite(w)):
            raise ValueError(f"the weight of channel {c} is {w}; it must be > 0")
        if not MIN_WEIGHT <= w <= MAX_WEIGHT:
            raise ValueError(
                f"the weight of channel {c} is {w:g}; give a weight between "
                f"{MIN_WEIGHT:g} and {MAX_WEIGHT:g} (weights set how much one channel "
                "counts against the other; beyond that range a channel is ignored in "
                "effect or its squared residuals overflow; to leave a channel out, fit "
                "without it)"
            )
        out[c] = w
    return out


def base_values(m: Model, base) -> dict[str, float]:
    """Every parameter's value from ``base`` (a mapping, a named set, a TOML file or None:
    the configuration's default set): values not given come from the default set, those
    of effects that are off go to their null value."""
    if isinstance(base, Mapping):
        for k, v in base.items():
            if isinstance(v, bool) or not isinstance(v, int | float | np.number):
                raise ParameterError(
                    f"base: {k} = {v!r} is not a number; give each "
                    "value as a number (in the parameter's unit)"
                )
        builtin = {k: v for k, v in base.items() if k in INFO}
        user = {k: float(v) for k, v in base.items() if k not in INFO}
        for k in user:
            if k not in m.info:
                raise ParameterError(unknown_name_message(k))
        full = resolve(builtin, config=m.config) if set(builtin) != set(INFO) else dict(builtin)
        full.update(user)
        given = set(base)
    else:
        full = resolve(base, config=m.config)
        given = set(INFO) if base is not None else set()
    # Values the user did not give come from the configuration's default set; those of
    # effects that are off here (e.g. --without upper_asymmetric_coulomb) go to null.
    for n in m.off:
        if n not in given:
            full[n] = INFO[n].null
    full = m.complete(full)
    m.check_off(full, where="start/base values")
    return full


def free_names(m: Model, free: Sequence[str] | None, fixed: Sequence[str]) -> list[str]:
    """The free parameters as given (``alpha0`` once), checked against the model ``m``;
    ``free`` None: the configuration's fitted parameters and those of the effects it fits
    and of every added one, less ``fixed``."""
    if free is None:
        cfg = m.configuration
        out = [] if m.prescribed_upper and m.config == "upper" else list(cfg.fitted)
        if m.prescribed_upper:
            out = [n for n in out if n not in ("k_m", "Tc_u", "b_u", "J_u")]
        fitted_effects = [
            e for e in m.base_effects if e.name in cfg.fitted_effects
        ] + list(m.added)  # fmt: skip
        for eff in fitted_effects:
            out += [p for p in eff.names if p not in out]
        if m.prescribed_upper:
            out = [n for n in out if n not in UPPER_PARAMETERS]
        out = [n for n in out if n not in fixed]
    else:
        out = list(free)
        for n in fixed:
            if n in out:
                raise ParameterError(
                    f"{n} is both fixed and free; remove it from one of the two lists"
                )
    for n in out:
        b, _ = local_name(n)
        if b not in m.info:
            raise ParameterError("free parameters: " + unknown_name_message(b))
        if b not in m.active:
            e = _effects.effect_of(b)
            if e is not None:
                raise ParameterError(
                    f"{b} belongs to the effect {e.name!r}, which is off in this "
                    f"{m.config} model, so freeing it would change nothing; switch "
                    f"the effect on (--add {e.name}) or remove {b} from the free list"
                )
            raise ParameterError(
                f"{b} does not enter the {m.config} configuration"
                + (" with the measured theta_u as input" if m.prescribed_upper else "")
                + "; remove it from the free list"
            )
    return out


@dataclass
class Evaluation:
    """Residuals at one point and the integrator's status per experiment."""

    residuals: np.ndarray
    status: np.ndarray

    @property
    def ok(self) -> bool:
        return bool(np.all(self.status == _layout.OK))

    def reasons(self) -> list[str]:
        """The integrator's words for every failed experiment."""
        return [
            f"experiment {i}: {_layout.STATUS_MESSAGES[int(s)]}"
            for i, s in enumerate(self.status)
            if s != _layout.OK
        ]


@dataclass(frozen=True)
class ValidationTorsion:
    """How a validation experiment's initial string torsion ``alpha0`` [rad] was chosen
    (:meth:`Problem.validation_params`): ``how`` is :data:`FITTED_ALONE`, :data:`GIVEN` or
    :data:`FIXED`."""

    experiment: str
    value: float
    how: str
    file: str | None = None

    def words(self, ratio: float | None = None) -> str:
        """One line a user reads under the fit; ``ratio``: the worst validation RMS/floor,
        which, far above the floor, makes a fitted torsion the misfit's (a study far from
        the floor reported a fitted 0.1994 rad for a run whose string was not wound)."""
        if self.how == FITTED_ALONE:
            far = (
                f"; the model is {ratio:.3g}x the floor on the validation data, so this is "
                "what its misfit needs, not the string's torsion"
                if ratio is not None and math.isfinite(ratio) and ratio > 3.0
                else ""
            )
            return (
                f"validation {self.experiment}: its initial torsion alpha0 fitted on that "
                f"run alone (a nuisance parameter, every other parameter at the fit): "
                f"{self.value:.4g} rad{far}"
            )
        if self.how == GIVEN:
            return (
                f"validation {self.experiment}: its initial torsion alpha0 = "
                f"{self.value:.6g} rad, given"
            )
        return (
            f"validation {self.experiment}: alpha0 = {self.value:g} rad, the model's fixed "
            "value (initial_torsion is off: no pre-wound string)"
        )

    def as_dict(self) -> dict:
        return {
            "experiment": self.experiment,
            "file": self.file,
            "value": self.value,
            "how": self.how,
        }

    @classmethod
    def from_dict(
        cls, d: Mapping, *, experiment: str = "validation data", file: str | None = None
    ) -> ValidationTorsion:
        """A record as :meth:`as_dict` wrote it (fit.json's ``validation_alpha0``);
        ``ValueError`` naming what is wrong when it is not one."""
        v, how = d.get("value"), d.get("how")
        if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
            raise ValueError(f"validation alpha0 record {dict(d)!r}: value is not a number")
        if how not in (FITTED_ALONE, GIVEN, FIXED):
            raise ValueError(
                f"validation alpha0 record {dict(d)!r}: how must be "
                f"{FITTED_ALONE!r}, {GIVEN!r} or {FIXED!r}"
            )
        return cls(
            str(d.get("experiment") or experiment),
            float(v),
            how,
            d.get("file") if isinstance(d.get("file"), str) else file,
        )


class _RowsBuffer(threading.local):
    """This thread's buffer of :meth:`Problem.jacobian_rows` (kept: a fresh 6 MB array per
    Jacobian cost as much in page faults as the rows themselves)."""

    array: np.ndarray | None = None


_ROWS_BUFFER = _RowsBuffer()


def compile_sensitivity_kernel() -> None:
    """Compile the sensitivity kernel for the arguments :meth:`Problem.jacobian` and
    :meth:`Problem.jacobian_rows` pass it, by calling both on a tenth of a second of
    made-up brake data (what they compute is not looked at; nothing else of the solver is
    compiled): what :func:`rotorbayes.util.coldstart.sensitivity_aside`'s second process
    runs."""
    from ..model.parameters import thesis_set

    t = np.arange(101) * 1e-3
    ex = Experiment(t=t, u=np.full(t.size, 1.0), theta_u=t * 0.1, theta_l=t * 0.05, name="aside")
    p = thesis_set("4.3", "P_ref")
    prob = Problem("brake", [ex], base=p)
    x = prob.x_from(p)
    try:
        prob.jacobian(x, method="sensitivity")
        prob.jacobian_rows(x)
    except Exception:  # noqa: BLE001 -- compiled all the same: the call is what compiles
        pass


def _rows_buffer(m1: int, n: int) -> np.ndarray:
    """An ``(m1, n)`` C-order array (contents undefined), this thread's own."""
    a = _ROWS_BUFFER.array
    if a is None or a.size < m1 * n:
        a = _ROWS_BUFFER.array = np.empty(m1 * n)
    return a[: m1 * n].reshape(m1, n)


@dataclass(init=False)
class Problem:
    """A least-squares / likelihood problem over one or more experiments.

    ``Problem(model, experiments, ...)`` takes the settings as a user gives them and
    normalises them once, here: every attribute then holds one type (the declared one).

    Parameters
    ----------
    model : Model or {'upper', 'coupled', 'brake'}
        The model, or a configuration name (then ``effects`` and ``prescribed_upper``
        build the model).
    experiments : Experiment or sequence of Experiment
        Measurements loaded with :func:`rotorbayes.load_experiment` (a path, or a list
        of paths, is refused with that advice).
    free : sequence of str, optional
        Parameters to estimate.  Default: the configuration's fitted parameters plus
        those of every added effect (``alpha0`` per experiment when ``initial_torsion``
        is on).  Parameters of effects that are off are refused.
    base : mapping, str or None
        The starting / fixed values of all parameters (a named set, TOML file or
        mapping; default the configuration's P_ref set).
    effects : iterable of str
        Effects switched on besides the configuration's base model.
    channels : sequence of str
        Fitted channels, ``'theta_u'`` and/or ``'theta_l'``.  Default ``theta_u`` for the
        upper configuration, ``theta_l`` otherwise (thesis eqs. 4.4, 4.10).
    weights : mapping, optional
        Weight per channel (default 1), between :data:`MIN_WEIGHT` and :data:`MAX_WEIGHT`.
    prescribed_upper : bool
        Drive the lower disc with the measured upper angle instead of the motor model.
    shape : str
        The Stribeck curve's shape (:class:`~rotorbayes.Simulator`).
    step : float or None
        The integrator's largest step [s]; ``None`` chooses it from the sample interval.
    fixed : sequence of str
        Parameters removed from the default free set.
    run_starts : mapping, optional
        Start values of per-experiment parameters (``{"alpha0[1]": -0.2}``), e.g. an
        earlier fit's estimates of the same experiments: :meth:`start_vector` takes
        ``alpha0[i]`` from here before it falls back to the shared ``alpha0``.  Names of
        experiments this problem does not have are dropped.

    Attributes
    ----------
    parameters : ParameterMap
        The free parameters: :attr:`names`, :attr:`lower`, :attr:`upper` and the maps
        between the vector ``x`` and parameter values.
    """

    model: Model
    experiments: list[Experiment]
    base: dict[str, float]
    channels: tuple[str, ...]
    weights: dict[str, float]
    shape: str
    step: float | None
    fixed: tuple[str, ...]
    run_starts: dict[str, float]
    parameters: ParameterMap

    def __init__(
        self,
        model: Model | str,
        experiments: Experiment | Iterable[Experiment],
        free: Sequence[str] | None = None,
        base: Mapping[str, float] | str | None = None,
        effects: Iterable[str] = (),
        channels: Sequence[str] | None = None,
        weights: Mapping[str, float] | None = None,
        prescribed_upper: bool = False,
        shape: str = "exp",
        step: float | None = DEFAULT_STEP,
        fixed: Sequence[str] = (),
        run_starts: Mapping[str, float] | None = None,
    ) -> None:
        experiments = checked_experiments(experiments)
        for name, v in (("free", free), ("fixed", fixed), ("channels", channels)):
            if isinstance(v, str):
                names = [n.strip() for n in v.split(",") if n.strip()]
                raise ParameterError(f"{name} = {v!r}: give a list of names, e.g. {name}={names!r}")
        self.model = model_of(model, effects, prescribed_upper, len(experiments))
        if not experiments:
            raise ValueError("give at least one experiment")
        self.experiments = experiments
        self.base = base_values(self.model, base)
        for i, ex in enumerate(self.experiments):
            where = ex.path or ex.name or f"experiment {i}"
            if self.config == "upper" and ex.has_lower:
                raise ValueError(
                    f"{where}: has a theta_l column but the configuration is "
                    "'upper' (string removed); use --model coupled or brake"
                )
            if self.config != "upper" and not ex.has_lower:
                raise ValueError(
                    f"{where}: has no theta_l column, so it is an upper-"
                    f"configuration file; use --model upper, not {self.config!r}"
                )
        self.fixed = tuple(fixed)
        info = self.model.info
        self.parameters = ParameterMap.expand(
            free_names(self.model, free, self.fixed),
            len(self.experiments),
            lambda n: (info[n].lower, info[n].upper),
        )
        self.run_starts = self._checked_run_starts(run_starts)
        if channels is None:
            channels = default_channels(self.config, self.prescribed_upper, self.names)
        self.channels = tuple(channels)
        for c in self.channels:
            if c not in CHANNELS:
                raise ValueError(f"unknown channel {c!r}; choose from {', '.join(CHANNELS)}")
        if self.config == "upper" and "theta_l" in self.channels:
            raise ValueError("the upper configuration has no theta_l channel")
        if self.prescribed_upper and "theta_u" in self.channels:
            raise ValueError(
                "with the measured theta_u as input, theta_u cannot also be fitted; "
                "use channels=('theta_l',)"
            )
        self.weights = checked_weights(self.channels, weights)
        self.shape = shape
        self.step = step
        for i, ex in enumerate(self.experiments):
            check_step(self.step, ex.dt, ex.n, where=str(ex.path or ex.name or f"experiment {i}"))
        self.sims = [self.simulator_for(ex) for ex in self.experiments]
        self._tighten_bounds()
        self.n_residuals = sum(ex.n for ex in self.experiments) * len(self.channels)
        self._fills: dict[int, tuple] = {}  # (base values, fill or None) per experiment
        self._columns: dict[int, tuple] = {}

    # ------------------------------------------------------------- derived settings
    @property
    def config(self) -> str:
        """The configuration: ``'upper'``, ``'coupled'`` or ``'brake'``."""
        return self.model.config

    @property
    def prescribed_upper(self) -> bool:
        """Whether the measured upper angle drives the lower disc."""
        return self.model.prescribed_upper

    @property
    def effects(self) -> tuple[str, ...]:
        """The names of the model's effects that are on."""
        return self.model.effect_names

    @property
    def names(self) -> list[str]:
        """The free parameters in vector order (``alpha0[i]`` per experiment)."""
        return self.parameters.names

    @property
    def lower(self) -> np.ndarray:
        """Lower bounds of the free parameters (tightened by validity constraints with a
        fixed partner)."""
        return self.parameters.lower

    @property
    def upper(self) -> np.ndarray:
        """Upper bounds of the free parameters."""
        return self.parameters.upper

    # ---------------------------------------------------------------- construction
    def _checked_run_starts(self, given) -> dict[str, float]:
        """``run_starts`` kept for this problem's experiments, every name checked."""
        out: dict[str, float] = {}
        for n, v in dict(given or {}).items():
            b, idx = local_name(n)
            if idx is None or b not in self.model.info:
                raise ParameterError(
                    f"run_starts: {n!r} is not a per-experiment name such as 'alpha0[1]'"
                )
            if idx < len(self.experiments):
                out[n] = float(v)
        return out

    def _tighten_bounds(self) -> None:
        """A validity constraint ``a >= |b|`` with one of the two fixed is a box bound on
        the other: make it one, so the optimiser meets a bound, not a penalty wall."""
        from ..kernel.terms import CONSTRAINTS

        pos = {n: j for j, n in enumerate(self.names)}
        for names, _, _ in CONSTRAINTS:
            if len(names) != 2 or not all(n in self.model.active for n in names):
                continue
            a, b = names
            if a in pos and b not in pos and math.isfinite(self.base[b]):
                self.lower[pos[a]] = max(self.lower[pos[a]], abs(self.base[b]))
            elif b in pos and a not in pos and math.isfinite(self.base[a]):
                self.lower[pos[b]] = max(self.lower[pos[b]], -self.base[a])
                self.upper[pos[b]] = min(self.upper[pos[b]], self.base[a])

    def noise_floors(self, noise_std: float | None = None) -> tuple[dict, list[str]]:
        """The noise floor [rad RMS] of every fitted channel, and notes in words.

        ``noise_std`` given: ``sqrt(q²/12 + noise_std²)``.  Otherwise the encoder
        quantisation floor ``q/√12``, raised only for broad-band jitter: where the measured
        angles jitter clearly more than that (above
        :data:`~rotorbayes.io.measurements.JITTER_FACTOR` x the quantisation floor) through most of
        the record (:meth:`rotorbayes.io.measurements.Jitter.broadband`), the data carry other noise
        and its typical jitter is the floor.  The notes say so with the evidence (how many
        stretches and samples, which band), so a verdict is never "far from the floor"
        only because the encoder is not the only noise.  Glitches (single samples far off,
        :mod:`rotorbayes.io.glitches`) never raise the floor: the loader leaves them out, and
        those kept with ``--keep-glitches`` raise a few stretches only.
        """
        from ..io.measurements import jitter_evidence, quantisation_floor

        cache = self.__dict__.setdefault("_floors_cache", {})
        if noise_std in cache:  # the data do not change: compute the jitter once
            f, n = cache[noise_std]
            return dict(f), list(n)
        floors, notes = {}, []
        for c in self.channels:
            q = quantisation_floor(c)
            if noise_std is not None:
                floors[c] = math.hypot(q, noise_std)
                continue
            angles = [
                (ex.theta_u if c == "theta_u" else ex.theta_l, ex.dt) for ex in self.experiments
            ]
            broad = [
                j
                for y, dt in angles
                if y is not None and (j := jitter_evidence(y, dt, c)) is not None and j.broadband
            ]
            if broad:
                j = max(broad, key=lambda e: e.rms)
                floors[c] = j.rms
                where = (
                    (f" ({len(broad)} of {len(self.experiments)} experiments; the largest)")
                    if len(self.experiments) > 1
                    else ""
                )
                notes.append(
                    f"{j.words()}{where}: broad-band noise besides the encoder's rounding, "
                    f"so {j.rms:.2g} rad is used as the floor (give --noise to set it)"
                )
            else:
                floors[c] = q
        cache[noise_std] = (dict(floors), list(notes))
        return floors, notes

    def rms_over_floor(self, r: np.ndarray, floors: Mapping | None = None) -> dict:
        """Residual RMS over the noise floor per fitted channel of a residual vector ``r``
        laid out as :meth:`residuals` lays it out: the worst experiment's, as ``fit``'s
        headline takes it (a run far off is not averaged away by a good one)."""
        floors = floors if floors is not None else self.noise_floors()[0]
        worst = dict.fromkeys(self.channels, 0.0)
        off = 0
        for ex in self.experiments:
            for c in self.channels:
                seg = r[off : off + ex.n] / self.weights[c]
                worst[c] = max(worst[c], float(seg @ seg) / ex.n)
                off += ex.n
        return {c: math.sqrt(v) / floors[c] for c, v in worst.items()}

    def info(self, name: str):
        """Metadata of a (possibly per-experiment) parameter name."""
        return self.model.info[local_name(name)[0]]

    def simulator_for(self, ex: Experiment, model: Model | None = None, steps_of=None) -> Simulator:
        """A :class:`~rotorbayes.Simulator` of this problem's model for experiment ``ex``
        (``steps_of``: see :class:`~rotorbayes.Simulator`)."""
        return Simulator(
            model or self.model,
            ex.u,
            ex.dt,
            shape=self.shape,
            step=self.step,
            theta_u=ex.theta_u if self.prescribed_upper else None,
            steps_of=steps_of,
        )

    def like(self, **changes) -> Problem:
        """A problem with this one's settings -- model, experiments, free names, base
        values, channels, weights, friction shape, step -- some of them changed
        (``like(free=[...], base=...)``). Every derived problem (an effect added, a
        parameter profiled, an experiment designed) is made here, so a new setting is
        carried over in one place, not at every call site."""
        kw: dict[str, Any] = {
            "model": self.model, "experiments": self.experiments,
            "free": list(self.names_base()), "base": self.base, "channels": self.channels,
            "weights": self.weights, "shape": self.shape, "step": self.step,
            "run_starts": self.run_starts}  # fmt: skip
        unknown = sorted(set(changes) - set(kw))
        if unknown:
            raise TypeError(f"Problem.like: no setting {', '.join(unknown)}")
        kw.update(changes)
        return Problem(kw.pop("model"), kw.pop("experiments"), **kw)

    def with_effects(self, extra: Iterable[str]) -> Problem:
        """The same data and free set with more effects on (their parameters fixed at null)."""
        return self.like(model=self.model.with_effects(extra))

    def names_base(self) -> list[str]:
        """Free parameter names with per-experiment names folded (``alpha0``)."""
        return self.parameters.names_base()

    # ------------------------------------------------------------------------ maps
    def x_from(self, params: Mapping[str, float]) -> np.ndarray:
        """Free-parameter vector from a mapping (``alpha0[i]`` falls back to ``alpha0``)."""
        return self.parameters.x_from(params)

    def point(self, x) -> np.ndarray:
        """``x`` as a free-parameter vector of this problem: a 1-D float array with one
        value per free parameter; :class:`ValueError` naming what is wrong otherwise."""
        return self.parameters.point(x)

    def params_for(self, x: np.ndarray, i: int) -> dict[str, float]:
        """The full parameter set of experiment ``i`` at free vector ``x``."""
        return self.parameters.params_for(x, i, self.base)

    def validation_params(
        self, x: np.ndarray, ex: Experiment, given=None
    ) -> tuple[dict[str, float], ValidationTorsion | None]:
        """The full parameter set at ``x`` for an experiment outside the problem
        (validation data), and how its initial string torsion ``alpha0`` was chosen.

        Every parameter but ``alpha0`` is the fit's (experiment 0's values; they are the
        same in every experiment).  A validation run starts with its own torsion, so its
        ``alpha0`` is never another experiment's:

        * ``given`` a number [rad]: that value (the user knows the run's torsion);
        * ``given`` a :class:`ValidationTorsion` (or its :meth:`~ValidationTorsion.as_dict`,
          as fit.json stores it): its value, as decided before (every later command gives
          the same figure as the fit);
        * otherwise, when the model has a pre-wound string (``initial_torsion`` on: always
          with several estimation experiments), ``alpha0`` is fitted on that run alone,
          every other parameter at ``x`` -- a one-parameter nuisance fit of the run's fitted
          channels (a scan, fine over the torsion the lower disc's static friction can
          hold at rest and geometric out to alpha0's bounds, then least squares between
          the best point's neighbours);
        * without ``initial_torsion`` the model has no pre-wound string: the fit's fixed
          value (the null, 0).

        Returns ``(params, record)``; ``record`` is None for the upper configuration (no
        string).  Raises :class:`ParameterError` for a given value outside alpha0's bounds,
        or a non-zero one where the model has no pre-wound string.
        """
        p = self.params_for(x, 0)
        if self.config == "upper":
            return p, None
        name = str(ex.name or ex.path or "validation data")
        file = str(Path(ex.path).absolute()) if ex.path else None
        info = self.model.info["alpha0"]
        if isinstance(given, Mapping):
            given = ValidationTorsion.from_dict(given, experiment=name, file=file)
        if isinstance(given, ValidationTorsion):
            rec = given
        elif given is not None:
            v = float(given)
            if not (math.isfinite(v) and info.lower <= v <= info.upper):
                raise ParameterError(
                    f"validation {name}: alpha0 = {v:g} rad lies outside alpha0's bounds "
                    f"[{info.lower:g}, {info.upper:g}]; give the run's initial torsion in rad"
                )
            rec = ValidationTorsion(name, v, GIVEN, file)
        elif "alpha0" in self.model.active:
            rec = ValidationTorsion(name, self._fit_validation_alpha0(p, ex), FITTED_ALONE, file)
        else:
            rec = ValidationTorsion(name, float(self.base["alpha0"]), FIXED, file)
        if rec.value != 0.0 and "alpha0" not in self.model.active:
            raise ParameterError(
                f"validation {name}: alpha0 = {rec.value:g} rad, but this {self.config} model "
                "has no pre-wound string (initial_torsion is off), so no run can start with "
                "torsion; add the effect (--add initial_torsion) or leave the value out"
            )
        p["alpha0"] = rec.value
        return p, rec

    def _fit_validation_alpha0(self, p: Mapping[str, float], ex: Experiment) -> float:
        """``alpha0`` of experiment ``ex`` fitted on its fitted channels alone, every other
        parameter at ``p``: see :meth:`validation_params`."""
        from scipy.optimize import least_squares

        sub = self.like(experiments=[ex], free=["alpha0"], base=dict(p), run_starts=None)
        info = self.model.info["alpha0"]
        lo, hi = info.lower, info.upper
        # A run that starts at rest holds |k_alpha alpha0| inside the lower disc's static
        # band: scan it finely, half as far again beyond it, and out to the bounds on a
        # geometric grid (a run may start moving: the data decide, not this guess).
        static = max(p.get("Tc_l", math.nan), p.get("Ts_l", math.nan)) + abs(p.get("dTc_l", 0.0))
        k = p.get("k_alpha", math.nan)
        reach = (
            1.5 * static / k
            if (math.isfinite(static) and math.isfinite(k) and k > 0 and static > 0)
            else 1.0
        )
        reach = min(reach, hi, -lo)
        far = np.geomspace(reach, max(hi, -lo), VALIDATION_SCAN // 2)
        grid = np.unique(
            np.clip(np.r_[np.linspace(-reach, reach, VALIDATION_SCAN), far, -far, 0.0], lo, hi)
        )
        R = sub.residuals_batch(grid[:, None], penalty=_FAILED)
        ok = ~np.any(R == _FAILED, axis=1)
        if not ok.any():  # no torsion lets the run be simulated: leave it unwound
            return 0.0
        ssr = np.where(ok, np.einsum("ij,ij->i", R, R), np.inf)
        j = int(np.argmin(ssr))
        a, b = grid[max(j - 1, 0)], grid[min(j + 1, grid.size - 1)]
        if a == b:
            return float(grid[j])
        res = least_squares(
            lambda z: sub.residuals(z, penalty=_FAILED),
            [grid[j]],
            bounds=([a], [b]),
            x_scale=[b - a],
            method="trf",
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-12,
            max_nfev=100,
        )
        best = float(res.x[0])
        r = sub.residuals(np.array([best]), penalty=_FAILED)
        return best if float(r @ r) <= float(R[j] @ R[j]) else float(grid[j])

    def start_vector(self, values: Mapping[str, float]) -> np.ndarray:
        """Start vector from ``values``; a free parameter of an added effect that sits at
        its null value starts at the effect's typical value instead (see
        :func:`rotorbayes.model.effects.typical_start`), so the fit can move it.  A
        per-experiment name (``alpha0[1]``) missing from ``values`` starts at its value in
        :attr:`run_starts` (an earlier fit's estimate for that experiment), before the
        shared ``alpha0``."""
        vals = dict(values)
        for e in self.model.added:
            for n, v in _effects.typical_start(e, vals).items():
                if any(local_name(f)[0] == n for f in self.names):
                    vals[n] = v
        for n, v in (self.run_starts or {}).items():
            if n in self.names and n not in vals:
                vals[n] = v
        return self.x_from(vals)

    def values(self, x: np.ndarray) -> dict[str, float]:
        """``{name: value}`` of the free parameters."""
        return self.parameters.values(x)

    def check_start(self, x: np.ndarray) -> None:
        """Raise :class:`ParameterError` if a start value lies outside its bounds."""
        for n, v, lo, hi in self.parameters.outside(x)[:1]:
            raise ParameterError(
                f"start value {n} = {v:g} {self.info(n).unit} lies outside the bounds "
                f"[{lo:g}, {hi:g}]; choose a start inside them"
            )

    # -------------------------------------------------------------------- residuals
    def _channel_residual(self, ex: Experiment, thu, thl) -> np.ndarray:
        parts = []
        for c in self.channels:
            sim = thu if c == "theta_u" else thl
            meas = ex.theta_u if c == "theta_u" else ex.theta_l
            parts.append(self.weights[c] * (meas - sim))
        return np.concatenate(parts)

    def _channel_columns(self, ex: Experiment, off: int):
        """The kernel's residual-only arguments for experiment ``ex`` whose residuals start
        at column ``off``: ``(measured, weight, column)`` for theta_u and theta_l, in the
        order and with the weights of :meth:`_channel_residual` (``None`` if not fitted)."""
        cols: dict[str, tuple | None] = {"theta_u": None, "theta_l": None}
        for j, c in enumerate(self.channels):
            meas = ex.theta_u if c == "theta_u" else ex.theta_l
            cols[c] = (meas, self.weights[c], off + j * ex.n)
        return cols["theta_u"], cols["theta_l"]

    def evaluate(self, x: np.ndarray) -> Evaluation:
        """Residuals at ``x`` (``nan`` for failed experiments) and each status.

        The kernel writes the weighted residuals straight into the vector (no simulated
        angles are kept); the numbers are those of :meth:`_channel_residual` applied to
        the simulated angles.
        """
        x = self.point(x)
        R = np.empty((1, self.n_residuals))
        status = []
        off = 0
        for i, (ex, sim) in enumerate(zip(self.experiments, self.sims, strict=True)):
            cols = self._columns[i] if i in self._columns else self._channel_columns(ex, off)
            self._columns[i] = cols
            status.append(sim.residuals_into(self.kernel_vectors(x, i), R, 0, cols))
            off += ex.n * len(self.channels)
        return Evaluation(R[0], np.array(status))

    def kernel_vectors(self, x: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The kernel vectors ``(p, q)`` of experiment ``i`` at free vector ``x``: those of
        :meth:`params_for`, made by putting ``x`` into a copy of the vectors at the base
        values (a tenth of the time; checked against the long way once per experiment)."""
        made = self._fills.get(i)
        if made is None or made[0] != self.base:  # new, or the base values were changed
            made = self._fills[i] = (dict(self.base), self._make_fill(x, i))
        if made[1] is None:
            return self.sims[i].kernel_vector(self.params_for(x, i))
        return made[1].vectors(x)

    def _make_fill(self, x: np.ndarray, i: int) -> FillTemplate | None:
        """How :meth:`kernel_vectors` fills experiment ``i``'s vectors from ``x``, or
        ``None`` where only the long way is right (a free name the kernel vectors do not
        take as it is, or a disagreement at ``x`` or near it)."""
        sim = self.sims[i]
        try:
            p0, q0 = sim.kernel_vector(self.base)
        except (ParameterError, KeyError, ValueError):
            return None
        fill = self.parameters.fill_template(
            i, self.model.kernel_slot, p0, q0, not self.model.stribeck
        )
        if fill is None:
            return None
        x = np.asarray(x, dtype=float)
        for probe in (x, x * (1.0 + 1e-3) + 1e-6):
            try:
                slow = sim.kernel_vector(self.params_for(probe, i))
            except (ParameterError, KeyError, ValueError):
                return None
            pairs = zip(fill.vectors(probe), slow, strict=True)
            if not all(np.array_equal(a, b, equal_nan=True) for a, b in pairs):
                return None
        return fill

    def residuals(self, x: np.ndarray, *, penalty: float | None = None) -> np.ndarray:
        """Weighted residual vector [rad].

        A failed simulation gives ``nan`` residuals, or ``penalty`` if one is given (the
        least-squares optimiser needs a finite number; a likelihood should use
        :meth:`evaluate` and return ``-inf``).
        """
        r = self.evaluate(x).residuals
        if penalty is not None:
            r = np.where(np.isnan(r), penalty, r)
        return r

    def _residuals_of_sets(self, sets: list[list[dict]], model: Model | None = None):
        """Residual matrix for full parameter sets ``sets[j][i]`` (row j, experiment i),
        simulated in kernel batches; returns ``(R, status[j, i])``."""
        m = len(sets)
        claim_kernel_threads()  # inside a pool's task: its share of the cores
        R = np.empty((m, self.n_residuals))
        S = np.zeros((m, len(self.experiments)), dtype=np.int64)
        off = 0
        mdl = model or self.model
        for i, ex in enumerate(self.experiments):
            sim = self.sims[i] if model is None else self.simulator_for(ex, model)
            vecs = [mdl.kernel_vectors(s[i]) for s in sets]
            P = np.array([v[0] for v in vecs])
            Q = np.array([v[1] for v in vecs]).reshape(m, -1)
            # Residuals straight from the kernel, every row in parallel (see evaluate).
            S[:, i] = sim.residuals_batch_into(P, Q, R, self._channel_columns(ex, off))
            off += ex.n * len(self.channels)
        return R, S

    def residuals_batch(self, X: np.ndarray, *, penalty: float | None = None) -> np.ndarray:
        """Residual vectors of many free vectors (rows), simulated in parallel."""
        try:
            X = np.atleast_2d(np.asarray(X, dtype=float))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"X must hold numbers, one row per point ({exc})") from None
        if X.ndim != 2 or X.shape[1] != len(self.names):
            raise ValueError(
                f"X has shape {np.shape(X)}, but this problem has "
                f"{len(self.names)} free parameter(s): give one row per point"
            )
        sets = [[self.params_for(x, i) for i in range(len(self.experiments))] for x in X]
        R, _ = self._residuals_of_sets(sets)
        if penalty is not None:
            R = np.where(np.isnan(R), penalty, R)
        return R

    def simulate(self, x: np.ndarray, i: int = 0) -> Simulation:
        """Full :class:`~rotorbayes.Simulation` of experiment ``i`` at ``x`` (with status)."""
        return self.sims[i].simulate(self.params_for(x, i), raise_on_failure=False)

    # --------------------------------------------------------------------- Jacobian
    def sensitivity_support(
        self,
        names: Sequence[str] | None = None,
        *,
        values: Mapping[str, float] | None = None,
        secant: Mapping[str, float] | None = None,
    ) -> str | None:
        """Why the kernel's forward sensitivities cannot give the Jacobian by ``names``
        (default: the free parameters) here, in words; ``None`` if they can.

        They exist for the plain kernel (no user effect, no effect of the full kernel, no
        effect that replaces a friction law), the motor-driven configurations (upper,
        coupled, brake; not a measured theta_u as input), no dead zone, and the
        parameters of :data:`rotorbayes.kernel.sensitivity.SUPPORTED` of effects that
        are on, at the problem's own values (no ``values``, no ``secant``)."""
        from ..kernel.sensitivity import SUPPORTED

        names = list(self.names if names is None else names)
        m = self.model
        if values or secant:
            return "evaluated at other values or by secants (a score test's steps)"
        if self.prescribed_upper:
            return "the measured theta_u drives the lower disc (prescribed upper motion)"
        if m.user_effects:
            return "the model has user-defined effects"
        if m.full_kernel or m.replacing is not None:
            what = m.replacing.name if m.replacing is not None else "an effect"
            return f"{what} needs the full kernel, which has no sensitivities yet"
        for n in names:
            b, idx = local_name(n)
            if b not in m.active:
                return f"{b} belongs to an effect that is off"
            slot = m.kernel_slot(b)
            if slot is None or slot[0] != 0 or slot[1] not in SUPPORTED:
                return f"no sensitivity by {b} in the kernel yet"
            if idx is not None and not 0 <= idx < len(self.experiments):
                return f"{n}: no experiment {idx}"
        if float(self.base.get("u_deadzone", 0.0) or 0.0) != 0.0:
            return "the input has a dead zone (its kinks move with the parameters)"
        return None

    def _jacobian_sensitivity(self, x: np.ndarray, names: list[str]) -> np.ndarray:
        """:meth:`jacobian` by the kernel's forward sensitivities (supported, see
        :meth:`sensitivity_support`)."""
        return self._sensitivity_pass(x, names, rows=False)[0]

    def jacobian_rows(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The free parameters' Jacobian by forward sensitivities, reduced: ``(A, b, r)``
        with ``Aᵀ A = Jᵀ J``, ``Aᵀ b = Jᵀ r`` and ``|b| <= |r|`` (``r`` the residuals at
        ``x``, whole).  Least squares needs no more than these (:func:`.least_squares.
        compress`); the kernel writes a few rows per step of its grid (the samples'
        rows of a step lie in the span of six Hermite weights; their part outside it, of
        ``r`` alone, is ``|r|² - |b|²``) instead of every sample's row, and never forms
        ``J``.  ``None`` where the sensitivities do not cover this problem
        (:meth:`sensitivity_support`); raises :class:`SimulationError` where ``x``
        cannot be simulated."""
        names = list(self.names)
        if self.sensitivity_support(names) is not None:
            return None
        W, r = self._sensitivity_pass(x, names, rows=True)
        return W[:-1].T, W[-1], r

    def _sensitivity_pass(
        self, x: np.ndarray, names: list[str], *, rows: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """One pass of the sensitivity kernel over every experiment: ``(J, r)``, or with
        ``rows`` the reduced rows ``Wt`` (a column per row, the residual last) and ``r``."""
        from ..kernel.sensitivity import sensitivities_into
        from ..model.simulate import SimulationError
        from ..util.coldstart import first_sensitivities

        x = self.point(x)
        m = len(names)
        if rows:
            J = np.empty((2, 2), order="F")  # unused: the same compiled kernel
            Wt = _rows_buffer(m + 1, self.n_residuals)
        else:
            # Fortran order: the kernel writes each column down the samples (vectorised,
            # sequential stores).  Not zeroed where every column is written whole.
            whole = len(self.experiments) == 1 or all(local_name(n)[1] is None for n in names)
            J = (np.empty if whole else np.zeros)((m, self.n_residuals)).T
            Wt = np.empty((m + 1, 0))
        info = np.zeros(2, dtype=np.int64)
        r = np.empty((1, self.n_residuals))
        tsf = not self.model.stribeck
        off = 0
        for i, (ex, sim) in enumerate(zip(self.experiments, self.sims, strict=True)):
            p, _ = self.kernel_vectors(x, i)
            if p[_layout.U_DEADZONE] != 0.0:
                raise SimulationError("Jacobian by sensitivities: the input has a dead zone")
            idx, jcol = [], []
            for j, n in enumerate(names):
                b, e = local_name(n)
                if e is None or e == i:
                    idx.append(_layout.INDEX[b])
                    jcol.append(j)
            cols = self._columns[i] if i in self._columns else self._channel_columns(ex, off)
            self._columns[i] = cols
            (mu, wu, cu), (ml, wl, cl) = [
                (c[0], c[1], c[2]) if c is not None else (np.empty(0), 1.0, -1) for c in cols
            ]
            with first_sensitivities():  # a cold cache: compiled here, said in one line
                st = sensitivities_into(
                    np.ascontiguousarray(p, dtype=float), sim.u, sim.dt, sim.cfg, sim.shape,
                    sim.grid, sim.h0, np.array(idx, dtype=np.int64), tsf, mu, ml, float(wu),
                    float(wl), r, J, np.array(jcol, dtype=np.int64), cu, cl, Wt, info,
                )  # fmt: skip
            if st != _layout.OK:
                raise SimulationError(
                    f"Jacobian: experiment {i} cannot be simulated at the "
                    f"point: {_layout.STATUS_MESSAGES[int(st)]}"
                )
            if info[1]:  # pragma: no cover - the rows never outnumber the samples
                raise SimulationError("Jacobian rows: more rows than residuals")
            off += ex.n * len(self.channels)
        if rows:
            return np.ascontiguousarray(Wt[:, : info[0]]), r[0]
        return J, r[0]

    def jacobian(
        self,
        x: np.ndarray,
        names: Sequence[str] | None = None,
        *,
        rel_step: float = 1e-6,
        r0: np.ndarray | None = None,
        values: Mapping[str, float] | None = None,
        secant: Mapping[str, float] | None = None,
        method: str | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sensitivity of the residuals to any parameters, by forward sensitivities or by
        finite differences.

        Parameters
        ----------
        x : array
            The free-parameter vector (the point).
        names : sequence of str, optional
            Parameters to differentiate by (default: the free ones).  May include fixed
            parameters, per-experiment names (``alpha0[1]``) and the parameters of
            effects that are off (then evaluated at their null value: ``Ts_l`` from
            ``Tc_l`` upwards; one-sided, inwards, where the value is on a bound).
        rel_step : float
            Step relative to the parameter's scale (its magnitude, at least 1e-3 of its
            bounds' width).
        r0 : array, optional
            Residuals at ``x`` if already known.
        values : mapping, optional
            Values of parameters that are not free at which to evaluate (e.g. the
            Stribeck velocity and shape, nuisance parameters of an effect that is off).
        secant : mapping, optional
            Absolute steps for some names (a secant instead of a derivative).
        method : {'sensitivity', 'differences'}, optional
            ``'sensitivity'``: the kernel's forward sensitivities
            (:mod:`rotorbayes.kernel.sensitivity`; the derivative of the computed
            residuals in one pass, no step), where they exist for this model and these
            names (see :meth:`sensitivity_support`); elsewhere finite differences, with a
            :class:`SensitivityFallback` warning that says why.  ``'differences'``:
            forward differences (``rel_step``).  Default (None):
            :data:`JACOBIAN_DEFAULT`, falling back to differences without a warning.

        Returns
        -------
        J : array (n_residuals, len(names))
            ``d r / d theta`` in parameter units (``r = y - yhat``).
        steps : array
            The signed steps used (zeros for sensitivities).

        Raises
        ------
        rotorbayes.SimulationError
            If the model cannot be simulated at ``x`` or at a perturbed point.
        """
        names = list(self.names if names is None else names)
        asked = method is not None
        method = JACOBIAN_DEFAULT if method is None else method
        if method not in ("sensitivity", "differences"):
            raise ValueError(f"method = {method!r}: choose 'sensitivity' or 'differences'")
        if method == "sensitivity":
            why = self.sensitivity_support(names, values=values, secant=secant)
            if why is None:
                return self._jacobian_sensitivity(x, names), np.zeros(len(names))
            if asked:
                warnings.warn(
                    f"Jacobian by finite differences: {why}", SensitivityFallback, stacklevel=2
                )
        D, base_r, steps = self._differences(x, names, rel_step, r0, values, secant)
        # In place: long data make D the largest array of a fit (k + 1 residual vectors);
        # no second and third copy for the difference and the quotient.
        difference_quotients(D, base_r, steps)
        return D.T, steps

    def difference_parts(
        self, x: np.ndarray, *, rel_step: float = 1e-6, r0: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The free parameters' forward differences before their quotients: ``(R, r,
        steps)`` with the Jacobian's column j ``(R[j] - r) / steps[j]`` (``R`` is
        ``(k, n_residuals)``, the perturbed sets' residuals).  For least squares, which
        forms the quotients on its way into the triangle (:func:`.least_squares.compress`)
        instead of in a pass of its own.  Raises :class:`SimulationError` as
        :meth:`jacobian` does."""
        return self._differences(x, list(self.names), rel_step, r0, None, None)

    def _differences(self, x, names, rel_step, r0, values, secant):
        """:meth:`jacobian`'s forward differences up to the quotients."""
        from ..model.simulate import SimulationError

        off_effects = []
        for n in names:
            b, _ = local_name(n)
            if b not in self.model.info:
                raise ParameterError(unknown_name_message(b))
            if b not in self.model.active:
                e = _effects.effect_of(b)
                if e is None:
                    raise ParameterError(f"{b} does not enter the {self.config} configuration")
                if e.name not in off_effects:
                    off_effects.append(e.name)
        prob = self.with_effects(off_effects) if off_effects else self
        n_exp = len(self.experiments)
        point = [{**prob.params_for(x, i), **(values or {})} for i in range(n_exp)]
        sets = [point]
        steps = np.empty(len(names))
        for k, n in enumerate(names):
            b, idx = local_name(n)
            info = prob.info(b)
            v = point[0 if idx is None else idx][b]
            if b == "Ts_l" and (math.isnan(v) or "lower_stribeck" in off_effects):
                v = point[0]["Tc_l"]
            scale = max(abs(v), 1e-3 * (info.upper - info.lower))
            h = rel_step * scale
            if secant and b in secant:
                h = float(secant[b])
            if v + h > info.upper:
                h = -h
            steps[k] = h
            row = []
            for i in range(n_exp):
                p = dict(point[i])
                if b == "Ts_l" and "lower_stribeck" in off_effects:
                    p["Ts_l"] = p["Tc_l"]
                if idx is None or idx == i:
                    p[b] = v + h
                row.append(p)
            sets.append(row)
        if prob is not self:
            for i in range(n_exp):
                if "lower_stribeck" in off_effects:
                    sets[0][i] = {**sets[0][i], "Ts_l": sets[0][i]["Tc_l"]}
        R, S = prob._residuals_of_sets(sets, model=prob.model if prob is not self else None)
        # A point on a constraint between parameters (viscous friction b >= |db|, static
        # >= Coulomb) has an outward step that is invalid: step inwards instead.
        flip = [
            j
            for j in range(1, len(sets))
            if np.all(S[0] == _layout.OK) and np.any(S[j] == _layout.BAD_PARAMETERS)
        ]
        if flip:
            for j in flip:
                b, idx = local_name(names[j - 1])
                steps[j - 1] = -steps[j - 1]
                for i in range(n_exp):
                    if idx is None or idx == i:
                        sets[j][i] = {**sets[j][i], b: sets[j][i][b] + 2 * steps[j - 1]}
            R2, S2 = prob._residuals_of_sets(
                [sets[0]] + [sets[j] for j in flip], model=prob.model if prob is not self else None
            )
            for k, j in enumerate(flip, start=1):
                R[j], S[j] = R2[k], S2[k]
        if np.any(S != _layout.OK):
            j, i = np.argwhere(S != _layout.OK)[0]
            what = "the point" if j == 0 else f"{names[j - 1]} perturbed by {steps[j - 1]:.3g}"
            raise SimulationError(
                f"Jacobian: experiment {i} cannot be simulated at {what}: "
                f"{_layout.STATUS_MESSAGES[int(S[j, i])]}"
            )
        base_r = R[0] if r0 is None or prob is not self or values else r0
        return R[1:], np.ascontiguousarray(base_r, dtype=float), steps
