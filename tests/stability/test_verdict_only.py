"""The verdict-only path (``margins=False``, used for posterior draws and searches) gives exactly the
verdict, failed condition and statuses of the full criterion: it skips only the margin computations
(issue 15: speed without trading exactness)."""

import numpy as np
import pytest

from hil.models.sdea import SDEA_TABLE1, sdea_vsic
from hil.models.teleop import bilateral_2dof, dual_master_3dof, mcet_trilateral
from hil.stability.criteria import check
from hil.stability.rational import S, TransferMatrix


def _random_network(rng: np.random.Generator) -> TransferMatrix:
    n = int(rng.integers(1, 4))
    M = rng.normal(size=(n, n))
    M = M @ M.T + 0.1 * np.eye(n)
    B = rng.normal(size=(n, n))
    B = B @ B.T + float(rng.uniform(-0.3, 0.1)) * np.eye(n)  # sometimes active
    K = rng.normal(size=(n, n))
    K = K @ K.T
    rows = [[(M[i, j] * S**2 + B[i, j] * S + K[i, j]) / (S * (S + float(rng.uniform(0.5, 2))) if rng.random() < 0.3
                                                         else S) for j in range(n)] for i in range(n)]
    return TransferMatrix(rows, "impedance", (1,) * n)


def _same(tm: TransferMatrix, criterion: str) -> None:
    full, fast = check(tm, criterion), check(tm, criterion, margins=False)
    assert fast.verdict == full.verdict
    # without margins there is no "worst" violated condition: the one named is one of them
    if full.failed_condition is None:
        assert fast.failed_condition is None
    else:
        assert fast.failed_condition is not None
        assert full.condition(fast.failed_condition).status == full.condition(full.failed_condition).status
    assert [(c.name, c.status) for c in fast.conditions] == [(c.name, c.status) for c in full.conditions]


@pytest.mark.parametrize("seed", range(24))
def test_verdict_only_agrees_on_random_networks(seed):
    rng = np.random.default_rng(seed)
    tm = _random_network(rng)
    for criterion in ("positive_real", "absolute_stability") + (("llewellyn",) if tm.n == 2 else ()):
        _same(tm, criterion)


@pytest.mark.parametrize("make,criterion", [
    (lambda: sdea_vsic(), "passivity"),
    (lambda: sdea_vsic(), "llewellyn"),
    (lambda: sdea_vsic(SDEA_TABLE1, k22=420.0), "passivity"),
    (lambda: mcet_trilateral(k_vm1=64), "absolute_stability"),
    (lambda: mcet_trilateral(k_vm1=80), "absolute_stability"),
    (lambda: bilateral_2dof("A1"), "absolute_stability"),
    (lambda: bilateral_2dof("B"), "absolute_stability"),
    (lambda: dual_master_3dof(k_pmyz=30), "absolute_stability"),
])
def test_verdict_only_agrees_on_the_case_studies(make, criterion):
    _same(make(), criterion)
