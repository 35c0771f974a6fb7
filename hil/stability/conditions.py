"""Condition records of the frequency conditions: the exact decision of each condition polynomial
(:mod:`hil.stability.exact`), its status, evidence and margin (docs/VERDICTS.md)."""

from __future__ import annotations

import itertools
import logging
import math
from typing import Any

import numpy as np

from hil.stability.exact import (
    SignDecision,
    decide_exact,
    flips_within,
)
from hil.stability.forms import (
    CondPoly,
    QEntries,
    _desc,
    _exact_llewellyn_polys,
    _exact_minor_polys,
    _lbl,
    _qpoly_float,
    _Setup,
)
from hil.stability.margins import frequency_margin
from hil.stability.rational import Rational
from hil.stability.results import Condition, ConditionStatus
from hil.stability.tolerances import Tolerances

logger = logging.getLogger(__name__)


def _axis_x(cp: CondPoly) -> list[float]:
    """The imaginary-axis poles' x = ω² at which the uncancelled polynomial vanishes (the positive
    roots of the cancelled factor h, from full = p·h^(2·cut))."""
    if cp.cut == 0:
        return []
    from hil.stability.exact import _positive_roots_arb

    hh = cp.full // cp.p
    g = hh.gcd(hh.derivative())
    roots = _positive_roots_arb(hh // g if g.degree() > 0 else hh)
    return roots or []


def _exact_decision(cp: CondPoly, K: int, tol: Tolerances, margins: bool) -> tuple[SignDecision, bool]:
    """Exact decision of one condition (its status from the cancelled polynomial ``cp.p``), its
    margin (``margins``: the frequency-domain margin of hil.stability.margins on the uncancelled
    ``cp.full`` with the envelope magnitude polynomial) and, with ``tol.rtol > 0``, whether the
    decision can flip under relative perturbations ≤ rtol of the coefficients of u and D (K
    coefficient factors per term of p; when axis factors were cancelled the bound is the cancelled
    polynomial's own |coefficients|: the uncancelled m does not divide)."""
    p, cut, m = cp.p, cp.cut, cp.m
    d = decide_exact(p, m if cut == 0 else None, margin=False)
    if margins and d.status != "equality" and m is not None:
        touch = [] if d.status == "violated" else sorted(list(d.touching) + _axis_x(cp))
        d.margin, d.worst_x = frequency_margin(cp.full, np.asarray(m), touch, d.negative_bands)
        if d.status == "violated" and not d.margin < 0:  # pragma: no cover - certified: cannot happen
            d.margin = -1e-300
    flip = False
    if tol.rtol > 0 and d.status != "equality":
        eps = (1.0 + tol.rtol) ** K - 1.0
        mm = m if cut == 0 else None
        mb = np.abs(d.coefficients) if mm is None else np.maximum(
            np.pad(np.abs(mm), (0, max(0, d.coefficients.size - np.asarray(mm).size))),
            np.pad(np.abs(d.coefficients), (0, max(0, np.asarray(mm).size - d.coefficients.size))))
        flip = flips_within(p, mb, eps, d.status)
    return d, flip


_RANK = {"violated": 3, "touching": 1, "equality": 1, "satisfied": 0}


def _cond_exact(name: str, label: str, d: SignDecision, flip: bool, extra: dict[str, Any],
                tol: Tolerances, cp: CondPoly | None = None) -> Condition:
    """Condition record from an exact decision (statuses: docs/VERDICTS.md); ``cp``: the condition
    polynomial the margin was taken on (kept for the critical band)."""
    from hil.stability.margins import restricted

    ratio = None
    if cp is not None and cp.m is not None and d.margin == d.margin and not cp.full.is_zero():
        ratio = (cp.full, restricted(cp.full, np.asarray(cp.m)))
    bands_w = [(math.sqrt(a), math.sqrt(b) if math.isfinite(b) else math.inf) for a, b in d.negative_bands]
    touching_w = [math.sqrt(x) for x in d.touching]
    status: ConditionStatus
    ev: dict[str, Any] = {
          "polynomial_x_desc": _desc(d.coefficients), "method": d.method, "distinct_positive_roots": d.n_roots,
          "negative_bands_rad_s": bands_w, "band_depths": d.band_depths,
          "touching_rad_s": touching_w, "formed": "exact",
          "margin_kind": "frequency-domain margin: min over x >= 0 of p(x)/m_r(x), p before the imaginary-axis "
                         "factors are cancelled (docs/VERDICTS.md)"}
    ev.update(extra)
    margin, wf = d.margin, d.worst_omega
    constant = wf is None and margin == margin and d.status in ("violated", "satisfied")  # ρ constant in ω
    if constant:
        ev["ratio_constant"] = True
    if d.status == "violated":
        status = "violated"
        detail = _band_detail(ev) if bands_w else "negative for all ω"
        if not (margin < 0):  # the margin of a violated condition is negative by definition
            margin = -abs(margin) if margin == margin and margin != 0 else -1e-300
    elif d.status == "equality":
        status, margin, detail = "equality", 0.0, "identically zero: holds with equality at all frequencies"
    elif d.status == "touching":
        status, margin = "equality", 0.0
        detail = ("touches zero (holds with equality) at ω = "
                  + ", ".join(f"{w:.6g}" for w in touching_w) + " rad/s")
        wf = touching_w[0] if touching_w else wf
    else:
        status, detail = "satisfied", "positive for all ω"
        if margin == 0.0 and extra.get("axis_pole_factors_cancelled"):
            detail += " (margin 0 at the imaginary-axis pole: a lossless pole is on the boundary)"
    if constant and status == "satisfied":
        detail += _CONSTANT_NOTE
    if flip:
        ev["flips_within_rtol"] = tol.rtol
        detail = (f"{detail}; the verdict of this condition can flip under a relative perturbation of "
                  f"{tol.rtol:.3g} of the coefficients")
        status = "marginal"
    return Condition(name, label, status, float(margin), wf, detail, ev, ratio=ratio)


def _band_detail(ev: dict[str, Any]) -> str:
    """The detail line of a violated frequency condition, from its evidence (the one definition
    shared by the JSON and the text table): the deepest negative band, in physical rad/s once
    :func:`_rescale` has scaled ``negative_bands_rad_s``."""
    b = ev["negative_bands_rad_s"][int(np.argmin(ev["band_depths"]))]
    return f"negative for ω in [{b[0]:.6g}, {b[1]:.6g}] rad/s" + (_CONSTANT_NOTE if ev.get("ratio_constant") else "")


#: the detail of a condition whose normalized polynomial p/m_r is constant in ω (no worst frequency)
_CONSTANT_NOTE = "; p/m_r is constant in ω (its minimum is attained at every frequency: no worst frequency)"


def _hermitian_minors(entries: list[list[Rational]], idx_all: list[int], tol: Tolerances, prefix: str,
                      label: str, margins: bool = True, q: QEntries | None = None) -> list[Condition]:
    """All principal minors of G(jω) + G(jω)ᴴ over the index set, as exact polynomial conditions.

    ``q``: the entries given exactly (Theorem 1's symmetrized Z', whose coefficients are rationals
    that floats need not represent, up to a diagonal similarity); ``entries`` is then ignored and
    the minors are those of the entrywise real part (2·Re Z'(jω))."""
    if q is not None:
        sub_q: QEntries | None = ([[q[0][i][j] for j in idx_all] for i in idx_all],
                                  [[q[1][i][j] for j in idx_all] for i in idx_all])
        sub: list[list[Rational]] = []
    else:
        sub_q, sub = None, [[entries[i][j] for j in idx_all] for i in idx_all]
    n = len(idx_all)
    exact = _exact_minor_polys(sub, margins or tol.rtol > 0, q=sub_q, entrywise_real=q is not None)
    conds = []
    for k in range(1, n + 1):
        for idx in itertools.combinations(range(n), k):
            glob = tuple(idx_all[i] for i in idx)
            name, lab = f"{prefix}{_lbl(glob)}", f"{label}, principal minor {_lbl(glob)}"
            cp = exact[idx]
            d, flip = _exact_decision(cp, 2 * k, tol, margins)
            conds.append(_cond_exact(name, lab, d, flip, {"axis_pole_factors_cancelled": cp.cut}, tol, cp))
    return conds


def _llewellyn_eta(entries: list[list[Rational]], i: int, j: int, tol: Tolerances,
                   margins: bool = True, diag_positive: bool = False) -> Condition:
    """Llewellyn's η_ij ≥ 0 for all ω as an exact condition (see :func:`llewellyn_polys`).

    ``diag_positive``: the caller has decided Re p_ii > 0 and Re p_jj > 0 for every ω > 0 (both
    conditions ``satisfied``, exactly). Then, without imaginary-axis poles at ω > 0, a > 0 on x > 0,
    and L2 ≥ 0 forces 4a(a - Re c) ≥ (Im c)² ≥ 0, so a ≥ Re c and L1 = a + (a - Re c) ≥ a > 0 on
    x > 0: L1 is ``satisfied`` whenever L2 holds, and is not decided separately on the verdict-only
    path (``margins=False``, no tolerance: its margin and flip test are not needed)."""
    st: list[_Setup] = []
    cp1, cp2 = _exact_llewellyn_polys([[entries[a][b] for b in (i, j)] for a in (i, j)], margins or tol.rtol > 0,
                                      _st=st)
    p1, c1, c2 = cp1.p, cp1.cut, cp2.cut
    d2, f2 = _exact_decision(cp2, 8, tol, margins)
    if (diag_positive and not margins and tol.rtol == 0 and st[0].h is None and not p1.is_zero()
            and d2.status in ("satisfied", "touching", "equality")):
        d1, f1 = SignDecision("satisfied", math.nan, math.nan, method="implied (L2 ≥ 0, Re p_ii > 0, Re p_jj > 0)",
                              coefficients=_qpoly_float(p1)), False
    else:
        d1, f1 = _exact_decision(cp1, 4, tol, margins)
    name = f"E{_lbl((i, j))}"
    a_, b_ = i + 1, j + 1
    label = f"Llewellyn η{a_}{b_} = 2Re p{a_}{a_} Re p{b_}{b_} - Re(p{a_}{b_}p{b_}{a_}) - |p{a_}{b_}p{b_}{a_}| ≥ 0"
    worst = d2 if _RANK[d2.status] >= _RANK[d1.status] else d1
    if worst.status == d1.status == d2.status and margins and d1.margin < d2.margin:
        worst = d1
    return _cond_exact(name, label, worst, f1 or f2,
                       {"L1_x_desc": _desc(d1.coefficients), "L1_status": d1.status,
                        "L2_x_desc": _desc(d2.coefficients), "L2_status": d2.status,
                        "axis_pole_factors_cancelled": max(c1, c2)}, tol, cp2 if worst is d2 else cp1)
