"""Fit-quality measures for comparing measured and simulated signals.

The thesis judges every fit by the coefficient of determination (eq. 3.2)

    R² = 1 - sum((y - ŷ)²) / sum((y - ȳ)²),

and its §6.2 warns that this number "gives a somewhat distorted indication": the angles
of the rig wander over tens of radians, so the denominator is huge and R² = 0.999 can
still hide errors of half a radian. This module therefore reports R² next to measures
that show the size of the error directly:

* :func:`nrmse_fit` -- the fit in percent used by MATLAB's ``compare``,
  ``100 (1 - ||y - ŷ|| / ||y - ȳ||)``. It is ``100 (1 - sqrt(1 - R²))``, so it spreads
  out exactly the range near R² = 1 that R² compresses (R² = 0.9988 is only 96.5 %).
* :func:`max_abs_error` and the RMSE -- in the signal's own unit [rad].
* :func:`aicc` and :func:`bic` -- to decide whether an added physical effect (more
  parameters) lowered the sum of squared residuals enough to be worth it.

:func:`channel_fit` bundles the measures for one signal (e.g. ``theta_l`` or ``alpha``)
and :func:`fit_table` prints several of them as an aligned plain-text table.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "ChannelFit",
    "aicc",
    "bic",
    "channel_fit",
    "fit_table",
    "max_abs_error",
    "nrmse_fit",
    "r_squared",
    "ssr",
]


def _pair(y: ArrayLike, yhat: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Validate a measured/simulated pair and return them as flat float arrays.

    Raises
    ------
    ValueError
        If the shapes differ, the signals are empty or a value is NaN or infinite.
    """
    a = np.asarray(y, dtype=float)
    b = np.asarray(yhat, dtype=float)
    if a.shape != b.shape:
        raise ValueError(
            f"shape mismatch: y has shape {a.shape} but yhat has shape {b.shape}; compare "
            "signals sampled at the same instants"
        )
    if a.size == 0:
        raise ValueError("empty input: y and yhat contain no samples")
    for label, arr in (("y", a), ("yhat", b)):
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.flatnonzero(bad.ravel())[0])
            raise ValueError(
                f"{label} contains {int(bad.sum())} non-finite value(s) (NaN or inf), the first "
                f"at flat index {i} ({arr.ravel()[i]}); a failed simulation returns NaN, so "
                "check the simulation status before computing fit measures"
            )
    return a.ravel(), b.ravel()


def _ssr_and_sst(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Sum of squared residuals and total sum of squares about the mean of ``a``."""
    r = a - b
    d = a - a.mean()
    return float(r @ r), float(d @ d)


def ssr(y: ArrayLike, yhat: ArrayLike) -> float:
    """Sum of squared residuals ``sum((y - yhat)**2)``.

    Parameters
    ----------
    y, yhat : array_like
        Measured and simulated signal, same shape [unit of the signal, e.g. rad].

    Returns
    -------
    float
        Sum of squared residuals [unit²], the objective of the thesis's eqs. 4.4 and 4.10.

    Raises
    ------
    ValueError
        Shape mismatch, empty input, or a NaN/inf value.
    """
    a, b = _pair(y, yhat)
    r = a - b
    return float(r @ r)


def r_squared(y: ArrayLike, yhat: ArrayLike) -> float:
    """Coefficient of determination, thesis eq. 3.2.

    ``R² = 1 - SSR / sum((y - mean(y))**2)``. It is 1 for a perfect fit and has no lower
    bound (a fit worse than the constant ``mean(y)`` gives R² < 0).

    Parameters
    ----------
    y : array_like
        Measured signal [e.g. rad].
    yhat : array_like
        Simulated signal, same shape and unit as ``y``.

    Returns
    -------
    float
        R² [-]. ``nan`` if ``y`` is constant (zero variance): the criterion then has no
        reference scale, and returning a number would suggest a meaning it does not have.

    Raises
    ------
    ValueError
        Shape mismatch, empty input, or a NaN/inf value.

    Notes
    -----
    For the rig's angles R² is dominated by the large excursion of ``y`` and stays close
    to 1 even for errors of tenths of a radian (thesis §6.2); report :func:`nrmse_fit`
    and :func:`max_abs_error` with it.
    """
    a, b = _pair(y, yhat)
    res, tot = _ssr_and_sst(a, b)
    if tot == 0.0:
        return math.nan
    return 1.0 - res / tot


def nrmse_fit(y: ArrayLike, yhat: ArrayLike) -> float:
    """Normalised-RMSE fit in percent, as MATLAB's ``compare`` reports it.

    ``fit = 100 * (1 - ||y - yhat|| / ||y - mean(y)||)`` with Euclidean norms. It equals
    ``100 * (1 - sqrt(1 - R²))``: 100 % for a perfect fit, 0 % for the constant
    ``mean(y)``, negative for worse fits.

    Parameters
    ----------
    y : array_like
        Measured signal [e.g. rad].
    yhat : array_like
        Simulated signal, same shape and unit as ``y``.

    Returns
    -------
    float
        Fit [%]. ``nan`` if ``y`` is constant (zero variance), for the same reason as
        :func:`r_squared`.

    Raises
    ------
    ValueError
        Shape mismatch, empty input, or a NaN/inf value.
    """
    a, b = _pair(y, yhat)
    res, tot = _ssr_and_sst(a, b)
    if tot == 0.0:
        return math.nan
    return 100.0 * (1.0 - math.sqrt(res / tot))


def max_abs_error(y: ArrayLike, yhat: ArrayLike) -> float:
    """Largest absolute error ``max |y - yhat|``.

    Parameters
    ----------
    y, yhat : array_like
        Measured and simulated signal, same shape [e.g. rad].

    Returns
    -------
    float
        Maximum absolute error [unit of the signal]; the figure the thesis quotes when
        it prefers the asymmetric friction model (§5.2.3, "almost 0.6 radians").

    Raises
    ------
    ValueError
        Shape mismatch, empty input, or a NaN/inf value.
    """
    a, b = _pair(y, yhat)
    return float(np.max(np.abs(a - b)))


def _check_counts(ssr: float, n: int, k: int, what: str) -> None:
    """Common argument checks of the information criteria."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"{what}: n = {n!r} must be a positive whole number of samples")
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 0:
        raise ValueError(f"{what}: k = {k!r} must be a non-negative whole number of parameters")
    if not (math.isfinite(ssr) and ssr >= 0.0):
        raise ValueError(f"{what}: ssr = {ssr!r} must be a finite sum of squares >= 0")


def _profiled_deviance(ssr: float, n: int) -> float:
    """``n log(ssr / n)``: -2 log-likelihood of Gaussian errors, sigma² profiled out.

    The constant ``n (1 + log 2π)`` is dropped; it cancels when models fitted to the
    same data are compared. A perfect fit (``ssr = 0``) gives ``-inf``.
    """
    if ssr == 0.0:
        return -math.inf
    return n * math.log(ssr / n)


def aicc(ssr: float, n: int, k: int) -> float:
    """Corrected Akaike information criterion for a least-squares fit.

    ``AICc = n log(SSR/n) + 2k + 2k(k+1)/(n-k-1)``: the Gaussian likelihood with the
    noise variance replaced by its maximum-likelihood value ``SSR/n``, plus the small-
    sample corrected penalty. Lower is better; only differences between models fitted
    to the same samples mean anything.

    Parameters
    ----------
    ssr : float
        Sum of squared residuals [unit²] at the fitted parameters.
    n : int
        Number of samples.
    k : int
        Number of fitted parameters.

    Returns
    -------
    float
        AICc [-]. ``inf`` if ``n - k - 1 <= 0`` (too few samples for the correction to be
        defined, so the model cannot be supported); ``-inf`` if ``ssr == 0``.

    Raises
    ------
    ValueError
        ``n < 1``, ``k < 0``, non-integer counts, or ``ssr`` negative or not finite.

    Notes
    -----
    Samples of the rig's angles are strongly autocorrelated, so ``n`` overstates the
    independent information and both criteria penalise parameters too weakly; treat
    them as a ranking, not as a significance test.
    """
    _check_counts(ssr, n, k, "aicc")
    dof = n - k - 1
    if dof <= 0:
        return math.inf
    return _profiled_deviance(ssr, n) + 2.0 * k + 2.0 * k * (k + 1) / dof


def bic(ssr: float, n: int, k: int) -> float:
    """Bayesian (Schwarz) information criterion for a least-squares fit.

    ``BIC = n log(SSR/n) + k log(n)``, with the Gaussian noise variance profiled out as
    in :func:`aicc`. Lower is better; its penalty grows with ``n``, so it prefers smaller
    models than AICc on long records.

    Parameters
    ----------
    ssr : float
        Sum of squared residuals [unit²] at the fitted parameters.
    n : int
        Number of samples.
    k : int
        Number of fitted parameters.

    Returns
    -------
    float
        BIC [-]; ``-inf`` if ``ssr == 0``.

    Raises
    ------
    ValueError
        ``n < 1``, ``k < 0``, non-integer counts, or ``ssr`` negative or not finite.
    """
    _check_counts(ssr, n, k, "bic")
    return _profiled_deviance(ssr, n) + k * math.log(n)


@dataclass(frozen=True)
class ChannelFit:
    """Fit-quality measures of one signal (channel), e.g. ``theta_l`` of one experiment.

    Attributes
    ----------
    name : str
        Channel name, e.g. ``'theta_l'`` or ``'alpha (exp. 4)'``.
    n : int
        Number of samples.
    r2 : float
        R² of thesis eq. 3.2 [-] (``nan`` for a constant measurement).
    nrmse_fit : float
        NRMSE fit [%] (``nan`` for a constant measurement).
    max_abs_error : float
        Largest absolute error [rad].
    rmse : float
        Root-mean-square error [rad].
    ssr : float
        Sum of squared residuals [rad²].
    """

    name: str
    n: int
    r2: float
    nrmse_fit: float
    max_abs_error: float
    rmse: float
    ssr: float

    def as_dict(self) -> dict:
        """The measures as a plain ``{field: value}`` dict (e.g. for JSON reports)."""
        return asdict(self)


def channel_fit(name: str, y: ArrayLike, yhat: ArrayLike) -> ChannelFit:
    """All fit measures of one measured/simulated pair.

    Parameters
    ----------
    name : str
        Channel name used in tables.
    y : array_like
        Measured signal [rad].
    yhat : array_like
        Simulated signal [rad], same shape as ``y``.

    Returns
    -------
    ChannelFit

    Raises
    ------
    ValueError
        Shape mismatch, empty input, or a NaN/inf value.
    """
    a, b = _pair(y, yhat)
    res, tot = _ssr_and_sst(a, b)
    # Computed here from one residual vector instead of calling the public functions, so
    # the input is validated and differenced once.
    r2 = math.nan if tot == 0.0 else 1.0 - res / tot
    fit = math.nan if tot == 0.0 else 100.0 * (1.0 - math.sqrt(res / tot))
    return ChannelFit(
        name=str(name),
        n=int(a.size),
        r2=r2,
        nrmse_fit=fit,
        max_abs_error=float(np.max(np.abs(a - b))),
        rmse=math.sqrt(res / a.size),
        ssr=res,
    )


_HEADERS = ("channel", "R²", "fit %", "max |e| [rad]", "RMSE [rad]", "SSR [rad²]")


#: What the table prints for R² and fit % of a constant measurement (and the note under it).
NO_SCALE = "n/a"
NO_SCALE_NOTE = (
    f"{NO_SCALE}: the measured signal is constant, so R² and fit % have no "
    "reference scale (judge the fit by its errors in rad)"
)


def _row(f: ChannelFit) -> tuple[str, ...]:
    # R² with 4 decimals as in the thesis's figures and table 5.5, so the numbers can be
    # compared with it directly; errors span decades, hence scientific notation.
    return (
        f.name,
        NO_SCALE if math.isnan(f.r2) else f"{f.r2:.4f}",
        NO_SCALE if math.isnan(f.nrmse_fit) else f"{f.nrmse_fit:.2f}",
        f"{f.max_abs_error:.3e}",
        f"{f.rmse:.3e}",
        f"{f.ssr:.3e}",
    )


def fit_table(fits: Sequence[ChannelFit], *, title: str = "") -> str:
    """An aligned plain-text table of channel fits.

    Columns: channel | R² | fit % | max |e| [rad] | RMSE [rad] | SSR [rad²]. R² is printed
    with 4 decimals (as in the thesis), the fit with 2 decimals, the errors in scientific
    notation. The channel column is left-aligned, the numbers right-aligned.  R² and fit %
    of a constant measurement (no reference scale) are printed as ``n/a``, with a note
    under the table that says why.

    Parameters
    ----------
    fits : sequence of ChannelFit
        One entry per row, in the order given.
    title : str, optional
        A line printed above the table.

    Returns
    -------
    str
        The table, lines separated by ``\\n``, without a trailing newline.

    Raises
    ------
    ValueError
        If ``fits`` is empty or holds something other than :class:`ChannelFit`.
    """
    fits = list(fits)
    if not fits:
        raise ValueError("fit_table needs at least one ChannelFit; got none")
    for i, f in enumerate(fits):
        if not isinstance(f, ChannelFit):
            raise ValueError(
                f"fits[{i}] is a {type(f).__name__}, not a ChannelFit; build rows with "
                "channel_fit(name, y, yhat)"
            )
    rows = [_row(f) for f in fits]
    widths = [max(len(h), *(len(r[j]) for r in rows)) for j, h in enumerate(_HEADERS)]

    def line(cells: Sequence[str]) -> str:
        parts = [cells[0].ljust(widths[0])]
        parts += [c.rjust(w) for c, w in zip(cells[1:], widths[1:], strict=True)]
        return " | ".join(parts).rstrip()

    out = []
    if title:
        out.append(title)
    out.append(line(_HEADERS))
    out.append("-+-".join("-" * w for w in widths))
    out.extend(line(r) for r in rows)
    if any(NO_SCALE in r[1:3] for r in rows):
        out.append(NO_SCALE_NOTE)
    return "\n".join(out)
