"""Beyond the catalogue: the missing-torque map.

With the fitted parameters and the *measured* angles (smoothed derivatives), each disc's
equation of motion should balance.  What is left over is the torque the model lacks:

    M_l = J_l θl'' + T_fl(ωl) + k_alpha α + c_alpha α'                      (lower disc)
    M_u = J_u θu'' + T_fu(ωu) − k_alpha α − c_alpha α' − k_m v(t)             (upper disc)

(friction levels shifted and torques added by user effects included).  Only samples in
clear slip are used: at rest friction is set-valued and balances anything.

The map ranks how much of ``M`` each candidate variable explains (adjusted R² of a
binned-mean or harmonic fit): the disc's velocity and its direction, its angle within a
revolution (once and twice per revolution), the string's torsion, the input and its rate,
time.  The strongest dependence is said in words, with what physics usually causes it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..inference.problem import Problem
from ..inference.starts import _slip_mask, derivatives
from ..model.friction import friction_curve

#: Words for a dependence: (what varies, what usually causes it).
WORDS = {
    "velocity": ("varies with its speed", "a friction law unlike the model's (viscous "
                 "or Stribeck part, or their asymmetry)"),
    "direction": ("depends on the direction of rotation", "friction that differs between "
                  "the two directions (asymmetric Coulomb or viscous friction)"),
    "angle_1": ("varies with its angle, once per revolution", "friction or load varying "
                "with angle (an eccentric or uneven bearing or brake surface)"),
    "angle_2": ("varies with its angle, twice per revolution", "friction or load varying "
                "with angle (an oval or misaligned contact)"),
    "torsion": ("varies with the string's torsion", "a string stiffness that is not "
                "linear, or damping in the string"),
    "input": ("varies with the input voltage", "a motor constant, offset or dead zone "
              "unlike the model's"),
    "input_rate": ("follows changes of the input", "a delay or dynamics between the "
                   "command and the motor torque"),
    "time": ("drifts with time", "slow changes: temperature, wear, or a drifting sensor"),
}


@dataclass
class TorqueMap:
    """The missing torque of one disc and what it depends on."""

    disc: str
    t: np.ndarray = field(repr=False)
    torque: np.ndarray = field(repr=False)
    features: dict[str, np.ndarray] = field(repr=False)
    ranking: list[tuple[str, float]]
    rms: float
    noise_rms: float

    @property
    def strongest(self) -> tuple[str, float] | None:
        return self.ranking[0] if self.ranking else None

    def words(self, min_r2: float = 0.2) -> str:
        disc = "upper" if self.disc == "u" else "lower"
        s = self.strongest
        if s is None or s[1] < min_r2 or self.rms < 2 * self.noise_rms:
            return (f"the {disc} disc's missing torque (RMS {self.rms:.2g} N m) shows no "
                    "clear dependence on the candidate variables")
        what, cause = WORDS[s[0]]
        return (f"the {disc} disc lacks a torque (RMS {self.rms:.2g} N m) that {what} "
                f"(explains {100 * s[1]:.0f} % of it): {cause}")

    def as_dict(self) -> dict:
        return {"disc": self.disc, "rms_N_m": self.rms, "noise_rms_N_m": self.noise_rms,
                "ranking": [{"variable": k, "adjusted_r2": v} for k, v in self.ranking],
                "words": self.words()}


def _adj_r2(y: np.ndarray, X: np.ndarray) -> float:
    n, k = X.shape
    if n <= k + 1:
        return math.nan
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    ss = float(np.sum((y - X @ beta) ** 2))
    st = float(np.sum((y - y.mean()) ** 2))
    if st <= 0:
        return 0.0
    return 1 - (ss / (n - k)) / (st / (n - 1))


def _binned(x: np.ndarray, n_bins: int = 16) -> np.ndarray:
    """Indicator columns of quantile bins of ``x``."""
    edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, max(len(edges) - 2, 0))
    X = np.zeros((x.size, idx.max() + 1))
    X[np.arange(x.size), idx] = 1.0
    return X


def _rank(M: np.ndarray, feats: dict[str, np.ndarray]) -> list[tuple[str, float]]:
    one = np.ones((M.size, 1))
    out = []
    for k, v in feats.items():
        if k == "direction":
            X = np.column_stack([one, v])
        elif k.startswith("angle_"):
            # A load varying with angle acts alike in both directions; a friction level
            # varying with angle acts against the motion: both columns, with the sign.
            h = int(k[-1])
            s = feats["direction"]
            X = np.column_stack([one, s, np.sin(h * v), np.cos(h * v), s * np.sin(h * v),
                                 s * np.cos(h * v)])
        elif k == "time":
            # A drift is a trend, not any function of time (which would explain everything).
            tt = (v - v.mean()) / max(np.ptp(v), 1e-12)
            X = np.column_stack([one, tt, tt**2])
        else:
            if np.ptp(v) == 0:
                continue
            X = _binned(v)
        out.append((k, _adj_r2(M, X)))
    return sorted([o for o in out if math.isfinite(o[1])], key=lambda kv: -kv[1])


def missing_torque(problem: Problem, x: np.ndarray, *, window: float = 0.1) -> list[TorqueMap]:
    """The missing-torque maps of the discs the problem models (lower, then upper)."""
    m = problem.model
    maps = {"l": [], "u": []}
    use, hook_t, hook_s = m.hooks()
    for i, ex in enumerate(problem.experiments):
        p = problem.params_for(x, i)
        dt = ex.dt
        thu, wu, au, n = derivatives(ex.theta_u, dt, window)
        t = ex.t
        u = ex.u
        v = _voltage(u, t, p)
        if ex.theta_l is not None:
            thl, wl, al, _ = derivatives(ex.theta_l, dt, window)
            alpha = thl - thu + p.get("alpha0", 0.0)
            dalpha = wl - wu
        else:
            thl = wl = al = alpha = dalpha = np.zeros_like(thu)
        c_alpha = p.get("c_alpha", 0.0) if "c_alpha" in m.active else 0.0
        string = p.get("k_alpha", 0.0) * alpha + c_alpha * dalpha if ex.theta_l is not None \
            else 0.0
        extra_u = np.zeros_like(t)
        extra_l = np.zeros_like(t)
        shift_u = np.zeros_like(t)
        shift_l = np.zeros_like(t)
        if use:
            pv, qv = m.kernel_vectors(p)
            for k in range(t.size):
                a_u, a_l = hook_t(t[k], thu[k], wu[k], thl[k], wl[k], v[k], pv, qv)
                s_u, s_l = hook_s(t[k], thu[k], wu[k], thl[k], wl[k], v[k], pv, qv)
                extra_u[k], extra_l[k] = a_u, a_l
                shift_u[k], shift_l[k] = s_u, s_l
        du = np.gradient(u, dt)
        common = {"input": v, "input_rate": du, "time": t}
        if ex.theta_l is not None and m.configuration.has_lower:
            fl = np.nan_to_num(friction_curve(wl, _complete(p), "l", shape=problem.shape))
            Ml = p["J_l"] * al + fl + np.sign(wl) * shift_l + string - extra_l
            sel = _slip_mask(wl, n, 0.02)
            maps["l"].append((t[sel], Ml[sel], {
                "velocity": wl[sel], "direction": np.sign(wl[sel]),
                "angle_1": np.mod(thl[sel], 2 * np.pi), "angle_2": np.mod(thl[sel], 2 * np.pi),
                "torsion": alpha[sel], **{k: c[sel] for k, c in common.items()}}))
        if not problem.prescribed_upper:
            fu = np.nan_to_num(friction_curve(wu, _complete(p), "u"))
            Mu = p["J_u"] * au + fu + np.sign(wu) * shift_u - string - p["k_m"] * v - extra_u
            sel = _slip_mask(wu, n, 0.02)
            feats = {"velocity": wu[sel], "direction": np.sign(wu[sel]),
                     "angle_1": np.mod(thu[sel], 2 * np.pi),
                     "angle_2": np.mod(thu[sel], 2 * np.pi),
                     **{k: c[sel] for k, c in common.items()}}
            if ex.theta_l is not None:
                feats["torsion"] = alpha[sel]
            maps["u"].append((t[sel], Mu[sel], feats))
    out = []
    for disc in ("l", "u"):
        parts = maps[disc]
        if not parts or sum(len(pt[0]) for pt in parts) < 50:
            continue
        T = np.concatenate([pt[0] for pt in parts])
        M = np.concatenate([pt[1] for pt in parts])
        F = {k: np.concatenate([pt[2][k] for pt in parts]) for k in parts[0][2]}
        # Noise of M: the sample-to-sample jitter of a smooth signal is mostly noise.
        noise = float(np.std(np.diff(M)) / math.sqrt(2)) if M.size > 2 else 0.0
        out.append(TorqueMap(disc, T, M, F, _rank(M, F), float(np.sqrt(np.mean(M**2))),
                             noise))
    return out


def _complete(p: dict) -> dict:
    q = dict(p)
    for k in ("dTc_l", "db_l", "dTc_u", "db_u"):
        q[k] = q.get(k, 0.0) if q.get(k) is not None else 0.0
    return q


def _voltage(u: np.ndarray, t: np.ndarray, p: dict) -> np.ndarray:
    """The effective motor voltage (offset, delay, dead zone) at the sample times."""
    d = p.get("t_delay", 0.0) or 0.0
    v = np.interp(t - d, t, u, left=0.0) if d > 0 else u.copy()
    v = v + (p.get("u_offset", 0.0) or 0.0)
    dz = p.get("u_deadzone", 0.0) or 0.0
    if dz > 0:
        v = np.where(v > dz, v - dz, np.where(v < -dz, v + dz, 0.0))
    return v
