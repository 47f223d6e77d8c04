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
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from . import effects as _effects
from . import integrator as _k
from .data import LOWER_COUNTS_PER_REV, UPPER_COUNTS_PER_REV, Experiment, add_noise, quantize
from .friction import shape_code
from .parameters import INDEX, NAMES, ParameterError, resolve

CONFIGS = ("upper", "coupled", "brake")
#: Default largest Runge-Kutta step [s].  Verified against an event-driven reference
#: (tests/test_integrator_accuracy.py); use ``step=dt`` for rough, noisy inputs.
DEFAULT_STEP = 5e-3


class SimulationError(RuntimeError):
    """The integrator reported a failure; the message names the parameter values."""


def check_config(config: str) -> str:
    """Return ``config`` or raise a ValueError listing the valid configurations."""
    if config not in CONFIGS:
        raise ValueError(f"unknown configuration {config!r}; choose one of {', '.join(CONFIGS)}")
    return config


def physics_problems(p: Mapping[str, float], config: str = "brake") -> list[str]:
    """Reasons why a parameter set cannot be simulated (empty if it can)."""
    out = []
    for n in NAMES:
        if n in p and not math.isfinite(p[n]) and not (n == "Ts_l" and math.isnan(p[n])):
            out.append(f"{n} = {p[n]} is not finite")
    checks = [("J_u", p["J_u"] > 0, "must be > 0")]
    checks += [
        (
            "Tc_u",
            p["Tc_u"] >= abs(p["dTc_u"]),
            f"must be >= |dTc_u| = {abs(p['dTc_u']):g} "
            "(friction may not push in the direction of motion)",
        ),
        ("b_u", p["b_u"] >= abs(p["db_u"]), f"must be >= |db_u| = {abs(p['db_u']):g}"),
        ("u_deadzone", p["u_deadzone"] >= 0, "must be >= 0"),
        ("t_delay", p["t_delay"] >= 0, "must be >= 0"),
    ]
    if config != "upper":
        checks += [
            ("J_l", p["J_l"] > 0, "must be > 0"),
            ("k_alpha", p["k_alpha"] >= 0, "must be >= 0"),
            ("c_alpha", p["c_alpha"] >= 0, "must be >= 0"),
            ("Tc_l", p["Tc_l"] >= abs(p["dTc_l"]), f"must be >= |dTc_l| = {abs(p['dTc_l']):g}"),
            ("b_l", p["b_l"] >= abs(p["db_l"]), f"must be >= |db_l| = {abs(p['db_l']):g}"),
            ("Ts_l", math.isnan(p["Ts_l"]) or p["Ts_l"] >= abs(p["dTc_l"]), "must be >= |dTc_l|"),
            ("ws_l", p["ws_l"] > 0, "must be > 0"),
            ("delta_l", p["delta_l"] > 0, "must be > 0"),
        ]
    for name, ok, why in checks:
        if not ok:
            out.append(f"{name} = {p[name]:g} {why}")
    return out


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


class Simulator:
    """A configuration and one experiment's input, ready to simulate many parameter sets.

    Parameters
    ----------
    config : {'upper', 'coupled', 'brake'}
        Rig configuration: string removed, no brake, or brake applied.
    u : array
        Input voltage [V] at uniform samples (linearly interpolated in between).
    dt : float
        Sample interval [s].
    theta_u : array, optional
        Prescribed upper-disc angle [rad] at the same samples.  The lower disc is then
        driven by this motion and ``u`` is not used (fit the lower disc with the
        measured upper angle as input).
    effects : iterable of str
        Catalogue effects switched on (see :mod:`rotorbayes.effects`).  The Stribeck
        part of the lower friction is on for ``'brake'`` or with ``'lower_stribeck'``.
    shape : {'exp', 'rational'}
        Stribeck curve shape.
    step : float
        Largest Runge-Kutta step [s]; the step is a whole number of samples (or a
        whole fraction of one).
    """

    def __init__(
        self,
        config: str,
        u,
        dt: float,
        *,
        theta_u=None,
        effects: Iterable[str] = (),
        shape: str = "exp",
        step: float = DEFAULT_STEP,
    ):
        self.config = check_config(config)
        self.effects = tuple(effects)
        for e in self.effects:
            _effects.get(e)
        self.u = np.ascontiguousarray(u, dtype=float)
        if self.u.ndim != 1 or self.u.size < 2:
            raise ValueError(
                f"u must be a 1-D array of at least 2 samples, got shape {self.u.shape}"
            )
        if not np.all(np.isfinite(self.u)):
            i = int(np.flatnonzero(~np.isfinite(self.u))[0])
            raise ValueError(f"u[{i}] = {self.u[i]} is not finite; the input must be finite")
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt = {dt} must be a positive sample interval in seconds")
        self.dt = float(dt)
        self.n = self.u.size
        self.prescribed = theta_u is not None
        if self.prescribed:
            if config == "upper":
                raise ValueError(
                    "a prescribed upper-disc motion needs the 'coupled' or 'brake' "
                    "configuration (the lower disc must be present)"
                )
            self.theta_u = np.ascontiguousarray(theta_u, dtype=float)
            if self.theta_u.shape != self.u.shape:
                raise ValueError(f"theta_u has {self.theta_u.size} samples but u has {self.n}")
            self.cfg = _k.CFG_PRESCRIBED
        else:
            self.theta_u = self.u  # unused by the kernel
            self.cfg = _k.CFG_UPPER if config == "upper" else _k.CFG_COUPLED
        self.stribeck = config == "brake" or "lower_stribeck" in self.effects
        self.shape = shape_code(shape)
        if not (step > 0):
            raise ValueError(f"step = {step} must be > 0 seconds")
        if step >= self.dt:
            self.stride, self.substeps = max(1, int(math.floor(step / self.dt + 1e-9))), 1
        else:
            self.stride, self.substeps = 1, int(math.ceil(self.dt / step - 1e-9))

    @property
    def _kernel_args(self) -> tuple:
        """The kernel's experiment arguments, shared by single and batched runs."""
        return (self.u, self.dt, self.cfg, self.shape, self.stride, self.substeps, self.theta_u)

    @property
    def t(self) -> np.ndarray:
        """Sample times [s], starting at 0."""
        return np.arange(self.n) * self.dt

    def kernel_vector(self, params: Mapping[str, float]) -> np.ndarray:
        """Parameter vector in kernel order; switches the Stribeck part off if inactive."""
        kv = np.array([params[n] for n in NAMES], dtype=float)
        if not self.stribeck or math.isnan(kv[INDEX["Ts_l"]]):
            kv[INDEX["Ts_l"]] = kv[INDEX["Tc_l"]]
        return kv

    def run(self, kv: np.ndarray, *, max_events: int = 0):
        """Simulate one kernel vector.

        Returns
        -------
        status : int
            0 on success, see :data:`rotorbayes.integrator.STATUS_MESSAGES`.
        arrays : tuple
            ``(theta_u, omega_u, theta_l, omega_l, mode_u, mode_l, events, n_events)``.
        """
        n = self.n
        out = [np.empty(n) for _ in range(4)] + [np.empty(n, np.int8) for _ in range(2)]
        ev = np.empty((max_events, 3))
        status, n_ev = _k.simulate_into(
            np.ascontiguousarray(kv, dtype=float), *self._kernel_args, *out, ev
        )
        return status, (*out, ev[: min(n_ev, max_events)], n_ev)

    def angles(self, kv: np.ndarray):
        """``(status, theta_u, theta_l)`` for one kernel vector (the fast path)."""
        status, arr = self.run(kv)
        return status, arr[0], arr[2]

    def run_batch(self, KV: np.ndarray):
        """Simulate many kernel vectors in parallel (numba ``prange``).

        Returns ``(status[m], theta_u[m, n], theta_l[m, n])``.
        """
        KV = np.ascontiguousarray(np.atleast_2d(KV), dtype=float)
        m = KV.shape[0]
        thu = np.empty((m, self.n))
        thl = np.empty((m, self.n))
        st = np.empty(m, dtype=np.int64)
        _k.simulate_batch_into(KV, *self._kernel_args, thu, thl, st)
        return st, thu, thl

    def simulate(
        self,
        params: Mapping[str, float],
        *,
        max_events: int = 100_000,
        raise_on_failure: bool = True,
    ) -> Simulation:
        """Full simulation with velocities, modes and events (see :class:`Simulation`)."""
        problems = physics_problems(params, self.config)
        if problems and raise_on_failure:
            raise SimulationError("cannot simulate: " + "; ".join(problems))
        kv = self.kernel_vector(params)
        status, (thu, wu, thl, wl, mu, ml, ev, n_ev) = self.run(kv, max_events=max_events)
        if status != _k.OK and raise_on_failure:
            vals = ", ".join(f"{n}={params[n]:g}" for n in NAMES)
            raise SimulationError(
                f"integration failed: {_k.STATUS_MESSAGES[status]} (parameters: {vals})"
            )
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
        )


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
    step: float = DEFAULT_STEP,
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
        Catalogue effects to switch on (see :mod:`rotorbayes.effects`).
    shape : {'exp', 'rational'}
        Stribeck curve shape.
    step : float
        Largest integration step [s].
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
    """
    check_config(config)
    p = resolve(params, config=config)
    if alpha0 is not None:
        p["alpha0"] = float(alpha0)
    if u is None:
        if theta_u is None:
            raise ValueError("give the input voltage u (or a prescribed theta_u)")
        u = np.zeros(len(theta_u))
    if t is not None:
        t = np.asarray(t, dtype=float)
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
    "DEFAULT_STEP",
    "Simulation",
    "SimulationError",
    "Simulator",
    "simulate",
    "ParameterError",
]
