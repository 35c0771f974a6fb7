"""Issue 11, "the SDEA's margins go to zero as k22 approaches k22_max and are monotone in k22":
the reliability index β (FORM, hil.stability.reliability) on the SDEA. With k22 the one uncertain
parameter, k22 ~ N(k22_0, σ²), the network stops being passive exactly at k22 = k22_max (decided
on the same exact polynomials), so the closed form is β = (k22_max - k22_0)/σ."""

import itertools

import numpy as np
import pytest

from hil.models.batch import sdea_passivity_batch
from hil.models.design import k22_max
from hil.models.sdea import SDEA_TABLE1
from hil.stability.reliability import form


def test_sdea_beta_is_the_standardized_distance_to_k22_max_and_tends_to_zero():
    kmax = k22_max(SDEA_TABLE1["b22"], SDEA_TABLE1["alpha"], params=SDEA_TABLE1).k22_max
    sigma = 10.0
    betas = []
    for f in (0.85, 0.95, 0.99, 0.999):
        k0 = f * kmax

        def stable(U: np.ndarray, k0: float = k0) -> np.ndarray:
            return sdea_passivity_batch({"k22": k0 + sigma * U[:, 0]}, band=False)["passive"]

        r = form(stable, 1, n_random=0)
        assert not r.censored
        # closed form; tolerance: k22_max's bisection (relative 1e-7, design.py) and FORM's own
        # bisection of the crossing (33-point grid on 8σ, then 30 halvings: < 1e-8 σ)
        assert r.beta == pytest.approx((kmax - k0) / sigma, abs=1e-7 * kmax / sigma + 1e-6)
        assert abs(r.design_point_u[0]) == pytest.approx(r.beta)
        betas.append(r.beta)
    assert all(a > b > 0 for a, b in itertools.pairwise(betas))  # monotone in k22, positive below k22_max
    assert betas[-1] < 0.05  # → 0 as k22 → k22_max
