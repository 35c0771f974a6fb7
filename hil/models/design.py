"""Design search: the largest virtual-coupler stiffness k22 that keeps the SDEA two-port passive
(or absolutely stable), over the coupler damping b22 and the feed-forward ratio alpha
(paper 002, section VII-A and Table II).

Everything is computed exactly from the hybrid matrix of eq. (12): the only conditions that
depend on (k22, b22) are the two-port ones involving h22 -- the passivity minor
Re h11 Re h22 - |h12* + h21|²/4 ≥ 0 and Llewellyn's η ≥ 0 -- whose polynomials in x = ω² are
formed by :func:`hil.stability.criteria.hermitian_minor_poly` /
:func:`~hil.stability.criteria.llewellyn_polys` and decided by exact root isolation. The
k22-independent conditions (poles, Re h11 ≥ 0) are checked once with the full criterion.

For fixed (b22, alpha) the feasible k22 form an interval [0, k22_max] (the condition polynomial
is a decreasing function of k22² coefficient-wise wherever it matters; the search verifies the
bracket), so k22_max is found by bisection to a relative tolerance of 1e-7. The outer
maximization over b22 (and alpha) is a bounded scalar search (k22_max is concave in b22, as the
paper notes) refined by golden section.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from scipy.optimize import minimize_scalar

from hil.errors import ModelError
from hil.models.sdea import SDEA_TABLE1, sdea_vsic
from hil.stability.criteria import (
    hermitian_minor_poly,
    llewellyn,
    llewellyn_polys,
    two_port_passivity,
)
from hil.stability.exact import DEFAULT_TOL, decide_nonnegative

logger = logging.getLogger(__name__)

__all__ = ["DESIGN_FIXED", "K22Design", "check_design_inputs", "k22_headroom", "k22_max", "optimize_coupler"]


@dataclass
class K22Design:
    """Result of a virtual-coupler design search (N.m/rad, N.m.s/rad)."""

    criterion: str
    alpha: float
    b22: float
    k22_max: float
    evaluations: int

    def to_dict(self) -> dict[str, Any]:
        return {"criterion": self.criterion, "alpha": self.alpha, "b22": self.b22, "k22_max": self.k22_max,
                "evaluations": self.evaluations}


class _Counter:
    n = 0


#: the SDEA parameters a design search may change (b22, k22 and alpha are the design variables)
DESIGN_FIXED = tuple(k for k in SDEA_TABLE1 if k not in ("k22", "b22", "alpha"))


def _plain(x: Any) -> str:
    """A value for a message: numbers (numpy ones too) as plain floats, never ``np.float64(...)``."""
    try:
        return repr(float(x)) if not isinstance(x, bool | str) else repr(x)
    except (TypeError, ValueError):
        return repr(x)


def _is_number(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def check_design_inputs(b22: float | None = None, alpha: float | None = None, criterion: str = "passivity",
                        params: Mapping[str, float] | None = None) -> None:
    """Refuse inputs a design search cannot use, with a one-line :class:`ModelError` naming the
    value: b22 must be a finite positive damping [N.m.s/rad], alpha a number in [0, 1], the
    criterion ``passivity`` or ``absolute_stability``, ``params`` finite numbers naming SDEA
    parameters (k22, b22 and alpha among them are ignored: the search sets them)."""
    if criterion not in ("passivity", "absolute_stability"):
        raise ModelError(f"criterion must be 'passivity' or 'absolute_stability', got {criterion!r}")
    if b22 is not None and (not _is_number(b22) or not math.isfinite(b22) or b22 <= 0):
        raise ModelError(f"b22 must be a finite positive damping [N.m.s/rad], got {_plain(b22)}")
    if alpha is not None and (not _is_number(alpha) or not math.isfinite(alpha) or not 0.0 <= alpha <= 1.0):
        raise ModelError(f"alpha must be a number in [0, 1], got {_plain(alpha)}")
    for k, v in (params or {}).items():  # values of the design variables here are replaced by the search
        if k not in SDEA_TABLE1:
            raise ModelError(f"unknown SDEA parameter {k!r}; expected one of {', '.join(DESIGN_FIXED)}")
        if not _is_number(v) or not math.isfinite(v):
            raise ModelError(f"SDEA parameter {k} must be a finite number, got {_plain(v)}")


def _feasible(params: Mapping[str, float], criterion: str, k22: float, b22: float, alpha: float,
              counter: _Counter) -> bool:
    counter.n += 1
    tm = sdea_vsic(params, k22=k22, b22=b22, alpha=alpha)
    if criterion == "passivity":
        d = decide_nonnegative(hermitian_minor_poly(tm.entries, (0, 1)), DEFAULT_TOL)
        return d.status in ("satisfied", "equality")
    L1, L2 = llewellyn_polys(tm.entries)
    return all(decide_nonnegative(p, DEFAULT_TOL).status in ("satisfied", "equality") for p in (L1, L2))


def _base_ok(params: Mapping[str, float], criterion: str, b22: float, alpha: float) -> bool:
    """k22-independent conditions (poles, Re h11 ≥ 0), checked with the full criterion at k22 = 1."""
    tm = sdea_vsic(params, k22=1.0, b22=b22, alpha=alpha)
    r = two_port_passivity(tm) if criterion == "passivity" else llewellyn(tm)
    return all(c.status in ("satisfied", "equality", "marginal") for c in r.conditions if c.name != "E{1,2}")


def k22_max(b22: float, alpha: float = 1.0, criterion: str = "passivity", params: Mapping[str, float] | None = None,
            k_hi: float = 1e5, rtol: float = 1e-7) -> K22Design:
    """Largest k22 with the two-port passive (``criterion="passivity"``) or absolutely stable
    (``"absolute_stability"``) for fixed b22 and alpha. Returns k22_max = 0 when even k22 → 0 fails.
    Raises :class:`ModelError` for b22 ≤ 0 or not finite, alpha outside [0, 1] (:func:`check_design_inputs`)."""
    check_design_inputs(b22, alpha, criterion, params)
    p = {**SDEA_TABLE1, **(params or {})}
    cnt = _Counter()
    if not _base_ok(p, criterion, b22, alpha):
        return K22Design(criterion, alpha, b22, 0.0, cnt.n)
    lo, hi = 0.0, 1.0
    if not _feasible(p, criterion, hi, b22, alpha, cnt):
        lo, hi = 0.0, 1.0
    else:
        lo = hi
        while hi < k_hi and _feasible(p, criterion, hi * 2, b22, alpha, cnt):
            lo, hi = hi * 2, hi * 2
        hi = min(hi * 2, k_hi)
    while hi - lo > rtol * max(hi, 1e-12):
        mid = 0.5 * (lo + hi)
        if _feasible(p, criterion, mid, b22, alpha, cnt):
            lo = mid
        else:
            hi = mid
    return K22Design(criterion, alpha, b22, lo, cnt.n)


def k22_headroom(k22: float, b22: float, alpha: float = 1.0, criterion: str = "passivity",
                 params: Mapping[str, float] | None = None, rtol: float = 1e-7) -> tuple[float, float]:
    """Parametric headroom of the coupler stiffness at a plant: (k22_max, k22_max/k22 − 1), with
    k22_max from :func:`k22_max` (bisection to ``rtol``) at the given b22, alpha and plant
    ``params``. Dimensionless: 0 at the stability boundary (k22 = k22_max), > 0 when k22 could grow
    by that fraction and stay passive, < 0 (down to -1) when k22 must shrink by that fraction.
    Its sign agrees with the exact verdict except within ``rtol`` of the boundary."""
    if not (math.isfinite(k22) and k22 > 0):
        raise ModelError(f"k22 must be a finite positive stiffness [N.m/rad], got {_plain(k22)}")
    r = k22_max(b22, alpha, criterion, params, rtol=rtol)
    return r.k22_max, r.k22_max / k22 - 1.0


def optimize_coupler(criterion: str = "passivity", alpha: float | None = 1.0,
                     params: Mapping[str, float] | None = None, b22_bounds: tuple[float, float] | None = None,
                     xtol: float = 1e-5, progress: Callable[[str], None] | None = None) -> K22Design:
    """Maximize k22_max over b22 (and over alpha ∈ [0, 1] when ``alpha`` is None).

    ``progress`` (optional) is called after every inner k22_max search with a one-line message
    (current alpha, b22, k22_max, the best so far and the number of exact verdicts so far)."""
    check_design_inputs(None, alpha, criterion, params)
    p = {**SDEA_TABLE1, **(params or {})}
    bf = p["B_f"]
    lo_b, hi_b = b22_bounds or ((1e-4 * bf, 4 * bf) if criterion == "passivity" else (1e-4 * bf, 10 * bf))
    if not (math.isfinite(lo_b) and math.isfinite(hi_b) and 0 < lo_b < hi_b):
        raise ModelError(f"b22 bounds must be finite with 0 < low < high, got ({_plain(lo_b)}, {_plain(hi_b)})")
    total = _Counter()
    best = [0.0]

    def best_for_alpha(a: float) -> K22Design:
        def neg(b: float) -> float:
            r = k22_max(b, a, criterion, p)
            total.n += r.evaluations
            best[0] = max(best[0], r.k22_max)
            if progress is not None:
                progress(f"alpha = {a:.4g}, b22 = {b:.4g} N.m.s/rad: k22_max = {r.k22_max:.5g} N.m/rad "
                         f"(best so far {best[0]:.5g}; {total.n} exact verdicts)")
            return -r.k22_max

        res = minimize_scalar(neg, bounds=(lo_b, hi_b), method="bounded", options={"xatol": xtol * bf})
        b = float(res.x)
        r = k22_max(b, a, criterion, p)
        total.n += r.evaluations
        return r

    if alpha is not None:
        r = best_for_alpha(alpha)
        return K22Design(criterion, alpha, r.b22, r.k22_max, total.n)
    res = minimize_scalar(lambda a: -best_for_alpha(a).k22_max, bounds=(0.0, 1.0), method="bounded",
                          options={"xatol": 1e-4})
    a = float(res.x)
    r = best_for_alpha(a)
    if math.isclose(a, 1.0, abs_tol=2e-4):  # the bounded search never evaluates the end point itself
        r1 = best_for_alpha(1.0)
        r, a = (r1, 1.0) if r1.k22_max >= r.k22_max else (r, a)
    return K22Design(criterion, a, r.b22, r.k22_max, total.n)
