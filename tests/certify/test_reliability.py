"""Certification metrics of issue 11: FORM β (exact on a linear limit state), importance sampling
against closed-form failure probabilities, worst ≤ nominal by construction, the k22 headroom's
sign property."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2, norm

from hil.certify.statistics import posterior_limit, probability_of_stability, worst_case_margin
from hil.stability.reliability import Standardization, form, importance_sampling


def _linear(a: np.ndarray, beta: float):
    a = a / np.linalg.norm(a)
    return a, (lambda U: np.atleast_2d(U) @ a < beta)


@pytest.mark.parametrize("d,beta", [(1, 2.0), (3, 1.645), (4, 5.2), (6, 3.0)])
def test_form_beta_exact_on_a_linear_limit_state(d, beta):
    """Closed form: for g(u) = β − aᵀu (‖a‖ = 1) the nearest failing point is β·a."""
    a, fn = _linear(np.random.default_rng(d).normal(size=d), beta)
    r = form(fn, d)
    assert not r.censored
    assert r.beta == pytest.approx(beta, rel=1e-7)  # 30 bisections of a 8/33-wide bracket: ~1e-10
    assert np.linalg.norm(r.design_point_u - beta * a) < 1e-5
    assert r.phi_beta == pytest.approx(norm.cdf(beta), rel=1e-7)


def test_form_on_curved_limit_states_against_closed_forms():
    # failure outside a ball of radius 3: β = 3
    assert form(lambda U: (U * U).sum(1) < 9.0, 4).beta == pytest.approx(3.0, rel=1e-6)
    # u1 + 0.3 Σ u_k² ≥ 3 fails: min ‖u‖² on the boundary at ρ² = 40/9, u1 = 5/3: β² = 25/9 + 40/9
    r = form(lambda U: U[:, 0] + 0.3 * (U[:, 1:] ** 2).sum(1) < 3.0, 3)
    assert r.beta == pytest.approx(math.sqrt(65 / 9), rel=1e-4)  # tangent-plane refinement to ~1e-5


def test_form_beta_is_negative_when_the_centre_is_not_stable():
    r = form(lambda U: U[:, 0] > 1.0, 2)  # centre fails; nearest stable point at u1 = 1
    assert r.beta == pytest.approx(-1.0, rel=1e-7)


def test_form_in_standardized_coordinates_of_correlated_draws():
    """θ ~ N(μ, Σ) with correlation: the limit cᵀθ < t is linear in u = L⁻¹(θ − μ) with
    β = (t − cᵀμ)/√(cᵀΣc), the closed form; P(stable) = Φ(β) sampled agrees."""
    rng = np.random.default_rng(5)
    mu = np.array([2.0, -1.0, 0.5])
    A = rng.normal(size=(3, 3))
    S = A @ A.T + 0.2 * np.eye(3)
    X = rng.multivariate_normal(mu, S, size=20000)
    c, t = np.array([1.0, 2.0, -0.5]), 3.0
    st = Standardization.from_draws(X)
    r = form(lambda U: st.to_theta(U) @ c < t, 3)
    m, C = X.mean(0), np.cov(X, rowvar=False)
    assert r.beta == pytest.approx((t - c @ m) / math.sqrt(c @ C @ c), rel=1e-6)
    _p, lo, hi = probability_of_stability(X @ c < t, 0.999)
    assert lo <= r.phi_beta <= hi  # the sampled P(stable) and Φ(β) agree within sampling error


def test_importance_sampling_matches_a_closed_form_rare_failure_probability():
    """Linear limit state, Gaussian input: P_f = Φ(−β) = 1.0e-7 at β = 5.199; plain Monte Carlo
    would need ~1e8 draws for 10 % precision, IS needs 4000."""
    beta = float(-norm.ppf(1e-7))
    _a, fn = _linear(np.array([1.0, -2.0, 0.5, 0.3]), beta)
    r = form(fn, 4)
    res = importance_sampling(fn, r.design_point_u, n=4000, confidence=0.95, seed=1)
    assert res.reliable and res.n_fail > 1000
    # relative standard error of IS with the optimal shift on a half-space is ~√(e^{β²}Φ(-2β)/Φ(-β)² − 1)/√n ≈ 2 %
    assert res.std_error / 1e-7 < 0.05
    assert res.lower <= 1e-7 <= res.upper
    assert abs(res.p_failure - 1e-7) < 4 * res.std_error


def test_importance_sampling_interval_coverage():
    """The normal-approximation interval covers the true P_f = Φ(−4) in ≥ 90 % of 200 repetitions
    (nominal 95 %; 90 % allows the binomial noise of 200 repetitions, sd 1.5 %)."""
    a, fn = _linear(np.array([0.6, 0.8]), 4.0)
    truth = float(norm.cdf(-4.0))
    hits = sum(importance_sampling(fn, 4.0 * a, n=400, confidence=0.95, seed=s).lower <= truth <=
               importance_sampling(fn, 4.0 * a, n=400, confidence=0.95, seed=s).upper for s in range(200))
    assert hits / 200 >= 0.90


def test_importance_sampling_refuses_a_failure_set_a_single_design_point_misses():
    """Failure outside a ball (closed form P_f = χ²_d survival at r² = 1.1e-3 for d = 3, r = 4):
    the mass of the failure set lies all around the sphere, far from one design point, so a few
    samples carry the weights; the estimator says so (reliable = False, interval [0, 1]) rather
    than certify the underestimate it makes (~4e-4)."""
    d, rad = 3, 4.0
    fn = lambda U: (U * U).sum(1) < rad * rad  # noqa: E731
    r = form(fn, d)
    assert r.beta == pytest.approx(rad, rel=1e-6)
    res = importance_sampling(fn, r.design_point_u, n=20000, seed=2)
    assert res.ess < 30 and not res.reliable
    assert res.lower == 0.0 and res.upper == 1.0
    assert chi2.sf(rad * rad, d) > res.p_failure  # the underestimate it refuses to certify


# ---------------------------------------------------------------------------------------------
# worst ≤ nominal by construction


def test_worst_case_never_exceeds_the_function_at_the_centre():
    """The centre is a candidate: for any margin function (here a non-smooth, non-convex one with
    its maximum at the centre) the worst case is ≤ its value at the centre, and equals it for a
    function constant on the region."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(400, 3)) * [1.0, 2.0, 0.5] + [1.0, 0.0, -1.0]
    centre = X.mean(axis=0)
    for fn in (lambda T: -np.abs(T - centre).sum(1), lambda T: np.sin(5 * T[:, 0]) * np.cos(3 * T[:, 1]),
               lambda T: np.where(T[:, 2] > 0, 1.0, 0.5)):
        val, _ = worst_case_margin(fn, X, centre=centre, n_starts=2, maxiter=3)
        assert val <= float(fn(centre[None, :])[0])
    val, _th = worst_case_margin(lambda T: np.full(T.shape[0], 0.25), X, centre=centre)
    assert val == 0.25


@pytest.mark.parametrize("k22", [300.0, 408.0, 408.04])
def test_sdea_worst_case_exact_margin_below_nominal(k22):
    """Defect 7 reproducer: with the exact criterion's margin (the nominal margin's function), the
    worst case over the credible region is ≤ the nominal margin at k22 = 300, 408.0, 408.04 (the old
    vectorized quantity read 0.685 > nominal at all three)."""
    from hil.certify.pipeline import _exact_margin_fn
    from hil.models.sdea import SDEA_TABLE1

    names = ["B", "B_f", "K_f", "M"]
    rng = np.random.default_rng(1)
    mu = np.array([SDEA_TABLE1[k] for k in names])
    X = mu * (1 + 1e-3 * rng.standard_normal((60, 4)))
    params = {**SDEA_TABLE1, "k22": k22}
    fn = _exact_margin_fn("sdea", "passivity", params, names)
    nominal = float(fn(mu[None, :])[0])
    from hil.models.sdea import sdea_vsic
    from hil.stability.criteria import check

    assert nominal == float(check(sdea_vsic({**params, **dict(zip(names, mu, strict=True))}), "passivity").margin)
    val, _ = worst_case_margin(fn, X, centre=mu, n_starts=2, maxiter=2, n_local=1)
    assert val <= nominal


# ---------------------------------------------------------------------------------------------
# parametric headroom


def test_k22_headroom_zero_at_the_limit_and_signed_by_the_exact_verdict():
    from hil.models.design import k22_headroom
    from hil.models.sdea import SDEA_TABLE1, sdea_vsic
    from hil.stability.criteria import check

    b22, alpha = SDEA_TABLE1["b22"], SDEA_TABLE1["alpha"]
    km, h = k22_headroom(300.0, b22, alpha, params=SDEA_TABLE1)
    assert h == pytest.approx(km / 300.0 - 1.0, rel=1e-15) and h > 0
    _km2, h0 = k22_headroom(km, b22, alpha, params=SDEA_TABLE1)
    assert abs(h0) < 1e-6  # zero at the boundary, up to the bisection's relative tolerance 1e-7
    for f in (0.5, 0.9, 0.999, 1.001, 1.1):
        k = km * f
        _, hk = k22_headroom(k, b22, alpha, params=SDEA_TABLE1)
        v = check(sdea_vsic(SDEA_TABLE1, k22=k), "passivity").verdict
        assert (hk > 0) == (v == "stable") and (hk < 0) == (v == "potentially_unstable"), (f, hk, v)
        assert hk == pytest.approx(1 / f - 1, rel=1e-5)  # k22_max is the same plant's: h = 1/f − 1


def test_posterior_limit_headroom_signs_and_zero():
    """Per-draw limits ~ N(400, 5): P(stable | x) = fraction of limits > x. The posterior limit x*
    is where the lower bound crosses 0.9; the headroom x*/x0 − 1 is > 0 for a passing x0, < 0 for
    a failing one, and ~0 at x0 = x*."""
    rng = np.random.default_rng(3)
    limits = 400 + 5 * rng.standard_normal(3000)

    def stable(x):
        return limits > x

    x_star, kind = posterior_limit(stable, 300.0, 0.9, 0.95)
    assert kind == "exact"
    lo_at = probability_of_stability(stable(x_star), 0.95)[1]
    assert lo_at >= 0.9 > probability_of_stability(stable(x_star * (1 + 1e-5)), 0.95)[1]
    assert x_star < np.quantile(limits, 0.1)  # conservative: below the point estimate of the 10 % quantile
    for x0 in (300.0, 380.0, 395.0, 420.0, 600.0):
        x, _ = posterior_limit(stable, x0, 0.9, 0.95)
        h = x / x0 - 1
        assert x == pytest.approx(x_star, rel=1e-5)
        passes = probability_of_stability(stable(x0), 0.95)[1] >= 0.9
        assert (h > 0) == passes and (h < 0) == (not passes)
    x, _ = posterior_limit(stable, x_star, 0.9, 0.95)
    assert abs(x / x_star - 1) < 1e-5


# ---------------------------------------------------------------------------------------------
# the pipeline's reliability stage on the SDEA (vectorized verdicts)


def test_sdea_rare_event_path_agrees_with_plain_monte_carlo_on_the_same_gaussian():
    """A 1 %-wide Gaussian posterior around Table I at k22 = 390: the requirement 1 − 1e-6 cannot be
    reached by 2000 draws, so the stage runs importance sampling around the FORM design point; its
    P_f agrees with plain Monte Carlo on 4e5 draws of the same N(μ, Σ) (an independent estimate)
    within 4 combined standard errors, and Φ(−β) is within 30 % of it (FORM is first order)."""
    from hil.certify.pipeline import _reliability_stage
    from hil.certify.statistics import Policy
    from hil.models.batch import sdea_passivity_batch
    from hil.models.sdea import SDEA_TABLE1

    names = ["B", "B_f", "K_f", "M"]
    rng = np.random.default_rng(0)
    mu = np.array([SDEA_TABLE1[k] for k in names])
    X = mu * (1 + 0.01 * rng.standard_normal((2000, 4)))
    params = {**SDEA_TABLE1, "k22": 390.0}
    stable = sdea_passivity_batch(dict(zip(names, X.T, strict=True)), fixed=params)["passive"]
    rel, _fr, rare = _reliability_stage("sdea", "passivity", params, names, X, X.mean(0), stable,
                                        Policy(1 - 1e-6, 0.95, 0.9), True, 0, None)
    assert rare is not None and rare.reliable and rel.verified is True
    st = Standardization(X.mean(0), np.linalg.cholesky(np.cov(X, rowvar=False)))
    U = np.random.default_rng(9).standard_normal((400_000, 4))
    T = st.to_theta(U)
    fail = ~sdea_passivity_batch(dict(zip(names, T.T, strict=True)), fixed=params, band=False)["passive"]
    p_mc = fail.mean()
    se_mc = math.sqrt(p_mc * (1 - p_mc) / fail.size)
    assert abs(rare.p_failure - p_mc) < 4 * math.hypot(se_mc, rare.std_error), (rare.p_failure, p_mc)
    assert norm.cdf(-rel.beta) == pytest.approx(p_mc, rel=0.3)
