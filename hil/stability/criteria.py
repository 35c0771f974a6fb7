"""Passivity and absolute-stability criteria for LTI networks, decided exactly.

Criteria (each returns a :class:`~hil.stability.results.StabilityResult`):

* :func:`positive_real` -- positive realness of a one-port or of a transfer matrix
  (Definition 2 of paper 000 / Definition 3 of paper 001): no RHP poles; imaginary-axis poles
  simple with Hermitian positive semidefinite residue matrices; G(jω) + G(jω)ᴴ ⪰ 0 for all ω,
  checked through *all* principal minors of the Hermitian part (each a polynomial in x = ω²).
* :func:`two_port_passivity` -- Theorem 2 of paper 002 = positive realness of any immittance
  matrix of the two-port (for m-DOF ports too).
* :func:`llewellyn` -- Llewellyn's absolute stability (Theorem 3 of paper 002; appendix of 000).
* :func:`absolute_stability` -- Theorem 1 of paper 000 (m-DOF n-port), with the
  symmetrization conditions A and B. Stability vs *weak* stability (paper 001) is the strict
  vs non-strict reading of the same conditions: see ``StabilityResult.weak``.
* :func:`check` -- picks the cheapest sufficient test for the network's size.

Frequency conditions are reduced to real polynomials in x = ω², formed exactly over Q from the
float coefficients (python-flint), and decided without rounding (:mod:`exact`); dense sweeps are
only used (and flagged ``method: sweep``) for Theorem 1 blocks of size ≥ 3 whose symmetrized
matrix Z' is not rational. Poles are located exactly (:func:`hil.stability.exact.exact_poles`: RHP
count by Routh-Hurwitz over Q, imaginary-axis poles from gcd(Re d(jω), Im d(jω)/ω)); no pole
tolerance. Verdicts, statuses and margins are defined in docs/VERDICTS.md.
"""

from __future__ import annotations

import itertools
import logging
import math
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from flint import fmpq, fmpq_poly
from numpy.polynomial import polynomial as P

from hil.errors import ModelError
from hil.stability.exact import (
    DEFAULT_TOL,
    SignDecision,
    decide_exact,
    exact_poles,
    flips_within,
    strictly_hurwitz,
)
from hil.stability.jpoly import JPoly, XPoly, trim_back
from hil.stability.rational import _RF, Rational, TransferMatrix, _to_rf
from hil.stability.residues import _xq  # N(jω) = a(x) + jω·b(x), shared with the residue tests
from hil.stability.results import Condition, ConditionStatus, StabilityResult, combine

logger = logging.getLogger(__name__)

POLE_TOL = 1e-9
RESIDUE_TOL = 1e-9

__all__ = [
    "Tolerances",
    "absolute_stability",
    "check",
    "infinity_condition",
    "llewellyn",
    "margin_curve",
    "pole_conditions",
    "positive_real",
    "two_port_passivity",
]


@dataclass(frozen=True)
class Tolerances:
    """Tolerances (all relative; docs/VERDICTS.md).

    ``rtol`` (default 0): a relative tolerance on the coefficients; a condition whose status can
    flip under such a perturbation is ``marginal``. With 0 every verdict is the exact one for the
    given coefficients. ``poly``, ``pole`` and ``residue``: unused (every condition is formed and
    decided exactly: Theorem 1's Z' over Q, poles by Routh-Hurwitz over Q, residues in Q[x]/(f),
    :mod:`hil.stability.residues`), kept for compatibility."""

    poly: float = DEFAULT_TOL
    pole: float = POLE_TOL
    residue: float = RESIDUE_TOL
    rtol: float = 0.0


TOL = Tolerances()


def _as_tm(g: TransferMatrix | Rational) -> TransferMatrix:
    if isinstance(g, Rational):
        return TransferMatrix([[g]])
    if not isinstance(g, TransferMatrix):
        raise ModelError("expected a TransferMatrix or a Rational")
    return g


def _netinfo(tm: TransferMatrix, w0: float = 1.0) -> dict[str, Any]:
    return {"name": tm.name, "type": tm.kind, "ports": list(tm.port_dofs), "size": tm.n, "omega_scale": w0}


def _normalized(tm: TransferMatrix) -> tuple[TransferMatrix, float]:
    cached = getattr(tm, "_normalized_cache", None)
    if cached is not None:
        return cast("tuple[TransferMatrix, float]", cached)
    out = _normalize(tm)
    tm._normalized_cache = out  # type: ignore[attr-defined]  # entries are never mutated in place
    return out


def _normalize(tm: TransferMatrix) -> tuple[TransferMatrix, float]:
    """Rescale frequency s = w0·s̃ so the condition polynomials stay well inside double range.

    w0 is the geometric mean of the smallest and largest non-zero pole/zero magnitudes. Verdicts
    are invariant (x̃ = x/w0² is a positive rescaling); reported frequencies are multiplied back.
    """
    # characteristic frequencies from the coefficients (|c_0/c_n|^(1/n) per polynomial): the
    # geometric mean of the root magnitudes, without root finding
    mags = []
    for row in tm.entries:
        for e in row:
            if e.is_zero:
                continue
            for arr in (e.num, e.den):
                c = arr.tolist()  # cleaned: the last coefficient is non-zero
                k = 0
                while c[k] == 0:
                    k += 1
                top = len(c) - 1
                if top > k:
                    mags.append((abs(c[k]) / abs(c[top])) ** (1.0 / (top - k)))
    if not mags:
        return tm, 1.0
    w0 = float(math.sqrt(min(mags) * max(mags)))
    if not (math.isfinite(w0) and w0 > 0) or abs(math.log10(w0)) < 0.5:
        return tm, 1.0
    # a power of two: the scaled coefficients c_k·w0^k / 2^e are then *exact* (no rounding), so
    # exact relations between the entries' coefficients (common factors, imaginary-axis poles,
    # cancellations) survive the normalization and the exact decisions see the given network
    e0 = round(math.log2(w0))
    w0 = 2.0**e0
    ent = [[e if e.is_zero else _scaled_exact(e, e0) for e in row] for row in tm.entries]
    return TransferMatrix(ent, tm.kind, tm.port_dofs, tm.name), w0


def _scaled_exact(e: Rational, e0: int) -> Rational:
    """e(w0·s̃) with w0 = 2^e0, divided by a power of two near den's largest coefficient: every
    coefficient is scaled exactly (``ldexp``), barring under/overflow (then the checked
    constructor). Pure Python on the (short) coefficient lists first, the same two ``ldexp`` steps
    as the array version below, which runs only when a step overflows."""
    try:
        dl = [math.ldexp(v, e0 * k) for k, v in enumerate(e.den.tolist())]
        es_ = round(math.log2(max(abs(v) for v in dl)))
        dl = [math.ldexp(v, -es_) for v in dl]
        nl = [math.ldexp(v, e0 * k - es_) for k, v in enumerate(e.num.tolist())]
        if nl[-1] != 0 and dl[-1] != 0:
            return Rational.trusted(np.array(nl), np.array(dl))
    except (OverflowError, ValueError):
        pass
    den = np.ldexp(e.den, e0 * np.arange(e.den.size))
    es = round(math.log2(float(np.max(np.abs(den)))))
    den = np.ldexp(den, -es)
    num = np.ldexp(e.num, e0 * np.arange(e.num.size) - es)
    if num[-1] != 0 and den[-1] != 0 and np.isfinite(num).all() and np.isfinite(den).all():
        return Rational.trusted(num, den)
    return Rational(num, den)


def _rescale(conds: list[Condition], w0: float) -> list[Condition]:
    if w0 == 1.0:
        return conds
    for c in conds:
        if c.worst_frequency is not None and math.isfinite(c.worst_frequency):
            c.worst_frequency *= w0
        ev = c.evidence
        if "negative_bands_rad_s" in ev:
            ev["negative_bands_rad_s"] = [(a * w0, b * w0) for a, b in ev["negative_bands_rad_s"]]
            if c.status == "violated" and ev["negative_bands_rad_s"] and c.detail.startswith("negative for ω"):
                c.detail = _band_detail(ev)
        if "touching_rad_s" in ev:
            ev["touching_rad_s"] = [x * w0 for x in ev["touching_rad_s"]]
        if "pole" in ev:
            ev["pole"] = ev["pole"] * w0
        if "poles" in ev:
            ev["poles"] = [p * w0 for p in ev["poles"]]
        if "rhp_poles" in ev:
            for r in ev["rhp_poles"]:
                r["pole"] *= w0
        if c.name.startswith("D[ω="):
            c.name = f"D[ω={float(c.name[4:-1]) * w0:.6g}]"
        if "polynomial_x_desc" in ev:
            ev["x_scale"] = w0 * w0
    return conds


def _desc(c: np.ndarray) -> list[float]:
    return cast("list[float]", np.asarray(c, float)[::-1].tolist())


# ------------------------------------------------------------------------------------------
# poles and residues


def _reduced_entries(tm: TransferMatrix) -> tuple[list[list[fmpq_poly | None]], list[list[fmpq_poly]]]:
    """Exact entries n_ij/d_ij with gcd(n_ij, d_ij) = 1 (None for zero entries)."""
    n = tm.n
    nums: list[list[fmpq_poly | None]] = [[None] * n for _ in range(n)]
    dens: list[list[fmpq_poly]] = [[fmpq_poly([1])] * n for _ in range(n)]
    for i in range(n):
        for j in range(n):
            e = tm[i, j]
            if e.is_zero:
                continue
            num, den = e.exact_reduced
            nums[i][j], dens[i][j] = num, den
    return nums, dens


def _permanent_abs(K: np.ndarray) -> float:
    n = K.shape[0]
    A = np.abs(K)
    return float(sum(np.prod([A[i, p[i]] for i in range(n)]) for p in itertools.permutations(range(n))))


def _rhp_poles(d: fmpq_poly) -> list[complex]:
    """The open right-half-plane roots of an exact polynomial: the count exact
    (:func:`hil.stability.exact.exact_poles`), the locations to double precision."""
    ep = exact_poles(d)
    if not ep.n_rhp:
        return []
    c = np.array([float(d[k]) for k in range(d.degree(), -1, -1)])
    r = sorted(np.roots(c), key=lambda z: -z.real)
    return [complex(z) for z in r[: ep.n_rhp]]


def pole_conditions(tm: TransferMatrix, residue_test: str = "hermitian", tol: Tolerances = TOL,
                    w0: float = 1.0, margins: bool = True) -> list[Condition]:
    """Conditions on poles of every entry: (C) none in the open RHP; (D) imaginary-axis poles are
    simple with an admissible residue matrix, decided exactly (:mod:`hil.stability.residues`).

    ``residue_test="hermitian"`` (positive realness): the residue matrix K must be Hermitian
    positive semidefinite. ``residue_test="minors"`` (Theorem 1 / Llewellyn): every principal
    minor of K is real and ≥ 0 and every product k_ij·k_ji is real and ≥ 0 (so that the
    symmetrized residue matrix K' = [±√(k_ij k_ji)] is real symmetric with the same principal
    minors, hence PSD). The k12 = k21* clause printed with Llewellyn's criterion in paper 000
    (eq. 57) is *not* imposed: the paper's own case study (eq. 25, residues -k_pm1, -k_pm2) violates
    it while being declared stable, and Theorem 1 (which 000 says reduces to Llewellyn) does not
    need it. ``w0``: the frequency normalization of ``tm`` (residues are reported physical).
    ``margins=False``: C's margin (the smallest damping ratio, from float roots) and its ``poles``
    evidence are not computed (verdict unchanged).
    """
    from hil.stability.residues import (
        ResidueDecision,
        axis_poles,
        decide_rational_residues,
        decide_residues,
        residue_matrix,
        residues_at_zero,
    )

    n = tm.n
    nums, dens = _reduced_entries(tm)
    rhp_all: list[tuple[int, int, complex]] = []
    D = _lcm([dens[i][j] for i in range(n) for j in range(n) if nums[i][j] is not None])
    # the roots of D are those of all the entries: one exact RHP count decides C; the entries are
    # searched only to name the offending ones. First the cheap exact test (Routh's array in
    # integers): D/s^k0 strictly Hurwitz -- no RHP pole, and no axis pole but those at s = 0
    dz = D.numer().coeffs()
    k0 = 0
    while dz[k0] == 0:
        k0 += 1
    hurwitz = strictly_hurwitz(dz[k0:])
    if not hurwitz and exact_poles(D).n_rhp:
        for i in range(n):
            for j in range(n):
                if nums[i][j] is not None:
                    rhp_all += [(i, j, p) for p in _rhp_poles(dens[i][j])]
    conds: list[Condition] = []
    if rhp_all:
        worst = max(rhp_all, key=lambda t: t[2].real / abs(t[2]))
        conds.append(Condition(
            "C", "no poles in the open right-half plane", "violated", -worst[2].real / abs(worst[2]),
            abs(worst[2].imag), f"entry ({worst[0] + 1},{worst[1] + 1}) has a pole at {worst[2] * w0:.6g} rad/s",
            {"rhp_poles": [{"entry": [i + 1, j + 1], "pole": p} for i, j, p in rhp_all]}))
    elif not margins:
        conds.append(Condition("C", "no poles in the open right-half plane", "satisfied", math.nan, None,
                               "all poles in the closed left-half plane", {}))
    else:
        allp = [p for row in tm.entries for e in row if not e.is_zero for p in e.poles()]
        m = min((-p.real / abs(p) for p in allp if abs(p) > 0 and -p.real > 1e-9 * abs(p)), default=1.0)
        conds.append(Condition("C", "no poles in the open right-half plane", "satisfied", float(m), None,
                               "all poles in the closed left-half plane", {"poles": allp}))
    for pole in axis_poles(fmpq_poly([0] * k0 + [1]) if hurwitz else D):
        w = pole.omega
        name = f"D[ω={w:.6g}]"
        wp = w * w0  # physical rad/s, for the detail lines
        label = "imaginary-axis pole simple with admissible residues"
        if pole.multiplicity > 1:
            conds.append(Condition(name, label, "violated", -1.0, w,
                                   f"pole at s = j{wp:.6g} has multiplicity {pole.multiplicity}",
                                   {"multiplicity": pole.multiplicity}))
            continue
        fast = None
        if pole.x0 == 0 and not margins and tol.rtol == 0:
            # verdict only at s = 0: a rational residue matrix, decided in Q without floats
            fast = decide_rational_residues(residues_at_zero(nums, dens), residue_test)
        if fast is not None:
            dec = ResidueDecision(fast[0], 0.0 if fast[0] == "equality" else math.nan, fast[1], {})
        else:
            dec = decide_residues(residue_matrix(nums, dens, D, pole, w0), residue_test, tol.rtol, margins)
        ev = dec.evidence
        ev["pole"] = complex(0, w)
        at = f" at s = j{wp:.6g}"
        mt = re.search(r"residue( matrix)?", dec.detail)
        detail = dec.detail[: mt.end()] + at + dec.detail[mt.end():] if mt else dec.detail + at
        conds.append(Condition(name, label, dec.status, dec.margin, w, detail, ev))  # type: ignore[arg-type]
    return conds


def infinity_condition(tm: TransferMatrix, residue_test: str = "hermitian", margins: bool = True) -> Condition:
    """Condition D[ω=∞]: at most a simple pole at s = ∞ with an admissible residue matrix.

    Positive realness (and therefore passivity, Llewellyn and Theorem 1, which all reduce to
    positive realness of an immittance or of its symmetrization) requires every entry to grow at
    most like s (degree excess deg num - deg den ≤ 1) and the residue R = lim_{s→∞} G(s)/s to be
    admissible. The residue of an entry is the ratio of its leading coefficients when the excess
    is 1 (else 0); the float coefficients are exact binary rationals, so R is formed and decided
    exactly (Fractions): ``hermitian`` -- R symmetric (Hermitian, R is real) with all principal
    minors ≥ 0, i.e. positive semidefinite; ``minors`` (Llewellyn, Theorem 1) -- every principal
    minor of R ≥ 0 and every r_ij·r_ji ≥ 0 (the symmetrized R' is PSD). An excess ≥ 2 (a double
    pole at infinity, e.g. Z = m s²) is a violation. Singular admissible R (some principal minor
    exactly 0 while R ≠ 0) is ``equality``, as for finite imaginary-axis poles.

    Evidence: ``degree_excess`` per entry (None for zero entries), ``residue_inf`` (R, floats),
    ``eigenvalues`` (of the symmetric part of R) and the decisive exact minor. Margin: the
    smallest eigenvalue of the symmetric part of R over max|r_ij| (``minors``: the smallest
    principal minor over the permanent of |R|), invariant under s → a·s and G → b·G;
    ``margins=False``: not computed (nan), the status unchanged.
    """
    n = tm.n
    name, label = "D[ω=∞]", "pole at s = ∞ at most simple with admissible residue R = lim G(s)/s"
    exc: list[list[int | None]] = [[None if tm[i, j].is_zero else int(tm[i, j].num.size - tm[i, j].den.size)
                                    for j in range(n)] for i in range(n)]
    ev: dict[str, Any] = {"degree_excess": exc, "pole": math.inf}
    top = max((d for row in exc for d in row if d is not None), default=-1)
    if top >= 2:
        i, j = next((i, j) for i in range(n) for j in range(n) if exc[i][j] == top)
        return Condition(name, label, "violated", -1.0, math.inf,
                         f"entry ({i + 1},{j + 1}) has a pole of order {top} at s = ∞ (degree excess {top})", ev)
    if top <= 0:
        return Condition(name, label, "satisfied", 1.0, None, "no pole at s = ∞ (all entries proper)", ev)
    R = [[fmpq(0) if exc[i][j] != 1 else
          fmpq(*float(tm[i, j].num[-1]).as_integer_ratio()) / fmpq(*float(tm[i, j].den[-1]).as_integer_ratio())
          for j in range(n)] for i in range(n)]
    Rf = np.array([[float(v) for v in row] for row in R])
    scale = float(np.max(np.abs(Rf))) or 1.0
    lam = np.linalg.eigvalsh((Rf + Rf.T) / 2)
    ev.update({"residue_inf": Rf, "eigenvalues": lam, "exact": True})
    lam_scale = float(np.max(np.abs(lam))) or scale  # spectral radius: eigenvalue margins in [-1, 1]
    if residue_test == "hermitian":
        asym = [(i, j) for i in range(n) for j in range(i + 1, n) if R[i][j] != R[j][i]]
        if asym:
            i, j = asym[0]
            err = max(abs(float(R[a][b] - R[b][a])) for a, b in asym) / scale
            return Condition(name, label, "violated", -err, math.inf,
                             f"residue matrix at s = ∞ is not symmetric (r{i + 1}{j + 1} ≠ r{j + 1}{i + 1})", ev)
    else:
        for i in range(n):
            for j in range(i + 1, n):
                if R[i][j] * R[j][i] < 0:
                    return Condition(name, label, "violated", -1.0, math.inf,
                                     f"r{i + 1}{j + 1}·r{j + 1}{i + 1} = {float(R[i][j] * R[j][i]):.4g} < 0 "
                                     "at s = ∞", ev)
    from hil.stability.residues import _scaled_int_minors, principal_minors

    # without margins only the signs and zeros of the minors are read: those of a positive
    # integer multiple of R (cheaper than rational arithmetic)
    minors: dict[tuple[int, ...], Any] = principal_minors(R) if margins else _scaled_int_minors(R)
    perm_of: dict[tuple[int, ...], float] = {}

    def perm(idx: tuple[int, ...]) -> float:
        if idx not in perm_of:
            perm_of[idx] = _permanent_abs(Rf[np.ix_(idx, idx)])
        return perm_of[idx]

    worst: tuple[float, tuple[int, ...]] | None = None
    zero_minor: tuple[int, ...] | None = None
    for idx, mnr in minors.items():
        if mnr < 0:
            if not margins:
                worst = (-1e-300, idx) if worst is None else worst
                continue
            pm = perm(idx)
            rel = float(mnr) / pm if pm else 0.0
            if worst is None or rel < worst[0]:
                worst = (min(rel, -1e-300), idx)
        elif mnr == 0 and zero_minor is None and perm(idx):
            zero_minor = idx
    if worst is not None:
        ev["negative_minor"] = [i + 1 for i in worst[1]]
        margin = float(np.min(lam)) / lam_scale if residue_test == "hermitian" else worst[0]
        if not margin < 0:
            margin = worst[0]
        what = "not positive semidefinite" if residue_test == "hermitian" else "not admissible"
        return Condition(name, label, "violated", margin, math.inf,
                         f"residue matrix at s = ∞ is {what}: principal minor {_lbl(worst[1])} < 0 "
                         f"(eigenvalues {', '.join(f'{v:.4g}' for v in lam)})", ev)
    if not margins:
        margin = math.nan
    elif residue_test == "hermitian":
        margin = max(float(np.min(lam)) / lam_scale, 0.0)
    else:
        margin = min((float(mnr) / perm(idx) for idx, mnr in minors.items() if perm(idx)), default=1.0)
    if zero_minor is not None or any(R[i][i] == 0 for i in range(n)):
        idx = zero_minor if zero_minor is not None else (next(i for i in range(n) if R[i][i] == 0),)
        return Condition(name, label, "equality", 0.0, math.inf,
                         f"simple pole at s = ∞, residue matrix singular (minor {_lbl(idx)} = 0, PSD)", ev)
    return Condition(name, label, "satisfied", float(min(margin, 1.0)) if margins else math.nan, math.inf,
                     "simple pole at s = ∞ with positive definite residue matrix", ev)


def _lbl(idx: Iterable[int]) -> str:
    return "{" + ",".join(str(i + 1) for i in idx) + "}"


# ------------------------------------------------------------------------------------------
# ratios evaluated on the transfer functions (plots; not the reported margins, docs/VERDICTS.md)


def _freq_range(entries: list[list[Rational]]) -> tuple[float, float]:
    """A plotting band: the non-zero pole and zero magnitudes of the entries, widened by two
    decades on each side (used by plots and benchmarks; margins are computed over all ω exactly,
    docs/VERDICTS.md)."""
    mags = [abs(r) for row in entries for e in row if not e.is_zero for r in (*e.poles(), *e.zeros())
            if abs(r) > 0 and np.isfinite(abs(r))]
    if not mags:
        return 1e-2, 1e2
    return min(mags) * 1e-2, max(mags) * 1e2


def _freq_values(sub: list[list[Rational]], w: np.ndarray) -> np.ndarray:
    k = len(sub)
    G = np.empty((w.size, k, k), complex)
    for i in range(k):
        for j in range(k):
            G[:, i, j] = 0.0 if sub[i][j].is_zero else sub[i][j].freq(w)
    return G


def _perm_batch(A: np.ndarray) -> np.ndarray:
    k = A.shape[-1]
    out = np.zeros(A.shape[0])
    for p in itertools.permutations(range(k)):
        term = np.ones(A.shape[0])
        for i in range(k):
            term = term * A[:, i, p[i]]
        out += term
    return out


def _hermitian_ratio(sub: list[list[Rational]], values: Callable[[np.ndarray], np.ndarray] | None = None
                     ) -> Callable[[np.ndarray], np.ndarray]:
    """ω ↦ det(H)/perm(|G|+|Gᵀ|) with H = G + Gᴴ on the index set: in [-1, 1], scale invariant,
    identical for every immittance form that describes the same passive quantity. ``values``
    (ω ↦ G(jω)) replaces the plain frequency response (e.g. by its regular part)."""

    def f(w: np.ndarray) -> np.ndarray:
        G = _freq_values(sub, w) if values is None else values(w)
        H = G + np.conj(np.swapaxes(G, 1, 2))
        S_ = np.abs(G) + np.abs(np.swapaxes(G, 1, 2))
        finite = np.all(np.isfinite(G), axis=(1, 2))  # only at an exact pole frequency
        H = np.where(finite[:, None, None], H, 0.0)
        S_ = np.where(finite[:, None, None], S_, 0.0)
        det = np.linalg.det(H).real if H.shape[1] > 1 else H[:, 0, 0].real
        sc = _perm_batch(S_)
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.where(sc > 0, det / np.where(sc > 0, sc, 1.0), 0.0)
        return r if values is None else np.where(finite, r, np.inf)

    return f


def _eta_ratio(sub: list[list[Rational]], scale_values: Callable[[np.ndarray], np.ndarray] | None = None
               ) -> Callable[[np.ndarray], np.ndarray]:
    """ω ↦ η/(2|p11||p22| + 2|p12 p21|), Llewellyn's η normalized to [-1, 1]. ``scale_values``
    (ω ↦ G_reg(jω), the regular part) supplies the scale when imaginary-axis poles were cancelled;
    η itself is always evaluated on G."""

    def f(w: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            G = _freq_values(sub, w)
            c = G[:, 0, 1] * G[:, 1, 0]
            eta = 2 * G[:, 0, 0].real * G[:, 1, 1].real - c.real - np.abs(c)
            Gs = G if scale_values is None else scale_values(w)
            cs = Gs[:, 0, 1] * Gs[:, 1, 0]
            sc = 2 * np.abs(Gs[:, 0, 0]) * np.abs(Gs[:, 1, 1]) + 2 * np.abs(cs)
            r = np.where(sc > 0, eta / np.where(sc > 0, sc, 1.0), 0.0)
        if scale_values is None:
            return r
        r = np.clip(r, -1.0, 1.0)
        return np.where(np.isfinite(r) & np.isfinite(sc), r, np.inf)

    return f


# ------------------------------------------------------------------------------------------
# polynomial conditions


def _qpoly_float(p: fmpq_poly) -> np.ndarray:
    """Ascending float coefficients of an exact polynomial, each correctly rounded."""
    from hil.stability.rational import _qpoly_floats

    return np.array(_qpoly_floats(p) or [0.0])


# -- exact formation of the frequency conditions -----------------------------------------------
#
# Every frequency condition (principal minors of G(jω) + G(jω)ᴴ, Llewellyn's L1 and L2) is a real
# polynomial in x = ω² once the entries are put over a common denominator D. It is formed EXACTLY
# over Q: the float coefficients are exact binary rationals, D is the lcm of the denominators over
# Q[s] and u_ij = n_ij·(D/d_ij) is an exact quotient (python-flint fmpq_poly). The sign decision
# (exact.decide_exact) is therefore free of rounding: a violation the given coefficients have is
# found however shallow it is, and equality / touching is recognised exactly.
#
# Imaginary-axis poles. A pole of G at s = ±jω_p (ω_p > 0) makes D(jω) vanish at x_p = ω_p², so
# every condition polynomial p(x) = (condition)·|D(jω)|^(2k) carries the factor (x - x_p)^(2k): a
# double root that would be read as "touching" although the condition itself (e.g. Re Z = 1 for
# Z = 1 + s/(s² + 1)) is strictly positive. The axis factor h(x) is found exactly: D(jω) = E(x) +
# jω O(x), and jω_p is a root iff x_p is a common root of E and O, so h is the squarefree part of
# gcd(E, O) over Q, without the factor x (s = 0 sits at the boundary x = 0). p is divided by h² as
# often as it is exactly divisible, at most as often as h² divides |D|^(2k). Dividing by a square
# keeps the sign of p at every frequency that is not a pole; at the pole frequency the frequency
# condition is undefined and the pole is judged by its residue condition D[ω=ω_p].
#
# Magnitude polynomial m. Alongside the exact p, the same construction is carried out on absolute
# values in floats (hil.stability.jpoly): m(x) ≥ Σ |terms of p(x)| for x ≥ 0, with terms the
# monomials in the coefficients of u and D. It bounds the effect of relative perturbations of those
# coefficients (|Δp(x)| ≤ ((1+r)^K - 1)·m(x) for relative perturbations ≤ r, K the number of
# coefficient factors per term) and normalizes the frequency-domain margin (docs/VERDICTS.md).


_X = fmpq_poly([0, 1])


def _jmul(u: tuple[fmpq_poly, fmpq_poly], v: tuple[fmpq_poly, fmpq_poly]) -> tuple[fmpq_poly, fmpq_poly]:
    return u[0] * v[0] - _X * u[1] * v[1], u[0] * v[1] + u[1] * v[0]


def _jfloat(u: tuple[fmpq_poly, fmpq_poly]) -> JPoly:
    """The float image of an exact (even, odd) pair, magnitudes = |coefficients|."""
    re, im = _qpoly_float(u[0]), _qpoly_float(u[1])
    return JPoly(re, im, np.abs(re), np.abs(im))


@dataclass
class _Setup:
    """Exact values at s = jω of the entries over their common denominator D (see above)."""

    u: list[list[tuple[fmpq_poly, fmpq_poly]]]
    Dc: tuple[fmpq_poly, fmpq_poly]  # conj(D(jω))
    h: fmpq_poly | None  # imaginary-axis factor of D in x (None: no axis pole with ω > 0)
    mu: int  # multiplicity of h in gcd(E, O)
    uf: list[list[JPoly]]  # float images (for the magnitude polynomials)
    Dcf: JPoly


#: the placeholder float image of a setup built without magnitude polynomials (never read)
_NO_M = JPoly.zero()

QEntries = tuple[list[list["fmpq_poly | None"]], list[list[fmpq_poly]]]


def _q_entries(sub: list[list[Rational]]) -> QEntries:
    """The exact (numerator or None for a zero entry, denominator) of float entries."""

    n = len(sub)
    nums: list[list[fmpq_poly | None]] = [[None if sub[i][j].is_zero else sub[i][j].exact[0]
                                           for j in range(n)] for i in range(n)]
    dens = [[sub[i][j].exact[1] for j in range(n)] for i in range(n)]
    return nums, dens


def _setup(sub: list[list[Rational]], need_m: bool = True, q: QEntries | None = None) -> _Setup:
    """``q``: the entries given exactly (then ``sub`` is only used for its size)."""
    nums, dens = q if q is not None else _q_entries(sub)
    n = len(nums)
    D, h, mu = _axis_factor([dens[i][j] for i in range(n) for j in range(n) if nums[i][j] is not None])
    E, O = _xq(D)
    Dc = (E, -O)
    zero = (fmpq_poly([]), fmpq_poly([]))
    u = [[zero if (nij := nums[i][j]) is None else _xq(nij * (D // dens[i][j])) for j in range(n)] for i in range(n)]
    if not need_m:
        return _Setup(u, Dc, h, mu, [], _NO_M)
    uf = [[_jfloat(e) for e in row] for row in u]
    return _Setup(u, Dc, h, mu, uf, _jfloat(Dc))


def _lcm(dens: list[fmpq_poly]) -> fmpq_poly:
    """The common denominator D of the entries: the running product D·d / gcd(D, d) from D = 1
    (FLINT's gcd is monic, so D is an lcm up to a constant factor). A denominator equal to the
    running D (the common case: entries over one denominator) gives D·lc(D), the same polynomial
    as D·d / gcd(D, d) = D²/(D/lc(D)), without the gcd."""
    D = fmpq_poly([1])
    first = True
    for d in dens:
        if first:
            D, first = d * 1, False  # 1·d / gcd(1, d) = d (a copy: callers never mutate, but safe)
        elif d == D:
            D = D * D[D.degree()]
        else:
            D = D * d // D.gcd(d)
    return D


def _axis_factor(dens: list[fmpq_poly]) -> tuple[fmpq_poly, fmpq_poly | None, int]:
    """(common denominator D = lcm, axis factor h or None, multiplicity μ of h in gcd(E, O))."""
    D = _lcm(dens)
    if D.degree() < 2:
        return D, None, 0
    dz = D.numer().coeffs()
    k0 = 0
    while dz[k0] == 0:
        k0 += 1
    if strictly_hurwitz(dz[k0:]):  # D = s^k0·(strictly Hurwitz): no axis pole at ω > 0 (exact, cheap)
        return D, None, 0
    E, O = _xq(D)
    g = E.gcd(O)
    while g.degree() > 0 and g[0] == 0:  # drop the factor x (poles at s = 0)
        g = g // _X
    if g.degree() < 1:
        return D, None, 0
    h = g // g.gcd(g.derivative())
    if h.degree() < 1:
        return D, None, 0
    mu, t = 0, g
    while t.degree() >= h.degree() and (t % h).is_zero():
        t, mu = t // h, mu + 1
    return D, h, max(mu, 1)


def _cancel(p: fmpq_poly, h: fmpq_poly | None, cap: int) -> tuple[fmpq_poly, int]:
    if h is None:
        return p, 0
    h2 = h * h
    cut = 0
    while not p.is_zero() and cut < cap and (p % h2).is_zero():
        p, cut = p // h2, cut + 1
    return p, cut


def _exact_minor_polys(sub: list[list[Rational]], need_m: bool = True, q: QEntries | None = None,
                       entrywise_real: bool = False
                       ) -> dict[tuple[int, ...], tuple[fmpq_poly, int, np.ndarray | None]]:
    """Every principal minor of (G + Gᴴ)(jω)·|D(jω)|^(2k), formed exactly over Q, divided by the
    squared axis factor where present. Values: (exact polynomial in x, number of h² factors
    cancelled, float magnitude polynomial m of the uncancelled minor, None unless ``need_m``).
    ``q``: the entries given exactly instead of ``sub``. ``entrywise_real``: minors of the
    entrywise real part 2·Re G(jω) instead (equal to G + Gᴴ for a symmetric G; Theorem 1's Z' is
    handled up to a diagonal similarity, which keeps the minors of Re Z' but not its symmetry)."""
    st = _setup(sub, need_m, q)
    n = len(st.u)
    zero = (fmpq_poly([]), fmpq_poly([]))
    A = [[_jmul(st.u[i][j], st.Dc) for j in range(n)] for i in range(n)]
    if entrywise_real:
        Pm = [[(2 * A[i][j][0], fmpq_poly([])) for j in range(n)] for i in range(n)]
    else:
        Pm = [[(A[i][j][0] + A[j][i][0], A[i][j][1] - A[j][i][1]) for j in range(n)] for i in range(n)]
    if need_m:
        Af = [[st.uf[i][j] * st.Dcf for j in range(n)] for i in range(n)]
        if entrywise_real:
            Pf = [[JPoly(2.0 * Af[i][j].re, np.zeros(1), 2.0 * Af[i][j].mre, np.zeros(1)) for j in range(n)]
                  for i in range(n)]
        else:
            Pf = [[Af[i][j] + Af[j][i].conj() for j in range(n)] for i in range(n)]
    memo: dict[tuple[tuple[int, ...], tuple[int, ...]], tuple[fmpq_poly, fmpq_poly]] = {}
    memof: dict[tuple[tuple[int, ...], tuple[int, ...]], JPoly] = {}

    def det(rows: tuple[int, ...], cols: tuple[int, ...]) -> tuple[fmpq_poly, fmpq_poly]:
        if len(rows) == 1:
            return Pm[rows[0]][cols[0]]
        if (rows, cols) in memo:
            return memo[(rows, cols)]
        acc = zero
        for k, c in enumerate(cols):
            t = _jmul(Pm[rows[0]][c], det(rows[1:], cols[:k] + cols[k + 1:]))
            acc = (acc[0] + t[0], acc[1] + t[1]) if k % 2 == 0 else (acc[0] - t[0], acc[1] - t[1])
        memo[(rows, cols)] = acc
        return acc

    def detf(rows: tuple[int, ...], cols: tuple[int, ...]) -> JPoly:
        if len(rows) == 1:
            return Pf[rows[0]][cols[0]]
        if (rows, cols) in memof:
            return memof[(rows, cols)]
        acc = JPoly.zero()
        for k, c in enumerate(cols):
            t = Pf[rows[0]][c] * detf(rows[1:], cols[:k] + cols[k + 1:])
            acc = acc + t if k % 2 == 0 else acc - t
        memof[(rows, cols)] = acc
        return acc

    memor: dict[tuple[tuple[int, ...], tuple[int, ...]], fmpq_poly] = {}

    def detr(rows: tuple[int, ...], cols: tuple[int, ...]) -> fmpq_poly:
        """det for entrywise_real: every entry is real (imaginary part the zero polynomial), so
        the complex products of ``det`` reduce to real ones (the same polynomials, exactly)."""
        if len(rows) == 1:
            return Pm[rows[0]][cols[0]][0]
        key = (rows, cols)
        if key in memor:
            return memor[key]
        acc = fmpq_poly([])
        for k, c in enumerate(cols):
            a = Pm[rows[0]][c][0]
            if a.is_zero():
                continue
            t = a * detr(rows[1:], cols[:k] + cols[k + 1:])
            acc = acc + t if k % 2 == 0 else acc - t
        memor[key] = acc
        return acc

    out = {}
    for k in range(1, n + 1):
        for idx in itertools.combinations(range(n), k):
            p, cut = _cancel(detr(idx, idx) if entrywise_real else det(idx, idx)[0], st.h, k * st.mu)
            out[idx] = (p, cut, detf(idx, idx).real().m if need_m else None)
    return out


_PolyCond = tuple[fmpq_poly, int, "np.ndarray | None"]


def _exact_llewellyn_polys(sub: list[list[Rational]], need_m: bool = True, _st: list[_Setup] | None = None
                           ) -> tuple[_PolyCond, _PolyCond]:
    """(L1, L2) of :func:`llewellyn_polys` formed exactly over Q with the squared imaginary-axis
    factor divided out where present (L1 carries |D|⁴, L2 |D|⁸): (polynomial, h² factors cancelled,
    magnitude polynomial or None unless ``need_m``) each. ``_st``: a list that receives the setup
    (the caller reads its axis factor)."""
    st = _setup(sub, need_m)
    if _st is not None:
        _st.append(st)
    u, Dc = st.u, st.Dc
    A1 = _jmul(u[0][0], Dc)[0]
    A2 = _jmul(u[1][1], Dc)[0]
    C = _jmul(_jmul(_jmul(u[0][1], u[1][0]), Dc), Dc)
    a = A1 * A2
    L1 = 2 * a - C[0]
    L2 = 4 * a * (a - C[0]) - _X * C[1] * C[1]
    if not need_m:
        p1, c1 = _cancel(L1, st.h, 2 * st.mu)
        p2, c2 = _cancel(L2, st.h, 4 * st.mu)
        return (p1, c1, None), (p2, c2, None)
    uf, Dcf = st.uf, st.Dcf
    a1f = (uf[0][0] * Dcf).real()
    a2f = (uf[1][1] * Dcf).real()
    cf = uf[0][1] * uf[1][0] * Dcf * Dcf
    af = a1f * a2f
    cr, ci = cf.real(), cf.imag_over_omega()
    m1 = (af * 2.0 - cr).m
    m2 = (af * (af - cr) * 4.0 - (ci * ci).mulx()).m
    p1, c1 = _cancel(L1, st.h, 2 * st.mu)
    p2, c2 = _cancel(L2, st.h, 4 * st.mu)
    return (p1, c1, m1), (p2, c2, m2)


def _exact_decision(p: fmpq_poly, cut: int, m: np.ndarray | None, K: int, tol: Tolerances,
                    margins: bool) -> tuple[SignDecision, bool]:
    """Exact decision of one condition polynomial and, with ``tol.rtol > 0``, whether the decision
    can flip under relative perturbations ≤ rtol of the coefficients of u and D (K coefficient
    factors per term of p). When axis factors were cancelled the magnitude bound is the cancelled
    polynomial's own |coefficients| (the uncancelled m does not divide)."""
    mm = m if cut == 0 and m is not None else None
    need_margin = margins or tol.rtol > 0
    d = decide_exact(p, mm, margin=need_margin)
    flip = False
    if tol.rtol > 0 and d.status != "equality":
        eps = (1.0 + tol.rtol) ** K - 1.0
        mb = np.abs(d.coefficients) if mm is None else np.maximum(
            np.pad(np.abs(mm), (0, max(0, d.coefficients.size - np.asarray(mm).size))),
            np.pad(np.abs(d.coefficients), (0, max(0, np.asarray(mm).size - d.coefficients.size))))
        flip = flips_within(p, mb, eps, d.status)
    return d, flip


_RANK = {"violated": 3, "touching": 1, "equality": 1, "satisfied": 0}


def _cond_exact(name: str, label: str, d: SignDecision, flip: bool, extra: dict[str, Any],
                tol: Tolerances) -> Condition:
    """Condition record from an exact decision (statuses: docs/VERDICTS.md)."""
    bands_w = [(math.sqrt(a), math.sqrt(b) if math.isfinite(b) else math.inf) for a, b in d.negative_bands]
    touching_w = [math.sqrt(x) for x in d.touching]
    status: ConditionStatus
    ev: dict[str, Any] = {
          "polynomial_x_desc": _desc(d.coefficients), "method": d.method, "distinct_positive_roots": d.n_roots,
          "negative_bands_rad_s": bands_w, "band_depths": d.band_depths,
          "touching_rad_s": touching_w, "formed": "exact",
          "margin_kind": "frequency-domain margin: min over x >= 0 of p(x)/m_r(x) (docs/VERDICTS.md)"}
    if d.magnitude is not None:  # m_r, so a plot draws exactly the function whose minimum is the margin
        ev["magnitude_x_desc"] = _desc(d.magnitude)
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
    if constant and status == "satisfied":
        detail += _CONSTANT_NOTE
    if flip:
        ev["flips_within_rtol"] = tol.rtol
        detail = (f"{detail}; the verdict of this condition can flip under a relative perturbation of "
                  f"{tol.rtol:.3g} of the coefficients")
        status = "marginal"
    return Condition(name, label, status, float(margin), wf, detail, ev)


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
    exact = _exact_minor_polys(sub, need_m=margins or tol.rtol > 0, q=sub_q, entrywise_real=q is not None)
    conds = []
    for k in range(1, n + 1):
        for idx in itertools.combinations(range(n), k):
            glob = tuple(idx_all[i] for i in idx)
            name, lab = f"{prefix}{_lbl(glob)}", f"{label}, principal minor {_lbl(glob)}"
            pq, cut, m = exact[idx]
            d, flip = _exact_decision(pq, cut, m, 2 * k, tol, margins)
            conds.append(_cond_exact(name, lab, d, flip, {"axis_pole_factors_cancelled": cut}, tol))
    return conds


# ------------------------------------------------------------------------------------------
# criteria


def positive_real(g: TransferMatrix | Rational, tol: Tolerances = TOL, margins: bool = True) -> StabilityResult:
    """Positive realness of a one-port Z(s) or an n×n transfer matrix G(s) (passivity).

    ``margins=False`` returns the same verdict without computing margins (faster)."""
    tm0 = _as_tm(g)
    tm, w0 = _normalized(tm0)
    conds = pole_conditions(tm, "hermitian", tol, w0, margins)
    conds += _hermitian_minors(tm.entries, list(range(tm.n)), tol, "E",
                               "G(jω)+G(jω)ᴴ ⪰ 0" if tm.n > 1 else "Re Z(jω) ≥ 0", margins)
    crit = "positive_real" if tm.n > 1 else "positive_real (one-port)"
    return combine(crit, [*_rescale(conds, w0), infinity_condition(tm0, "hermitian", margins)], _netinfo(tm0, w0))


def two_port_passivity(tm: TransferMatrix, tol: Tolerances = TOL, margins: bool = True) -> StabilityResult:
    """Two-port passivity (Theorem 2 of paper 002) in whatever immittance form ``tm`` is given.

    For the hybrid form this is exactly (a) no RHP poles, (b) simple imaginary poles with
    admissible residues, (c-i) Re h11 ≥ 0, Re h22 ≥ 0, (c-ii) Re h11 Re h22 - |h12* + h21|²/4 ≥ 0,
    i.e. positive realness of the immittance matrix; m-DOF ports are handled blockwise.
    """
    if tm.n_ports != 2:
        raise ModelError(f"two-port passivity needs a two-port, got {tm.n_ports} ports")
    r = positive_real(tm, tol, margins)
    r.criterion = "two_port_passivity"
    return r


def hermitian_minor_poly(entries: list[list[Rational]], idx: tuple[int, ...]) -> XPoly:
    """The principal minor ``idx`` of G(jω)+G(jω)ᴴ times |D(jω)|^(2k), D the exact lcm of the
    denominators, as a polynomial in x = ω²: formed exactly over Q and rounded once (``c``), with
    its magnitude polynomial ``m`` (no imaginary-axis cancellation)."""
    sub = [[entries[i][j] for j in idx] for i in idx]
    st = _setup(sub)
    n = len(sub)
    A = [[_jmul(st.u[i][j], st.Dc) for j in range(n)] for i in range(n)]
    Pm = [[(A[i][j][0] + A[j][i][0], A[i][j][1] - A[j][i][1]) for j in range(n)] for i in range(n)]
    Af = [[st.uf[i][j] * st.Dcf for j in range(n)] for i in range(n)]
    Pf = [[Af[i][j] + Af[j][i].conj() for j in range(n)] for i in range(n)]
    if n == 1:
        return XPoly(_qpoly_float(Pm[0][0][0]), Pf[0][0].real().m, Pm[0][0][0])
    if n == 2:
        p = _jmul(Pm[0][0], Pm[1][1])[0] - _jmul(Pm[0][1], Pm[1][0])[0]
        return XPoly(_qpoly_float(p), (Pf[0][0] * Pf[1][1] - Pf[0][1] * Pf[1][0]).real().m, p)
    raise ModelError("hermitian_minor_poly supports 1x1 and 2x2 minors; use _hermitian_minors for larger ones")


def llewellyn_polys(entries: list[list[Rational]], i: int = 0, j: int = 1) -> tuple[XPoly, XPoly]:
    """(L1, L2) with η_ij ≥ 0 ⟺ L1 ≥ 0 and L2 ≥ 0, formed exactly over Q (no axis cancellation)
    and rounded once, with their magnitude polynomials.

    η_ij = 2 Re p_ii Re p_jj - Re(p_ij p_ji) - |p_ij p_ji|. With the common denominator D (p = u/D):
    a = Re(u_ii D*) Re(u_jj D*), c = u_ij u_ji D*², all over |D|⁴ > 0. Then η ≥ 0 ⟺
    L1 = 2a - Re c ≥ 0 and L2 = (2a - Re c)² - |c|² = 4a(a - Re c) - x·(Im c/ω)² ≥ 0
    (L2 alone decides where a > 0; L1 matters only where a = 0).
    """
    sub = [[entries[a][b] for b in (i, j)] for a in (i, j)]
    st = _setup(sub)
    u, Dc = st.u, st.Dc
    a = _jmul(u[0][0], Dc)[0] * _jmul(u[1][1], Dc)[0]
    C = _jmul(_jmul(_jmul(u[0][1], u[1][0]), Dc), Dc)
    L1 = 2 * a - C[0]
    L2 = 4 * a * (a - C[0]) - _X * C[1] * C[1]
    uf, Dcf = st.uf, st.Dcf
    af = (uf[0][0] * Dcf).real() * (uf[1][1] * Dcf).real()
    cf = uf[0][1] * uf[1][0] * Dcf * Dcf
    cr, ci = cf.real(), cf.imag_over_omega()
    return (XPoly(_qpoly_float(L1), (af * 2.0 - cr).m, L1),
            XPoly(_qpoly_float(L2), (af * (af - cr) * 4.0 - (ci * ci).mulx()).m, L2))


def _llewellyn_eta(entries: list[list[Rational]], i: int, j: int, tol: Tolerances,
                   margins: bool = True, diag_positive: bool = False) -> Condition:
    """Llewellyn's η_ij ≥ 0 for all ω as an exact condition (see :func:`llewellyn_polys`).

    ``diag_positive``: the caller has decided Re p_ii > 0 and Re p_jj > 0 for every ω > 0 (both
    conditions ``satisfied``, exactly). Then, without imaginary-axis poles at ω > 0, a > 0 on x > 0,
    and L2 ≥ 0 forces 4a(a - Re c) ≥ (Im c)² ≥ 0, so a ≥ Re c and L1 = a + (a - Re c) ≥ a > 0 on
    x > 0: L1 is ``satisfied`` whenever L2 holds, and is not decided separately on the verdict-only
    path (``margins=False``, no tolerance: its margin and flip test are not needed)."""
    st: list[_Setup] = []
    (p1, c1, m1), (p2, c2, m2) = _exact_llewellyn_polys([[entries[a][b] for b in (i, j)] for a in (i, j)],
                                                        need_m=margins or tol.rtol > 0, _st=st)
    d2, f2 = _exact_decision(p2, c2, m2, 8, tol, margins)
    if (diag_positive and not margins and tol.rtol == 0 and st[0].h is None and not p1.is_zero()
            and d2.status in ("satisfied", "touching", "equality")):
        d1, f1 = SignDecision("satisfied", math.nan, math.nan, method="implied (L2 ≥ 0, Re p_ii > 0, Re p_jj > 0)",
                              coefficients=_qpoly_float(p1)), False
    else:
        d1, f1 = _exact_decision(p1, c1, m1, 4, tol, margins)
    name = f"E{_lbl((i, j))}"
    a_, b_ = i + 1, j + 1
    label = f"Llewellyn η{a_}{b_} = 2Re p{a_}{a_} Re p{b_}{b_} - Re(p{a_}{b_}p{b_}{a_}) - |p{a_}{b_}p{b_}{a_}| ≥ 0"
    worst = d2 if _RANK[d2.status] >= _RANK[d1.status] else d1
    if worst.status == d1.status == d2.status and margins and d1.margin < d2.margin:
        worst = d1
    return _cond_exact(name, label, worst, f1 or f2,
                       {"L1_x_desc": _desc(d1.coefficients), "L1_status": d1.status,
                        "L2_x_desc": _desc(d2.coefficients), "L2_status": d2.status,
                        "axis_pole_factors_cancelled": max(c1, c2)}, tol)



def llewellyn(tm: TransferMatrix, tol: Tolerances = TOL, margins: bool = True) -> StabilityResult:
    """Llewellyn's absolute stability criterion for a 1-DOF two-port (any immittance form).

    (a) no RHP poles, (b) imaginary poles simple with k11, k22 ≥ 0 and k11k22 - k12k21 ≥ 0,
    (c) Re p11 ≥ 0, Re p22 ≥ 0 and η = 2 Re p11 Re p22 - Re(p12 p21) - |p12 p21| ≥ 0 for all ω.
    """
    if tm.n != 2:
        raise ModelError("Llewellyn's criterion applies to 1-DOF two-ports (2×2 immittance matrices)")
    tm0 = tm
    tm, w0 = _normalized(tm0)
    conds = pole_conditions(tm, "minors", tol, w0, margins)
    diag: list[Condition] = []
    for k in range(2):
        diag += _hermitian_minors(tm.entries, [k], tol, "E", "Re p(jω) ≥ 0", margins)
    conds += diag
    conds.append(_llewellyn_eta(tm.entries, 0, 1, tol, margins, all(c.status == "satisfied" for c in diag)))
    return combine("llewellyn", [*_rescale(conds, w0), infinity_condition(tm0, "minors", margins)], _netinfo(tm0, w0))


# -- Theorem 1 of paper 000 ------------------------------------------------------------------


def _poly_sqrt(c: np.ndarray, rtol: float = 1e-9) -> tuple[np.ndarray, float] | None:
    """If c(s) = κ·r(s)² with r monic-led real polynomial, return (r, κ); else None."""
    c = trim_back(np.asarray(c, float))
    n = c.size - 1
    if n % 2:
        return None
    k = 0
    while c[k] == 0:
        k += 1
    if k % 2:
        return None
    kappa = c[-1]
    cn = c / kappa  # monic
    m = n // 2
    r = np.zeros(m + 1)
    r[m] = 1.0
    # match coefficients from the top: (r²)_{m+i} determines r_{i}
    for i in range(m - 1, -1, -1):
        deg = m + i
        # coefficient of s^deg in r² = 2 r_i r_m + (sum of pairs not involving r_i)
        acc = 0.0
        for a in range(m + 1):
            b = deg - a
            if 0 <= b <= m and a != i and b != i:
                acc += r[a] * r[b]
        r[i] = (cn[deg] - acc) / 2.0
    sq = P.polymul(r, r)
    mag: np.ndarray = P.polymul(np.abs(r), np.abs(r))
    if np.all(np.abs(sq - np.pad(cn, (0, sq.size - cn.size))) <= rtol * np.maximum(mag, 1e-300) + 1e-300):
        return r, float(kappa)
    return None


def _rational_sqrt(a: Rational, b: Rational) -> Rational | None:
    """√(a·b) as a real rational function when a·b is the square of one (up to a positive constant)."""
    num = P.polymul(a.num, b.num)
    den = P.polymul(a.den, b.den)
    rn, rd = _poly_sqrt(num), _poly_sqrt(den)
    if rn is None or rd is None:
        return None
    kap = rn[1] / rd[1]
    if kap <= 0:
        return None
    return Rational(math.sqrt(kap) * rn[0], rd[0])


def _components(nz: np.ndarray) -> list[list[int]]:
    n = nz.shape[0]
    seen = [False] * n
    comps = []
    for s in range(n):
        if seen[s]:
            continue
        stack, comp = [s], []
        seen[s] = True
        while stack:
            v = stack.pop()
            comp.append(v)
            for u in range(n):
                if nz[v, u] and not seen[u]:
                    seen[u] = True
                    stack.append(u)
        comps.append(sorted(comp))
    return comps


def _symmetrize(tm: TransferMatrix, comp: list[int], W: dict[tuple[int, int], Rational]) -> list[list[Rational]] | None:
    """Rational Z' on a component with signs chosen so that cycle products match Z's."""
    rng = np.random.default_rng(12345)
    s0 = complex(0.37 + rng.random(), 1.1 + rng.random())
    parent: dict[int, int | None] = {comp[0]: None}
    sign: dict[tuple[int, int], float] = {}
    # BFS spanning tree with + signs
    q = [comp[0]]
    while q:
        v = q.pop(0)
        for u in comp:
            if u not in parent and (min(u, v), max(u, v)) in W:
                parent[u] = v
                sign[(min(u, v), max(u, v))] = 1.0
                q.append(u)
    # non-tree edges: sign from the triangle/cycle product through the tree root paths
    def path(v: int) -> list[int]:
        out = [v]
        while (p := parent[out[-1]]) is not None:
            out.append(p)
        return out

    for (i, j), _w in W.items():
        if (i, j) in sign or i not in parent:
            continue
        pi, pj = path(i), path(j)
        # cycle: i -> ... -> root -> ... -> j -> i (through the spanning tree)
        nodes = pi + pj[::-1][1:]
        zprod = complex(1.0)
        wprod = complex(1.0)
        seq = [*nodes, i]
        for a, b in itertools.pairwise(seq):
            zprod *= complex(tm[a, b](s0))
            key = (min(a, b), max(a, b))
            ws = sign.get(key, 1.0) if key != (i, j) else 1.0
            wprod *= ws * complex(W[key](s0))
        ratio = zprod / wprod if wprod != 0 else 0
        if abs(abs(ratio) - 1) > 1e-6 or abs(ratio.imag) > 1e-6:
            return None
        sign[(i, j)] = 1.0 if ratio.real > 0 else -1.0
    k = len(comp)
    out = [[Rational.const(0.0)] * k for _ in range(k)]
    for a, i in enumerate(comp):
        for b, j in enumerate(comp):
            if i == j:
                out[a][b] = tm[i, i]
            else:
                key = (min(i, j), max(i, j))
                if key in W:
                    out[a][b] = W[key] * sign[key]
    return out


def _rf_equal(a: _RF, b: _RF) -> bool:
    """Exact equality of rational functions (both reduced with monic denominators)."""
    return bool(a.n == b.n and a.d == b.d)


def _poly_square_root(p: fmpq_poly) -> tuple[fmpq, fmpq_poly] | None:
    """(κ, r) with p = κ·r² exactly (squarefree decomposition over Q), or None."""
    c, facs = p.factor_squarefree()
    r = fmpq_poly([1])
    for f, e in facs:
        if e % 2:
            return None
        r *= f ** (int(e) // 2)
    return fmpq(c), r


def _exact_sqrt(P_: _RF) -> tuple[fmpq, _RF] | None:
    """(κ, ρ) with P = κ·ρ² exactly, κ > 0 rational and ρ a rational function over Q, or None
    (then √P, the entry z'_ij = √(z_ij z_ji) of Theorem 1, is not a real rational function up
    to a constant and the block is swept)."""
    a, b = _poly_square_root(P_.n), _poly_square_root(P_.d)
    if a is None or b is None:
        return None
    kap = a[0] / b[0]
    if kap <= 0:
        return None
    # normalize ρ by λ ≈ √κ (exact when κ is a rational square): κ/λ² ≈ 1, so the diagonal
    # similarity of _exact_symmetrize stays near the identity and the margins near those of Z'
    num, den = int(kap.p), int(kap.q)
    lam = fmpq(math.isqrt(num * den * 4**64), den * 2**64)
    return kap / (lam * lam), _RF(a[1], b[1]) * _RF(fmpq_poly([lam]), fmpq_poly([1]), reduced=True)


def _sqrt_of_pair(zij: _RF, zji: _RF) -> tuple[fmpq, _RF] | None:
    """(κ, ρ) with z_ij z_ji = κ ρ² (:func:`_exact_sqrt`); a symmetric pair z_ij = z_ji needs no
    factorization: κ = 1, ρ = z_ij."""
    if _rf_equal(zij, zji):
        return fmpq(1), zij
    return _exact_sqrt(zij * zji)


def _fmpq_sqrt(q: fmpq) -> fmpq | None:
    """The exact rational square root of q ≥ 0, or None when q is not a rational square."""
    num, den = int(q.p), int(q.q)
    if num < 0:
        return None
    rn, rd = math.isqrt(num), math.isqrt(den)
    return fmpq(rn, rd) if rn * rn == num and rd * rd == den else None


def _exact_symmetrize(RF: list[list[_RF]], comp: list[int],
                      roots: dict[tuple[int, int], tuple[fmpq, _RF]]) -> tuple[QEntries | None, str]:
    """Theorem 1's symmetrized block Z' (z'_ij = γ_ij √(z_ij z_ji) = γ_ij √κ_ij ρ_ij), exactly.

    √κ_ij need not be rational, so Z' is formed up to a diagonal similarity S = T⁻¹ Z' T,
    T = diag(√q_i) with q_root = 1 and q_j = q_i κ_ij along a spanning tree: S_ij = γ_ij
    √(κ_ij q_j/q_i) ρ_ij is rational on tree edges and is required to be on the other edges. A real
    diagonal similarity keeps Re S = T⁻¹ Re Z' T and so every principal minor of Re Z'(jω). Signs
    γ: +1 on tree edges; on the others the cycle product of S (= that of Z') must equal Z's exactly
    up to sign. Then every principal minor of S must equal Z's (exactly, over Q(s)).

    Returns (S as exact entries, "") or (None, reason): ``"irrational"`` when S is not rational
    (the caller sweeps), else why no Z' reproduces Z's principal minors (not applicable)."""
    from hil.stability.rational import _rf_det

    k = len(comp)
    loc = {g: a for a, g in enumerate(comp)}
    adj = {g: [h for h in comp if h != g and (min(g, h), max(g, h)) in roots] for g in comp}
    q: dict[int, fmpq] = {comp[0]: fmpq(1)}
    parent: dict[int, int | None] = {comp[0]: None}
    order = [comp[0]]
    for v in order:
        for u in adj[v]:
            if u not in q:
                q[u] = q[v] * roots[(min(u, v), max(u, v))][0]
                parent[u] = v
                order.append(u)
    S: list[list[_RF]] = [[RF[comp[a]][comp[a]] if a == b else _RF(fmpq_poly([]), fmpq_poly([1]), reduced=True)
                           for b in range(k)] for a in range(k)]

    def set_edge(i: int, j: int, sign: int) -> bool:
        kap, rho = roots[(min(i, j), max(i, j))]
        t = _fmpq_sqrt(kap * q[j] / q[i])
        if t is None:
            return False
        S[loc[i]][loc[j]] = rho * _RF(fmpq_poly([sign * t]), fmpq_poly([1]), reduced=True)
        S[loc[j]][loc[i]] = rho * _RF(fmpq_poly([sign * kap / t]), fmpq_poly([1]), reduced=True)
        return True

    tree = {(min(u, p), max(u, p)) for u, p in parent.items() if p is not None}
    for i, j in tree:
        set_edge(i, j, 1)  # rational by construction of q

    def path(v: int) -> list[int]:
        out = [v]
        while parent[out[-1]] is not None:
            out.append(parent[out[-1]])  # type: ignore[arg-type]
        return out

    for i, j in sorted(set(roots) - tree):
        if not set_edge(i, j, 1):
            return None, "irrational"
        pi, pj = path(i), path(j)
        seq = [*pi, *pj[::-1][1:], i]
        zp = sp = _RF(fmpq_poly([1]), fmpq_poly([1]), reduced=True)
        for a, b in itertools.pairwise(seq):
            zp = zp * RF[a][b]
            sp = sp * S[loc[a]][loc[b]]
        if _rf_equal(zp, sp):
            continue
        if _rf_equal(zp, -sp):
            set_edge(i, j, -1)
            continue
        return None, (f"no sign choice of √(z{i + 1}{j + 1} z{j + 1}{i + 1}) reproduces Z's cycle products "
                      "(a longer cycle condition fails)")
    # With every fundamental cycle balanced, the ratios z_ij/S_ij (whose two directions multiply to
    # 1) are potential differences φ_i/φ_j on the coupling graph, so Z = Φ S Φ⁻¹ on the edges and
    # all principal minors agree. Only an entry with z_ij ≠ 0 but z_ji = 0 (no edge, S_ij = 0) can
    # still make them differ (through a longer cycle): then they are compared exactly.
    one_way = any(RF[comp[a]][comp[b]].is_zero != RF[comp[b]][comp[a]].is_zero
                  for a in range(k) for b in range(a + 1, k))
    for r in range(2, k + 1 if one_way else 2):
        for idx in itertools.combinations(range(k), r):
            mz = _rf_det([[RF[comp[a]][comp[b]] for b in idx] for a in idx])
            ms = _rf_det([[S[a][b] for b in idx] for a in idx])
            if not _rf_equal(mz, ms):
                return None, (f"principal minor {_lbl([comp[a] for a in idx])} of Z' differs from Z's "
                              "(no sign choice of √(z_ij z_ji) reproduces it)")
    nums: list[list[fmpq_poly | None]] = [[None if S[a][b].is_zero else S[a][b].n for b in range(k)]
                                          for a in range(k)]
    dens = [[S[a][b].d for b in range(k)] for a in range(k)]
    return (nums, dens), ""


def _sweep_block(tm: TransferMatrix, comp: list[int], tol: Tolerances) -> list[Condition]:
    """Numerical fallback for a Theorem-1 block of size ≥ 3 whose Z' is not rational.

    Re Z'(jω) is formed pointwise (principal square roots with cycle-consistent signs) on a
    dense logarithmic grid spanning the poles/zeros, and each principal minor is minimized with
    local refinement. Flagged ``method: sweep`` in the evidence: this is not an exact decision.
    """
    mags = [abs(p) for p in tm.poles() if abs(p) > 0] + [1.0]
    lo, hi = min(mags) * 1e-4, max(mags) * 1e4
    w = np.geomspace(lo, hi, 20001)
    G = tm.freq(w)[:, comp][:, :, comp]
    k = len(comp)
    R = np.zeros((w.size, k, k))
    for a in range(k):
        R[:, a, a] = G[:, a, a].real
    # pointwise symmetrization via a star from node 0 plus cycle consistency
    for a in range(k):
        for b in range(a + 1, k):
            c = G[:, a, b] * G[:, b, a]
            root = np.sqrt(c)
            if a > 0:
                ref = G[:, 0, a] * G[:, a, b] * G[:, b, 0]
                w0a = np.sqrt(G[:, 0, a] * G[:, a, 0])
                w0b = np.sqrt(G[:, 0, b] * G[:, b, 0])
                prod = w0a * root * w0b
                flip = (np.abs(prod) > 0) & ((ref / np.where(prod == 0, 1, prod)).real < 0)
                root = np.where(flip, -root, root)
            R[:, a, b] = R[:, b, a] = root.real
    conds = []
    for r in range(1, k + 1):
        for idx in itertools.combinations(range(k), r):
            sub = R[:, idx][:, :, idx]
            mn = np.linalg.det(sub) if r > 1 else sub[:, 0, 0]
            scale = np.abs(np.linalg.det(np.abs(sub))) + np.prod(np.abs(np.diagonal(sub, axis1=1, axis2=2)), axis=1)
            rho = mn / np.maximum(scale, 1e-300)
            i0 = int(np.argmin(rho))
            v = float(rho[i0])
            status: ConditionStatus = "violated" if v < -1e-6 else ("marginal" if v <= 1e-6 else "satisfied")
            glob = tuple(comp[i] for i in idx)
            conds.append(Condition(f"E{_lbl(glob)}", f"principal minor {_lbl(glob)} of Re Z'(jω) ≥ 0", status, v,
                                   float(w[i0]), "decided on a dense frequency grid (Z' is not rational)",
                                   {"method": "sweep", "grid_points": int(w.size)}))
    return conds


def absolute_stability(tm: TransferMatrix, tol: Tolerances = TOL, margins: bool = True) -> StabilityResult:
    """Theorem 1 of paper 000: absolute stability of an m-DOF n-port (impedance form, or any
    immittance form by its Remark 1).

    Preconditions (symmetrization): (A) z_ij z_jk z_ki = z_ji z_kj z_ik for all distinct i, j, k;
    (B) each diagonal block Z_ll is symmetric. If either fails the result is ``not_applicable``
    with the failing entries. Then: (C) no RHP poles; (D) imaginary-axis poles simple with
    non-negative principal minors of the residue matrix; (E) all principal minors of
    Re Z'(jω) ≥ 0 where z'_ij = γ_ij √(z_ij z_ji) (signs γ chosen so Z' and Z have equal principal
    minors). Blocks of Re Z' are decided exactly: 1×1 and 2×2 blocks through Re z_ii and
    Llewellyn's η (eq. 15b); larger blocks through the Hermitian minors of the rational Z' when
    √(z_ij z_ji) is rational, otherwise by a flagged numerical sweep. ``margins=False`` returns
    the same verdict without computing margins (faster).
    """
    tm0 = tm
    tm, w0 = _normalized(tm0)
    n = tm.n
    net = _netinfo(tm0, w0)
    conds: list[Condition] = []
    RF = _to_rf(tm.entries)  # exact entries over Q(s): A, B and the symmetrization are exact
    # (B) diagonal blocks symmetric
    off = 0
    bad_b = []
    for m in tm.port_dofs:
        for a in range(off, off + m):
            for b in range(a + 1, off + m):
                if not _rf_equal(RF[a][b], RF[b][a]):
                    bad_b.append((a, b))
        off += m
    if bad_b:
        a, b = bad_b[0]
        conds.append(Condition("B", "diagonal blocks Z_ll symmetric", "not_applicable", math.nan, None,
                               f"z{a + 1}{b + 1} ≠ z{b + 1}{a + 1} inside a port block", {"entries": bad_b}))
    else:
        conds.append(Condition("B", "diagonal blocks Z_ll symmetric", "satisfied", 1.0))
    # (A) cycle condition on all triples
    bad_a = []
    for i, j, k in itertools.combinations(range(n), 3):
        lhs = RF[i][j] * RF[j][k] * RF[k][i]
        rhs = RF[j][i] * RF[k][j] * RF[i][k]
        if not _rf_equal(lhs, rhs):
            bad_a.append((i, j, k))
    if bad_a:
        i, j, k = bad_a[0]
        conds.append(Condition("A", "symmetrization: z_ij z_jk z_ki = z_ji z_kj z_ik", "not_applicable", math.nan, None,
                               f"fails for (i,j,k) = ({i + 1},{j + 1},{k + 1})",
                               {"triples": [[a + 1, b + 1, c + 1] for a, b, c in bad_a]}))
    else:
        conds.append(Condition("A", "symmetrization: z_ij z_jk z_ki = z_ji z_kj z_ik", "satisfied", 1.0))
    if bad_a or bad_b:
        return combine("absolute_stability_nport", conds, net,
                       reason="Theorem 1 does not apply: the symmetrization conditions do not hold")
    # pairs with z_ij z_ji ≢ 0 define the coupling graph of Z'
    nz = np.zeros((n, n), bool)
    roots: dict[tuple[int, int], tuple[fmpq, _RF]] = {}
    irrational: set[tuple[int, int]] = set()
    for i in range(n):
        for j in range(i + 1, n):
            if tm[i, j].is_zero or tm[j, i].is_zero:
                continue
            nz[i, j] = nz[j, i] = True
            r = _sqrt_of_pair(RF[i][j], RF[j][i])
            if r is None:
                irrational.add((i, j))
            else:
                roots[(i, j)] = r
    conds += pole_conditions(tm, "minors", tol, w0, margins)
    for comp in _components(nz):
        if len(comp) == 1:
            conds += _hermitian_minors(tm.entries, comp, tol, "E", "Re z_ii(jω) ≥ 0", margins)
            continue
        edges = {(i, j) for i in comp for j in comp if i < j and nz[i, j]}
        # 2×2 blocks: Llewellyn's η on the given entries (eq. 15b), formed exactly; larger blocks
        # through the Hermitian minors of Z' (exactly, up to a diagonal similarity) when
        # √(z_ij z_ji) is a rational function up to a constant
        if len(comp) > 2 and not (edges & irrational):
            Sq, why = _exact_symmetrize(RF, comp, {e: roots[e] for e in edges})
            if Sq is not None:
                for c in _hermitian_minors(tm.entries, list(range(len(comp))), tol, "E", "Re Z'(jω) ⪰ 0", margins,
                                           q=Sq):
                    # relabel local indices to global ones
                    loc = [int(t) - 1 for t in c.name[2:-1].split(",")]
                    c.name = "E" + _lbl([comp[t] for t in loc])
                    c.label = f"principal minor {c.name[1:]} of Re Z'(jω) ≥ 0 (Z' exact over Q)"
                    c.evidence["formed"] = "exact (Z' up to a diagonal similarity, over Q)"
                    conds.append(c)
                continue
            if why != "irrational":
                conds.append(Condition("A*", "equal principal minors of Z' and Z", "not_applicable", math.nan, None,
                                       why))
                return combine("absolute_stability_nport", _rescale(conds, w0), net,
                               reason="Theorem 1 does not apply: Z is not symmetrizable")
        if len(comp) == 2:
            i, j = comp
            diag = (_hermitian_minors(tm.entries, [i], tol, "E", "Re z_ii(jω) ≥ 0", margins)
                    + _hermitian_minors(tm.entries, [j], tol, "E", "Re z_ii(jω) ≥ 0", margins))
            conds += diag
            conds.append(_llewellyn_eta(tm.entries, i, j, tol, margins, all(c.status == "satisfied" for c in diag)))
        else:
            conds += _sweep_block(tm, comp, tol)
    return combine("absolute_stability_nport", [*_rescale(conds, w0), infinity_condition(tm0, "minors", margins)], net)


#: a criterion's function: (network, tolerances, margins) -> result; ``margins=False`` may skip
#: the margins (the same verdict, faster)
CriterionFn = Callable[[TransferMatrix, Tolerances, bool], StabilityResult]


@dataclass(frozen=True)
class Criterion:
    """A named stability criterion :func:`check` can run: ``run(tm, tol, margins)``."""

    name: str
    run: CriterionFn
    description: str = ""


def _passivity(tm: TransferMatrix, tol: Tolerances, margins: bool) -> StabilityResult:
    return two_port_passivity(tm, tol, margins) if tm.n_ports == 2 else positive_real(tm, tol, margins)


#: the built-in criteria :func:`check` runs by name (besides ``auto``, which picks one by the
#: network's size)
CRITERIA: tuple[str, ...] = ("positive_real", "passivity", "llewellyn", "absolute_stability")

#: criterion name -> :class:`Criterion`: the built-ins, then those registered with
#: :func:`register_criterion` or through the entry-point group :data:`ENTRY_POINT_GROUP`
_REGISTRY: dict[str, Criterion] = {
    "positive_real": Criterion("positive_real", positive_real, "positive realness (one-port or matrix)"),
    "passivity": Criterion("passivity", _passivity, "two-port passivity (002 Theorem 2)"),
    "llewellyn": Criterion("llewellyn", llewellyn, "Llewellyn's absolute stability (002 Theorem 3)"),
    "absolute_stability": Criterion("absolute_stability", absolute_stability, "m-DOF n-port (000 Theorem 1)"),
}
#: entry points of other distributions: each loads a :class:`Criterion` (or a zero-argument
#: callable returning one); read once, on the first name that is not built in
ENTRY_POINT_GROUP = "hil_certify.criteria"
_entry_points_loaded = False


def register_criterion(criterion: Criterion, *, replace: bool = False) -> None:
    """Add a criterion :func:`check`, ``hil stability --criterion``, scenes and network files
    accept by name; refuses to shadow an existing name unless ``replace``."""
    if not re.fullmatch(r"[a-z][a-z0-9_]*", criterion.name) or criterion.name == "auto":
        raise ValueError(f"criterion name {criterion.name!r}: lower-case identifier other than 'auto' expected")
    if criterion.name in _REGISTRY and not replace and _REGISTRY[criterion.name] is not criterion:
        raise ValueError(f"criterion {criterion.name!r} is already registered")
    _REGISTRY[criterion.name] = criterion


def load_entry_points() -> list[str]:
    """Register the criteria other distributions declare in :data:`ENTRY_POINT_GROUP` (once; a
    broken entry point is logged and skipped). Returns the names registered."""
    global _entry_points_loaded
    if _entry_points_loaded:
        return []
    _entry_points_loaded = True
    from importlib.metadata import entry_points  # scanned only when a name is not built in

    out: list[str] = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
            crit = obj() if callable(obj) and not isinstance(obj, Criterion) else obj
            if not isinstance(crit, Criterion):
                raise TypeError(f"{ep.value} is not a Criterion")
            register_criterion(crit)
            out.append(crit.name)
        except Exception:
            logger.warning("criterion entry point %r (%s) could not be registered", ep.name, ep.value,
                           exc_info=True)
    return out


def criterion_names() -> tuple[str, ...]:
    """Every criterion :func:`check` runs by name (built-in first, then registered ones)."""
    load_entry_points()
    return tuple(_REGISTRY)


def is_criterion(name: str) -> bool:
    """Whether :func:`check` runs ``name`` (``auto`` included); entry points are read only for a
    name that is not built in."""
    if name == "auto" or name in _REGISTRY:
        return True
    load_entry_points()
    return name in _REGISTRY


class CriterionChoices(tuple[str, ...]):
    """``auto`` (optional) and the criterion names, for argparse ``choices``: membership of a
    built-in name reads no entry points (start-up time); iteration (an error message, help)
    lists every registered name."""

    _auto: bool

    def __new__(cls, auto: bool = True) -> CriterionChoices:
        obj = super().__new__(cls, (("auto",) if auto else ()) + CRITERIA)
        obj._auto = auto
        return obj

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and (self._auto or name != "auto") and is_criterion(name)

    def __iter__(self) -> Iterator[str]:
        return iter((("auto",) if self._auto else ()) + criterion_names())


def check(tm: TransferMatrix | Rational, criterion: str = "auto", tol: Tolerances = TOL,
          margins: bool = True) -> StabilityResult:
    """Run the criterion that fits the network (``auto``) or the named one.

    ``auto``: a one-port → positive realness; a 1-DOF two-port → Llewellyn; anything larger →
    Theorem 1 (which reduces to Llewellyn for m = 1, n = 2). Names: ``positive_real``,
    ``passivity`` (two-port passivity), ``llewellyn``, ``absolute_stability``, and any criterion
    registered (:func:`register_criterion`, entry points). ``margins=False``: the same verdict
    without margins (faster).
    """
    tm = _as_tm(tm)
    if criterion == "auto":
        if tm.n == 1:
            return positive_real(tm, tol, margins)
        if tm.n == 2 and tm.n_ports == 2:
            return llewellyn(tm, tol, margins)
        return absolute_stability(tm, tol, margins)
    if not is_criterion(criterion):
        raise ModelError(f"unknown criterion {criterion!r}; expected auto, {', '.join(criterion_names())}")
    return _REGISTRY[criterion].run(tm, tol, margins)


def margin_curve(g: TransferMatrix | Rational, condition: str = "E{1}") -> Callable[[np.ndarray], np.ndarray]:
    """ω ↦ p(x)/m_r(x) of one frequency condition, the quantity whose minimum is that condition's
    frequency-domain margin (docs/VERDICTS.md), for plots: ω in physical rad/s, values in [-1, 1].

    ``condition`` is a condition name as in the results: ``E{i,j,...}`` (a principal minor of
    G + Gᴴ) or, for a 1-DOF two-port, ``L1`` / ``L2`` (Llewellyn's polynomials of E{1,2})."""
    from hil.stability.exact import _Ratio, exact_sign

    tm, w0 = _normalized(_as_tm(g))
    if condition in ("L1", "L2"):
        if tm.n != 2:
            raise ModelError("L1/L2 are defined for 1-DOF two-ports")
        pair = _exact_llewellyn_polys([[tm[a, b] for b in (0, 1)] for a in (0, 1)])
        p, cut, m = pair[0] if condition == "L1" else pair[1]
    else:
        try:
            idx = tuple(int(t) - 1 for t in condition[2:-1].split(","))
        except ValueError:
            raise ModelError(f"unknown condition {condition!r}; expected E{{i,...}}, L1 or L2") from None
        if not condition.startswith("E{") or any(i < 0 or i >= tm.n for i in idx):
            raise ModelError(f"unknown condition {condition!r} for a {tm.n}x{tm.n} network")
        sub = [[tm[a, b] for b in idx] for a in idx]
        p, cut, m = _exact_minor_polys(sub)[tuple(range(len(idx)))]
    c = _qpoly_float(p)
    mm = np.abs(c) if (cut or m is None) else np.maximum(
        np.pad(np.abs(m), (0, max(0, c.size - m.size)))[: max(c.size, m.size)],
        np.pad(np.abs(c), (0, max(0, m.size - c.size))))
    a = exact_sign(p).order0 if not p.is_zero() else 0
    m_rep = mm.copy()
    m_rep[:a] = 0.0
    m_rep[c.size:] = 0.0
    ratio = _Ratio(c, m_rep)

    def f(w: np.ndarray) -> np.ndarray:
        x = (np.asarray(w, float) / w0) ** 2
        return ratio(x) if not p.is_zero() else np.zeros_like(x)

    return f
