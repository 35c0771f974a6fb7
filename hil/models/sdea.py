"""Series damped elastic actuator (SDEA) under velocity-sourced impedance control (VSIC) with a
virtual coupler: paper 002 (Mengilli, Caliskan, Orhan, Patoglu).

Hybrid two-port, eq. (12)::

    [F_int; v_e] = [[h11, h12], [-1, h22]] [-v_h; F_e]

taken, as in the paper, as the hybrid matrix in the standard port orientation when applying
Theorems 2 and 3. Rotary units: M [kg.m²], B, B_f, P_m, b22 [N.m.s/rad], K_f, I_m, k22 [N.m/rad],
P_f [rad/(N.m.s)], I_f [rad/(N.m.s²)]; alpha ∈ [0, 1] (1 - alpha = fraction of the interaction
force fed forward; alpha = 1 means no feed-forward).

Re-derivation (kept in tests): from eq. (10) with P = 1/(Ms+B), C_m = P_m + I_m/s,
C_f = P_f + I_f/s, G11 = 0, G12 = -G21 = 1 and the feed-forward turning the "+1" of
(C_m C_f + 1) into alpha, multiplying through by s²(Ms + B) gives exactly (12a)-(12b):
h11 = s(K_f + B_f s)(Ms² + (B+P_m)s + I_m)/a(s), h12 = (P_f s + I_f)(P_m s + I_m)(K_f + B_f s)/a(s).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hil.errors import ModelError
from hil.stability.rational import Rational, S, TransferMatrix
from hil.stability.results import Condition, StabilityResult, combine

__all__ = [
    "SDEA_TABLE1",
    "SDEA_TABLE2_PRINTED",
    "lemma5_nonnegative_cubic",
    "sdea_coefficients",
    "sdea_vsic",
    "theorem5",
    "transmitted_impedance",
    "z_min",
    "z_width",
]

#: Table I of paper 002 (nominal parameters; J is the actuator inertia M) plus a virtual coupler
#: inside the passive region and alpha = 1 (no feed-forward).
SDEA_TABLE1: dict[str, float] = {
    "K_f": 362.0, "B_f": 0.05, "M": 6.399e-4, "B": 0.169,
    "P_m": 0.28, "I_m": 100.0, "P_f": 40.0, "I_f": 70.0,
    "k22": 300.0, "b22": 0.17, "alpha": 1.0,
}

#: Table II of paper 002 as printed: (alpha, criterion) -> (optimal b22, max k22).
SDEA_TABLE2_PRINTED: dict[tuple[float, str], tuple[float, float]] = {
    (0.0, "passivity"): (0.14, 367.0),
    (1.0, "passivity"): (0.17, 408.5),
    (0.9, "passivity"): (0.15, 415.5),
    (1.0, "absolute_stability"): (0.13, 432.0),
}


@dataclass(frozen=True)
class SDEACoefficients:
    """Polynomial coefficients of eq. (12) (descending powers of s)."""

    a: tuple[float, float, float, float, float]  # a4..a0
    n11: tuple[float, float, float, float, float]  # B_f M, ..., K_f I_m, 0
    n12: tuple[float, float, float, float]  # B_f P_m P_f, ..., K_f I_m I_f


def _params(p: Mapping[str, float] | None, kw: Mapping[str, float]) -> dict[str, float]:
    q = {**SDEA_TABLE1, **(p or {}), **kw}
    unknown = set(q) - set(SDEA_TABLE1)
    if unknown:
        raise ModelError(f"unknown SDEA parameter(s): {', '.join(sorted(unknown))}; "
                         f"expected {', '.join(SDEA_TABLE1)}")
    for k, v in q.items():
        if not math.isfinite(float(v)):
            raise ModelError(f"SDEA parameter {k} must be finite")
    if q["M"] <= 0 or q["K_f"] <= 0 or q["P_m"] <= 0 or q["P_f"] <= 0:
        raise ModelError("M, K_f, P_m and P_f must be positive")
    if min(q["B"], q["B_f"], q["I_m"], q["I_f"], q["b22"], q["k22"]) < 0:
        raise ModelError("B, B_f, I_m, I_f, b22 and k22 must be non-negative")
    if not 0.0 <= q["alpha"] <= 1.0:
        raise ModelError("alpha must lie in [0, 1]")
    return {k: float(v) for k, v in q.items()}


def sdea_coefficients(p: Mapping[str, float] | None = None, **kw: float) -> SDEACoefficients:
    """Coefficients of eq. (12a)-(12b) with μ = I_m/P_m, ν = I_f/P_f (products written out so that
    P_m or P_f need not divide)."""
    q = _params(p, kw)
    K, Bf, M, B = q["K_f"], q["B_f"], q["M"], q["B"]
    Pm, Im, Pf, If = q["P_m"], q["I_m"], q["P_f"], q["I_f"]
    mn = Pm * If + Im * Pf  # = P_m P_f (μ + ν)
    a = sdea_polynomials(q)["a"]
    n11 = (Bf * M, Bf * (B + Pm) + K * M, Bf * Im + K * (B + Pm), K * Im, 0.0)
    n12 = (Bf * Pm * Pf, Pm * Pf * K + Bf * mn, Bf * Im * If + K * mn, K * Im * If)
    return SDEACoefficients(a, n11, n12)


def sdea_vsic(p: Mapping[str, float] | None = None, **kw: float) -> TransferMatrix:
    """The hybrid matrix of eq. (12) with the virtual coupler of eq. (11)."""
    q = _params(p, kw)
    c = sdea_coefficients(q)
    if q["b22"] == 0 and q["k22"] == 0:
        raise ModelError("the virtual coupler needs k22 > 0 or b22 > 0 (h22 = s/(b22 s + k22))")
    h11 = Rational.from_desc(c.n11, c.a)
    h12 = Rational.from_desc(c.n12, c.a)
    h22 = S / (q["b22"] * S + q["k22"])
    return TransferMatrix([[h11, h12], [Rational.const(-1.0), h22]], "hybrid", (1, 1), "sdea_vsic (002 eq. 12)")


# ---------------------------------------------------------------------------------------------
# performance (section VI)


def z_min(tm: TransferMatrix) -> Rational:
    """Minimum transmitted impedance, eq. (7): Z_min = h11."""
    return tm.to("hybrid")[0, 0]


def z_width(tm: TransferMatrix) -> Rational:
    """Range of passively renderable impedances, eq. (8): Z_width = -h12 h21 / h22.

    For eq. (12) this is n12 (b22 s + k22) / (s a(s)); paper eq. (24) prints the denominator as
    "a4 s⁵ + … + a1 s² + a0", which lacks the factor s on a0 (a typo: see docs/PAPER_NOTES.md).
    """
    h = tm.to("hybrid")
    return -(h[0, 1] * h[1, 0]) / h[1, 1]


def transmitted_impedance(tm: TransferMatrix, Ze: Rational) -> Rational:
    """Impedance felt by the operator with environment Z_e at port 2, eq. (6):
    Z_to = (h11 + Δh Z_e)/(1 + h22 Z_e), Δh = h11 h22 - h12 h21."""
    h = tm.to("hybrid")
    dh = h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0]
    return (h[0, 0] + dh * Ze) / (1.0 + h[1, 1] * Ze)


# ---------------------------------------------------------------------------------------------
# Theorem 5 (closed form) and Lemma 5


def lemma5_nonnegative_cubic(p3: float, p2: float, p1: float, p0: float) -> bool:
    """Lemma 5 of paper 002: p3 x³ + p2 x² + p1 x + p0 ≥ 0 for all x ≥ 0, as printed.

    True iff p3 ≥ 0, p0 ≥ 0 and either (a) p1 ≥ 0 and p2 ≥ -√(3 p1 p3), or (b) σ = p2² - 3p1p3 > 0,
    σ3 = p1p2 - 9p0p3 < 0 and 4 p2 σ3 < 4 p1 σ + 3 p3 σ3²/σ. Tested against the exact Sturm decision.
    """
    if p3 < 0 or p0 < 0:
        return False
    if p1 >= 0 and p2 >= -math.sqrt(3 * p1 * p3):
        return True
    sig = p2 * p2 - 3 * p1 * p3
    s3 = p1 * p2 - 9 * p0 * p3
    return bool(sig > 0 and s3 < 0 and 4 * p2 * s3 < 4 * p1 * sig + 3 * p3 * s3 * s3 / sig)


def sdea_polynomials(q: Mapping[str, Any]) -> dict[str, Any]:
    """Coefficients of eq. (12)'s a(s), and of the (c-i) cubic r(x) (eq. 34) and (c-ii) cubic t(x)
    (eq. 36), for a mapping of scalars **or numpy arrays** (vectorized over draws; no validation).

    Returns ``{"a": (a4, a3, a2, a1, a0), "r": (r0, r1, r2, r3), "t": (t0, t1, t2, t3)}``.
    """
    K, Bf, M, B = q["K_f"], q["B_f"], q["M"], q["B"]
    Pm, Im, Pf, If, al = q["P_m"], q["I_m"], q["P_f"], q["I_f"], q["alpha"]
    b22, k22 = q["b22"], q["k22"]
    mn = Pm * If + Im * Pf  # = P_m P_f (μ + ν)
    a = (M, B + Pm + Bf * (al + Pm * Pf), Im + K * (al + Pm * Pf) + Bf * mn, Bf * Im * If + K * mn, K * Im * If)
    k1 = Pf * Im - B * If
    k3 = al * (B + Pm) + (B + Pm) * Pm * Pf - M * mn  # α(B+P_m) + P_m P_f κ2
    r3 = Bf * M * M
    r2 = Bf * (Bf * k3 + (B + Pm) ** 2 - 2 * Im * M)
    r1 = K * K * k3 + Bf * Im * Im + Bf * Bf * Im * k1
    r0 = Im * K * K * k1
    tau1 = 4 * Bf - b22
    tau2 = 2 * M * (Im + al * K) - (B + Pm + al * Bf) ** 2
    t3 = tau1 * b22 * M * M
    t2 = 4 * b22 * r2 + b22 * b22 * tau2 - k22 * k22 * M * M
    t1 = 4 * b22 * r1 + k22 * k22 * tau2 - b22 * b22 * (Im + al * K) ** 2
    t0 = 4 * b22 * K * K * Im * k1 - k22 * k22 * (Im + al * K) ** 2
    return {"a": a, "r": (r0, r1, r2, r3), "t": (t0, t1, t2, t3)}


def theorem5_polynomials(p: Mapping[str, float] | None = None, **kw: float) -> dict[str, tuple[float, ...]]:
    """The cubic factors of (c-i) r(x) (eq. 34, ascending r0..r3) and (c-ii) t(x) (eq. 36, t0..t3)."""
    polys = sdea_polynomials(_params(p, kw))
    return {"r": polys["r"], "t": polys["t"]}


def theorem5(p: Mapping[str, float] | None = None, **kw: float) -> StabilityResult:
    """Closed-form two-port passivity conditions of Theorem 5 (paper 002).

    (a) Lemma 2 on the characteristic polynomial a(s): a1(a2a3 - a1a4) - a0a3² ≥ 0 (the paper's
    expanded inequality is this expression with eq. (12)'s coefficients substituted);
    (b) if it holds with equality, Lemma 4's residue conditions on h11's imaginary-axis poles;
    (c-i) Lemma 5 on r(x); (c-ii) 0 < b22 ≤ 4B_f and Lemma 5 on t(x).
    Cross-checked against :func:`hil.stability.criteria.two_port_passivity` in the tests.
    """
    q = _params(p, kw)
    c = sdea_coefficients(q)
    a4, a3, a2, a1, a0 = c.a
    conds: list[Condition] = []
    hur = a1 * (a2 * a3 - a1 * a4) - a0 * a3 * a3
    scale = abs(a1 * a2 * a3) + abs(a1 * a1 * a4) + abs(a0 * a3 * a3)
    rel = hur / scale if scale else 0.0
    if rel < -1e-12:
        conds.append(Condition("(a)", "Lemma 2: h11 has no RHP poles", "violated", rel))
    elif rel <= 1e-12:
        b3, b2, b1, b0 = c.n11[:4]
        lhs = a1 * b3 - a3 * b1
        den = a2 * a3 - 2 * a1 * a4
        ok_a = abs(lhs - (a3 * b0 - a1 * b2) * a3 * a3 / den) <= 1e-9 * (abs(lhs) + 1e-300) if den else False
        ok_b = lhs < 0
        conds.append(Condition("(a)", "Lemma 2: h11 has no RHP poles", "equality", 0.0,
                               detail="imaginary-axis pole pair (Lemma 3)"))
        conds.append(Condition("(b)", "Lemma 4: residues real and positive",
                               "satisfied" if ok_a and ok_b else "violated", 0.0 if ok_a and ok_b else -1.0))
    else:
        conds.append(Condition("(a)", "Lemma 2: h11 has no RHP poles", "satisfied", rel))
    polys = theorem5_polynomials(q)
    r0, r1, r2, r3 = polys["r"]
    ok_ci = lemma5_nonnegative_cubic(r3, r2, r1, r0)
    conds.append(Condition("(c-i)", "Lemma 5 on r(x): Re h11 ≥ 0", "satisfied" if ok_ci else "violated",
                           1.0 if ok_ci else -1.0, evidence={"r_x_desc": [r3, r2, r1, r0]}))
    t0, t1, t2, t3 = polys["t"]
    ok_b22 = 0.0 < q["b22"] <= 4 * q["B_f"]
    ok_cii = ok_b22 and lemma5_nonnegative_cubic(t3, t2, t1, t0)
    conds.append(Condition("(c-ii)", "0 < b22 ≤ 4B_f and Lemma 5 on t(x): passivity inequality",
                           "satisfied" if ok_cii else "violated", 1.0 if ok_cii else -1.0,
                           evidence={"t_x_desc": [t3, t2, t1, t0]}))
    return combine("theorem5 (002, closed form)", conds, {"name": "sdea_vsic", "params": q})
