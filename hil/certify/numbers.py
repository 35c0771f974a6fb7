"""How a certificate prints a number: the one formatter of the report tables *and* of the numbers
written into plot legends (:mod:`hil.certify.figures`), so a plotted number and the table row it
repeats print the same text from the same field (issue 28). No heavy imports.

* :func:`fmt` -- 4 significant digits (None an em dash, NaN/inf spelled out);
* :func:`fmt_p` -- a probability that never prints as 1 (or 0) unless it is;
* :func:`fmt_w` -- a frequency in rad/s with Hz in parentheses;
* :func:`fmt_range` -- ``lo … hi`` whose two ends never print alike;
* :func:`fmt_signed` -- a headroom with its sign (``+0.3601``).
"""

from __future__ import annotations

import logging
import math
from typing import Any

logger = logging.getLogger(__name__)

__all__ = ["fmt", "fmt_p", "fmt_range", "fmt_signed", "fmt_w"]


def fmt(v: Any, digits: int = 4) -> str:
    """A value as a short human-readable string (None -> an em dash, NaN/inf spelled out)."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "NaN"
        if math.isinf(v):
            return "∞" if v > 0 else "−∞"
        if v == 0.0:
            return "0"
        return f"{v:.{digits}g}"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(fmt(x, digits) for x in v) + "]"
    if isinstance(v, dict):
        s = "{" + ", ".join(f"{k}: {fmt(x, digits)}" for k, x in v.items()) + "}"
        return s if len(s) <= 240 else s[:237] + "…"
    return str(v)


def fmt_p(v: float | None) -> str:
    """A probability with enough digits that a value below 1 never prints as 1."""
    if v is None or not isinstance(v, int | float) or not math.isfinite(v):
        return fmt(v)
    if v in (0.0, 1.0):
        return f"{v:.0f}"
    for d in range(4, 10):
        s = f"{v:.{d}f}"
        if float(s) not in (0.0, 1.0):
            return s
    return f"{v:.3g}"


def fmt_w(w: Any) -> str:
    """A frequency in rad/s (the unit is the column's) with Hz in parentheses; strings as given."""
    if isinstance(w, int | float) and not isinstance(w, bool) and math.isfinite(w):
        return f"{fmt(float(w))} ({fmt(float(w) / (2 * math.pi))} Hz)"
    return fmt(w)


def fmt_range(lo: Any, hi: Any) -> str:
    """``lo … hi`` with enough digits that two different ends never print alike."""
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in (lo, hi)):
        return f"{fmt(lo)} … {fmt(hi)}"
    for d in range(4, 12):
        a, b = fmt(float(lo), d), fmt(float(hi), d)
        if a != b or lo == hi:
            return f"{a} … {b}"
    return f"{fmt(lo)} … {fmt(hi)}"


def fmt_signed(v: float | None) -> str:
    """A signed quantity such as a headroom, 4 significant digits with its sign; None an em dash."""
    if v is None:
        return "—"
    if not math.isfinite(v):
        return fmt(v)
    return f"{v:+.4g}"
