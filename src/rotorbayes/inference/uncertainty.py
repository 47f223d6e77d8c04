"""Honest uncertainty of a fit: what the residuals say, and what the model leaves open.

The Gauss-Newton covariance ``s² (JᵀJ)⁻¹`` assumes independent errors.  On this rig they
are not: while a disc sticks or turns slowly the encoder's rounding error is constant or
periodic for hundreds of samples, and whatever the model gets wrong (friction shape, the
input between samples, physics it lacks) leaves errors that last as long as the motion that
causes them.  The i.i.d. formula then counts thousands of samples where the data hold far
fewer, and its standard errors come out 2–60× too small on stick-slip data.

:func:`fit_uncertainty` builds the covariance of the estimate from three parts:

* **noise** — rounding to encoder counts *as it is*: the fitted trajectory is rounded
  again with random sub-count phases (where a disc sits inside a count at the start is
  unknown), Gaussian noise is added where the floor says the data carry it, and the
  linearised estimator ``A⁺ Jᵀ e`` is applied to each error (:func:`rounding_covariance`,
  :data:`N_BOOT` draws).  Never narrower, in any direction, than white noise at the floor
  (``σ² (JᵀJ)⁻¹``, kept as ``cov_white`` for comparison);
* **model error shown by the residuals** — the delete-one-block jackknife of the residual
  scores over contiguous :data:`BLOCK_SECONDS` blocks (both channels of a time window in one
  block): what errors correlated over a block do to the estimate, whatever their cause.  At
  the floor the residual *is* the noise, so this part is weighted by the share of the
  residual's mean square above the floor, ``1 − 1.05² floor²/RMS²`` (an RMS within 5 %
  of the floor is noise);
* **input hold** — the input between samples is a model too: the file holds samples, an
  amplifier holds or filters them, no file says which.  rotorbayes interpolates linearly;
  the same samples through a smooth (cubic-spline) interpolant move the estimate by
  ``Δθ = A⁺ Jᵀ Δr``.  The data weigh the two input models: the SSR of each after its
  Gauss-Newton step, in noise units and deflated by the errors' correlation, is a
  log-likelihood ratio, and with equal prior odds the smooth model's weight ``w`` follows;
  ``w Δθ Δθᵀ`` (the mean squared distance of the truth from the linear-input estimate under
  that mixture) is added.  At 200 Hz the data usually decide (``w`` near 0 or 1); at 1 kHz
  they often cannot, and the allowance stays.

The parts add.  Interval quantiles are Student's t with Welch–Satterthwaite degrees of
freedom per parameter (the jackknife has B − 1, the noise simulation ``N_BOOT − 1``, the
allowance is taken as known).  ``n_eff``, the effective number of independent samples, is
the number of white samples at the floor that would carry the information the noise part
leaves (median over parameters).

What is left out: the constant sub-count offset (up to half a count) a real encoder adds
once a disc has moved (simulated data have none); the bias of physics the model lacks, which
no residual of one experiment shows in full.  When the fit is far from the floor
(:data:`FAR_FROM_FLOOR`), every interval is conditional on a model the data reject, and the
output says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

#: Length of one block of the block sandwich [s]: long enough to hold a typical stick phase
#: or a slow-turning stretch whose rounding error repeats, short enough for ≥ 30 blocks
#: in 30 s of data.
BLOCK_SECONDS = 1.0
#: Fewest blocks: with fewer, shorter blocks are used (down to :data:`MIN_BLOCK_SECONDS`).
MIN_BLOCKS = 30
MIN_BLOCK_SECONDS = 0.2
#: Worst channel's RMS / floor above which the intervals are said to be conditional on a
#: model the data reject.
FAR_FROM_FLOOR = 3.0
#: Upsampling factor of the smooth-input simulation of the input-hold allowance.
HOLD_UPSAMPLE = 8
#: Largest fine grid of that simulation [samples]; longer data get a smaller factor (>= 2).
HOLD_MAX_FINE = 24_000_000
#: Mean square of RMS/floor up to which the residual counts as noise alone (RMS 5 % above
#: the floor: rounding while discs stick scatters the RMS that much around q/√12).
NOISE_MS = 1.05**2
#: Draws of the rounding simulation (:func:`rounding_covariance`).
N_BOOT = 200


@dataclass
class Uncertainty:
    """Covariances of a fit's estimates and what they assume (see the module docstring)."""

    names: list[str]
    x: np.ndarray
    cov: np.ndarray
    cov_white: np.ndarray
    cov_noise: np.ndarray
    cov_model: np.ndarray
    cov_hold: np.ndarray
    n_blocks: int
    block_seconds: float
    n_samples: int
    n_eff: float
    rms_over_floor: float
    noise_share: float
    dof: np.ndarray
    notes: list[str] = field(default_factory=list)
    hold_weight: float = 0.0

    @property
    def stderr(self) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            return np.sqrt(np.diag(self.cov))

    @property
    def stderr_white(self) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            return np.sqrt(np.diag(self.cov_white))

    @property
    def misspecified(self) -> bool:
        return self.rms_over_floor > FAR_FROM_FLOOR

    def quantile(self, level: float) -> np.ndarray:
        """Half-width of the central ``level`` interval in standard errors, per parameter
        (Student's t with the Welch–Satterthwaite degrees of freedom)."""
        from scipy.special import stdtrit  # Student's t quantile (scipy.stats: 0.3 s import)

        return stdtrit(np.maximum(self.dof, 1.0), 0.5 + level / 2)

    def shares(self) -> dict[str, dict[str, float]]:
        """Per parameter: the share of the total variance that is noise, model error shown
        by the residuals, and the input-hold allowance (they add to 1)."""
        out = {}
        for j, n in enumerate(self.names):
            tot = self.cov[j, j]
            if not (math.isfinite(tot) and tot > 0):
                out[n] = {"noise": math.nan, "model_error": math.nan, "input_hold": math.nan}
                continue
            out[n] = {
                "noise": self.cov_noise[j, j] / tot,
                "model_error": self.cov_model[j, j] / tot,
                "input_hold": self.cov_hold[j, j] / tot,
            }
        return out

    def inflation(self) -> np.ndarray:
        """Total standard error over the white-noise one, per parameter."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.stderr / self.stderr_white

    def assumptions(self) -> str:
        return (
            "rounding to encoder counts simulated as it is (constant while a disc sticks); "
            f"other errors correlated within {self.block_seconds:.3g} s blocks and "
            f"independent between them ({self.n_blocks} blocks); the input between samples "
            f"linear or smooth (the data weigh smooth {self.hold_weight:.2f}); the model's "
            "structure taken as right" + (" — which these data reject" if self.misspecified else "")
        )

    def as_dict(self) -> dict:
        sh = self.shares()
        se, sw = self.stderr, self.stderr_white
        return {
            "method": "rounding simulated + block jackknife (model error) + input-hold allowance",
            "assumptions": self.assumptions(),
            "n_blocks": self.n_blocks,
            "block_seconds": self.block_seconds,
            "dof_min": _num(np.min(self.dof)) if len(self.dof) else None,
            "n_samples": self.n_samples,
            "n_eff": self.n_eff,
            "input_hold_weight": self.hold_weight,
            "rms_over_floor": self.rms_over_floor,
            "misspecified": self.misspecified,
            "notes": self.notes,
            "parameters": {
                n: {
                    "stderr": _num(se[j]),
                    "stderr_white": _num(sw[j]),
                    "inflation": (
                        _num(se[j] / sw[j])
                        if np.isfinite(se[j]) and np.isfinite(sw[j]) and sw[j] > 0
                        else None
                    ),
                    "share_noise": _num(sh[n]["noise"]),
                    "share_model_error": _num(sh[n]["model_error"]),
                    "share_input_hold": _num(sh[n]["input_hold"]),
                    "dof": _num(self.dof[j]),
                }
                for j, n in enumerate(self.names)
            },
        }

    def warning(self) -> str | None:
        """A sentence for the user when the intervals rest on a model the data reject."""
        if not self.misspecified:
            return None
        return (
            f"the fit is {self.rms_over_floor:.3g}x the noise floor: a physical effect is "
            "missing or the fit ended in a wrong basin (try `rotorbayes multistart`), and "
            "every interval is conditional on a model these data reject (the estimates are "
            "the best of a wrong model or a local minimum; standard errors carry the "
            "residual's size and correlation, not that bias). Run `rotorbayes diagnose` "
            "and add what is missing before trusting the numbers."
        )


def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None


def _segments(problem):
    """(experiment index, channel, offset, n, dt) of every residual segment, in order."""
    out, off = [], 0
    for i, ex in enumerate(problem.experiments):
        for c in problem.channels:
            out.append((i, c, off, ex.n, ex.dt))
            off += ex.n
    return out


def block_scores(
    problem,
    J: np.ndarray,
    r: np.ndarray,
    block_seconds: float | None = None,
    *,
    with_information: bool = False,
    col_scale: np.ndarray | None = None,
):
    """Scores ``J_bᵀ r_b`` of contiguous time blocks (rows) and the block length used [s].

    Both channels of one experiment's time window go into one block.  The block length is
    :data:`BLOCK_SECONDS`, shortened (not below :data:`MIN_BLOCK_SECONDS`) when the data
    are too short for :data:`MIN_BLOCKS` blocks.  ``col_scale`` ``d``: the scores of
    ``J / d`` (without a scaled copy of ``J``).
    """
    total = sum(ex.n * ex.dt for ex in problem.experiments)
    if block_seconds is None:
        block_seconds = min(BLOCK_SECONDS, max(MIN_BLOCK_SECONDS, total / MIN_BLOCKS))
    d = np.ones(J.shape[1]) if col_scale is None else np.asarray(col_scale, float)
    dd = np.outer(d, d)
    rows, info = [], []
    segs = _segments(problem)
    for i, ex in enumerate(problem.experiments):
        mine = [s for s in segs if s[0] == i]
        L = max(1, int(round(block_seconds / ex.dt)))
        nb = max(1, ex.n // L)
        for b in range(nb):
            a = b * L
            e = ex.n if b == nb - 1 else (b + 1) * L
            g = np.zeros(J.shape[1])
            ab = np.zeros((J.shape[1], J.shape[1]))
            for _, _, off, _, _ in mine:
                Jb = J[off + a : off + e]
                g += Jb.T @ r[off + a : off + e]
                if with_information:
                    ab += Jb.T @ Jb
            rows.append(g / d)
            info.append(ab / dd)
    if with_information:
        return np.array(rows), block_seconds, np.array(info)
    return np.array(rows), block_seconds


def col_norms(J: np.ndarray) -> np.ndarray:
    """Euclidean norm of every column of ``J`` without a temporary as large as ``J``
    (``numpy.linalg.norm`` squares a copy: long data)."""
    return np.sqrt(np.einsum("ij,ij->j", J, J))


def _gram(J: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``(J/d)ᵀ (J/d)`` without a scaled copy of ``J`` (long data: ``J`` is large)."""
    return (J.T @ J) / np.outer(d, d)


def _sym_sqrt(S: np.ndarray, inverse: bool = False) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    w = np.clip(w, 0.0, None)
    if inverse:
        w = np.where(w > 0, 1.0 / np.sqrt(np.where(w > 0, w, 1.0)), 0.0)
    else:
        w = np.sqrt(w)
    return (V * w) @ V.T


def robust_covariances(
    problem, J: np.ndarray, r: np.ndarray, floors: dict, *, block_seconds: float | None = None
):
    """White and block-robust covariances, in the scaled frame where ``JᵀJ`` is singular.

    Returns ``(cov_white, cov_robust, n_blocks, block_seconds, singular_mask)``.
    """
    k = J.shape[1]
    # Residual weights to noise units: every residual divided by its channel's floor
    # (times the channel weight already in r and J), one number per segment. Products
    # segment by segment: no scaled copies of J.
    d2 = np.zeros(k)
    M_white = np.zeros((k, k))
    for _, c, off, n, _ in _segments(problem):
        sig = floors[c] * problem.weights[c]
        Jseg = J[off : off + n]
        Gs = Jseg.T @ Jseg
        d2 += np.diag(Gs) / sig**2
        # White noise at the floor: Var(Jᵀe) = Jᵀ diag(σ²) J.
        M_white += sig**2 * Gs
    d = np.sqrt(d2)
    d = np.where(d > 0, d, 1.0)
    M_white /= np.outer(d, d)
    A = _gram(J, d)
    w, V = np.linalg.eigh(A)
    small = w <= 1e-12 * max(w.max(), 1e-300)
    Ainv = (V * np.where(small, 0.0, 1.0 / np.where(small, 1.0, w))) @ V.T
    G, bsec, Ab = block_scores(problem, J, r, block_seconds, with_information=True, col_scale=d)
    nb = G.shape[0]
    cov_white = Ainv @ M_white @ Ainv
    # Delete-one-block jackknife (one Gauss-Newton step per deleted block): unlike the plain
    # sandwich it sees that a block holding most of a parameter's information (the one
    # direction reversal, the one long stick) fits its own errors.
    D = np.empty_like(G)
    for b in range(nb):
        Ar = A - Ab[b]
        try:
            D[b] = np.linalg.solve(Ar, G[b])
        except np.linalg.LinAlgError:
            D[b] = np.linalg.lstsq(Ar, G[b], rcond=1e-12)[0]
    D -= D.mean(axis=0)
    cov_block = D.T @ D * ((nb - 1) / nb)
    # Never narrower than white noise at the floor, in any direction.
    cov_robust = loewner_max(cov_white, cov_block)
    unscale = 1.0 / np.outer(d, d)
    hit = np.zeros(k, bool)
    if small.any():
        hit = np.any(np.abs(V[:, small]) > 0.1, axis=1)
    return cov_white * unscale, cov_robust * unscale, nb, bsec, hit, (d, Ainv)


def rounding_covariance(
    problem,
    x: np.ndarray,
    J: np.ndarray,
    r: np.ndarray,
    floors: dict,
    *,
    n_boot: int = N_BOOT,
    seed: int = 0,
) -> np.ndarray | None:
    """Covariance of the estimate that rounding to encoder counts causes, by simulation.

    The encoders' error is not white: it is ``round((θ + φ)/q)·q − (θ + φ)``, a function of
    the angle and of the sub-count phase ``φ`` of the disc's position at the start, constant
    while a disc sticks and periodic while it turns steadily.  The fitted trajectory is
    rounded again with ``n_boot`` random phases per channel and experiment (Gaussian noise is
    added where the floor says the data carry it), and the linearised estimator
    ``A⁺ Jᵀ e`` is applied to each error.  Returns the covariance of those estimates
    (parameter units), or ``None`` when the fit cannot be simulated.
    """
    from ..io.measurements import LOWER_COUNTS_PER_REV, UPPER_COUNTS_PER_REV

    counts = {"theta_u": UPPER_COUNTS_PER_REV, "theta_l": LOWER_COUNTS_PER_REV}
    rng = np.random.default_rng(seed)
    d = col_norms(J)
    d = np.where(d > 0, d, 1.0)
    A = _gram(J, d)
    w, V = np.linalg.eigh(A)
    small = w <= 1e-12 * max(w.max(), 1e-300)
    Apinv = (V * np.where(small, 0.0, 1.0 / np.where(small, 1.0, w))) @ V.T
    if not np.all(np.isfinite(r)):
        return None
    segs = []
    off = 0
    for ex in problem.experiments:
        for c in problem.channels:
            meas = ex.theta_u if c == "theta_u" else ex.theta_l
            wt = problem.weights[c]
            # The fitted trajectory: r = w (meas − sim).
            sim = meas - r[off : off + ex.n] / wt
            q = 2 * math.pi / counts[c]
            # Until a disc first leaves the count it started in, its encoder reads 0.
            moved = np.abs(sim) >= q / 2
            first = int(np.argmax(moved)) if moved.any() else ex.n
            segs.append((c, off, ex.n, wt, sim, first))
            off += ex.n
    # The scores Jᵀe of every draw.  The rounding error of a draw is a sawtooth of the
    # fitted angle shifted by the draw's phase, so its scores are sums of J over the rows
    # whose sub-count position lies beyond the phase: one pass over each segment for all
    # draws (rounding_scores) instead of one pass over J per draw.  The Gaussian noise of a
    # segment, white with variance ``extra``, scores ``sqrt(extra) Jᵀz``: a normal vector
    # of covariance ``extra JᵀJ``, drawn as ``sqrt(extra) (JᵀJ)^½ z`` with ``z`` of ``k``
    # standard normals (the same distribution as ``n`` normals multiplied into ``J``: the
    # 4 x 600 s fit spent 6.9 of its 23 s drawing and multiplying 200 x 4.8 M of them).
    # The random numbers are drawn per draw and segment: the phase, then the segment's
    # ``k`` normals where the floor asks for noise beyond the rounding.
    k = J.shape[1]
    scores = np.zeros((n_boot, k))
    phase = np.empty((n_boot, len(segs)))
    qs = [2 * math.pi / counts[c] for c, *_ in segs]
    extra = [floors[c] ** 2 - q * q / 12 for (c, *_), q in zip(segs, qs, strict=True)]
    noisy = [i for i, e in enumerate(extra) if e > 0]
    Z = {i: np.empty((n_boot, k)) for i in noisy}
    for b in range(n_boot):
        for i, q in enumerate(qs):
            phase[b, i] = rng.uniform(-q / 2, q / 2)
            if extra[i] > 0:
                rng.standard_normal(k, out=Z[i][b])
    for i in noisy:
        _, o, n, wt, _, _ = segs[i]
        # In the columns' units (d): the square root keeps the directions these data
        # barely see, which an unscaled Gram's rounding would lose.
        root = _sym_sqrt(_gram(J[o : o + n], d))
        scores += (wt * math.sqrt(extra[i])) * (Z[i] @ root) * d
    for i, (c, o, n, wt, sim, first) in enumerate(segs):
        q = 2 * math.pi / counts[c]
        scores += wt * rounding_scores(sim, J[o : o + n], q, first, phase[:, i])
    D = (scores / d) @ Apinv
    return np.cov(D.T).reshape(k, k) / np.outer(d, d)


def rounding_scores(
    sim: np.ndarray, J: np.ndarray, q: float, first: int, phase: np.ndarray
) -> np.ndarray:
    """``Jᵀ e`` for the rounding error ``e = round((sim + φ)/q)·q − sim − φ`` of every phase
    ``φ`` in ``phase`` (``|φ| ≤ q/2``), with ``e = −sim`` on the rows before ``first`` (the
    encoder still reads 0 there); one row per phase.

    With ``s = sim/q`` and its sub-count part ``f = s − round(s)`` (in ``[−½, ½]``), the
    error is ``q (r − f − φ/q)`` where ``r`` is +1 for ``f > ½ − φ/q``, −1 for
    ``f < −½ − φ/q`` and 0 otherwise (exact ties, where rounding to even would decide,
    have measure zero).  The sums of ``J`` over those rows come from one histogram of
    ``f`` over the ``2 × len(phase)`` thresholds, so ``J`` is read once for all phases.
    """
    J = np.asarray(J, float)
    n, k = J.shape
    out = np.zeros((phase.size, k))
    if first > 0:
        out -= sim[:first] @ J[:first]
    if first >= n:
        return out
    s = sim[first:] / q
    f = s - np.round(s)
    Jr = J[first:]
    u = np.asarray(phase, float) / q
    edges = np.concatenate([0.5 - u, -0.5 - u])
    order = np.argsort(edges, kind="stable")
    # bin[i]: how many thresholds lie below f[i]; rows above threshold j are bin > pos[j].
    where = np.searchsorted(edges[order], f, side="left")
    pos = np.empty(edges.size, np.int64)
    pos[order] = np.arange(edges.size)
    hist = np.empty((edges.size + 1, k))
    for j in range(k):
        hist[:, j] = np.bincount(where, weights=Jr[:, j], minlength=edges.size + 1)
    below = np.cumsum(hist, axis=0)  # below[m]: sum of the rows in bins 0..m
    total = below[-1]
    up, down = pos[: u.size], pos[u.size :]
    saw = (total - below[up]) - below[down] - f @ Jr - u[:, None] * total
    out += q * saw
    return out


def loewner_max(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """The smallest-looking covariance at least as wide as ``P`` and ``Q`` in every direction
    (eigenvalues of ``Q`` in the frame where ``P`` is the identity, clipped below at 1)."""
    Ph = _sym_sqrt(P)
    Pi = _sym_sqrt(P, inverse=True)
    S = Pi @ Q @ Pi
    lam, U = np.linalg.eigh(0.5 * (S + S.T))
    return Ph @ ((U * np.maximum(lam, 1.0)) @ U.T) @ Ph


def hold_shift(
    problem, x: np.ndarray, J: np.ndarray, r: np.ndarray, *, upsample: int = HOLD_UPSAMPLE
) -> tuple[np.ndarray, float, float]:
    """Change of the estimate if the input between samples were smooth (cubic spline
    through the same samples) instead of linear, by one Gauss-Newton step ``A⁺ Jᵀ Δr``; and
    the SSR of the linear and of the smooth input model after that step."""
    from scipy.interpolate import CubicSpline

    if problem.prescribed_upper:
        return np.zeros(J.shape[1]), 0.0, 0.0
    dr = np.zeros_like(r)
    off = 0
    for i, ex in enumerate(problem.experiments):
        n = ex.n
        # Long data: at most HOLD_MAX_FINE samples on the fine grid (a 10 M-sample record
        # at 8x took 9 GiB), but never fewer than 2 per sample, which still resolves the
        # spline's bulge between two samples.
        K = max(2, min(int(upsample), HOLD_MAX_FINE // max(n, 1)))
        tf = ex.t[0] + np.arange((n - 1) * K + 1) * (ex.dt / K)
        uf = CubicSpline(ex.t, ex.u)(tf)
        # Only the input and its step on the fine grid: the angles there are never
        # compared, only the coarse samples are (no Experiment of zeros is built).
        fine = SimpleNamespace(u=uf, dt=float((tf[-1] - tf[0]) / (tf.size - 1)), theta_u=None)
        del tf
        # On the steps of the fit's own simulation (the same stage times): the two input
        # models differ by their inputs alone, not by two step grids' integration errors
        # (and the fine input's own grid, searched at K times the samples, took 0.28 s
        # of each 600 s experiment).
        coarse = problem.sims[i]
        ordinary = coarse.substeps == 1
        sim = problem.simulator_for(fine, steps_of=(coarse, K) if ordinary else None)
        del uf
        st, thu, thl = sim.angles(sim.kernel_vector(problem.params_for(x, i)))
        del sim
        st0, thu0, thl0 = coarse.angles(coarse.kernel_vector(problem.params_for(x, i)))
        for c in problem.channels:
            if st != 0 or st0 != 0:
                return np.full(J.shape[1], np.nan), math.nan, math.nan
            a = (thu if c == "theta_u" else thl)[::K]
            b = thu0 if c == "theta_u" else thl0
            # r = w (meas − sim): a smoother input changes r by −w Δsim.
            dr[off : off + n] = -problem.weights[c] * (a - b)
            off += n
    d = col_norms(J)
    d = np.where(d > 0, d, 1.0)
    # The estimate moves so that the new residual is again orthogonal to J: Δx = −A⁺ Jᵀ Δr.
    A = _gram(J, d)
    w, V = np.linalg.eigh(A)
    small = w <= 1e-10 * max(w.max(), 1e-300)
    Apinv = (V * np.where(small, 0.0, 1.0 / np.where(small, 1.0, w))) @ V.T
    rs = r + dr
    del dr
    g_s, g_l = (J.T @ rs) / d, (J.T @ r) / d
    step, step_lin = -Apinv @ g_s, -Apinv @ g_l
    # SSR after a Gauss-Newton step: |r|² − gᵀ A⁺ g.
    ssr_smooth = float(rs @ rs + g_s @ step)
    ssr_lin = float(r @ r + g_l @ step_lin)
    return (step - step_lin) / d, ssr_lin, ssr_smooth


def fit_uncertainty(
    problem,
    x: np.ndarray,
    J: np.ndarray,
    r: np.ndarray | None = None,
    *,
    floors: dict | None = None,
    hold: bool = True,
    rounding: bool = True,
    block_seconds: float | None = None,
    seed: int = 0,
) -> Uncertainty:
    """The honest covariance of a least-squares estimate (module docstring).

    Parameters
    ----------
    problem : Problem
    x : array
        The estimate.
    J : array (n_residuals, k)
        Jacobian of the weighted residuals at ``x``.
    r : array, optional
        Weighted residuals at ``x`` (simulated if not given).
    floors : mapping, optional
        Noise floor per channel [rad]; default :meth:`Problem.noise_floors`.
    hold : bool
        Add the input-hold allowance (one extra simulation at 8× the sample rate).
    """
    x = np.asarray(x, float)
    if r is None:
        r = problem.residuals(x)
    if floors is None:
        floors, _ = problem.noise_floors()
    names = list(problem.names)
    k = len(names)
    notes = []
    cov_white, cov_jk, nb, bsec, hit, _ = robust_covariances(
        problem, J, r, floors, block_seconds=block_seconds
    )
    ratios = problem.rms_over_floor(r, floors)
    worst = max(ratios.values()) if ratios else math.nan
    # The floor's share of the residual's mean square (channels pooled, in floor units).
    ms = float(np.mean([v * v for v in ratios.values()])) if ratios else math.nan
    # Rounding alone scatters the RMS a few per cent around the floor: an excess within
    # NOISE_MS is noise, not model error.
    noise_share = min(1.0, NOISE_MS / ms) if ms > 0 and math.isfinite(ms) else 1.0
    cov_round = None
    if rounding:
        cov_round = rounding_covariance(problem, x, J, r, floors, seed=seed)
        if cov_round is None:
            notes.append(
                "the rounding simulation failed for most draws: the noise part "
                "rests on the residual blocks alone"
            )
    if cov_round is not None:
        cov_noise = loewner_max(cov_white, cov_round)
        cov_model = (1.0 - noise_share) * cov_jk
        dof_noise, dof_model = N_BOOT - 1, max(nb - 1, 1)
    else:
        cov_noise = noise_share * cov_jk
        cov_model = (1.0 - noise_share) * cov_jk
        dof_noise = dof_model = max(nb - 1, 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        infl_noise = np.diag(cov_noise) / np.diag(cov_white)
    infl_noise = infl_noise[np.isfinite(infl_noise) & (infl_noise > 0)]
    cov_hold = np.zeros((k, k))
    hold_weight = 0.0
    if hold:
        dx, ssr_lin, ssr_smooth = hold_shift(problem, x, J, r)
        if np.all(np.isfinite(dx)) and math.isfinite(ssr_smooth):
            # Which input model do the data prefer?  The SSR difference in noise units,
            # deflated by the errors' correlation (the noise part's variance inflation),
            # is a log-likelihood ratio; equal prior odds.
            sig2 = float(np.mean([floors[c] ** 2 for c in problem.channels]))
            kappa = float(np.median(infl_noise)) if infl_noise.size else 1.0
            llr = (ssr_smooth - ssr_lin) / (2 * sig2 * max(kappa, 1.0))
            hold_weight = float(1.0 / (1.0 + math.exp(min(llr, 700.0))))
            cov_hold = hold_weight * np.outer(dx, dx)
        else:
            notes.append("the smooth-input simulation failed: no input-hold allowance")
    cov = cov_noise + cov_model + cov_hold
    vn, vm, vt = np.diag(cov_noise), np.diag(cov_model), np.diag(cov)
    with np.errstate(invalid="ignore", divide="ignore"):
        dof = vt**2 / (vn**2 / dof_noise + vm**2 / dof_model)
    dof = np.where(np.isfinite(dof), np.minimum(dof, 1e6), 1e6)
    with np.errstate(invalid="ignore", divide="ignore"):
        infl = np.diag(cov_noise) / np.diag(cov_white)
    infl = infl[np.isfinite(infl) & (infl > 0)]
    if hit.any():
        for M in (cov, cov_white, cov_noise, cov_model, cov_hold):
            M[hit, :] = np.nan
            M[:, hit] = np.nan
            M[hit, hit] = np.inf
    n = int(r.size)
    n_eff = float(n / np.median(infl)) if infl.size else math.nan
    if nb < k + 2 and noise_share < 0.9:
        notes.append(
            f"only {nb} time blocks for {k} free parameters: the model-error part is itself "
            "uncertain (longer or more experiments help)"
        )
    return Uncertainty(
        names,
        x,
        cov,
        cov_white,
        cov_noise,
        cov_model,
        cov_hold,
        nb,
        bsec,
        n,
        n_eff,
        worst,
        noise_share,
        dof,
        notes,
        hold_weight,
    )
