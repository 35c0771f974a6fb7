"""Certification core: Monte Carlo probability with exact intervals, worst case over a credible
region against closed forms, design guidance, and the verdict policy (ERROR kept apart)."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from hil.certify.statistics import (
    Decision,
    Policy,
    decide,
    max_safe_parameter,
    probability_of_stability,
    worst_case_margin,
)


def test_clopper_pearson_all_stable_closed_form():
    p, lo, hi = probability_of_stability(np.ones(100, bool), 0.95)
    assert p == 1.0 and hi == 1.0
    assert lo == pytest.approx(0.025 ** (1 / 100), rel=1e-9)  # exact bound when k = n


def test_interval_coverage_is_at_least_nominal():
    rng = np.random.default_rng(3)
    p_true, n, reps = 0.97, 200, 400
    hits = 0
    for _ in range(reps):
        _, lo, hi = probability_of_stability(rng.random(n) < p_true, 0.95)
        hits += lo <= p_true <= hi
    assert hits / reps >= 0.93  # Clopper-Pearson is conservative (≥ 95 %); 0.93 allows MC noise at 400 reps


def test_worst_case_margin_linear_closed_form():
    rng = np.random.default_rng(0)
    mu = np.array([1.0, -2.0, 0.5])
    A = rng.normal(size=(3, 3))
    cov = A @ A.T + 0.1 * np.eye(3)
    X = rng.multivariate_normal(mu, cov, size=4000)
    a = np.array([0.3, -1.2, 2.0])
    b = 5.0
    val, theta = worst_case_margin(lambda T: T @ a + b, X, credible=0.9)
    # exact minimum over the ellipsoid of the sample mean/covariance
    m, C = X.mean(axis=0), np.cov(X, rowvar=False)
    exact = a @ m + b - math.sqrt(chi2.ppf(0.9, 3)) * math.sqrt(a @ C @ a)
    assert val == pytest.approx(exact, rel=1e-4)
    d = theta - m
    assert d @ np.linalg.solve(C, d) <= chi2.ppf(0.9, 3) * (1 + 1e-6)  # the minimizer lies in the region


def test_max_safe_parameter_bisection():
    rng = np.random.default_rng(1)
    kmax_draws = rng.normal(400.0, 5.0, size=2000)  # each draw is stable while k22 < its k_max

    def stable(x):
        return kmax_draws > x

    x, p = max_safe_parameter(stable, 300.0, 500.0, required=0.9, confidence=0.95)
    assert probability_of_stability(stable(x), 0.95)[1] >= 0.9
    assert p >= 0.9
    assert probability_of_stability(stable(x * 1.001), 0.95)[1] < 0.9
    assert x < np.quantile(kmax_draws, 0.1)  # conservative with respect to the point estimate


_ALL = np.ones(500, bool)


@pytest.mark.parametrize("args,kw,expected", [
    (("stable", _ALL), {"beta": 3.0}, Decision.GO),
    (("stable", np.r_[np.ones(480, bool), np.zeros(20, bool)]), {"beta": 3.0}, Decision.MARGINAL),  # lower<.95
    (("stable", np.r_[np.ones(400, bool), np.zeros(100, bool)]), {"beta": 3.0}, Decision.NO_GO),  # CI below .95
    (("stable", np.r_[np.ones(470, bool), np.zeros(30, bool)]), {"beta": 3.0}, Decision.MARGINAL),  # straddles
    (("potentially_unstable", _ALL), {"beta": 3.0}, Decision.NO_GO),
    (("stable", _ALL), {"beta": 3.0, "converged": False}, Decision.MARGINAL),
    (("marginal", _ALL), {"beta": 3.0}, Decision.MARGINAL),
    (("stable", _ALL), {"beta": 3.0, "nominal_weak": True}, Decision.GO),  # equality is allowed by ≥ 0
    (("stable", _ALL), {"beta": 1.6}, Decision.MARGINAL),  # β below Φ⁻¹(0.95) = 1.645
    (("stable", _ALL), {}, Decision.MARGINAL),  # β required but missing
    (("stable", _ALL), {"require_beta": False}, Decision.GO),
    (("stable", _ALL), {"beta": float("nan")}, Decision.ERROR),
    (("stable", _ALL), {"beta": 3.0, "headroom_nominal": 0.3, "headroom_posterior": 0.2}, Decision.GO),
    (("stable", _ALL), {"beta": 3.0, "headroom_nominal": 0.3, "headroom_posterior": 0.0}, Decision.MARGINAL),
    (("stable", _ALL), {"beta": 3.0, "headroom_nominal": -0.01, "headroom_posterior": -0.02}, Decision.NO_GO),
    (("stable", _ALL), {"beta": 3.0, "headroom_nominal": float("inf")}, Decision.ERROR),
    # the rare-event interval replaces the Monte Carlo one: 500 stable draws cannot certify 1 - 1e-6
    (("stable", _ALL), {"beta": 6.0, "policy": Policy(1 - 1e-6, 0.95)}, Decision.MARGINAL),
    (("stable", _ALL), {"beta": 6.0, "policy": Policy(1 - 1e-6, 0.95), "rare_event": (1 - 2e-7, 1 - 1e-8)},
     Decision.GO),
    (("stable", _ALL), {"beta": 6.0, "policy": Policy(1 - 1e-6, 0.95), "rare_event": (1 - 5e-6, 1 - 2e-6)},
     Decision.NO_GO),
    (("stable", _ALL), {"beta": 4.0, "policy": Policy(1 - 1e-6, 0.95), "rare_event": (1 - 2e-7, 1 - 1e-8)},
     Decision.MARGINAL),  # β = 4 < Φ⁻¹(1 - 1e-6) = 4.75
    ((None, _ALL), {}, Decision.ERROR),
    (("stable", np.array([])), {}, Decision.ERROR),
    (("stable", np.array([1.0, np.nan])), {}, Decision.ERROR),
    (("stable", _ALL), {"beta": 3.0, "evidence_errors": ["identification failed"]}, Decision.ERROR),
])
def test_policy(args, kw, expected):
    kw = {"policy": Policy(0.95, 0.95), **kw}
    d, reasons, _ = decide(*args, **kw)
    assert d == expected and reasons


def test_go_rule_ignores_the_frequency_margin():
    """Defect 6: the GO rule does not take the nominal margin at all (its inputs are the verdict,
    the P(stable) bound, β and the headroom)."""
    import inspect

    assert "margin" not in inspect.signature(decide).parameters


def test_beta_required_is_the_normal_quantile():
    from scipy.stats import norm

    from hil.certify.statistics import beta_required

    for p in (0.9, 0.95, 0.999, 1 - 1e-6):
        assert norm.cdf(beta_required(p)) == pytest.approx(p, rel=1e-12)
    assert beta_required(0.95) == pytest.approx(1.6448536269514722, rel=1e-12)


def test_policy_validates_levels():
    with pytest.raises(Exception, match="required_probability"):
        Policy(required_probability=1.5)


def _ar1_chains(rng, phi, n_steps, n_walkers, reps=1):
    """Stationary AR(1) chains θ_t = φ θ_{t-1} + √(1-φ²) ε_t (unit variance), shape
    (reps, n_steps, n_walkers); integrated autocorrelation time τ = (1 + φ)/(1 - φ)."""
    x = np.empty((reps, n_steps, n_walkers))
    x[:, 0] = rng.standard_normal((reps, n_walkers))
    e = rng.standard_normal((reps, n_steps, n_walkers)) * math.sqrt(1 - phi * phi)
    for t in range(1, n_steps):
        x[:, t] = phi * x[:, t - 1] + e[:, t]
    return x


def _width(stable):
    _, lo, hi = probability_of_stability(stable, 0.95)
    return hi - lo


def test_thinned_ar1_chain_interval_as_wide_as_for_n_over_tau_independent_draws():
    """Defect 8: on a strongly autocorrelated chain (AR(1), τ = 39) the Clopper-Pearson interval on
    the thinned chain is as wide as the one for n/τ independent draws, not √τ times narrower."""
    from scipy.stats import norm

    from hil.certify.statistics import autocorrelation_time, thin_indices

    rng = np.random.default_rng(11)
    phi = 0.95
    tau_true = (1 + phi) / (1 - phi)
    n_steps, n_walkers = 8000, 8
    chain = _ar1_chains(rng, phi, n_steps, n_walkers)[0]
    tau = autocorrelation_time(chain)
    assert tau == pytest.approx(tau_true, rel=0.2)
    stable = (chain < 1.0).ravel()  # row-major: step * n_walkers + walker, emcee's flat order
    idx = thin_indices(n_steps, n_walkers, tau)
    n_eff = n_steps * n_walkers / tau_true
    assert idx.size == pytest.approx(n_eff, rel=0.2)
    p_true = norm.cdf(1.0)
    ref = _width(rng.random(int(n_eff)) < p_true)  # n/τ independent draws
    assert _width(stable[idx]) == pytest.approx(ref, rel=0.15)
    assert _width(stable) < 0.4 * ref  # the unthinned chain claims far too much precision


def test_thinned_chain_interval_covers_the_true_probability():
    """Coverage of the interval over 150 independent AR(1) ensembles: ≥ 95 % nominal, ≥ 0.9
    allowing for Monte Carlo noise, where the unthinned interval covers far less often."""
    from scipy.stats import norm

    from hil.certify.statistics import autocorrelation_time, thin_indices

    rng = np.random.default_rng(5)
    phi, n_steps, n_walkers, reps = 0.9, 2000, 8, 150
    chains = _ar1_chains(rng, phi, n_steps, n_walkers, reps)
    p_true = norm.cdf(1.5)
    hit_thin = hit_raw = 0
    for c in chains:
        s = (c < 1.5).ravel()
        idx = thin_indices(n_steps, n_walkers, autocorrelation_time(c))
        _, lo, hi = probability_of_stability(s[idx], 0.95)
        hit_thin += lo <= p_true <= hi
        _, lo, hi = probability_of_stability(s, 0.95)
        hit_raw += lo <= p_true <= hi
    assert hit_thin / reps >= 0.9
    assert hit_raw / reps < 0.8


def test_thin_indices_layout():
    from hil.certify.statistics import thin_indices

    idx = thin_indices(10, 3, 3.2)  # every 4th step of each of 3 walkers: steps 0, 4, 8
    assert idx.tolist() == [0, 1, 2, 12, 13, 14, 24, 25, 26]
    assert len(set(idx.tolist())) == idx.size  # never a duplicate
