"""Property tests: passive mechanical networks, negative resistance, conversions, scaling."""

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from hil.errors import ConversionError
from hil.stability.criteria import absolute_stability, llewellyn, positive_real, two_port_passivity
from hil.stability.rational import Rational, S, TransferMatrix


def _psd(rng, n, rank=None, scale=1.0):
    A = rng.normal(size=(n, rank or n)) * scale
    return A @ A.T


def mbk_impedance(M, B, K, ports=None):
    """Impedance of a mass-damper-spring network with symmetric PSD M, B, K: Z = (M s² + B s + K)/s.
    Positive real by construction (Re Z = B ⪰ 0, residue K ⪰ 0 at s = 0)."""
    n = M.shape[0]
    rows = [[(M[i, j] * S**2 + B[i, j] * S + K[i, j]) / S for j in range(n)] for i in range(n)]
    return TransferMatrix(rows, "impedance", ports or (1,) * n)


@given(st.integers(0, 10_000), st.integers(1, 3))
@settings(max_examples=25, deadline=None)
def test_random_passive_networks_are_passive_and_absolutely_stable(seed, n):
    rng = np.random.default_rng(seed)
    M, B, K = _psd(rng, n) + 0.1 * np.eye(n), _psd(rng, n) + 0.05 * np.eye(n), _psd(rng, n)
    z = mbk_impedance(M, B, K)
    assert positive_real(z).verdict == "stable"
    if n >= 2:
        assert absolute_stability(z).verdict == "stable"


@given(st.integers(0, 10_000), st.integers(1, 3), st.floats(0.05, 2.0))
@settings(max_examples=25, deadline=None)
def test_added_negative_resistance_breaks_passivity(seed, n, extra):
    rng = np.random.default_rng(seed)
    M, B, K = _psd(rng, n) + 0.1 * np.eye(n), _psd(rng, n) + 0.05 * np.eye(n), _psd(rng, n)
    lam = np.linalg.eigvalsh(B)[0]
    Bneg = B - (lam + extra) * np.eye(n)  # now λ_min(B) = -extra < 0
    z = mbk_impedance(M, Bneg, K)
    assert positive_real(z).verdict == "potentially_unstable"
    if n >= 2:  # symmetric: passivity ⟺ absolute stability (Lemma 2 of paper 000)
        assert absolute_stability(z).verdict == "potentially_unstable"


def random_two_port(rng, active: bool) -> TransferMatrix:
    """A 1-DOF two-port z-matrix: masses on each port coupled through a spring-damper, with a
    non-reciprocal (controller-like) transfer term of random gain; `active` adds a negative damper."""
    m1, m2 = rng.uniform(0.1, 2, size=2)
    b1, b2, bc = rng.uniform(0.1, 2, size=3)
    kc = rng.uniform(1, 50)
    g = rng.uniform(0.0, 0.5)
    neg = rng.uniform(0.5, 2.0) if active else 0.0
    zc = (bc * S + kc) / S
    z11 = m1 * S + (b1 - neg * (b1 + bc)) + zc
    z22 = m2 * S + b2 + zc
    z12 = -zc * (1 + g)
    z21 = -zc * (1 - g)
    return TransferMatrix([[z11, z12], [z21, z22]], "impedance", (1, 1))


@given(st.integers(0, 10_000), st.booleans())
@settings(max_examples=20, deadline=None)
def test_verdict_invariant_under_immittance_conversion(seed, active):
    rng = np.random.default_rng(seed)
    z = random_two_port(rng, active)
    base_l = llewellyn(z).verdict
    base_p = two_port_passivity(z).verdict
    assume(base_l != "marginal" and base_p != "marginal")
    for kind in ("admittance", "hybrid", "inverse_hybrid"):
        try:
            other = z.to(kind)
        except ConversionError:
            continue
        assert llewellyn(other).verdict == base_l, kind
        assert two_port_passivity(other).verdict == base_p, kind


@given(st.integers(0, 10_000), st.booleans())
@settings(max_examples=20, deadline=None)
def test_llewellyn_and_theorem1_agree_for_one_dof_two_ports(seed, active):
    z = random_two_port(np.random.default_rng(seed), active)
    a, b = llewellyn(z), absolute_stability(z)
    assert a.verdict == b.verdict


def _scaled(tm: TransferMatrix, kappa: float, lam: float) -> TransferMatrix:
    """kappa·Z(s/lam): impedance scaled by kappa, frequencies by lam."""
    rows = []
    for row in tm.entries:
        out = []
        for e in row:
            num = kappa * e.num / lam ** np.arange(e.num.size)
            den = e.den / lam ** np.arange(e.den.size)
            out.append(Rational(num, den))
        rows.append(out)
    return TransferMatrix(rows, tm.kind, tm.port_dofs)


@given(st.integers(0, 10_000), st.booleans(), st.integers(-9, 9), st.integers(-9, 9))
@settings(max_examples=30, deadline=None)
def test_verdict_invariant_under_frequency_and_impedance_scaling(seed, active, ek, el):
    z = random_two_port(np.random.default_rng(seed), active)
    base = llewellyn(z)
    assume(base.verdict != "marginal")
    zs = _scaled(z, 10.0**ek, 10.0**el)
    r = llewellyn(zs)
    assert r.verdict == base.verdict
    # the frequency-domain margin is invariant under s -> a·s, Z -> b·Z (docs/VERDICTS.md); the
    # decimal scalings round the coefficients (1e-16 relative), the margin's minimization is to ~1e-8
    np.testing.assert_allclose(r.margin, base.margin, rtol=1e-5, atol=1e-12)


@given(st.integers(0, 10_000), st.integers(-9, 9), st.integers(-9, 9))
@settings(max_examples=20, deadline=None)
def test_passive_mbk_stays_passive_at_extreme_scales(seed, ek, el):
    rng = np.random.default_rng(seed)
    M, B, K = _psd(rng, 2) + 0.1 * np.eye(2), _psd(rng, 2) + 0.05 * np.eye(2), _psd(rng, 2)
    z = _scaled(mbk_impedance(M, B, K), 10.0**ek, 10.0**el)
    assert positive_real(z).verdict == "stable"
    zneg = _scaled(mbk_impedance(M, B - (np.linalg.eigvalsh(B)[0] + 0.5) * np.eye(2), K), 10.0**ek, 10.0**el)
    assert positive_real(zneg).verdict == "potentially_unstable"
