"""Calibration of the identification with friction on synthetic records (not a test; issue 25).

Run: ``python benchmarks/bench_friction_calibration.py [mbk2] [sdea] [stribeck]`` (default: all).
Each case identifies 20 records simulated by the tests' event-located stick-slip simulator
(``tests/identify/friction_synth.py``, independent of ``hil.identify``; the record builders of
``tests/identify/test_friction_models.py``) with ``identify_record(..., friction=..., posterior="laplace")``
and prints per parameter: the truth, the mean estimate, ``bias/sd`` (mean error over the mean
reported sd), ``sd/scatter`` (reported sd over the seeds' scatter: 1 = honest intervals),
``scatter/CRB`` (the seeds' scatter over the mean Cramer-Rao bound: efficiency, 1 = efficient)
and the 90 % interval coverage; then the pooled coverage, the misfit flags, the seeds replaced
because the simulator chattered, and the CPU time (``time.process_time``) per record.

Cases: ``mbk2`` the 2-DOF coupled plant with Coulomb friction and an offset per joint (1 kHz);
``sdea`` paper 002's SDEA, locked output, Coulomb friction on the motor (2 kHz, resonance 119 Hz);
``stribeck`` a 1-DOF axis with a Stribeck dip (1 kHz).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "identify"))


def calibrate(build: Any, friction: str, truth: dict[str, float]) -> None:
    from hil.identify.api import identify_record

    rows: list[dict[str, dict[str, float]]] = []
    misfit = chatter = 0
    seed = 100
    cpu = 0.0
    while len(rows) < 20:
        try:
            rec = build(seed)
        except RuntimeError:
            chatter += 1
            seed += 1
            continue
        t0 = time.process_time()
        res = identify_record(rec, seed=seed, friction=friction, posterior="laplace")
        cpu += time.process_time() - t0
        rows.append(res.summary())
        misfit += bool(res.misfit)
        seed += 1
    print(f"{'parameter':>8} {'truth':>11} {'mean':>11} {'bias/sd':>8} {'sd/scat':>8} {'scat/CRB':>9} {'cover90':>8}")
    cov_all = []
    for k, v in truth.items():
        m = np.array([r[k]["median"] for r in rows])
        sd = np.array([r[k]["std"] for r in rows])
        crb = np.array([r[k]["crb_std"] for r in rows])
        cov = np.array([r[k]["q05"] <= v <= r[k]["q95"] for r in rows])
        cov_all += list(cov)
        sc = float(np.std(m, ddof=1))
        print(f"{k:>8} {v:11.5g} {m.mean():11.5g} {(m.mean() - v) / sd.mean():8.2f} {sd.mean() / sc:8.2f} "
              f"{sc / crb.mean():9.2f} {cov.mean():8.2f}")
    print(f"pooled 90% coverage {np.mean(cov_all):.3f} ({len(cov_all)} intervals); misfit flags {misfit}/20; "
          f"seeds replaced (simulator chattering) {chatter}; CPU {cpu / 20:.2f} s per record; "
          f"load average {os.getloadavg()[0]:.1f}")


def main(argv: list[str]) -> None:
    import test_friction_models as tf

    cases = {"mbk2": (tf.mbk2_record, "coulomb,offset", tf.MBK2), "sdea": (tf.sdea_record, "coulomb", tf.SDEA),
             "stribeck": (tf.stribeck_record, "stribeck", tf.STRIBECK)}
    for name in argv or list(cases):
        print(f"\n== {name}")
        calibrate(*cases[name])


if __name__ == "__main__":
    main(sys.argv[1:])
