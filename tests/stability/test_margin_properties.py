"""Issue 31: the defining properties of the margins, the critical band and the weak flag, as
property tests over random networks (hypothesis draws the seeds; numpy builds the networks).

The perturbation model is the margin's own (docs/VERDICTS.md, "What a margin measures"): a
network U/D over its common denominator, each coefficient of each u_ij and of D changed by a
relative amount, zeros kept. The generators therefore build networks as U/D, and perturb U and D.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from flint import fmpq, fmpq_poly
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.stability.criteria import check
from hil.stability.margins import CRITICAL_BAND_FRACTION, critical_band
from hil.stability.rational import Rational, S, TransferMatrix

SEEDS = st.integers(0, 2**31 - 1)
ONE_PORT = ("positive_real",)
TWO_PORT = ("passivity", "llewellyn", "absolute_stability")


def _roots(rng: np.random.Generator, n: int, side: int = -1) -> list[complex]:
    """n roots (conjugate pairs complete), moduli 0.1..10 at least 20 % apart, real parts of sign
    ``side`` (0: either)."""
    mods = np.sort(10 ** rng.uniform(-1, 1, n))
    for i in range(1, n):
        mods[i] = max(mods[i], 1.2 * mods[i - 1])
    out: list[complex] = []
    i = 0
    while len(out) < n:
        sg = side if side else float(rng.choice([-1, 1]))
        if n - len(out) >= 2 and rng.random() < 0.5:
            th = rng.uniform(0.2, 1.3)
            z = mods[i] * complex(sg * math.cos(th), math.sin(th))
            out += [z, z.conjugate()]
        else:
            out.append(complex(sg * mods[i], 0.0))
        i += 1
    return out


def _poly(roots: list[complex], gain: float = 1.0) -> np.ndarray:
    """Ascending real coefficients of gain·∏(s - r)."""
    return gain * np.real(np.poly(roots))[::-1] if roots else np.array([gain])


def _network(rng: np.random.Generator, n: int) -> tuple[list[list[np.ndarray]], np.ndarray]:
    """(U, D) ascending: D with left-half-plane roots (and sometimes a structural pole at s = 0),
    u_ij of degree ≤ deg D + 1 with roots anywhere; the diagonal made dominant so that some draws
    are passive and some are not."""
    dd = int(rng.integers(1, 4))
    D = _poly(_roots(rng, dd))
    if rng.random() < 0.25:
        D = np.concatenate([[0.0], D])  # a pole at s = 0
    U = []
    for i in range(n):
        row = []
        for j in range(n):
            k = int(rng.integers(0, D.size + 1))
            g = rng.uniform(0.2, 2.0) * (1.0 if i == j else float(rng.choice([-0.3, 0.3])))
            row.append(_poly(_roots(rng, k, side=-1 if i == j and rng.random() < 0.7 else 0), g))
        U.append(row)
    return U, D


def _tm(U: list[list[np.ndarray]], D: np.ndarray) -> TransferMatrix:
    return TransferMatrix([[Rational(u, D) for u in row] for row in U])


def _shifted(tm: TransferMatrix, shift: float) -> TransferMatrix:
    """The network with a resistance ``shift`` added to every diagonal entry."""
    return TransferMatrix([[e + (shift if a == b else 0.0) for b, e in enumerate(row)]
                           for a, row in enumerate(tm.entries)])


def _perturbed(U: list[list[np.ndarray]], D: np.ndarray, rng: np.random.Generator, t: float
               ) -> tuple[list[list[np.ndarray]], np.ndarray]:
    """Every coefficient times (1 + t·r), r uniform in [-1, 1]: the model's relative perturbation
    (D perturbed once: it stays the common denominator; zeros stay zero)."""
    return ([[u * (1 + t * rng.uniform(-1, 1, u.size)) for u in row] for row in U],
            D * (1 + t * rng.uniform(-1, 1, D.size)))


def _criteria(n: int) -> tuple[str, ...]:
    return ONE_PORT if n == 1 else TWO_PORT


# ------------------------------------------------------------------------------------------------
# continuity


@given(SEEDS, st.integers(1, 2))
@settings(max_examples=12, deadline=None)
def test_margin_is_continuous_under_the_models_perturbations_on_both_sides(seed, n):
    """margin(N + ε) → margin(N) as ε → 0, with ε = ±t·(random direction) in the coefficients of
    U and D: the change is at most 1e5·t (far above the bound 4K·t of a frequency condition, K ≤ 8
    coefficient factors per term; the damping ratio of a root 20 % away from the next moves by at
    most ~1e2·t) plus the certified accuracy 3e-6·|μ|, down to t = 1e-12."""
    rng = np.random.default_rng(seed)
    U, D = _network(rng, n)
    for crit in _criteria(n):
        mu0 = check(_tm(U, D), crit).margin
        for t in (1e-6, -1e-6, 1e-12, -1e-12):
            mu = check(_tm(*_perturbed(U, D, np.random.default_rng(seed + 7), t)), crit).margin
            assert abs(mu - mu0) <= 1e5 * abs(t) + 3e-6 * max(abs(mu0), abs(mu)), (crit, t, mu0, mu)


@given(SEEDS, st.sampled_from([1e-3, 1e-6, 1e-9]), st.sampled_from([-1.0, 1.0]))
@settings(max_examples=25, deadline=None)
def test_margin_tends_to_zero_on_both_sides_of_the_boundary(seed, eps, side):
    """Random networks *on* the boundary (margin 0) and their neighbours at ±ε: a touching real
    part (s² + a)/(s² + bs + a), a lossless pole r + k s/(s² + a) gaining damping ±ε, Llewellyn's η
    of f(s)·[[1, c], [c, 1]] with c = 1 ± ε (η = 2(Re f)²(1 - c²)). Each: margin 0 at ε = 0, |margin|
    ≤ C·ε next to it, and its sign the verdict's."""
    rng = np.random.default_rng(seed)
    # dyadic parameters (k/64, k ≤ 640): the products that form the coefficients are exact, so the
    # networks at ε = 0 are exactly on the boundary
    a, b, c, r, k = (max(1, round(float(v) * 64)) / 64 for v in 10 ** rng.uniform(-1, 1, 5))
    f = Rational.from_desc([1.0, float(10 ** rng.uniform(-1, 1))], [1.0, float(10 ** rng.uniform(-1, 1))])
    # the constants C: family 1 -- p = c((a - x)² + εbx), m = c((a + x)² + |ε|bx), at x = a the
    # ratio is εb/(4a + |ε|b); family 2 -- E{1}: p = r(a - x)² + ε(k + rε)x, ratio ≈ εk/(4ra) at
    # x = a, and C's damping ratio ε/(2√a); family 3 -- L2 ≈ -4ε(...)², a ratio ≤ ε/2
    families = [
        (lambda e: Rational.from_desc([c, c * e, c * a], [1.0, b, a]), "positive_real", 1.5 * b / (4 * a) + 1),
        (lambda e: r + k * S / (S**2 + e * S + a) if e else r + k * S / (S**2 + a), "positive_real",
         1.5 * max(k / (4 * r * a), 1 / (2 * math.sqrt(a))) + 1),
        (lambda e: TransferMatrix([[f, f * (1 + e)], [f * (1 + e), f]]), "llewellyn", 8.0),
    ]
    for make, crit, C in families:
        r0 = check(make(0.0), crit)
        assert str(r0.verdict) == "stable" and r0.margin == 0.0, (crit, r0.summary())
        re = check(make(side * eps), crit)
        stable = str(re.verdict) == "stable"
        assert stable == (re.margin >= 0) and abs(re.margin) <= C * eps, (crit, side, eps, re.summary())


# ------------------------------------------------------------------------------------------------
# written form, sign, scaling


def _exact(p: np.ndarray) -> fmpq_poly:
    return fmpq_poly([fmpq(*float(v).as_integer_ratio()) for v in p])


@given(SEEDS, st.integers(1, 2), st.sampled_from(["lhp", "rhp", "axis", "origin"]))
@settings(max_examples=12, deadline=None)
def test_margin_is_invariant_under_rewriting_an_entry_unreduced(seed, n, where):
    """n·g/(d·g) for a random common factor g (roots in the left or right half plane, on the axis
    or at the origin), formed exactly: the same verdict, weak flag and margin (to the certified
    accuracy), for every criterion."""
    rng = np.random.default_rng(seed)
    U, D = _network(rng, n)
    g = {"lhp": [1.0, 1.5, 0.5], "rhp": [1.0, -2.0], "axis": [1.0, 0.0, 3.0], "origin": [1.0, 0.0]}[where][::-1]
    i, j = (int(v) for v in rng.integers(0, n, 2))
    ents = [[Rational(u, D) for u in row] for row in U]
    if not ents[i][j].is_zero:
        gq = _exact(np.asarray(g, float))
        ents[i][j] = Rational.of_exact(_exact(U[i][j]) * gq, _exact(D) * gq)
    for crit in _criteria(n):
        a, b = check(_tm(U, D), crit), check(TransferMatrix(ents), crit)
        assert (str(a.verdict), a.weak) == (str(b.verdict), b.weak)
        assert b.margin == pytest.approx(a.margin, rel=3e-6, abs=1e-300)


#: diagonal shifts (resistances added): both verdicts occur; coefficients stay in a physical range
SHIFTS = st.sampled_from([0.0, -1.0, -0.5, -0.1, -0.01, -1e-6, 1e-6, 0.01, 0.1, 0.5, 1.0])


@given(SEEDS, st.integers(1, 2), SHIFTS)
@settings(max_examples=30, deadline=None)
def test_sign_of_the_margin_is_the_verdict(seed, n, shift):
    """stable ⇔ margin ≥ 0 and potentially_unstable ⇔ margin < 0, for every criterion; the
    diagonal is shifted by a random resistance so that both verdicts occur."""
    rng = np.random.default_rng(seed)
    U, D = _network(rng, n)
    tm = _shifted(_tm(U, D), shift)
    for crit in _criteria(n):
        r = check(tm, crit)
        if str(r.verdict) in ("stable", "potentially_unstable"):
            assert (r.margin >= 0) == (str(r.verdict) == "stable"), r.summary()
        # every margin is dimensionless and in [-1, 1] (docs/VERDICTS.md)
        assert all(-1.0 <= c.margin <= 1.0 for c in r.conditions if c.margin == c.margin), r.summary()


@given(SEEDS, st.integers(1, 2), st.integers(-30, 30), st.integers(-30, 30), st.sampled_from([0.0, 1e-15, -1e-15]))
@settings(max_examples=20, deadline=None)
def test_power_of_two_scalings_give_identical_margins(seed, n, k, j, nudge):
    """Item 6: s -> 2^k s and Z -> 2^j Z, applied exactly: the same margin bit for bit, the worst
    frequency times exactly 2^-k, for every criterion; ``nudge`` moves the network onto the edge of
    its boundary (a resistance -(1 ± 1e-15)·min Re z11 added), where margins are tiny."""
    rng = np.random.default_rng(seed)
    U, D = _network(rng, n)
    if nudge and D[0] != 0:
        w = np.geomspace(1e-3, 1e3, 2001)
        z11 = Rational(U[0][0], D).freq(w).real
        u = np.asarray(U[0][0], float)
        size = max(u.size, D.size)
        U[0][0] = np.pad(u, (0, size - u.size)) - float(np.min(z11)) * (1 + nudge) * np.pad(D, (0, size - D.size))
    a, b = 2.0**k, 2.0**j
    sc = [[u * b * a ** np.arange(u.size) for u in row] for row in U]
    for crit in _criteria(n):
        r1, r2 = check(_tm(U, D), crit), check(_tm(sc, D * a ** np.arange(D.size)), crit)
        assert (str(r1.verdict), r1.weak, r1.failed_condition) == (str(r2.verdict), r2.weak, r2.failed_condition)
        assert r2.margin == r1.margin or (r1.margin != r1.margin and r2.margin != r2.margin)
        if r1.worst_frequency is not None and math.isfinite(r1.worst_frequency):
            assert r2.worst_frequency == r1.worst_frequency / a


# ------------------------------------------------------------------------------------------------
# the critical band


def _ratio(cond, x: float) -> float:
    from hil.stability.margins import _exact_ratio

    p, mr = cond.ratio
    return _exact_ratio(p, mr, x)


@given(SEEDS, st.integers(1, 2), SHIFTS)
@settings(max_examples=25, deadline=None)
def test_critical_band_contains_the_minimum_and_every_frequency_near_it(seed, n, shift):
    """The band contains the worst frequency of its condition, and every frequency (sampled on 400
    points over 16 decades, ratio evaluated exactly) where the ratio is below the threshold θ =
    μ + 0.1(1 - μ) (at least 0 for a violated condition); just outside it the ratio is above θ."""
    rng = np.random.default_rng(seed)
    U, D = _network(rng, n)
    tm = _shifted(_tm(U, D), shift)
    for crit in _criteria(n):
        r = check(tm, crit)
        band = critical_band(r)
        conds = [c for c in r.conditions if c.ratio is not None]
        if band is None:
            assert not conds
            continue
        bad = [c for c in conds if c.status == "violated"] or conds
        c = min(bad, key=lambda c: c.margin)
        lo, hi = band
        w0 = r.network["omega_scale"]
        if c.worst_frequency is not None:
            assert lo <= c.worst_frequency <= hi
        theta = c.margin + CRITICAL_BAND_FRACTION * (1 - c.margin)
        if c.margin < 0:
            theta = max(theta, 0.0)
        for om in np.geomspace(1e-8, 1e8, 400) * w0:
            v = _ratio(c, (om / w0) ** 2)
            if v <= theta - 1e-9:
                assert lo <= om <= hi, (crit, om, v, theta, band)
        for om in (lo / 1.05, hi * 1.05):
            if 0 < om < math.inf:
                assert _ratio(c, (om / w0) ** 2) > theta - 1e-6


# ------------------------------------------------------------------------------------------------
# the weak flag on block-diagonal networks


BLOCKS = {  # name -> (one-port, weak?)
    "R + damped": (1 + S / (S**2 + 0.3 * S + 2), False),
    "lossless tank": (S / (S**2 + 2), True),
    "spring": (1 / (2 * S), True),
    "mass": (0.5 * S, True),
    "touching": (Rational.from_desc([1.0, 0.0, 3.0], [1.0, 0.5, 3.0]), True),
    "R + spring": (1 + 1 / S, False),
    "R + mass": (1 + S, False),
    "R + tank": (2 + S / (S**2 + 1), False),
    "resistor": (Rational.const(3.0), False),
}


@given(st.sampled_from(sorted(BLOCKS)), st.sampled_from(sorted(BLOCKS)))
@settings(max_examples=40, deadline=None)
def test_block_diagonal_networks_get_one_weak_flag_from_every_criterion(a, b):
    """diag(a, b): positive realness, two-port passivity, Llewellyn and Theorem 1 agree on the
    verdict and the weak flag, which is that of the blocks (weak when one block is)."""
    (za, wa), (zb, wb) = BLOCKS[a], BLOCKS[b]
    assert check(za, "positive_real").weak is wa and check(zb, "positive_real").weak is wb
    tm = TransferMatrix([[za, 0], [0, zb]])
    got = {(str(r.verdict), r.weak) for r in (check(tm, c) for c in ("positive_real", *TWO_PORT))}
    assert got == {("stable", wa or wb)}
