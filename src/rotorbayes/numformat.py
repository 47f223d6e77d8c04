"""Numbers printed with as many digits as their spread needs.

A posterior can be a million times narrower than its value (k_m = 4.3687 with sd 3e-6):
printed to a fixed number of significant digits its interval reads ``[4.369, 4.369]``.
Here the digits follow the width: enough that an interval's two ends differ in about
two digits, and no more.
"""

from __future__ import annotations

import math


def significant_digits(value: float, spread: float, *, extra: int = 2,
                       default: int = 6) -> int:
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


def fmt_interval(lo: float, hi: float) -> str:
    """``[lo, hi]`` with both ends distinguishable (two digits of the width)."""
    big = lo if abs(lo) >= abs(hi) else hi
    n = significant_digits(big, hi - lo)
    return f"[{lo:.{n}g}, {hi:.{n}g}]"
