"""Numbers printed with as many digits as their spread needs.

A posterior can be a million times narrower than its value (k_m = 4.3687 with sd 3e-6):
printed to a fixed number of significant digits its interval reads ``[4.369, 4.369]``.
Here the digits follow the width: enough that an interval's two ends differ in about
two digits, and no more.
"""

from __future__ import annotations

import math


def significant_digits(value: float, spread: float, *, extra: int = 2, default: int = 6) -> int:
    """Significant digits that show ``value`` to about ``extra`` digits of ``spread``."""
    if not (math.isfinite(value) and math.isfinite(spread)) or spread <= 0:
        return default
    if value == 0:
        return extra
    lead = math.floor(math.log10(abs(value)))
    return max(extra, min(15, lead - math.floor(math.log10(spread)) + extra))


def fmt_value(value: float, spread: float, **kw) -> str:
    """``value`` with the digits that its spread (an sd or an interval's width) resolves,
    trailing zeros kept (3.2 resolved to 1e-6 is ``3.200000``, not ``3.2``)."""
    if not math.isfinite(value):
        return f"{value}"
    out = f"{value:#.{significant_digits(value, spread, **kw)}g}"
    return out[:-1] if out.endswith(".") else out


def sd_place(sd: float) -> int | None:
    """The power of ten of the last digit of ``sd`` written to two significant digits
    (6.9e-7 -> -8, 0.0123 -> -3, 230 -> 1); None for an sd that is not finite and > 0."""
    if not (isinstance(sd, int | float) and math.isfinite(sd) and sd > 0):
        return None
    rounded = float(f"{sd:.1e}")  # 9.96e-7 becomes 1.0e-6: its place is one up
    return math.floor(math.log10(rounded)) - 1


def fmt_at(x: float, place: int) -> str:
    """``x`` rounded to the decimal place ``10**place``: fixed notation for |x| from 1e-3
    to 1e6 (``3.61876540``, ``12350``), else scientific with the digits down to that place
    (``2.300e-05``)."""
    if not math.isfinite(x):
        return f"{x}"
    lead = math.floor(math.log10(abs(x))) if x else 0
    if x == 0 or 1e-3 <= abs(x) < 1e6 or lead < place:
        if place >= 0:
            return f"{round(x, -place):.0f}"
        return f"{x:.{-place}f}"
    return f"{x:.{lead - place}e}"


def fmt_sd(sd: float) -> str:
    """An sd to two significant digits (``0.0069``, ``23``, ``230``, ``6.9e-07``); "—"
    for none."""
    place = sd_place(sd)
    if place is None:
        return "—" if not (isinstance(sd, int | float) and sd == 0) else "0"
    if 1e-3 <= sd < 1e6:
        return fmt_at(sd, place)
    return f"{sd:.1e}"


def mean_sd(mean: float, sd: float) -> tuple[str, str]:
    """A mean and its sd as a table prints them: the sd to two significant digits, the
    mean to the same decimal place (``3.61876540``, ``6.9e-07``), so the interval can be
    read from the table.  Without a finite sd > 0 the mean keeps six significant digits."""
    place = sd_place(sd)
    if place is None or not math.isfinite(mean):
        return (f"{mean:.6g}" if math.isfinite(mean) else f"{mean}"), fmt_sd(sd)
    return fmt_at(mean, place), fmt_sd(sd)


def fmt_interval_at(lo: float, hi: float, sd: float) -> str:
    """``lo, hi`` to the decimal place of ``sd`` (two significant digits), as :func:`mean_sd`
    prints the mean beside it; six significant digits without a usable sd."""
    place = sd_place(sd)
    if place is None:
        return f"{lo:.6g}, {hi:.6g}"
    return f"{fmt_at(lo, place)}, {fmt_at(hi, place)}"
