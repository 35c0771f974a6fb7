"""Benchmark: the watchdog's reaction time to a stale or silent device (issue 10; goal: the stop
comes within ``watchdog_ms`` + one tick of the last fresh data).

For each ``safety.watchdog_ms`` and each fault (simulated ODrive that stops publishing its cyclic
encoder estimates while its heartbeats go on; an ODrive that goes silent; a Bota sensor that
repeats its last frame with the same timestamp), ``sdea_bench``'s first chirp runs in lockstep with
the fault from tick 400 (300 for the Bota). From the record: the run time of the last sample whose
data changed (the last fresh data) and the time of the ``safety_stop`` event. Reaction = stop -
last fresh; bound = watchdog_ms + one control period. Lockstep time is the simulated clock, so the
numbers are the same on every machine; the wall-clock column is the whole run (setup included).

Run: ``python benchmarks/bench_watchdog.py [--watchdog-ms 10 20 50 100]``. Not a test: prints a table.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hil.record.hdf5 import RunRecord
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict

FAULTS: dict[str, tuple[int, str, dict[str, Any], str]] = {
    # name: (device index, channel, sim settings, extra params)
    "odrive stale estimates": (0, "motor.position", {"faults": {"stale_at_tick": 400}}, "cyclic"),
    "odrive silent": (0, "motor.position", {"faults": {"disconnect_at_tick": 400}}, "cyclic"),
    "bota stale frames": (1, "spring_ft.wrench", {"measure": "body", "faults": {"stale_at_tick": 300}}, ""),
}


def _scene(watchdog_ms: float, fault: str) -> Any:
    dev, _ch, sim, feedback = FAULTS[fault]
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["duration"] = 1.0
    d.pop("certification", None)
    d.setdefault("safety", {})["watchdog_ms"] = watchdog_ms
    d["devices"][dev]["sim"] = sim
    if feedback:
        d["devices"][dev].setdefault("params", {})["feedback"] = feedback
    return scene_from_dict(d, label=f"watchdog-{watchdog_ms}-{fault}")


def _last_fresh(x: np.ndarray) -> int:
    x = np.asarray(x).reshape(x.shape[0], -1)
    changed = np.flatnonzero(np.any(np.diff(x, axis=0) != 0, axis=1))
    return int(changed[-1]) + 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--watchdog-ms", type=float, nargs="+", default=[10.0, 20.0, 50.0, 100.0])
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)  # the stops are the point here: keep the table readable
    print(f"{'fault':24s} {'watchdog ms':>11s} {'tick ms':>8s} {'reaction ms':>11s} {'bound ms':>9s} "
          f"{'within':>6s} {'wall s':>7s}")
    with tempfile.TemporaryDirectory() as tmp:
        for fault, (_dev, ch, _sim, _fb) in FAULTS.items():
            for w in args.watchdog_ms:
                sc = _scene(w, fault)
                t0 = time.perf_counter()
                o = Runner(sc, Path(tmp) / f"{fault.replace(' ', '_')}-{w:g}").run()[0]
                wall = time.perf_counter() - t0
                if o.record is None or o.status != "safety_stop":
                    print(f"{fault:24s} {w:11g}  no stop: {o.status} {o.stop_reason}")
                    continue
                rec = RunRecord.open(o.record)
                fresh = _last_fresh(rec.channels[ch])
                stop = [e for e in rec.events if e.get("kind") == "safety_stop"]
                t_stop = float(stop[0]["t"]) if stop else float("nan")
                reaction = (t_stop - float(rec.t[fresh])) * 1e3
                bound = w + sc.dt * 1e3
                print(f"{fault:24s} {w:11g} {sc.dt * 1e3:8.3g} {reaction:11.3f} {bound:9.3f} "
                      f"{'yes' if reaction <= bound + 1e-9 else 'NO':>6s} {wall:7.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
