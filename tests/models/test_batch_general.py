"""The general robust path (hil.models.batch_general, used by hil.certify.evaluation._robust_eval for models
without a closed-form batch): its per-draw stability equals the exact criterion's on every draw,
its screen rejects only real violations, and its coefficient map is refused when not affine."""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest

from hil.certify.evaluation import _check, _robust_eval, exactly_stable
from hil.certify.pipeline import build_network
from hil.models import get_model
from hil.models.batch_general import coefficient_map, screen, screened_stability
from hil.stability.rational import Rational, TransferMatrix


def _exact(model: str, criterion: str, params: Mapping[str, Any], draws: Mapping[str, np.ndarray]) -> np.ndarray:
    """The reference: build each draw's network and run the exact criterion (no screen)."""
    n = len(next(iter(draws.values())))
    return np.array([exactly_stable(model, criterion, {**params, **{k: float(v[i]) for k, v in draws.items()}})
                     for i in range(n)], dtype=bool)


def _params(model: str, drawn: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in get_model(model).defaults.items() if v is not None and k not in drawn}


def _mbk_draws(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    # Re Z = B is PSD iff B_01² ≤ B_00 B_11 (= 48 at the centre): B_01 spread across the boundary,
    # plus draws placed on it (B_01 = ±√(B_00 B_11) (1 ± 1e-9)) where only the exact path decides
    b00 = 8.0 * (1 + 0.05 * rng.standard_normal(n))
    b11 = 6.0 * (1 + 0.05 * rng.standard_normal(n))
    b01 = -2.0 + 3.5 * rng.standard_normal(n)
    k = n // 10
    edge = np.sqrt(b00[:k] * b11[:k]) * rng.choice([-1.0, 1.0], k) * (1 + 1e-9 * rng.choice([-1.0, 1.0], k))
    b01[:k] = edge
    m01 = 0.2 + 0.3 * rng.standard_normal(n)  # M PSD iff M_01² ≤ 0.6: rarely violated (the infinity condition)
    return {"B_00": b00, "B_11": b11, "B_01": b01, "M_01": m01}


def test_mbk_screened_equals_exact_on_every_draw() -> None:
    rng = np.random.default_rng(11)
    draws = _mbk_draws(rng, 150)
    params = _params("mbk_impedance", draws)
    res = screened_stability("mbk_impedance", "positive_real", params, draws,
                             lambda q: str(_check(build_network("mbk_impedance", q), "positive_real",
                                                  margins=False).verdict) == "stable")
    ref = _exact("mbk_impedance", "positive_real", params, draws)
    assert np.array_equal(res["stable"], ref)
    # the screen did work (rejections), only on draws the exact path calls not stable, and both
    # outcomes occur among the draws
    assert res["rejected"].sum() >= 10
    assert not np.any(res["rejected"] & ref)
    assert 0 < ref.sum() < ref.size


def test_bilateral_1dof_llewellyn_through_robust_eval() -> None:
    rng = np.random.default_rng(5)
    n = 300
    # η ≥ 1 fails for small dampings relative to the gains: b_m, b_s spread across zero
    draws = {"b_m": 0.01 + 0.01 * rng.standard_normal(n), "b_s": 0.01 + 0.01 * rng.standard_normal(n),
             "k_vm": 0.1 * (1 + 0.2 * rng.standard_normal(n))}
    draws["b_m"][:20] = 0.0  # an undamped master (Re z11 = k_vm only)
    params = _params("bilateral_1dof", draws)
    stable, proxy, method, band, _cmap = _robust_eval("bilateral_1dof", "llewellyn", params, draws)
    ref = _exact("bilateral_1dof", "llewellyn", params, draws)
    assert np.array_equal(stable, ref)
    assert 0 < ref.sum() < n
    assert proxy is None and band is None
    assert method == "general exact criterion per draw"


def test_bilateral_2dof_absolute_stability_equals_exact() -> None:
    rng = np.random.default_rng(2)
    n = 40
    # gain set A1 with k_vyz spread (set B has k_vyz 300 with k_vzz 250: potentially unstable)
    draws = {"k_vyz": 250.0 * (1 + 0.2 * rng.standard_normal(n)), "m_yy": 2.0 * (1 + 0.1 * rng.standard_normal(n)),
             "b_yy": 0.5 * (1 + 0.2 * rng.standard_normal(n))}
    params = _params("bilateral_2dof", draws)
    stable, _, _, _, _ = _robust_eval("bilateral_2dof", "absolute_stability", params, draws)
    ref = _exact("bilateral_2dof", "absolute_stability", params, draws)
    assert np.array_equal(stable, ref)
    assert 0 < ref.sum() < n


def test_coefficient_map_predicts_a_fresh_build() -> None:
    rng = np.random.default_rng(3)
    draws = {"k_vm1": 64.0 * (1 + 0.1 * rng.standard_normal(40)), "m_s": 1.5 * (1 + 0.1 * rng.standard_normal(40))}
    names = sorted(draws)
    X = np.column_stack([draws[k] for k in names])
    m = get_model("mcet_trilateral")
    cmap = coefficient_map(lambda th: m.network(th), names, X)
    assert cmap is not None
    th = np.array([71.3, 1.234])  # a point that is neither a probe nor a check point
    tm = m.network(dict(zip(names, th.tolist(), strict=True)))
    num, den = cmap.coefficients(th[None, :])
    for i in range(tm.n):
        for j in range(tm.n):
            e = tm.entries[i][j]
            # affine map from float builds: agreement to round-off of the coefficients' magnitude
            np.testing.assert_allclose(num[0, i, j, :e.num.size], e.num, rtol=0, atol=1e-12 * max(1, abs(e.num).max()))
            np.testing.assert_allclose(den[0, i, j, :e.den.size], e.den, rtol=0, atol=1e-12 * max(1, abs(e.den).max()))
            assert not np.any(num[0, i, j, e.num.size:]) or np.allclose(num[0, i, j, e.num.size:], 0, atol=1e-12)


def test_non_affine_map_is_refused() -> None:
    def build(th: Mapping[str, float]) -> TransferMatrix:
        a = th["a"]
        return TransferMatrix([[Rational.from_desc([a * a, 1.0], [1.0, 0.0])]], "impedance", (1,))

    X = np.linspace(1.0, 3.0, 20)[:, None]
    assert coefficient_map(build, ["a"], X) is None



def _mbk_screen(draws: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, dict]:
    """(rejected, screen margin, fixed parameters) of the m-b-k impedance's float screen over ``draws``."""
    names = sorted(draws)
    X = np.column_stack([draws[k] for k in names])
    params = _params("mbk_impedance", draws)
    m = get_model("mbk_impedance")
    cmap = coefficient_map(lambda th: m.network({**params, **th}), names, X)
    assert cmap is not None
    rejected, margin = screen(cmap, X, "positive_real")
    return rejected, margin, params

@pytest.mark.parametrize("b00", [0.0, 1e-300])
def test_screen_never_rejects_touching(b00: float) -> None:
    # Re z_00 = B_00 = 0 (touching: the exact verdict is stable) or a denormal-small positive value
    rng = np.random.default_rng(0)
    n = 30
    draws = {"B_00": np.full(n, b00), "B_11": 6.0 * (1 + 0.1 * rng.standard_normal(n)), "B_01": np.zeros(n)}
    rejected, _, params = _mbk_screen(draws)
    assert not rejected.any()
    assert _exact("mbk_impedance", "positive_real", params, draws).all()


def test_screen_rejects_a_clear_violation() -> None:
    # B_00 = -0.5: Re z_00(jω) = -0.5 at every ω, far beyond round-off: rejected on every draw
    rng = np.random.default_rng(1)
    n = 30
    draws = {"B_00": np.full(n, -0.5), "B_11": 6.0 * (1 + 0.1 * rng.standard_normal(n))}
    rejected, margin, params = _mbk_screen(draws)
    assert rejected.all()
    assert np.all(margin < 0)
    assert not _exact("mbk_impedance", "positive_real", params, draws).any()


def test_screen_rejects_an_indefinite_mass_matrix_at_infinity() -> None:
    # Re Z(jω) = B is PSD, but the residue at s = ∞ (the mass matrix) has M_00 M_11 − M_01² =
    # 0.6 − 0.81 < 0: not positive real (a condition the frequency grid cannot see); M_01 = 0.5 is PSD
    n = 30
    m01 = np.where(np.arange(n) % 2 == 0, 0.9, 0.5) * (1 + 1e-3 * np.arange(n) / n)
    draws = {"M_01": m01, "B_00": np.full(n, 8.0) + 1e-3 * np.arange(n)}
    rejected, _, params = _mbk_screen(draws)
    ref = _exact("mbk_impedance", "positive_real", params, draws)
    assert np.array_equal(rejected, m01 > 0.8)
    assert np.array_equal(ref, m01 < 0.8)


# ------------------------------------------------------------------------------------------
# vectorized acceptance (hil.models.batch_accept): accepted draws are the exact path's stable ones

from hil.models.batch_accept import Poly, accept_reject, certainly_negative, certify_positive, hurwitz  # noqa: E402


def _screened_vs_exact(model: str, params: Mapping[str, Any], draws: Mapping[str, np.ndarray]
                       ) -> tuple[dict[str, Any], np.ndarray]:
    criterion = get_model(model).criterion
    res = screened_stability(model, criterion, params, draws,
                             lambda q: exactly_stable(model, criterion, q))
    return res, _exact(model, criterion, params, draws)


def _check_agreement(res: dict[str, Any], ref: np.ndarray) -> None:
    assert np.array_equal(res["stable"], ref)
    # every accepted draw is stable exactly, every rejected one is not
    assert not np.any(res["accepted"] & ~ref)
    assert not np.any(res["rejected"] & ref)


def test_mcet_3port_accepts_the_equality_manifold_and_agrees() -> None:
    # MCET at Table I: η ≡ 0 identically (weakly stable, the exact path's "equality"); drawing the
    # masses keeps it so and the screen certifies it exactly (η's inputs do not depend on them)
    rng = np.random.default_rng(7)
    n = 30
    draws = {"m_m1": 0.7 * (1 + 0.1 * rng.standard_normal(n)), "m_s": 1.5 * (1 + 0.1 * rng.standard_normal(n))}
    params = _params("mcet_trilateral", draws)
    res, ref = _screened_vs_exact("mcet_trilateral", params, draws)
    _check_agreement(res, ref)
    assert ref.all() and res["accepted"].all()
    # drawing k_vm1 breaks η ≡ 0 (potentially unstable) except on draws exactly at 64, and draws
    # within 1e-12 of it: the float bounds decide none of those, the exact path all of them
    draws["k_vm1"] = 64.0 * (1 + 0.05 * rng.standard_normal(n))
    draws["k_vm1"][:10] = 64.0
    draws["k_vm1"][10:16] = 64.0 * (1 + 1e-12 * rng.choice([-1.0, 1.0], 6))
    res, ref = _screened_vs_exact("mcet_trilateral", params, draws)
    _check_agreement(res, ref)
    assert ref[:10].all() and not ref[10:].any()


def test_bilateral_2dof_4x4_agrees_with_boundary_draws() -> None:
    # set A1 with k_vyz spread across its stability limit and draws placed at the limit
    # (1 ± 1e-10; the limit 300.225 found by bisection on the exact path, the robot dampings shift
    # it from √(k_vyy k_vzz) = 300): the screen decides the clear draws, the exact path the rest
    rng = np.random.default_rng(4)
    n = 50
    kv = 250.0 * (1 + 0.15 * rng.standard_normal(n))
    kv[:8] = 300.225 * (1 + 1e-10 * rng.choice([-1.0, 1.0], 8))
    draws = {"k_vyz": kv, "m_yy": 2.0 * (1 + 0.1 * rng.standard_normal(n))}
    params = _params("bilateral_2dof", draws)
    res, ref = _screened_vs_exact("bilateral_2dof", params, draws)
    _check_agreement(res, ref)
    assert 0 < ref.sum() < n
    assert res["accepted"].sum() >= 0.5 * ref.sum()
    assert not res["accepted"][:8].any()


def test_sdea_through_the_general_path_agrees() -> None:
    # the SDEA hybrid two-port (passivity) without its closed form: every draw agrees; draws with
    # k22 beyond k22_max (408.04 N.m/rad) are not passive
    rng = np.random.default_rng(9)
    n = 24
    # plus draws at (1 ± 1e-6)·k22_max, where the binding condition's margin is ~1e-14 (VERDICTS.md)
    draws = {"k22": 360.0 * (1 + 0.15 * rng.standard_normal(n)), "M": 6.399e-4 * (1 + 0.05 * rng.standard_normal(n))}
    draws["k22"][:4] = 408.0448 * (1 + 1e-6 * np.array([-1.0, -1.0, 1.0, 1.0]))
    params = _params("sdea", draws)
    res, ref = _screened_vs_exact("sdea", params, draws)
    _check_agreement(res, ref)
    assert 0 < ref.sum() < n
    # the two-port Hermitian certificate (per-entry denominators) decides most clear draws
    assert res["accepted"][4:].sum() >= 0.5 * ref[4:].sum()
    assert not res["accepted"][:4].any()


def test_one_port_agrees_with_boundary_draws() -> None:
    # Z = (m s² + b s + k)/s: positive real iff b ≥ 0 (m, k ≥ 0): b spread across 0, some exactly 0
    # (touching: stable) and ±1e-15 (only the exact path decides)
    rng = np.random.default_rng(12)
    n = 60
    b = 0.5 * rng.standard_normal(n) + 0.3
    b[:4] = 0.0
    b[4:8] = 1e-15 * rng.choice([-1.0, 1.0], 4)
    draws = {"B_00": b, "M_00": 1.0 + 0.1 * rng.standard_normal(n)}
    params = {**_params("mbk_impedance", draws), "dof": 1}
    params = {k: v for k, v in params.items() if not k.endswith(("_01", "_11", "_10"))}
    res, ref = _screened_vs_exact("mbk_impedance", params, draws)
    _check_agreement(res, ref)
    assert res["accepted"].sum() >= 0.9 * ref[8:].sum()
    assert ref[:4].all()


@pytest.mark.parametrize("model,spec", [
    ("bilateral_1dof", {"b_m": (0.01, 0.02), "b_s": (0.01, 0.02), "k_vm": (0.1, 0.3)}),
    ("mbk_impedance", {"B_01": (-2.0, 4.0), "M_01": (0.2, 0.4), "K_01": (-2500.0, 3000.0)}),
    ("bilateral_2dof", {"k_vyz": (250.0, 60.0), "b_yy": (0.5, 0.5)}),
])
def test_accepted_draws_are_never_potentially_unstable_and_rejected_never_stable(
        model: str, spec: dict[str, tuple[float, float]]) -> None:
    # property: across wide posteriors (both sides of the boundary), a draw the screen accepts is
    # stable under the exact criterion
    # a seed per model that is the same in every process (str hash() is salted per interpreter:
    # it made this draw set, and whether it held a rejected draw, change from run to run)
    rng = np.random.default_rng(zlib.crc32(model.encode()))
    n = 40
    draws = {k: c + s * rng.standard_normal(n) for k, (c, s) in spec.items()}
    params = _params(model, draws)
    names = sorted(draws)
    X = np.column_stack([draws[k] for k in names])
    m = get_model(model)
    cmap = coefficient_map(lambda th: m.network({**params, **th}), names, X)
    assert cmap is not None
    acc, rej = accept_reject(cmap, X, m.criterion)
    ref = _exact(model, m.criterion, params, draws)
    assert not np.any(acc & ~ref)
    assert not np.any(rej & ref)  # and a draw it rejects is never stable
    assert acc.any() and rej.any()


def _exact_poly(c: np.ndarray) -> Poly:
    return Poly(np.asarray(c, float)[None, :], np.zeros((1, len(c))))


def test_certify_positive_and_hurwitz_against_roots() -> None:
    # random integer polynomials (exact inputs): a certified one has no root where it claims,
    # checked against numpy's roots (independent); and the certificates are not vacuous
    rng = np.random.default_rng(0)
    n_pos = n_hur = 0
    for _ in range(400):
        d = int(rng.integers(1, 7))
        c = rng.integers(-5, 9, d + 1).astype(float)
        c[-1] = abs(c[-1]) + 1
        r = np.roots(c[::-1])
        if certify_positive(_exact_poly(c))[0]:
            n_pos += 1
            assert not np.any((np.abs(r.imag) < 1e-9) & (r.real > 0))
            assert c[np.nonzero(c)[0][0]] > 0
        if hurwitz(_exact_poly(c))[0]:
            n_hur += 1
            assert np.all(r.real < 0)
    assert n_pos > 40 and n_hur > 20
    # Pólya: positive on (0, ∞) with a negative coefficient: x² − x + 1 (min 3/4 at x = 1/2) and
    # (x − 1)² + 0.3; (x − 1)² + 1e-4 would need m ≈ 4e4 > POLYA_MAX: left to the exact path
    assert certify_positive(_exact_poly(np.array([1.0, -1.0, 1.0])))[0]
    assert certify_positive(_exact_poly(np.array([1.3, -2.0, 1.0])))[0]
    assert not certify_positive(_exact_poly(np.array([1.0001, -2.0, 1.0])))[0]
    # a double root at x = 1 (touching) and a shallow negative band are never certified
    assert not certify_positive(_exact_poly(np.array([1.0, -2.0, 1.0])))[0]
    assert not certify_positive(_exact_poly(np.array([0.99, -2.0, 1.0])))[0]
    # certainly_negative: x² − 2x + 0.9 < 0 near x = 1; (x − 1)² ≥ 0 (touching) never
    assert certainly_negative(_exact_poly(np.array([0.9, -2.0, 1.0])))[0]
    assert not certainly_negative(_exact_poly(np.array([1.0, -2.0, 1.0])))[0]
    # s³ + s² + s + 1 has roots ±j (not strictly Hurwitz); s³ + 2s² + 2s + 1 is Hurwitz
    assert not hurwitz(_exact_poly(np.array([1.0, 1.0, 1.0, 1.0])))[0]
    assert hurwitz(_exact_poly(np.array([1.0, 2.0, 2.0, 1.0])))[0]


def test_interval_bound_contains_the_exact_value() -> None:
    # products of random float polynomials: the exact product (Fractions) lies within the bound,
    # and a product of small integers is exact (bound 0)
    from fractions import Fraction

    rng = np.random.default_rng(3)
    a = rng.standard_normal((5, 4)) * 10.0 ** rng.integers(-8, 8, (5, 4))
    b = rng.standard_normal((5, 3))
    p = Poly(a, np.zeros_like(a)) * Poly(b, np.zeros_like(b)) - Poly(a, np.zeros_like(a)).mulx()
    for r in range(5):
        for k in range(p.L):
            want = sum((Fraction(a[r, j]) * Fraction(b[r, k - j]) for j in range(4) if 0 <= k - j < 3), Fraction(0))
            want -= Fraction(a[r, k - 1]) if 1 <= k <= 4 else 0
            assert abs(Fraction(p.v[r, k]) - want) <= Fraction(p.e[r, k])
    q = _exact_poly(np.array([3.0, -2.0])) * _exact_poly(np.array([5.0, 7.0, 1.0]))
    assert np.all(q.e == 0) and q.v[0].tolist() == [15.0, 11.0, -11.0, -2.0]


@pytest.mark.parametrize("seed", range(4))
def test_random_one_ports_accept_and_reject_soundly(seed: int) -> None:
    # property over random one-ports Z = (a0 + a1 s + a2 s² + a3 s³)/(b0 + b1 s + b2 s²) (+ a pole
    # at 0 on odd seeds): every coefficient drawn around a random centre; the screen's accepted
    # draws are stable and its rejected ones not, against the exact criterion (hil.stability)
    from hil.stability.criteria import check

    rng = np.random.default_rng(100 + seed)
    centre = {f"a{k}": float(v) for k, v in enumerate(rng.uniform(0.2, 3.0, 4))}
    centre |= {f"b{k}": float(v) for k, v in enumerate(rng.uniform(0.5, 3.0, 3))}
    centre["a3"] *= 0.1
    pole0 = seed % 2 == 1

    def build(th: Mapping[str, float]) -> TransferMatrix:
        num = [th["a0"], th["a1"], th["a2"], th["a3"]]
        den = [th["b0"], th["b1"], th["b2"]]
        if pole0:
            den = [0.0, *den]
        return TransferMatrix([[Rational(np.array(num), np.array(den))]], "impedance", (1,))

    n = 80
    names = sorted(centre)
    X = np.column_stack([centre[k] * (1 + 0.6 * rng.standard_normal(n)) for k in names])
    cmap = coefficient_map(build, names, X)
    assert cmap is not None
    acc, rej = accept_reject(cmap, X, "positive_real")
    ref = np.array([str(check(build(dict(zip(names, X[i].tolist(), strict=True))), "positive_real",
                              margins=False).verdict) == "stable" for i in range(n)])
    assert not np.any(acc & ~ref)
    assert not np.any(rej & ref)
    assert (acc | rej).mean() > 0.5  # the screen decides most draws
