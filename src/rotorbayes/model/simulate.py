"""Configurations, active effects and simulation of the rig.

:class:`Simulator` binds a configuration, its active effects and one experiment's input
(time grid, voltage, optionally a prescribed upper-disc motion) and then maps parameter
vectors to simulated angles, one at a time or in parallel batches.  Estimation and
sampling reuse one ``Simulator`` for thousands of evaluations.  :func:`simulate` is the
one-call version that returns a :class:`Simulation` with angles, velocities, stick/slip
modes and the event log.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ..io.measurements import (
    LOWER_COUNTS_PER_REV,
    UPPER_COUNTS_PER_REV,
    Experiment,
    add_noise,
    quantize,
)
from ..kernel import layout as _k
from ..kernel import solver as _solver
from ..util.coldstart import kernel_entry
from .configurations import CONFIGS, Model, check_config
from .friction import shape_code
from .parameters import NAMES, ParameterError, resolve

#: Default step: ``None`` chooses it from the sample interval (:func:`default_step`).
DEFAULT_STEP = None

#: How much of the input a Runge-Kutta step may misjudge [V s] (see
#: :func:`rotorbayes.kernel.solver.step_grid`): a step is shortened where the stages,
#: reading the linearly interpolated input at five points, misjudge its integral or its
#: first two moments over the step by more than this (a transition between two levels
#: within a few tens of milliseconds, or the first milliseconds of one).  With 5e-7 a
#: 43 ms step over the start of a transition misjudged the input by 3.8e-7 V s and left
#: the upper disc 3e-6 rad/s off (k_m / J_u = 9 rad/s^2 per volt).
INPUT_TOLERANCE = 1e-7


def default_step(dt: float) -> float:
    """The default largest Runge-Kutta step [s] for samples ``dt`` apart: 55 ms at 1 kHz
    and faster, ``55 ms * sqrt(1 ms / dt)`` at slower rates (three samples at 200 Hz).

    The step grid shortens it over fast input transitions (:data:`INPUT_TOLERANCE`), and
    the solver takes substeps where a slipping lower disc crosses the Stribeck band
    (:func:`rotorbayes.kernel.terms.stribeck_step`) and where a disc decelerates towards a
    stop (:func:`rotorbayes.kernel.terms.approach_step`).  Measured against the event-driven
    reference (tests/reference.py) on the accuracy suite's 28 cases (every configuration
    and catalogue effect, stick-slip, delays, fast transitions; benchmarks/
    bench_step_accuracy.py): the worst case is 2.5e-6, 1.6e-6 and 3.5e-6 rad with 25, 55
    and 65 ms steps; on 16 random brake rigs (benchmarks/bench_random_rigs.py) 8.5e-7 at
    25 ms and 5.9e-6 at 55.  Verified by tests/test_integrator_accuracy.py,
    test_effects.py and test_input_delay.py; use ``step=dt`` for rough, noisy inputs (a
    sticking disc whose torque leaves its band and returns between two step points is
    not seen).
    """
    return 55e-3 * min(1.0, math.sqrt(1e-3 / dt))


#: The shortest largest step a user may choose, as a fraction of the sample interval: at
#: dt/100 every sample holds 100 Runge-Kutta steps (30 s at 1 kHz: 3 million), far finer
#: than any accuracy needs; shorter steps only cost memory and time (1e-12 s at 200 Hz
#: would need a grid of 4e12 points, 29 TiB).
MIN_STEP_FRACTION = 0.01
#: Most points of a step grid (800 MB as float64).  The user's shortest step keeps three
#: times this margin, for the integration check's finer grid (a third of the step).
MAX_GRID_POINTS = 100_000_000


def step_range(dt: float, n: int) -> tuple[float, float]:
    """The largest Runge-Kutta steps [s] a user may choose for ``n`` samples ``dt`` apart:
    from a hundredth of the sample interval (:data:`MIN_STEP_FRACTION`; longer on records
    so long that the grid would not fit in :data:`MAX_GRID_POINTS`) to the record's
    length."""
    duration = (n - 1) * dt
    return max(dt * MIN_STEP_FRACTION, 3.0 * duration / MAX_GRID_POINTS), duration


def check_step(step, dt: float, n: int, *, what: str = "step", where: str = "") -> None:
    """Raise :class:`ValueError` (a :class:`ParameterError`) unless ``step`` is ``None`` (the
    default) or a number of seconds within :func:`step_range` of ``n`` samples ``dt``
    apart; the message names ``what`` (``"--step"``), the value, the allowed range and
    ``where`` (the data file)."""
    if step is None:
        return
    if isinstance(step, bool) or not isinstance(step, numbers.Real):
        raise ParameterError(
            f"{what} = {step!r}: give the largest Runge-Kutta step in "
            "seconds (a number), or None for the default"
        )
    lo, hi = step_range(dt, n)
    of = f" of {where}" if where else ""
    allowed = (
        f"give a step between {lo:.3g} s and {hi:.4g} s{' for ' + where if where else ''}"
        f" (or leave it out: the default, {1e3 * default_step(dt):.3g} ms there, suits "
        "most data)"
    )
    if not math.isfinite(step) or step <= 0:
        raise ParameterError(f"{what} {step:g} s: not a positive number of seconds; {allowed}")
    if step < lo:
        points = (n - 1) * math.ceil(dt / step - 1e-9) + 1
        raise ParameterError(
            f"{what} {step:g} s is shorter than a hundredth of the sample interval "
            f"({dt:g} s){of}: the simulation would take {points:.3g} Runge-Kutta steps "
            f"({8 * points / 2**30:.3g} GiB for the step grid alone); {allowed}"
        )
    if step > hi:
        raise ParameterError(
            f"{what} {step:g} s is longer than the record{of} ({hi:.4g} s); {allowed}"
        )


def stride_of(step: float, dt: float) -> tuple[int, int]:
    """``(stride, substeps)`` of the Runge-Kutta grid for a largest step ``step``.

    A step of at least one sample is the largest *odd* number of samples not above
    ``step``: with an odd stride no Runge-Kutta stage (quarters, middle) falls on a
    sample, where the linearly interpolated input has a kink.
    A step shorter than a sample divides each sample into equal substeps.
    """
    if step >= dt:
        k = max(1, int(math.floor(step / dt + 1e-9)))
        if k % 2 == 0:
            k -= 1
        return k, 1
    return 1, int(math.ceil(dt / step - 1e-9))


class SimulationError(RuntimeError):
    """The integrator reported a failure; the message names the parameter values."""


def physics_problems(p: Mapping[str, float], config: str = "brake") -> list[str]:
    """Reasons why a parameter set cannot be simulated in ``config`` (empty if it can)."""
    return Model(config).problems(p)


@dataclass
class Simulation:
    """The result of :func:`simulate`.

    Attributes
    ----------
    t, u : arrays
        Sample times [s] and input voltage [V].
    theta_u, theta_l : arrays
        Disc angles [rad], both zero at ``t[0]`` like the encoders (``theta_l`` is
        ``None`` for the upper configuration).
    omega_u, omega_l : arrays
        Angular velocities [rad/s].
    mode_u, mode_l : int8 arrays
        -1 / +1 slip in the negative / positive direction, 0 stick.
    events : array (m, 3)
        ``(time [s], disc (0 upper, 1 lower), new mode)`` of each stick/slip switch.
    params : dict
        The complete parameter set used.
    """

    t: np.ndarray
    u: np.ndarray
    theta_u: np.ndarray
    theta_l: np.ndarray | None
    omega_u: np.ndarray
    omega_l: np.ndarray | None
    mode_u: np.ndarray
    mode_l: np.ndarray | None
    events: np.ndarray
    params: dict[str, float]
    config: str
    effects: tuple[str, ...] = ()
    meta: dict[str, str] = field(default_factory=dict)
    status: int = 0

    @property
    def ok(self) -> bool:
        """The integration succeeded (``status`` 0)."""
        return self.status == _k.OK

    @property
    def status_message(self) -> str:
        """The integrator's own words for ``status``."""
        return _k.STATUS_MESSAGES[self.status]

    @property
    def alpha(self) -> np.ndarray | None:
        """String torsion ``theta_l - theta_u + alpha0`` [rad]."""
        if self.theta_l is None:
            return None
        return self.theta_l - self.theta_u + self.params["alpha0"]

    def stick_fraction(self, disc: str = "l") -> float:
        """Fraction of samples in which the disc sticks."""
        m = self.mode_l if disc == "l" else self.mode_u
        return float(np.mean(m == 0)) if m is not None else float("nan")

    def to_experiment(self, name: str = "simulated") -> Experiment:
        """The simulated angles as a measurement (for saving or fitting)."""
        return Experiment(
            t=self.t,
            u=self.u,
            theta_u=self.theta_u,
            theta_l=self.theta_l,
            name=name,
            meta=dict(self.meta),
        )


def samples(a, name: str, what: str) -> np.ndarray:
    """``a`` as the kernel takes a signal: a contiguous, writable 1-D float array.

    A read-only array (``np.load(..., mmap_mode="r")``, a pandas column) is copied (the
    compiled kernel takes writable arrays only); a string, or anything that is not numbers,
    is a :class:`ValueError` that names the argument ``name`` and says ``what`` it holds.
    """
    if isinstance(a, str | bytes):
        raise ValueError(
            f"{name} is the text {a[:40]!r}; give {what} at each sample as an array of numbers"
        )
    try:
        out = np.ascontiguousarray(a, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name} must hold {what} at each sample as numbers ({exc}); "
            "convert it first, e.g. with np.asarray(..., dtype=float)"
        ) from None
    if out.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array of samples, got shape {out.shape}")
    if not out.flags.writeable:
        out = out.copy()
    return out


class Simulator:
    """A model and one experiment's input, ready to simulate many parameter sets.

    Parameters
    ----------
    model : Model or {'upper', 'coupled', 'brake'}
        The model (configuration and active effects), or a configuration name.
    u : array
        Input voltage [V] at uniform samples (linearly interpolated in between).
    dt : float
        Sample interval [s].
    theta_u : array, optional
        Prescribed upper-disc angle [rad] at the same samples.  The lower disc is then
        driven by this motion and ``u`` is not used (fit the lower disc with the
        measured upper angle as input).
    effects : iterable of str
        Effects switched on besides the configuration's base model (only with a
        configuration name; see :mod:`rotorbayes.model.effects`).
    shape : {'exp', 'rational'}
        Stribeck curve shape.
    step : float, optional
        Largest Runge-Kutta step [s] (default :func:`default_step`); the step is an odd
        number of samples (or a whole fraction of one), see :func:`stride_of`.
    steps_of : tuple (Simulator, int), optional
        ``(other, K)``: take the Runge-Kutta steps of ``other``, a simulation of the same
        record whose samples are ``K`` of these apart (``u`` its input resampled ``K``
        times finer), instead of the steps this input would give: two input models
        compared on the same steps differ by their inputs alone.
    """

    #: What the kernel reads (:meth:`args`): the sample interval, the configuration code,
    #: the friction shape's code, the step grid (in samples) and the first step.
    u: np.ndarray
    theta_u: np.ndarray
    n: int
    dt: float
    cfg: int
    shape: int
    grid: np.ndarray
    h0: float

    def __init__(
        self,
        model,
        u,
        dt: float,
        *,
        theta_u=None,
        effects: Iterable[str] = (),
        shape: str = "exp",
        step: float | None = DEFAULT_STEP,
        steps_of: tuple[Simulator, int] | None = None,
    ):
        if isinstance(model, Model):
            if tuple(effects):
                raise ValueError("give the effects with the Model, not to the Simulator")
            if model.prescribed_upper != (theta_u is not None):
                raise ValueError(
                    "the model's prescribed_upper flag and the theta_u argument disagree"
                )
        else:
            model = Model(model, effects, prescribed_upper=theta_u is not None)
        self.model = model
        self.config = model.config
        self.u = samples(u, "u", "the input voltage [V]")
        if self.u.size < 2:
            raise ValueError(
                f"u must be a 1-D array of at least 2 samples, got shape {self.u.shape}"
            )
        if not np.all(np.isfinite(self.u)):
            i = int(np.flatnonzero(~np.isfinite(self.u))[0])
            raise ValueError(f"u[{i}] = {self.u[i]} is not finite; the input must be finite")
        if (
            isinstance(dt, bool)
            or not isinstance(dt, numbers.Real)
            or not (dt > 0 and math.isfinite(dt))
        ):
            raise ValueError(
                f"dt = {dt!r} must be a positive sample interval in seconds (a number)"
            )
        self.dt = float(dt)
        self.n = self.u.size
        self.prescribed = theta_u is not None
        if self.prescribed:
            self.theta_u = samples(theta_u, "theta_u", "the upper disc's angle [rad]")
            if self.theta_u.shape != self.u.shape:
                raise ValueError(f"theta_u has {self.theta_u.size} samples but u has {self.n}")
        else:
            self.theta_u = self.u  # unused by the kernel
        self.cfg = model.kernel_cfg
        self.shape = shape_code(shape)
        if step is None:
            step = default_step(self.dt)
        if (
            isinstance(step, bool)
            or not isinstance(step, numbers.Real)
            or not (step > 0 and math.isfinite(step))
        ):
            raise ValueError(f"step = {step!r} must be a positive number of seconds")
        self.step = float(step)
        self.stride, self.substeps = stride_of(step, self.dt)
        if (self.n - 1) * self.substeps + 1 > MAX_GRID_POINTS:
            lo, hi = step_range(self.dt, self.n)
            raise ValueError(
                f"step = {step:g} s divides each of the {self.n} samples into "
                f"{self.substeps:.3g} Runge-Kutta steps: a grid beyond {MAX_GRID_POINTS:.0e} "
                f"points, more memory than a simulation may take; give a step between "
                f"{lo:.3g} s and {hi:.4g} s"
            )
        if steps_of is not None:
            other, finer = steps_of
            if (
                (other.n - 1) * finer != self.n - 1
                or other.substeps != 1
                or other.prescribed
                or self.prescribed
            ):
                raise ValueError(
                    f"steps_of: the steps of {other.n} samples at {finer} times the spacing do "
                    f"not fit these {self.n} (nor a prescribed motion's, or steps shorter "
                    "than a sample)"
                )
            self.grid = other.grid * finer
        elif self.substeps > 1:  # steps shorter than a sample: every sample alike
            k = np.arange((self.n - 1) * self.substeps + 1, dtype=float)
            self.grid = k / self.substeps
        elif self.prescribed:  # the motion is the input; its steps stay uniform
            self.grid = np.minimum(
                np.arange(0, self.n - 1 + self.stride, self.stride, dtype=float), self.n - 1.0
            )
        else:
            self.grid = _solver.step_grid(self.u, self.stride, INPUT_TOLERANCE / self.dt)
        self.h0 = self.stride / self.substeps if steps_of is None else other.h0 * finer

    @property
    def effects(self) -> tuple[str, ...]:
        return self.model.effect_names

    def _kernel_args(self) -> tuple:
        """The kernel's experiment arguments, shared by single and batched runs."""
        use, ht, hs, hr, reset = self.model.hooks()
        return (self.u, self.dt, self.cfg, self.shape, self.grid, self.h0,
                self.theta_u, use, ht, hs, hr, reset)  # fmt: skip

    def _entry(self, name: str):
        """``(kernel function, experiment arguments)`` for the kernel entry point ``name``:
        without user effects (or a catalogue effect only the full kernel has, see
        ``Model.full_kernel``) its ``_plain`` twin, which takes no hooks (a function
        argument costs 0.1-0.27 ms per call from Python to type and unbox).  Each is
        compiled on its first use (:func:`rotorbayes.util.coldstart.kernel_entry`)."""
        a = self._kernel_args()
        if a[7]:
            return kernel_entry(name), a
        if self.model.full_kernel:
            return kernel_entry(name + "_full"), a[:7]
        return kernel_entry(name + "_plain"), a[:7]

    @property
    def t(self) -> np.ndarray:
        """Sample times [s], starting at 0."""
        return np.arange(self.n) * self.dt

    def kernel_vector(self, params: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """``(p, q)`` kernel vectors; parameters of effects that are off at their nulls."""
        return self.model.kernel_vectors(params)

    def run(self, kv, *, max_events: int = 0):
        """Simulate one pair of kernel vectors ``(p, q)``.

        Returns
        -------
        status : int
            0 on success, see :data:`rotorbayes.kernel.layout.STATUS_MESSAGES`.
        arrays : tuple
            ``(theta_u, omega_u, theta_l, omega_l, mode_u, mode_l, events, n_events)``.
        """
        p, q = kv
        n = self.n
        out = [np.empty(n) for _ in range(4)] + [np.empty(n, np.int8) for _ in range(2)]
        ev = np.empty((max_events, 3))
        fn, a = self._entry("simulate_into")
        status, n_ev = fn(np.ascontiguousarray(p, dtype=float),
                          np.ascontiguousarray(q, dtype=float), *a, *out, ev)  # fmt: skip
        return status, (*out, ev[: min(n_ev, max_events)], n_ev)

    def angles(self, kv):
        """``(status, theta_u, theta_l)`` for one pair of kernel vectors (the fast path)."""
        status, arr = self.run(kv)
        return status, arr[0], arr[2]

    def run_batch(self, P: np.ndarray, Q: np.ndarray | None = None):
        """Simulate many kernel vectors in parallel (numba ``prange``).

        Returns ``(status[m], theta_u[m, n], theta_l[m, n])``.
        """
        P = np.ascontiguousarray(np.atleast_2d(P), dtype=float)
        m = P.shape[0]
        if Q is None:
            Q = np.zeros((m, 0))
        Q = np.ascontiguousarray(np.reshape(Q, (m, -1)), dtype=float)
        thu = np.empty((m, self.n))
        thl = np.empty((m, self.n))
        st = np.empty(m, dtype=np.int64)
        fn, a = self._entry("simulate_batch_into")
        fn(P, Q, *a, thu, thl, st)
        return st, thu, thl

    def residuals_into(self, kv, r, row, channels) -> int:
        """Weighted residuals of one pair of kernel vectors, written into ``r[row]``.

        ``channels`` is a sequence of ``(measured angles, weight, column)`` for
        ``theta_u`` and ``theta_l`` (``None`` for a channel left out): ``r[row, column + k]
        = weight * (measured[k] - simulated[k])``.  No output arrays are made (the fast
        path of a fit or a posterior); the numbers equal those from :meth:`angles`
        followed by the same subtraction.  A failed run leaves NaN residuals.  Returns
        the status (0 on success).
        """
        p, q = kv
        p = np.ascontiguousarray(p, dtype=float)
        q = np.ascontiguousarray(q, dtype=float)
        (mu, wu, cu), (ml, wl, cl) = _channel_args(channels)
        fn, a = self._entry("residuals_into")
        return int(fn(p, q, *a, mu, ml, wu, wl, r, row, cu, cl))

    def residuals_batch_into(self, P, Q, R, channels) -> np.ndarray:
        """:meth:`residuals_into` for every row of ``P`` (``Q``) in parallel: row ``j`` of
        ``R`` receives the residuals of row ``j``.  Returns the status per row."""
        P = np.ascontiguousarray(np.atleast_2d(P), dtype=float)
        m = P.shape[0]
        if Q is None:
            Q = np.zeros((m, 0))
        Q = np.ascontiguousarray(np.reshape(Q, (m, -1)), dtype=float)
        (mu, wu, cu), (ml, wl, cl) = _channel_args(channels)
        st = np.empty(m, dtype=np.int64)
        fn, a = self._entry("residuals_batch_into")
        fn(P, Q, *a, mu, ml, wu, wl, R, cu, cl, st)
        return st

    def simulate(
        self,
        params: Mapping[str, float],
        *,
        max_events: int = 100_000,
        raise_on_failure: bool = True,
        strict: bool = True,
    ) -> Simulation:
        """Full simulation with velocities, modes and events (see :class:`Simulation`).

        ``strict`` refuses a non-null value for a parameter of an effect that is off.
        """
        params = self.model.complete(params)
        if strict:
            self.model.check_off(params)
        problems = self.model.problems(params)
        if problems and raise_on_failure:
            raise SimulationError("cannot simulate: " + "; ".join(problems))
        kv = self.kernel_vector(params)
        status, (thu, wu, thl, wl, mu, ml, ev, n_ev) = self.run(kv, max_events=max_events)
        if status != _k.OK and raise_on_failure:
            why = _k.STATUS_MESSAGES[status]
            if status == _k.BAD_PARAMETERS and problems:
                why += ": " + "; ".join(problems)
            vals = ", ".join(f"{n}={params[n]:g}" for n in (*NAMES, *self.model.user_names))
            raise SimulationError(f"integration failed: {why} (parameters: {vals})")
        lower = self.config != "upper"
        return Simulation(
            t=self.t,
            u=self.u.copy(),
            theta_u=thu,
            theta_l=thl if lower else None,
            omega_u=wu,
            omega_l=wl if lower else None,
            mode_u=mu,
            mode_l=ml if lower else None,
            events=ev,
            params=dict(params),
            config=self.config,
            effects=self.effects,
            meta={"status": _k.STATUS_MESSAGES[status], "n_events": str(n_ev)},
            status=int(status),
        )


def _check_number(v, name: str, what: str) -> None:
    """:class:`ValueError` naming ``name`` unless ``v`` is a real number (NaN is the
    simulation's own business: it names the parameter)."""
    if isinstance(v, np.ndarray) and v.ndim == 0 and v.dtype.kind in "fiu":
        return
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        raise ValueError(f"{name} = {v!r} is not a number; give {what} as a number")


_NO_MEAS = np.empty(0)


def _channel_args(channels):
    """Kernel arguments ``(measured, weight, column)`` of the theta_u and theta_l channels."""
    out = []
    for ch in channels:
        if ch is None:
            out.append((_NO_MEAS, 1.0, -1))
        else:
            meas, w, col = ch
            meas = np.ascontiguousarray(meas, dtype=float)
            if not meas.flags.writeable:  # the kernel takes writable arrays only
                meas = meas.copy()
            out.append((meas, float(w), int(col)))
    return out


def simulate(
    params=None,
    u=None,
    *,
    dt: float | None = None,
    t=None,
    config: str = "brake",
    alpha0: float | None = None,
    theta_u=None,
    effects: Iterable[str] = (),
    shape: str = "exp",
    step: float | None = DEFAULT_STEP,
    quantize_angles: bool = False,
    noise_std: float = 0.0,
    seed: int | np.random.Generator | None = None,
    max_events: int = 100_000,
) -> Simulation:
    """Simulate the rig for one input.

    Parameters
    ----------
    params : mapping, str or None
        Parameter values by name (missing ones from the configuration's default set,
        thesis chapter 4 P_ref), a named set such as ``'thesis:4.3:P_ref'``, or a TOML
        file path.
    u : array
        Input voltage [V] at uniform samples.
    dt, t : float or array
        Sample interval [s], or the sample times (must be uniform).
    config : {'upper', 'coupled', 'brake'}
    alpha0 : float, optional
        Initial string torsion [rad]; overrides ``params['alpha0']``.
    theta_u : array, optional
        Prescribed upper-disc angle [rad]; the lower disc is driven by it.
    effects : iterable of str
        Effects to switch on besides the configuration's base model: catalogue names or
        ``'FILE.py:NAME'`` user effects (see :mod:`rotorbayes.model.effects`).  A
        non-null value for a parameter of an effect that is off is refused.
    shape : {'exp', 'rational'}
        Stribeck curve shape.
    step : float, optional
        Largest integration step [s] (default: chosen from the sample interval, see
        :func:`default_step`).
    quantize_angles : bool
        Round the angles to the encoders' resolution (thesis §2.2).
    noise_std : float
        Standard deviation [rad] of Gaussian noise added before quantisation.
    seed : int or Generator, optional
        Random source of the noise.

    Returns
    -------
    Simulation

    Raises
    ------
    SimulationError
        The parameters are physically invalid or the integration failed.
    ValueError
        An argument is not what it must be (text for ``u`` or a parameter value, a
        2-D ``u``, a ``dt`` that is not a positive number); the message names it.
        Read-only arrays (``np.load(..., mmap_mode="r")``, pandas columns) are accepted:
        the compiled kernel gets a copy.
    """
    check_config(config)
    if isinstance(params, Mapping):
        for k, v in params.items():
            _check_number(v, f"params[{k!r}]", "its value")
        user = {k: v for k, v in params.items() if k not in NAMES}
        p = resolve({k: v for k, v in params.items() if k in NAMES}, config=config)
        p.update(user)
    else:
        p = resolve(params, config=config)
    if isinstance(effects, str):
        effects = [effects]  # one name, not its letters
    effects = list(effects)
    for v, name, what in (
        (alpha0, "alpha0", "the initial string torsion [rad]"),
        (noise_std, "noise_std", "a standard deviation [rad], >= 0"),
    ):
        if v is not None:
            _check_number(v, name, what)
    if noise_std is not None and not noise_std >= 0:
        raise ValueError(f"noise_std = {noise_std!r}: give a standard deviation [rad], >= 0")
    if alpha0 is not None:
        p["alpha0"] = float(alpha0)
        if alpha0 != 0.0 and config != "upper" and "initial_torsion" not in effects:
            effects.append("initial_torsion")
    if u is None:
        if theta_u is None:
            raise ValueError("give the input voltage u (or a prescribed theta_u)")
        u = np.zeros(len(theta_u))
    if t is not None:
        t = samples(t, "t", "the sample times [s]")
        steps = np.diff(t)
        if t.ndim != 1 or t.size != len(u) or np.any(steps <= 0):
            raise ValueError("t must be increasing and have as many samples as u")
        med = float(np.median(steps))
        if np.max(np.abs(steps - med)) > 1e-6 * med:
            raise ValueError("t must be uniformly sampled (resample the input first)")
        dt = med
    if dt is None:
        raise ValueError("give the sample interval dt [s] or the sample times t")
    sim = Simulator(config, u, dt, theta_u=theta_u, effects=effects, shape=shape, step=step)
    out = sim.simulate(p, max_events=max_events)
    if t is not None:
        out.t = t.copy()
    if noise_std or quantize_angles:
        rng = np.random.default_rng(seed)
        if noise_std:
            out.theta_u = add_noise(out.theta_u, noise_std, rng)
            if out.theta_l is not None:
                out.theta_l = add_noise(out.theta_l, noise_std, rng)
        if quantize_angles:
            out.theta_u = quantize(out.theta_u, UPPER_COUNTS_PER_REV)
            if out.theta_l is not None:
                out.theta_l = quantize(out.theta_l, LOWER_COUNTS_PER_REV)
    if theta_u is not None:
        out.meta["prescribed"] = "theta_u"
    return out


__all__ = [
    "CONFIGS",
    "Model",
    "DEFAULT_STEP",
    "default_step",
    "Simulation",
    "SimulationError",
    "Simulator",
    "simulate",
    "ParameterError",
]
