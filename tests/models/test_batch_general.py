"""The general robust path (hil.models.batch_general, used by hil.certify.pipeline._robust_eval for models
without a closed-form batch): its per-draw stability equals the exact criterion's on every draw,
its screen rejects only real violations, and its coefficient map is refused when not affine."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest

from hil.certify.pipeline import _check, _robust_eval, build_network, exactly_stable
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
    stable, proxy, method, band = _robust_eval("bilateral_1dof", "llewellyn", params, draws)
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
    stable, _, _, _ = _robust_eval("bilateral_2dof", "absolute_stability", params, draws)
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


@pytest.mark.parametrize("b00", [0.0, 1e-300])
def test_screen_never_rejects_touching(b00: float) -> None:
    # Re z_00 = B_00 = 0 (touching: the exact verdict is stable) or a denormal-small positive value
    rng = np.random.default_rng(0)
    n = 30
    draws = {"B_00": np.full(n, b00), "B_11": 6.0 * (1 + 0.1 * rng.standard_normal(n)), "B_01": np.zeros(n)}
    names = sorted(draws)
    X = np.column_stack([draws[k] for k in names])
    params = _params("mbk_impedance", draws)
    m = get_model("mbk_impedance")
    cmap = coefficient_map(lambda th: m.network({**params, **th}), names, X)
    assert cmap is not None
    rejected, _ = screen(cmap, X, "positive_real")
    assert not rejected.any()
    assert _exact("mbk_impedance", "positive_real", params, draws).all()


def test_screen_rejects_a_clear_violation() -> None:
    # B_00 = -0.5: Re z_00(jω) = -0.5 at every ω, far beyond round-off: rejected on every draw
    rng = np.random.default_rng(1)
    n = 30
    draws = {"B_00": np.full(n, -0.5), "B_11": 6.0 * (1 + 0.1 * rng.standard_normal(n))}
    names = sorted(draws)
    X = np.column_stack([draws[k] for k in names])
    params = _params("mbk_impedance", draws)
    m = get_model("mbk_impedance")
    cmap = coefficient_map(lambda th: m.network({**params, **th}), names, X)
    assert cmap is not None
    rejected, margin = screen(cmap, X, "positive_real")
    assert rejected.all()
    assert np.all(margin < 0)
    assert not _exact("mbk_impedance", "positive_real", params, draws).any()


def test_screen_rejects_an_indefinite_mass_matrix_at_infinity() -> None:
    # Re Z(jω) = B is PSD, but the residue at s = ∞ (the mass matrix) has M_00 M_11 − M_01² =
    # 0.6 − 0.81 < 0: not positive real (a condition the frequency grid cannot see); M_01 = 0.5 is PSD
    n = 30
    m01 = np.where(np.arange(n) % 2 == 0, 0.9, 0.5) * (1 + 1e-3 * np.arange(n) / n)
    draws = {"M_01": m01, "B_00": np.full(n, 8.0) + 1e-3 * np.arange(n)}
    names = sorted(draws)
    X = np.column_stack([draws[k] for k in names])
    params = _params("mbk_impedance", draws)
    m = get_model("mbk_impedance")
    cmap = coefficient_map(lambda th: m.network({**params, **th}), names, X)
    assert cmap is not None
    rejected, _ = screen(cmap, X, "positive_real")
    ref = _exact("mbk_impedance", "positive_real", params, draws)
    assert np.array_equal(rejected, m01 > 0.8)
    assert np.array_equal(ref, m01 < 0.8)
