"""Loop timing as certificate evidence (issue 17): the rows a realtime run adds to a certificate."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from hil.certify.certificate import Measurement
from hil.identify.diagnostics import check_sample_times
from hil.record.hdf5 import RunRecord
from hil.run.realtime import DEFAULT_MAX_OVERRUN_FRACTION

__all__ = ["lateness_measurements"]


def lateness_measurements(outcomes: Mapping[str, Any], scene: Any) -> list[Any]:
    """Certificate rows for the loop timing of each realtime experiment in ``outcomes`` (name ->
    :class:`hil.run.runner.ExperimentOutcome`): p50 / p99 / max lateness [s] (upper limit: the scene's
    ``max_lateness_ms``; PASS when within), overrun fraction (upper: ``max_overrun_fraction``),
    and the sample-timing check of :func:`hil.identify.diagnostics.check_sample_times` on the
    record's ``loop.tick_start`` (FAIL when the timing departs from the nominal rate beyond its
    tolerance). Lockstep experiments (the simulated clock: no lateness) give no rows."""
    safety = getattr(scene, "safety", None)
    limit = float(getattr(safety, "max_lateness_ms", None) or getattr(safety, "watchdog_ms", None) or 50.0) / 1e3
    frac = float(getattr(safety, "max_overrun_fraction", DEFAULT_MAX_OVERRUN_FRACTION))
    rows: list[Any] = []
    for name, o in outcomes.items():
        if (getattr(o, "stats", {}) or {}).get("mode") != "realtime" or getattr(o, "record", None) is None:
            continue
        try:
            rec = RunRecord.open(o.record)
        except Exception as exc:  # the record is evidence; an unreadable one is said, not hidden
            rows.append(Measurement(name=f"loop lateness ({name})", value=None, outcome="ERROR",
                                    description=f"record unreadable: {exc}"))
            continue
        late = rec.channels.get("loop.late")
        if late is None or late.size == 0:
            continue
        late = late.reshape(late.shape[0], -1)[:, 0]
        late = late[np.isfinite(late)]
        dt = 1.0 / float(scene.rate_hz)
        for q in (50, 99):
            v = float(np.percentile(late, q))
            rows.append(Measurement(name=f"loop lateness p{q} ({name})", value=v, unit="s", upper=limit,
                                    outcome="PASS" if v <= limit else "FAIL",
                                    description=f"tick start after its deadline, {q}th percentile of "
                                                f"{late.size} ticks"))
        mx = float(late.max())
        rows.append(Measurement(name=f"loop lateness max ({name})", value=mx, unit="s", upper=limit,
                                outcome="PASS" if mx <= limit else "FAIL",
                                description="latest tick start after its deadline (limit max_lateness_ms)"))
        over = int(np.count_nonzero(late > dt))
        f = over / late.size
        rows.append(Measurement(name=f"loop overruns ({name})", value=f, unit="fraction", upper=frac,
                                outcome="PASS" if f <= frac else "FAIL",
                                description=f"{over} of {late.size} ticks later than one period ({1e3 * dt:g} ms)"))
        start = rec.channels.get("loop.tick_start")
        if start is not None and start.size:
            diags = check_sample_times(rec.t, start.reshape(start.shape[0], -1)[:, 0], rate_hz=float(scene.rate_hz))
            rows.append(Measurement(
                name=f"sample timing ({name})", value="uniform" if not diags else "departs", outcome=(
                    "PASS" if not diags else "FAIL"),
                description=diags[0].message if diags else "tick starts within the tolerance of k / rate_hz"))
    return rows
