"""Certification core: Monte Carlo probability with exact intervals, worst case over a credible
region against closed forms, design guidance, and the verdict policy (ERROR kept apart)."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from hil.certify import Decision, Policy, decide, max_safe_parameter, probability_of_stability, worst_case_margin


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


@pytest.mark.parametrize("args,kw,expected", [
    (("stable", 0.1, np.ones(500, bool)), {}, Decision.GO),
    (("stable", 0.1, np.r_[np.ones(480, bool), np.zeros(20, bool)]), {}, Decision.MARGINAL),  # p=.96, lower<.95
    (("stable", 0.1, np.r_[np.ones(400, bool), np.zeros(100, bool)]), {}, Decision.NO_GO),  # CI below .95
    (("stable", 0.1, np.r_[np.ones(470, bool), np.zeros(30, bool)]), {}, Decision.MARGINAL),  # p=.94, CI straddles
    (("potentially_unstable", -0.1, np.ones(500, bool)), {}, Decision.NO_GO),
    (("stable", 0.1, np.ones(500, bool)), {"converged": False}, Decision.MARGINAL),
    (("marginal", 0.0, np.ones(500, bool)), {}, Decision.MARGINAL),
    (("stable", float("nan"), np.ones(500, bool)), {}, Decision.ERROR),
    (("stable", 0.1, np.array([])), {}, Decision.ERROR),
    (("stable", 0.1, np.array([1.0, np.nan])), {}, Decision.ERROR),
    (("stable", 0.1, np.ones(500, bool)), {"evidence_errors": ["identification failed"]}, Decision.ERROR),
])
def test_policy(args, kw, expected):
    d, reasons, _ = decide(*args, policy=Policy(0.95, 0.95), **kw)
    assert d == expected and reasons


def test_policy_validates_levels():
    with pytest.raises(Exception, match="required_probability"):
        Policy(required_probability=1.5)
