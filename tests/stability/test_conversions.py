"""Immittance conversions (exact over Q(s), hil.stability.rational) against an independent
derivation: the matrices evaluated numerically at random complex s, inverted with numpy or put
through the definitions of the hybrid forms ([F1; V2] = H [V1; F2], [V1; F2] = G [F1; V2]).

Tolerance. The conversion itself is exact; the only errors are (a) one rounding of every
converted coefficient to a float (relative 2^-53), amplified when the converted entry is
evaluated by its evaluation condition number Σ|c_k||s|^k / |p(s)| (large for the degree-30+
entries of a 6×6 inverse with distinct denominators), and (b) numpy's evaluation and LU inverse
at s, about cond(Z(s))·eps; test points are kept where cond ≤ 1e4. Over these cases the largest
relative error measured is 1.8e-11 (median 3e-16): rel 1e-9 leaves a factor 50 for round-off and
still fails on any wrong entry, sign or block (errors of order 1).
"""

import numpy as np
import pytest
from numpy.polynomial import polynomial as P

from hil.errors import ConversionError
from hil.models.sdea import SDEA_TABLE1, sdea_coefficients, sdea_vsic
from hil.stability.rational import KINDS, Rational, S, TransferMatrix

RTOL = 1e-9


def _random_rational(rng: np.random.Generator) -> Rational:
    """A proper entry with poles in the left half plane (real or complex pairs), random gain."""
    if rng.random() < 0.15:
        return Rational.const(float(rng.normal()))
    nd = int(rng.integers(1, 4))
    poles = []
    while len(poles) < nd:
        if nd - len(poles) >= 2 and rng.random() < 0.5:
            re, im = -rng.uniform(0.2, 5.0), rng.uniform(0.1, 5.0)
            poles += [complex(re, im), complex(re, -im)]
        else:
            poles.append(complex(-rng.uniform(0.2, 5.0), 0.0))
    den = np.real(P.polyfromroots(poles))
    num = rng.normal(size=int(rng.integers(1, nd + 2)))
    return Rational(num, den)


def _random_matrix(rng: np.random.Generator, n: int) -> list[list[Rational]]:
    return [[_random_rational(rng) for _ in range(n)] for _ in range(n)]


def _eval(tm: TransferMatrix, s: complex) -> np.ndarray:
    return np.array([[complex(e(s)) for e in row] for row in tm.entries])


def _points(rng: np.random.Generator, k: int = 4) -> list[complex]:
    r = np.exp(rng.uniform(np.log(0.3), np.log(5.0), k))
    th = rng.uniform(-np.pi / 2 + 0.2, np.pi / 2 - 0.2, k)  # right half plane, off the poles
    return list(r * np.exp(1j * th))


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.linalg.norm(a - b) <= RTOL * max(np.linalg.norm(b), 1e-300))


def _well_conditioned(*Ms: np.ndarray) -> bool:
    return all(np.linalg.cond(M) <= 1e4 for M in Ms)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6])
def test_impedance_to_admittance_is_the_inverse_at_random_points(n):
    rng = np.random.default_rng(100 + n)
    checked = 0
    for _ in range(4):
        Z = TransferMatrix(_random_matrix(rng, n), "impedance")
        Y = Z.to("admittance")
        # the way back starts from Y's rounded coefficients, which share no exact factors any more:
        # with 6 entries of distinct denominators per row its degrees run into the hundreds, so the
        # round trip is checked on the smaller sizes
        back = Y.to("impedance") if n <= 4 else None
        for s in _points(rng):
            Zs = _eval(Z, s)
            if not _well_conditioned(Zs):
                continue
            assert _close(_eval(Y, s), np.linalg.inv(Zs))
            if back is not None:
                assert _close(_eval(back, s), Zs)
            checked += 1
    assert checked >= 8


@pytest.mark.parametrize("dofs", [(1, 1), (2, 1), (1, 2), (2, 2), (3, 3)])
def test_hybrid_forms_satisfy_their_definitions(dofs):
    """From F = Z V at a random V: H [V1; F2] = [F1; V2] and G [F1; V2] = [V1; F2]."""
    rng = np.random.default_rng(sum(dofs) * 10 + dofs[0])
    m1, n = dofs[0], sum(dofs)
    checked = 0
    for _ in range(4):
        Z = TransferMatrix(_random_matrix(rng, n), "impedance", dofs)
        H, G = Z.to("hybrid"), Z.to("inverse_hybrid")
        for s in _points(rng):
            Zs = _eval(Z, s)
            if not _well_conditioned(Zs, Zs[m1:, m1:]):
                continue
            V = rng.normal(size=n) + 1j * rng.normal(size=n)
            F = Zs @ V
            x_h, y_h = np.r_[V[:m1], F[m1:]], np.r_[F[:m1], V[m1:]]
            assert _close(_eval(H, s) @ x_h, y_h)
            assert _close(_eval(G, s) @ y_h, x_h)
            checked += 1
    assert checked >= 8


@pytest.mark.parametrize("src", ["admittance", "hybrid", "inverse_hybrid"])
def test_every_pair_of_kinds_agrees_at_random_points(src):
    """Start from a random matrix of kind ``src``; every other kind is checked through the
    definitions against the impedance obtained numerically (numpy) from the source."""
    rng = np.random.default_rng(7 + KINDS.index(src))
    dofs = (1, 2)
    m1, n = dofs[0], sum(dofs)
    checked = 0
    for _ in range(3):
        A = TransferMatrix(_random_matrix(rng, n), src, dofs)
        conv = {k: A.to(k) for k in KINDS}
        for s in _points(rng):
            As = _eval(A, s)
            if not _well_conditioned(As, As[m1:, m1:], As[:m1, :m1]):
                continue
            # numeric impedance from the definition of the source kind
            if src == "admittance":
                Zs = np.linalg.inv(As)
            else:
                # [a1; b2] = A [b1; a2]: solve for F given V from two blocks of linear equations
                E = np.zeros((n, n), complex)  # F = Zs V: column by column from unit velocities
                for j in range(n):
                    V = np.eye(n)[j]
                    if src == "hybrid":  # [F1; V2] = H [V1; F2]  ->  unknowns F1, F2
                        H11, H12, H21, H22 = As[:m1, :m1], As[:m1, m1:], As[m1:, :m1], As[m1:, m1:]
                        F2 = np.linalg.solve(H22, V[m1:] - H21 @ V[:m1])
                        F1 = H11 @ V[:m1] + H12 @ F2
                    else:  # [V1; F2] = G [F1; V2]  ->  unknowns F1, F2
                        G11, G12, G21, G22 = As[:m1, :m1], As[:m1, m1:], As[m1:, :m1], As[m1:, m1:]
                        F1 = np.linalg.solve(G11, V[:m1] - G12 @ V[m1:])
                        F2 = G21 @ F1 + G22 @ V[m1:]
                    E[:, j] = np.r_[F1, F2]
                Zs = E
            if not _well_conditioned(Zs, Zs[m1:, m1:]):
                continue
            assert _close(_eval(conv["impedance"], s), Zs)
            assert _close(_eval(conv["admittance"], s), np.linalg.inv(Zs))
            V = rng.normal(size=n) + 1j * rng.normal(size=n)
            F = Zs @ V
            assert _close(_eval(conv["hybrid"], s) @ np.r_[V[:m1], F[m1:]], np.r_[F[:m1], V[m1:]])
            assert _close(_eval(conv["inverse_hybrid"], s) @ np.r_[F[:m1], V[m1:]], np.r_[V[:m1], F[m1:]])
            checked += 1
    assert checked >= 5


def _monic(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ascending coefficients normalized to a monic denominator."""
    num, den = np.trim_zeros(np.asarray(num, float), "b"), np.trim_zeros(np.asarray(den, float), "b")
    return num / den[-1], den / den[-1]


def test_sdea_shared_characteristic_polynomial_cancels_exactly():
    """h11 = n11/a and h12 = n12/a share the quartic a(s) of paper 002 eq. (12). In exact
    arithmetic g = h⁻¹ reduces to, with h22 = s/(b22 s + k22) and c(s) = n11 s + n12 (b22 s + k22):

        g11 = a s / c,   g12 = -n12 (b22 s + k22) / c,   g21 = a (b22 s + k22) / c,
        g22 = n11 (b22 s + k22) / c,

    degree 5 over degree 5; without cancelling a(s) the entries would be degree 10 over 10 (and
    z21 = (b22 s + k22)/s would carry a quartic pole/zero pair)."""
    p = {**SDEA_TABLE1, "k22": 450.0}
    h = sdea_vsic(k22=450.0)
    c = sdea_coefficients(p)
    a, n11, n12 = (np.asarray(v, float)[::-1] for v in (c.a, c.n11, c.n12))  # ascending
    lin = np.array([p["k22"], p["b22"]])  # b22 s + k22
    s1 = np.array([0.0, 1.0])
    cc = P.polyadd(P.polymul(n11, s1), P.polymul(n12, lin))
    expected = [[(P.polymul(a, s1), cc), (-P.polymul(n12, lin), cc)],
                [(P.polymul(a, lin), cc), (P.polymul(n11, lin), cc)]]
    g = h.to("inverse_hybrid")
    for i in range(2):
        for j in range(2):
            e = g[i, j]
            assert e.den.size - 1 == 5, (i, j, e)
            en, ed = _monic(*expected[i][j])
            gn, gd = _monic(e.num, e.den)
            assert gn.size == en.size and gd.size == ed.size
            assert np.allclose(gn, en, rtol=1e-12, atol=0) and np.allclose(gd, ed, rtol=1e-12, atol=0)
    z = h.to("impedance")
    assert (z[1, 0].num.size - 1, z[1, 0].den.size - 1) == (1, 1)  # -h21/h22 = (b22 s + k22)/s
    assert (z[0, 0].den.size - 1, z[0, 1].den.size - 1) == (5, 5)  # a(s)·s, not a(s)²·s


def test_converted_entries_are_scaled_by_their_largest_denominator_coefficient():
    Z = TransferMatrix([[2 * S + 3, 1 / (S + 4)], [1 / (S + 4), 5 / (0.25 * S + 1)]], "impedance")
    for k in ("admittance", "hybrid", "inverse_hybrid"):
        for row in Z.to(k).entries:
            for e in row:
                assert float(np.max(np.abs(e.den))) == 1.0


def test_identically_singular_matrices_raise():
    one = Rational.const(1.0)
    with pytest.raises(ConversionError, match="identically singular: this immittance form does not exist"):
        TransferMatrix([[1 / S, 1 / S], [2 / S, 2 / S]], "impedance").to("admittance")
    with pytest.raises(ConversionError, match="Z22 is identically singular"):
        TransferMatrix([[one, one], [one, Rational.const(0.0)]], "impedance").to("hybrid")
    # exactly singular only in exact arithmetic: rank one through a shared factor (s + 0.1)
    r = (S + 0.1) / (S + 3)
    with pytest.raises(ConversionError):
        TransferMatrix([[r, r * 2], [r * 3, r * 6]], "impedance").to("admittance")


def test_exact_determinant_against_numpy_and_exactly_zero_when_singular():
    from hil.stability.rational import _rf_det, _to_rf

    rng = np.random.default_rng(5)
    for n in (1, 2, 3, 4):
        Z = TransferMatrix(_random_matrix(rng, n), "impedance")
        d = _rf_det(_to_rf(Z.entries)).to_rational()
        for s in _points(rng):
            ref = np.linalg.det(_eval(Z, s))
            assert abs(complex(d(s)) - ref) <= RTOL * max(abs(ref), 1e-300) or not _well_conditioned(_eval(Z, s))
    r = (S + 0.1) / (S + 3)
    assert _rf_det(_to_rf([[r, r * 2], [r * 3, r * 6]])).is_zero


# ------------------------------------------------------------------------------------------------
# issue 31, item 5: a converted network is decided exactly, not as its rounded coefficients


def _ladder() -> TransferMatrix:
    """A passive RLC T ladder: series 0.3 + 0.3 s, shunt 0.7 s + 1/(0.7 s), series
    0.1 s + 1/(0.7 s); its hybrid, inverse hybrid and admittance forms have coefficients that are
    not binary rationals, and two imaginary-axis pole pairs (lossless, on the boundary)."""
    a = 0.3 + S * 0.3
    b = 0.7 * S + 1 / (0.7 * S)
    c = 0.1 * S + 1 / (0.7 * S)
    return TransferMatrix([[a + b, b], [b, c + b]])


def _same_over_q(a: TransferMatrix, b: TransferMatrix) -> bool:
    from hil.stability.rational import _to_rf

    return all(x.n == y.n and x.d == y.d for ra, rb in zip(_to_rf(a.entries), _to_rf(b.entries), strict=True)
               for x, y in zip(ra, rb, strict=True))


@pytest.mark.parametrize("kind", ["hybrid", "inverse_hybrid", "admittance"])
def test_conversion_keeps_the_network_exact_for_the_verdict(kind):
    from hil.stability.criteria import check

    z = _ladder()
    assert str(check(z, "passivity").verdict) == "stable"
    conv = z.to(kind)
    assert all(e.exact_given for row in conv.entries for e in row if not e.is_zero)
    # independent: the exact conversion back gives z itself, entry for entry over Q(s)
    assert _same_over_q(conv.to("impedance"), z)
    for crit in ("passivity", "llewellyn", "absolute_stability"):
        assert str(check(conv, crit).verdict) == "stable", (kind, crit)
        assert str(check(conv, crit, margins=False).verdict) == "stable"
    # the same entries rounded to their float coefficients are another network, which is not
    # passive (margin about -1e-17: the rounding moved a lossless pole or a touching point);
    # the old conversion returned exactly that one
    rounded = TransferMatrix([[Rational(e.num, e.den) for e in row] for row in conv.entries], kind, conv.port_dofs)
    assert not _same_over_q(rounded, conv)
    assert str(check(rounded, "passivity").verdict) == "potentially_unstable"


def test_exact_entries_survive_the_frequency_normalization():
    """s -> s/2^12 applied exactly to the exact hybrid matrix: the criteria normalize frequency by
    a power of two, and the normalized entries must still be the exact ones (same verdict)."""
    from flint import fmpq, fmpq_poly

    from hil.stability.criteria import _normalized, check

    def scale(p: fmpq_poly, e: int) -> fmpq_poly:
        return fmpq_poly([p[k] * fmpq(2) ** (-e * k) for k in range(p.degree() + 1)])

    h = _ladder().to("hybrid")
    ent = [[e if e.is_zero else Rational.of_exact(scale(e.exact[0], 12), scale(e.exact[1], 12)) for e in row]
           for row in h.entries]
    hs = TransferMatrix(ent, "hybrid", (1, 1))
    tmn, w0 = _normalized(hs)
    assert w0 != 1.0
    assert all(e.exact_given for row in tmn.entries for e in row if not e.is_zero)
    for crit in ("passivity", "llewellyn"):
        assert str(check(hs, crit).verdict) == "stable"
