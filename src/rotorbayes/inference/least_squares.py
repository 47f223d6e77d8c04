"""Least squares from a start (the thesis's lsqnonlin method) over one or several experiments.

The optimiser works on scaled variables ``z = x / scale`` so parameters from 1e-3 to 1e1
are treated alike.  The Jacobian is :meth:`Problem.jacobian` (forward differences, all
perturbed sets simulated in one parallel kernel batch), kept with the result for standard
errors, the Fisher information and the sampler's starting covariance.  A parameter set the
integrator cannot simulate gets a large penalty residual here (the optimiser needs a
number) and the result says so; the likelihood uses the status instead.
"""

from __future__ import annotations

import math
import threading
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..io.measurements import Experiment
from ..kernel.triangle import triangle
from ..model.parameters import ParameterError
from ..model.simulate import SimulationError, Simulator
from ..util import coldstart as _coldstart
from ..util import metrics as _metrics
from . import problem as _problem
from .parallel import claim_kernel_threads
from .problem import Problem
from .uncertainty import Uncertainty, col_norms, fit_uncertainty


class StartError(SimulationError):
    """The start point of a fit cannot be simulated (the integrator's reason included).

    ``reason``: the message without the advice to a user who gave the start (a search's
    own start is not one to leave out)."""

    def __init__(self, message: str, reason: str = "") -> None:
        super().__init__(message)
        self.reason = reason or message


class FitInterrupted(KeyboardInterrupt):
    """Ctrl-C during a fit, with the best point evaluated so far.

    Attributes: ``names`` (free parameters), ``x`` (their values at the best point),
    ``ssr`` (its sum of squared residuals) and ``nfev`` (evaluations done).
    """

    def __init__(self, names: list[str], x: np.ndarray, ssr: float, nfev: int) -> None:
        super().__init__(f"interrupted after {nfev} evaluations (best SSR {ssr:.6g})")
        self.names, self.x, self.ssr, self.nfev = names, x, ssr, nfev


#: Penalty residual [rad] the optimiser sees for parameter sets the integrator rejects.
FAIL_RESIDUAL = 1e3


@dataclass
class FitResult:
    """Outcome of :func:`fit`.

    Attributes
    ----------
    names, x, x0 : list, arrays
        Free parameter names, estimates and start values.
    stderr : array
        Honest standard errors (:mod:`.uncertainty`: block-robust, rounding simulated,
        input-hold allowance) when the fit was asked for them (``uncertainty=True``, the
        default); otherwise the i.i.d. Gauss-Newton ``s² (JᵀJ)⁻¹`` (``inf`` where the
        information matrix is singular).
    uncertainty : Uncertainty or None
        The covariances behind ``stderr`` and what they assume.
    jac : array (n_residuals, k)
        Jacobian of the residuals at the solution (in parameter units).
    ssr, cost : float
        Sum of squared residuals [rad²] and ``ssr / 2``.
    success : bool
        The optimiser met a convergence criterion; ``message`` says which, or why not.
    """

    names: list[str]
    x: np.ndarray
    x0: np.ndarray
    stderr: np.ndarray
    jac: np.ndarray
    ssr: float
    n_residuals: int
    success: bool
    message: str
    nfev: int
    njev: int
    seconds: float
    problem: Problem = field(repr=False)
    uncertainty: Uncertainty | None = field(default=None, repr=False)
    #: How the Jacobians were computed: 'differences' or 'sensitivity'.
    jacobian_method: str = "differences"

    @property
    def values(self) -> dict[str, float]:
        """``{name: estimate}``."""
        return dict(zip(self.names, map(float, self.x), strict=True))

    @property
    def params(self) -> dict[str, float]:
        """Complete parameter set of the first experiment at the estimate."""
        return self.problem.params_for(self.x, 0)

    @property
    def stderr_iid(self) -> np.ndarray:
        """Standard errors if the errors were independent (Gauss-Newton, for comparison)."""
        with np.errstate(invalid="ignore"):
            return np.sqrt(np.diag(self.covariance()))

    def honest_covariance(self) -> np.ndarray:
        """The covariance behind ``stderr``: :attr:`uncertainty`'s total if computed."""
        return self.uncertainty.cov if self.uncertainty is not None else self.covariance()

    def correlation(self) -> np.ndarray:
        """Parameter correlation matrix (of :meth:`honest_covariance`)."""
        cov = self.honest_covariance()
        d = np.sqrt(np.abs(np.diag(cov)))
        with np.errstate(invalid="ignore", divide="ignore"):
            return cov / np.outer(d, d)

    def covariance(self) -> np.ndarray:
        """Gauss-Newton covariance ``s² (JᵀJ)⁻¹`` with ``s² = SSR / (n - k)``.

        Computed in scaled coordinates; where ``JᵀJ`` is singular (directions the data
        do not determine, e.g. a parameter without influence), the variance of every
        parameter that takes part in such a direction is ``inf``, not the tiny number a
        pseudo-inverse would give.
        """
        k = len(self.names)
        s2 = self.ssr / max(self.n_residuals - k, 1)
        d = col_norms(self.jac)
        d = np.where(d > 0, d, 1.0)
        # (J/d)ᵀ(J/d) without a scaled copy of J (long data: J is the largest array).
        w, V = np.linalg.eigh((self.jac.T @ self.jac) / np.outer(d, d))
        small = w <= 1e-12 * max(w.max(), 1e-300)
        inv = np.where(small, 0.0, 1.0 / np.where(small, 1.0, w))
        cov = (V * inv) @ V.T / np.outer(d, d) * s2
        if small.any():
            hit = np.any(np.abs(V[:, small]) > 0.1, axis=1)
            cov[hit, :] = np.nan
            cov[:, hit] = np.nan
            cov[hit, hit] = np.inf
        return cov

    def undetermined(self) -> list[str]:
        """Free parameters in a direction the data do not determine (singular JᵀJ)."""
        return [
            n
            for n, v in zip(self.names, np.diag(self.covariance()), strict=True)
            if not np.isfinite(v)
        ]

    def sloppy_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues (ascending) and eigenvectors of the Fisher information in
        relative (log-parameter) coordinates: small eigenvalues are directions along
        which the fit barely changes."""
        xs = np.where(self.x != 0, self.x, 1.0)
        w, V = np.linalg.eigh((self.jac.T @ self.jac) * np.outer(xs, xs))
        return w, V


#: Jacobians larger than this [bytes] are not kept with the starts of a multistart (a
#: 4 x 600 s coupled fit at 1 kHz has a 576 MB Jacobian).
COMPRESS_BYTES = 64 * 2**20
#: Rows of ``[J | r]`` factorised at a time by :func:`tsqr` [bytes].
_QR_CHUNK_BYTES = 16 * 2**20


def tsqr(*parts: np.ndarray) -> np.ndarray:
    """The triangle ``T`` of a QR factorisation of the columns ``[parts...]`` side by side
    (each a vector or an ``(n, m)`` array), taken over row blocks: the blocks' triangles are
    stacked and factorised again, so no copy of the whole matrix is made (long data).
    ``Tᵀ T`` is the Gram matrix of the columns; ``T`` has as many rows as columns."""
    cols = [p[:, None] if p.ndim == 1 else p for p in parts]
    n = cols[0].shape[0]
    k = sum(c.shape[1] for c in cols)
    step = max(k, _QR_CHUNK_BYTES // (8 * k))
    T = np.zeros((0, k))
    for a in range(0, n, step):
        b = min(n, a + step)
        blk = np.empty((T.shape[0] + b - a, k))
        blk[: T.shape[0]] = T
        j = 0
        for c in cols:
            blk[T.shape[0] :, j : j + c.shape[1]] = c[a:b]
            j += c.shape[1]
        T = np.asarray(np.linalg.qr(blk, mode="r"))  # mode "r": the triangle alone
    if T.shape[0] < k:
        T = np.vstack([T, np.zeros((k - T.shape[0], k))])
    return T


def _triangle(J: np.ndarray, r: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
    """The triangle of ``[J diag(scale) | r]`` (:func:`tsqr`'s), on the kernel's threads in
    fixed row blocks (:func:`rotorbayes.kernel.triangle.triangle`: the same bits on any
    number of threads) where the data are long enough, else by NumPy."""
    n, k = J.shape
    scale = np.ones(k) if scale is None else np.asarray(scale, dtype=float)
    if n < 2 * (k + 1):
        return tsqr(J * scale[None, :], r)
    D = np.asfortranarray(J).T  # (k, n), each row one column of J: no copy for ours
    claim_kernel_threads()  # inside a pool's task: its share of the cores
    return triangle(
        np.ascontiguousarray(D),
        np.ascontiguousarray(r, dtype=float),
        np.ascontiguousarray(scale),
        _NO_BASE,
    )


#: ``triangle``'s ``base`` where its rows are the Jacobian's columns already.
_NO_BASE = np.empty(0)


def compress_differences(
    R: np.ndarray, r: np.ndarray, steps: np.ndarray, scale: np.ndarray | None = None
) -> np.ndarray:
    """:func:`compress` of the forward-difference Jacobian ``(R[j] - r) / steps[j]``
    (:meth:`Problem.difference_parts`: ``R`` is ``(k, n)``, the perturbed residuals),
    the quotients formed on the way into the triangle (times ``scale[j] / steps[j]``)
    instead of in a pass over the ``k x n`` values of their own."""
    k, n = R.shape
    scale = np.ones(k) if scale is None else np.asarray(scale, dtype=float)
    r = np.ascontiguousarray(r, dtype=float)
    if n < 2 * (k + 1):
        return compress(((R - r[None, :]) / steps[:, None]).T, r, scale)
    claim_kernel_threads()
    T = triangle(np.ascontiguousarray(R), r, np.ascontiguousarray(scale / steps), r)
    return _compressed(T, k, math.sqrt(float(r @ r)))


def compress(
    J: np.ndarray, r: np.ndarray, scale: np.ndarray | None = None, *, norm: float | None = None
) -> np.ndarray:
    """A ``(k + 1) x k`` matrix ``C`` with ``Cᵀ C = Jᵀ J`` and ``Cᵀ f = Jᵀ r`` for
    ``f = (|r|, 0, ..., 0)``: least squares on ``(f, C)`` has the same cost and the same
    Gauss-Newton model ``|J p + r|²`` as on ``(r, J)``.  ``scale`` (optional) multiplies
    the columns of ``J`` on the way (the optimiser's variables), without a scaled copy.
    ``norm``: ``|r|`` where ``(J, r)`` are reduced rows (:meth:`Problem.jacobian_rows`:
    the same ``Jᵀ J`` and ``Jᵀ r``, ``r`` shorter than the residuals).

    ``[J | r] = Q [[R, q], [0, ρ]]`` (:func:`_triangle`: no copy of ``J``); with
    ``u = q / |r|``, ``C = [uᵀ R; (I − α u uᵀ) R]``, ``α = 1 / (1 + √(1 − |u|²))``, the
    square root of ``I − u uᵀ`` (stable, no ``JᵀJ`` formed).
    """
    k = J.shape[1]
    T = _triangle(J, r, scale)
    return _compressed(T, k, math.sqrt(float(r @ r)) if norm is None else float(norm))


def _compressed(T: np.ndarray, k: int, rho: float) -> np.ndarray:
    """:func:`compress`'s matrix from the triangle ``T`` of ``[J | r]`` and ``|r|``."""
    R, q = T[:k, :k], T[:k, k]
    u = q / rho if rho > 0 else np.zeros(k)
    uu = min(float(u @ u), 1.0)
    alpha = 1.0 / (1.0 + math.sqrt(1.0 - uu))
    uR = u @ R
    C = np.empty((k + 1, k))
    C[0] = uR
    C[1:] = R - alpha * np.outer(u, uR)
    return C


def _jacobian_method(problem: Problem, jacobian: str | None) -> str:
    """The fit's Jacobian method: ``jacobian`` or the default; sensitivities asked for a
    model the kernel cannot differentiate become differences, said once."""
    method = _problem.JACOBIAN_DEFAULT if jacobian is None else jacobian
    if method not in ("differences", "sensitivity"):
        raise ValueError(f"jacobian = {jacobian!r}: choose 'differences' or 'sensitivity'")
    if method == "sensitivity":
        why = problem.sensitivity_support()
        if why is not None:
            if jacobian is not None:
                warnings.warn(
                    f"Jacobian by finite differences: {why}",
                    _problem.SensitivityFallback,
                    stacklevel=3,
                )
            return "differences"
    return method


class _Rows(threading.local):
    """The number of residuals of the fit running on this thread, or None."""

    n: int | None = None


_ROWS = _Rows()


def _count_true_rows() -> bool:
    """Make scipy's trust-region step on a compressed problem decide the Jacobian's rank as
    on the whole one.  scipy calls ``J`` rank-deficient where its smallest singular value is
    under ``eps * rows * largest``; handed the ``k + 1`` rows of :func:`compress` it would
    take Gauss-Newton steps along directions it treats as flat on the ``n`` rows.  The
    step routine of scipy's solver is wrapped once to see the fit's own row count (set per
    thread while a compressed fit runs; other calls pass through unchanged).  False where
    this scipy has no such routine: the fit then hands the optimiser the whole problem."""
    try:
        from scipy.optimize._lsq import trf as _trf
    except ImportError:  # pragma: no cover - another scipy layout
        return False
    inner = getattr(_trf, "solve_lsq_trust_region", None)
    if inner is None:  # pragma: no cover - another scipy layout
        return False
    if getattr(inner, "_counts_rows", False):
        return True

    def solve_lsq_trust_region(n, m, *args, **kwargs):
        rows = _ROWS.n
        return inner(n, m if rows is None else rows, *args, **kwargs)

    solve_lsq_trust_region._counts_rows = True  # type: ignore[attr-defined]
    _trf.solve_lsq_trust_region = solve_lsq_trust_region
    return True


#: Fewest samples an experiment must have to be fitted.  Fewer cannot hold a stick and a
#: slip phase of the lower disc or a reversal of the upper one, the standard errors' time
#: blocks (:mod:`.uncertainty`) need more than that, and a record of a few samples that
#: never moves is "at the floor" whatever the parameters.  The rig's experiments last
#: seconds to minutes (thousands of samples or more).
MIN_FIT_SAMPLES = 100


def check_fittable(problem: Problem) -> None:
    """Raise :class:`ParameterError` when ``problem`` cannot be fitted: no free parameter
    (nothing left to fit), or an experiment with fewer than :data:`MIN_FIT_SAMPLES`
    samples (named, with its length)."""
    if not problem.names:
        raise ParameterError(
            "the problem has no free parameters: nothing left to fit; free at least one "
            "(name it in free=[...], or leave it out of fixed)"
        )
    for i, ex in enumerate(problem.experiments):
        if ex.n < MIN_FIT_SAMPLES:
            where = ex.path or ex.name or f"experiment {i}"
            raise ParameterError(
                f"{where}: only {ex.n} samples ({(ex.n - 1) * ex.dt:.3g} s); a fit needs at "
                f"least {MIN_FIT_SAMPLES} per experiment (its angles must show the discs "
                "moving and sticking, and the standard errors need stretches of data to "
                "compare): record or simulate a longer run"
            )


def _scale(problem: Problem, x0: np.ndarray) -> np.ndarray:
    """Typical magnitudes of the free parameters (for the optimiser's variables)."""
    return problem.parameters.scale(x0)


def fit(
    problem: Problem,
    x0=None,
    *,
    ftol: float = 1e-10,
    xtol: float = 1e-10,
    gtol: float = 1e-10,
    max_nfev: int = 200,
    fd_step: float = 1e-6,
    verbose: bool = False,
    parallel: bool = True,
    callback: Callable[[int, float], None] | None = None,
    uncertainty: bool = True,
    compressed: bool | None = None,
    jacobian: str | None = None,
) -> FitResult:
    """Least squares from a start (thesis: MATLAB ``lsqnonlin``; here scipy's
    trust-region-reflective ``least_squares`` with bounds).

    Parameters
    ----------
    problem : Problem
    x0 : array or mapping, optional
        Start values (default: the problem's base set).
    ftol, xtol, gtol : float
        Convergence tolerances of :func:`scipy.optimize.least_squares`.
    max_nfev : int
        Largest number of residual evaluations (Jacobians not counted).
    fd_step : float
        Forward-difference step in scaled variables (relative to each parameter's
        magnitude).
    parallel : bool
        Simulate the Jacobian's perturbed sets in one parallel batch.
    callback : callable, optional
        Called as ``callback(n_evaluations, ssr)`` after each residual evaluation.
    uncertainty : bool
        Compute honest standard errors (:func:`.uncertainty.fit_uncertainty`, about 200
        extra simulations); ``False`` keeps the i.i.d. Gauss-Newton ones (multistart's
        many starts; :func:`attach_uncertainty` adds them later).
    compressed : bool, optional
        Hand the optimiser the problem compressed to k + 1 rows (:func:`compress`: the
        same Gauss-Newton model and rank decisions, so the same steps up to rounding; its
        QR on the kernel's threads instead of an SVD of the whole Jacobian on one, and
        far less memory).  Default: True (False hands scipy the whole Jacobian, as
        before; so does a scipy whose step routine :func:`_count_true_rows` cannot see).
    jacobian : {'differences', 'sensitivity'}, optional
        How the Jacobian is computed (default :data:`.problem.JACOBIAN_DEFAULT`):
        forward differences, or the kernel's forward sensitivities, which hand the
        compressed optimiser each step's rows reduced (:meth:`Problem.jacobian_rows`; a
        30 s brake Jacobian and its compression in 1.8 ms against 6.5 ms by differences
        on one core).  Where the kernel has no sensitivities for the model, differences,
        with a :class:`.problem.SensitivityFallback` warning that says why.

    Returns
    -------
    FitResult
        Also when the optimiser did not converge (``success`` False; ``message`` why).
    """
    check_fittable(problem)
    if x0 is None:
        x0 = problem.x_from(problem.base)
    elif isinstance(x0, Mapping):
        x0 = problem.x_from({**problem.base, **x0})
    x0 = problem.point(x0)
    problem.check_start(x0)
    ev0 = problem.evaluate(x0)
    if not ev0.ok:
        why = problem.model.problems(problem.params_for(x0, 0)) or ev0.reasons()
        reason = "the start cannot be simulated: " + "; ".join(why)
        raise StartError(
            reason + "; choose another start (e.g. leave out --p0 for a start from the data)",
            reason,
        )
    scale = _scale(problem, x0)
    lo, hi = problem.lower / scale, problem.upper / scale
    counter = {"n": 0, "best": math.inf}
    best_x: dict = {}  # the best point so far, reported if the fit is interrupted
    compressed = (compressed is None or compressed) and _count_true_rows()
    method = _jacobian_method(problem, jacobian)
    # The compressed problem straight from the sensitivity kernel's reduced rows (no
    # n x k Jacobian formed or triangularised) where the Jacobian is by sensitivities.
    use_rows = compressed and method == "sensitivity"

    last: dict = {}

    def fun(z):
        r = full_fun(z)
        if compressed:
            f = np.zeros(z.size + 1)
            f[0] = math.sqrt(float(r @ r))
            return f
        return r

    def full_fun(z):
        r = problem.residuals(z * scale, penalty=FAIL_RESIDUAL)
        # The optimiser asks for the Jacobian at the point it just evaluated.
        last["z"], last["r"] = z.copy(), r
        counter["n"] += 1
        s = float(r @ r)
        if s < counter["best"]:
            counter["best"], best_x["x"] = s, z * scale
        if verbose and counter["n"] % 10 == 0:
            print(
                f"  evaluation {counter['n']:4d}  SSR {s:.6e}  best {counter['best']:.6e}",
                flush=True,
            )
        if callback is not None:
            callback(counter["n"], s)
        return r

    def jac(z):
        if not compressed:
            return full_jac(z)
        r = last["r"] if "z" in last and np.array_equal(z, last["z"]) else full_fun(z)
        try:
            if use_rows:
                A, b, rk = problem.jacobian_rows(z * scale)
                return compress(A, b, scale, norm=math.sqrt(float(rk @ rk)))
            # The quotients and the scaling on the way into the triangle: no pass over the
            # k x n values of their own.
            R, base, steps = problem.difference_parts(z * scale, rel_step=fd_step, r0=r)
            return compress_differences(R, base, steps, scale)
        except SimulationError:
            # A perturbed set cannot be simulated: penalised differences (not the same
            # sets again through unscaled_jac).
            return compress(penalised_jac(z, r), r, scale)

    def full_jac(z):
        J = unscaled_jac(z)
        J *= scale[None, :]  # in place: J is ours (long data: no second copy)
        return J

    def unscaled_jac(z):
        r0 = last["r"] if "z" in last and np.array_equal(z, last["z"]) else None
        try:
            J, _ = problem.jacobian(z * scale, rel_step=fd_step, r0=r0, method=method)
        except Exception:
            # A perturbed set cannot be simulated: fall back to penalised differences.
            if r0 is None:
                r0 = problem.residuals(z * scale, penalty=FAIL_RESIDUAL)
            return penalised_jac(z, r0)
        return J

    def penalised_jac(z, r0):
        """Forward differences with failed simulations' residuals penalised (unscaled)."""
        k = z.size
        Z = np.repeat(z[None, :], k, axis=0)
        steps = np.where(z + fd_step <= hi, fd_step, -fd_step)
        Z[np.arange(k), np.arange(k)] += steps
        R = problem.residuals_batch(Z * scale, penalty=FAIL_RESIDUAL)
        return ((R - r0[None, :]) / (steps * scale)[:, None]).T

    t0 = time.perf_counter()
    compiled0 = sum(_coldstart.COMPILE_SECONDS.values())
    outer_rows, _ROWS.n = _ROWS.n, (problem.n_residuals if compressed else None)
    try:
        from scipy.optimize import least_squares  # here: diagnose and report never use it

        res = least_squares(
            fun,
            x0 / scale,
            jac=jac,
            bounds=(lo, hi),
            method="trf",
            x_scale=1.0,
            ftol=ftol,
            xtol=xtol,
            gtol=gtol,
            max_nfev=max_nfev,
        )
    except KeyboardInterrupt:
        if "x" not in best_x:
            raise
        raise FitInterrupted(
            list(problem.names), best_x["x"], counter["best"], int(counter["n"])
        ) from None
    finally:
        _ROWS.n = outer_rows
    # The fit's own time: a first compilation meanwhile was said in its own line.
    seconds = max(
        0.0, time.perf_counter() - t0 - (sum(_coldstart.COMPILE_SECONDS.values()) - compiled0)
    )
    x = res.x * scale
    J = unscaled_jac(res.x)
    ev = problem.evaluate(x)
    r = np.where(np.isnan(ev.residuals), FAIL_RESIDUAL, ev.residuals)
    ssr_val = float(r @ r)
    out = FitResult(
        names=list(problem.names),
        x=x,
        x0=x0,
        stderr=np.full(x.size, np.nan),
        jac=J,
        ssr=ssr_val,
        n_residuals=r.size,
        success=bool(res.status > 0) and ev.ok,
        message=_explain(res)
        if ev.ok
        else "the model cannot be simulated at the end point: " + "; ".join(ev.reasons()),
        nfev=int(res.nfev),
        njev=int(res.njev or 0),
        seconds=seconds,
        problem=problem,
        jacobian_method=method,
    )
    cov = out.covariance()
    with np.errstate(invalid="ignore"):
        out.stderr = np.sqrt(np.diag(cov))
    if uncertainty and ev.ok:
        attach_uncertainty(out)
    return out


def attach_uncertainty(res: FitResult, **kw) -> FitResult:
    """Give ``res`` honest standard errors (:func:`.uncertainty.fit_uncertainty`)."""
    r = res.problem.residuals(res.x)
    if not np.all(np.isfinite(r)):
        return res
    res.uncertainty = fit_uncertainty(res.problem, res.x, res.jac, r, **kw)
    res.stderr = res.uncertainty.stderr
    return res


def _explain(res) -> str:
    """Plain-words reason the optimiser stopped."""
    reasons = {
        -1: "improper input parameters",
        0: "stopped: the maximum number of evaluations was reached before convergence "
        "(raise max_nfev or start closer)",
        1: "converged: gradient small (gtol)",
        2: "converged: cost change small (ftol)",
        3: "converged: step small (xtol)",
        4: "converged: cost change and step small (ftol and xtol)",
    }
    return reasons.get(res.status, res.message)


# --------------------------------------------------------------------------- quality
def integration_error(problem: Problem, ex: Experiment, sim: Simulator, p: Mapping, s) -> dict:
    """The integrator's own error at ``p``: per angle channel the largest and the RMS
    difference [rad] between the simulation ``s`` on ``sim``'s step grid and one with
    finer steps: one sample (within 1e-10 rad of the event-driven reference at 1 kHz), or a
    third of the step when the steps are a sample or shorter already (200 Hz data).  Empty
    when either run fails."""
    longest = float(np.max(np.diff(sim.grid)))
    fine_step = ex.dt if longest > 1.0 else longest * ex.dt / 3.0
    fine = Simulator(
        sim.model,
        ex.u,
        ex.dt,
        shape=problem.shape,
        step=fine_step,
        theta_u=ex.theta_u if problem.prescribed_upper else None,
    )
    f = fine.simulate(p, raise_on_failure=False)
    if not (s.ok and f.ok):
        return {}
    out = {}
    for c in ("theta_u", "theta_l") if ex.has_lower else ("theta_u",):
        if problem.prescribed_upper and c == "theta_u":
            continue
        d = getattr(s, c) - getattr(f, c)
        out[c] = {
            "max": float(np.max(np.abs(d))),
            "rms": float(np.sqrt(np.mean(d * d))),
            "fine_step": fine_step,
        }
    return out


def quality(
    problem: Problem,
    x: np.ndarray,
    experiments: Sequence[Experiment] | None = None,
    *,
    k: int | None = None,
    validation_alpha0: Sequence | None = None,
) -> list[dict]:
    """Per experiment and channel (theta_l, theta_u, alpha as in the thesis): R², NRMSE
    fit %, max ``|error|``, SSR, plus AICc and BIC of the fitted channels, and the
    integrator's own error there (:func:`integration_error`).

    ``experiments`` default to the problem's own (estimation data); pass validation
    experiments to evaluate the same parameters on other inputs.  A validation run's
    ``alpha0`` is its own, decided by :meth:`Problem.validation_params`: ``validation_alpha0``
    gives one entry per experiment (a number [rad] the user gave, a stored
    :class:`~rotorbayes.inference.problem.ValidationTorsion` or its dict, or None: decide
    -- fitted on that run alone when the model has a pre-wound string); each validation row
    carries the record as ``"validation_alpha0"``.
    """
    exps = problem.experiments if experiments is None else experiments
    k = len(problem.names) if k is None else k
    given = list(validation_alpha0) if validation_alpha0 is not None else [None] * len(exps)
    if experiments is not None and len(given) != len(exps):
        raise ValueError(
            f"validation_alpha0 has {len(given)} entries for {len(exps)} "
            "validation experiments; give one per experiment (None: decide)"
        )
    rows = []
    for i, ex in enumerate(exps):
        own = experiments is None
        torsion = None
        if own:
            p = problem.params_for(x, i)
        else:
            p, torsion = problem.validation_params(x, ex, given[i])
        sim = problem.sims[i] if own else problem.simulator_for(ex)
        s = sim.simulate(p, raise_on_failure=False)
        chans = {"theta_u": (ex.theta_u, s.theta_u)}
        if ex.theta_l is not None and s.theta_l is not None:  # the lower disc is measured
            chans["theta_l"] = (ex.theta_l, s.theta_l)
            a0 = p["alpha0"]
            chans["alpha"] = (ex.theta_l - ex.theta_u + a0, s.theta_l - s.theta_u + a0)
        fits = {}
        for c, (y, yh) in chans.items():
            if problem.prescribed_upper and c == "theta_u":
                continue
            if not np.all(np.isfinite(yh)):
                continue
            fits[c] = _metrics.channel_fit(c, y, yh)
        fitted_ssr = sum(fits[c].ssr for c in problem.channels if c in fits)
        n = ex.n * len(problem.channels)
        rows.append(
            {
                "experiment": ex.name or (ex.path or f"experiment {i}"),
                "channels": {c: f.as_dict() for c, f in fits.items()},
                "aicc": _metrics.aicc(fitted_ssr, n, k) if fitted_ssr > 0 else -math.inf,
                "bic": _metrics.bic(fitted_ssr, n, k) if fitted_ssr > 0 else -math.inf,
                "integration": integration_error(problem, ex, sim, p, s),
                "simulation": s,
            }
        )
        if not own:
            rows[-1]["validation_alpha0"] = torsion
    return rows
