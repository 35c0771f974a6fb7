"""The vectorized SDEA passivity path agrees with the general exact criterion draw by draw."""

import numpy as np

from hil.models.sdea import SDEA_TABLE1, sdea_vsic
from hil.stability.batch import sdea_passivity_batch
from hil.stability.criteria import two_port_passivity
from hil.stability.design import k22_max


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
