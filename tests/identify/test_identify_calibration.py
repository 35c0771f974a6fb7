"""Calibration of the 90 % credible intervals over many seeded synthetic SDEA datasets (slow)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SDEA_SETUP, SDEA_TRUTH, make_sdea_record

from hil.identify.api import identify_arrays
from hil.identify.models import SdeaLockedOutput

N_DATASETS = 80


@pytest.mark.slow
def test_90pct_intervals_cover_truth_80_to_97pct() -> None:
    truth = SdeaLockedOutput().vector(SDEA_TRUTH)
    hits = np.zeros((N_DATASETS, truth.size), bool)
    n_conv = 0
    for k in range(N_DATASETS):
        rec = make_sdea_record(10_000 + k)
        res = identify_arrays(
            rec.t,
            {"torque": rec.u[:, 0]},
            {"velocity": rec.y[:, 0], "force": rec.y[:, 1]},
            band=SDEA_SETUP["band"],
            period=SDEA_SETUP["period"],
            seed=k,
            n_starts=1,
        )
        n_conv += res.converged
        q05, q95 = res.posterior.quantiles([0.05, 0.95])  # intervals from the posterior samples
        hits[k] = (q05 <= truth) & (truth <= q95)
    cover = hits.mean(axis=0)
    print("coverage of the 90% intervals per parameter:", dict(zip(res.model.names, cover.round(3), strict=True)))
    assert n_conv == N_DATASETS
    # Under perfect calibration the hit count is Binomial(80, 0.9): mean 72, sd 2.7. The window 80-97 %
    # (64..77 hits) is then violated with probability ~1 % per parameter (mostly on the upper side).
    assert np.all((cover >= 0.80) & (cover <= 0.97)), cover
