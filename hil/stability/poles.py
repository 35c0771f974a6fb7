"""The pole conditions of every criterion: C (no pole in the open right-half plane), D[ω=ω_p]
(imaginary-axis poles simple with admissible residues) and D[ω=∞] (at most a simple pole at
infinity with an admissible residue), decided exactly (docs/VERDICTS.md)."""

from __future__ import annotations

import itertools
import logging
import math
import re
from typing import Any

import numpy as np
from flint import fmpq, fmpq_poly

from hil.stability.exact import (
    exact_poles,
    strictly_hurwitz,
)
from hil.stability.forms import _lbl, _lcm
from hil.stability.rational import TransferMatrix
from hil.stability.results import Condition
from hil.stability.tolerances import TOL, Tolerances

logger = logging.getLogger(__name__)


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
    """The open right-half-plane roots of an exact polynomial, isolated exactly and located to
    double precision (:func:`hil.stability.roots.rhp_roots`)."""
    from hil.stability.roots import rhp_roots

    return rhp_roots(d)


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
    ``margins=False``: C's margin and its ``poles`` evidence are not computed (verdict unchanged).

    C's margin is the smallest damping ratio -Re p/|p| over the poles off the origin (exactly
    isolated, :mod:`hil.stability.roots`): 0 for a pole on the imaginary axis (a lossless pole is
    on the boundary: a relative perturbation of the coefficients of u and D moves the pole off the
    point where the numerator's real part vanishes, docs/VERDICTS.md), negative for the worst
    right-half-plane pole, 1 without poles; poles at s = 0 are structural (a trailing zero
    coefficient, which a relative perturbation keeps) and do not count. Its worst frequency is
    that pole's |Im p| (rad/s).
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
        from hil.stability.roots import isolate_roots

        # the poles of the network are the roots of D, isolated exactly (hil.stability.roots)
        roots = isolate_roots(D, hurwitz=hurwitz)
        allp = [r.value for r in roots for _ in range(r.multiplicity)]
        damp = [(0.0 if r.region == "axis" else -r.value.real / abs(r.value), abs(r.value.imag))
                for r in roots if r.region in ("lhp", "axis")]
        m, wf = min(damp, default=(1.0, None))
        detail = "all poles in the closed left-half plane"
        if m == 0.0:
            detail += " (margin 0: a pole on the imaginary axis is on the boundary)"
        conds.append(Condition("C", "no poles in the open right-half plane", "satisfied", float(m), wf, detail,
                               {"poles": allp}))
    for pole in axis_poles(fmpq_poly([0] * k0 + [1]) if hurwitz else D):
        om = pole.omega
        name = f"D[ω={om:.6g}]"
        wp = om * w0  # physical rad/s, for the detail lines
        label = "imaginary-axis pole simple with admissible residues"
        if pole.multiplicity > 1:
            conds.append(Condition(name, label, "violated", -1.0, om,
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
        ev["pole"] = complex(0, om)
        at = f" at s = j{wp:.6g}"
        mt = re.search(r"residue( matrix)?", dec.detail)
        detail = dec.detail[: mt.end()] + at + dec.detail[mt.end():] if mt else dec.detail + at
        conds.append(Condition(name, label, dec.status, dec.margin, om, detail, ev))  # type: ignore[arg-type]
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
    exact = [[tm[i, j].exact for j in range(n)] for i in range(n)]  # the entries themselves (exact)
    exc: list[list[int | None]] = [[None if tm[i, j].is_zero else exact[i][j][0].degree() - exact[i][j][1].degree()
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
          exact[i][j][0][exact[i][j][0].degree()] / exact[i][j][1][exact[i][j][1].degree()]
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
            err = min(max(abs(float(R[a][b] - R[b][a])) for a, b in asym) / scale, 1.0)  # in [-1, 1]
            return Condition(name, label, "violated", -err, math.inf,
                             f"residue matrix at s = ∞ is not symmetric (r{i + 1}{j + 1} ≠ r{j + 1}{i + 1})", ev)
    else:
        for i in range(n):
            for j in range(i + 1, n):
                if R[i][j] * R[j][i] < 0:
                    return Condition(name, label, "violated", -1.0, math.inf,
                                     f"r{i + 1}{j + 1}·r{j + 1}{i + 1} = {float(R[i][j] * R[j][i]):.4g} < 0 "
                                     "at s = ∞", ev)
    from hil.stability.residues import _scaled_int_minors, principal_minors, structural_eigmin

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
        # over the structurally active ports (an entry without a pole at ∞ is a structural 0)
        nz = [[exc[i][j] == 1 for j in range(n)] for i in range(n)]
        margin = max(structural_eigmin((Rf + Rf.T) / 2, nz) / lam_scale, 0.0)
    else:
        margin = min((float(mnr) / perm(idx) for idx, mnr in minors.items() if perm(idx)), default=1.0)
    if zero_minor is not None:  # a minor zero by the pattern alone (perm |R| = 0) is not equality
        return Condition(name, label, "equality", 0.0, math.inf,
                         f"simple pole at s = ∞, residue matrix singular (minor {_lbl(zero_minor)} = 0, PSD)", ev)
    return Condition(name, label, "satisfied", float(min(margin, 1.0)) if margins else math.nan, math.inf,
                     "simple pole at s = ∞ with positive definite residue matrix", ev)
