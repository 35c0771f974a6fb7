"""The vectorized SDEA passivity path agrees with the general exact criterion draw by draw."""

import numpy as np
import pytest

from hil.models.batch import sdea_passivity_batch
from hil.models.design import k22_max
from hil.models.sdea import SDEA_TABLE1, sdea_vsic
from hil.stability.criteria import two_port_passivity


def test_batch_matches_general_criterion_on_random_draws():
    rng = np.random.default_rng(42)
    n = 60
    draws = {k: SDEA_TABLE1[k] * np.exp(0.1 * rng.normal(size=n)) for k in ("K_f", "B_f", "M", "B", "I_f")}
    draws["k22"] = rng.uniform(250.0, 500.0, n)
    draws["b22"] = rng.uniform(0.05, 0.25, n)
    res = sdea_passivity_batch(draws)
    verdicts = [two_port_passivity(sdea_vsic({k: float(v[i]) for k, v in draws.items()})).verdict for i in range(n)]
    decided = [i for i, v in enumerate(verdicts) if v != "marginal"]
    assert len(decided) >= n - 2
    assert all(bool(res["passive"][i]) == (verdicts[i] == "stable") for i in decided)
    # both outcomes occur, so the agreement is not trivial
    assert 0 < res["passive"].sum() < n


def test_batch_boundary_is_the_design_limit():
    kmax = k22_max(0.17, 1.0, "passivity").k22_max
    res = sdea_passivity_batch({"k22": np.array([kmax * 0.999, kmax * 1.01]), "b22": np.array([0.17, 0.17])})
    assert res["passive"].tolist() == [True, False]


def test_b22_above_4Bf_gets_a_finite_margin_and_the_exact_verdict():
    """Defect 9: b22 > 4 B_f made t3 < 0 and the margin -inf, which sent every such draw through the
    exact path. The margin is now the exact infimum -1 of t(x)/|t|(x), decided without the exact
    path, and the verdict agrees with the general exact criterion."""
    rng = np.random.default_rng(7)
    n = 6
    draws = {"B_f": rng.uniform(0.02, 0.04, n), "b22": rng.uniform(0.17, 0.3, n),
             "k22": rng.uniform(100.0, 400.0, n)}
    assert np.all(draws["b22"] > 4 * draws["B_f"])
    res = sdea_passivity_batch(draws)
    assert np.all(np.isfinite(res["margin"])) and np.all(res["margin"] == -1.0)
    assert not res["exact_rechecked"].any()
    for i in range(n):
        r = two_port_passivity(sdea_vsic({**SDEA_TABLE1, **{k: float(v[i]) for k, v in draws.items()}}))
        assert r.verdict == "potentially_unstable" and r.margin < 0
        assert not res["passive"][i]


def test_b22_at_4Bf_is_rechecked_exactly():
    res = sdea_passivity_batch({"B_f": np.array([0.05]), "b22": np.array([0.2])})
    assert res["exact_rechecked"][0]


def test_critical_band_has_width_and_contains_the_worst_frequency():
    """The critical band at the default scene: where g = t/|t| is within 10 % (of 1 - g_min) of its
    minimum; positive width, contains the minimizer, and g at its edges equals the threshold
    (checked against a dense independent evaluation)."""
    from hil.models.batch import CRITICAL_BAND_FRACTION
    from hil.models.sdea import sdea_polynomials

    res = sdea_passivity_batch({"k22": np.array([300.0])}, band=True)
    lo, hi, w = res["band_lo"][0], res["band_hi"][0], res["worst_omega"][0]
    assert 0 < lo < w < hi and hi / lo > 1.2
    t0, t1, t2, t3 = (float(c) for c in sdea_polynomials(SDEA_TABLE1)["t"])
    om = np.geomspace(1.0, 1e6, 200001)
    x = om * om
    g = (((t3 * x + t2) * x + t1) * x + t0) / (((abs(t3) * x + abs(t2)) * x + abs(t1)) * x + abs(t0))
    gmin = g.min()
    assert om[np.argmin(g)] == pytest.approx(w, rel=0.03)
    thr = gmin + CRITICAL_BAND_FRACTION * (1 - gmin)
    inside = om[g <= thr]
    assert lo == pytest.approx(inside.min(), rel=5e-3) and hi == pytest.approx(inside.max(), rel=5e-3)


def test_band_only_when_asked():
    """The critical band is computed only when a caller asks for it (``band=True``): the default
    returns the same verdicts and margins without the band's keys (issue 26: callers that discard
    the band must not pay for it)."""
    rng = np.random.default_rng(7)
    draws = {k: SDEA_TABLE1[k] * np.exp(0.05 * rng.standard_normal(64)) for k in ("K_f", "B_f", "M", "B")}
    draws["k22"] = rng.uniform(300.0, 450.0, 64)
    plain = sdea_passivity_batch(draws)
    banded = sdea_passivity_batch(draws, band=True)
    assert not {"band_lo", "band_hi", "worst_omega"} & set(plain)
    assert {"band_lo", "band_hi", "worst_omega"} <= set(banded)
    np.testing.assert_array_equal(plain["passive"], banded["passive"])
    np.testing.assert_array_equal(plain["margin"], banded["margin"])
