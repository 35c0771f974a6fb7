"""Benchmark: `hil certify`.

1. A full certification of each built-in scene, broken down by stage (run, identify, nominal,
   robust, design, witness) -- the SDEA bench runs its experiments and identifies its plant; the
   teleoperation scenes certify from their stated parameter uncertainty (``--no-experiments``).
2. Error of the probability of stability against the number of posterior draws (error against run
   time): the SDEA with its coupler stiffness set near the passive limit (P ≈ 0.9), draws from a
   posterior-like log-normal around Table I; the reference is 200 000 draws in the same run.

Run: ``python benchmarks/bench_certify.py [--scenes sdea_bench,...] [--no-draws]``. Not a test;
prints tables (``--scenes``: only these scenes in table 1; ``--no-draws``: skip table 2).
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from hil.certify.pipeline import certify_scene
from hil.models.batch import sdea_passivity_batch
from hil.models.sdea import SDEA_TABLE1
from hil.scene.spec import builtin_scenes, load_scene


def stages(names: list[str] | None = None) -> None:
    print("Full certification by stage (seconds; total: wall clock, CPU: this process's CPU time)")
    cols = ("run", "identify", "nominal", "robust", "design", "witness")
    print(f"{'scene':28s} {'decision':9s} " + " ".join(f"{c:>9s}" for c in cols) + f" {'total':>8s} {'CPU':>8s}")
    for name in names or [n for n, _ in builtin_scenes()]:
        sc = load_scene(name)
        run = bool(sc.certification and sc.certification.identify)
        t0, c0 = time.perf_counter(), time.process_time()
        with tempfile.TemporaryDirectory() as d:
            cert = certify_scene(sc, d, run_experiments=run)
        total, cpu = time.perf_counter() - t0, time.process_time() - c0
        timing = {}
        for m in cert.measurements:
            if m.name == "run time":
                for part in m.description.split(", "):
                    k, v, _ = part.split(" ")
                    timing[k] = float(v)
        print(f"{name:28s} {cert.decision:9s} " + " ".join(
            f"{timing[c]:9.2f}" if c in timing else f"{'-':>9s}" for c in cols) + f" {total:8.1f} {cpu:8.1f}")


def draws_error() -> None:
    rng = np.random.default_rng(0)
    sig = {"K_f": 0.01, "B_f": 0.03, "M": 0.01, "B": 0.02}  # relative posterior spread

    def sample(n: int) -> dict[str, np.ndarray]:
        return {k: SDEA_TABLE1[k] * np.exp(s * rng.standard_normal(n)) for k, s in sig.items()}

    # a k22 near the limit so that P(stable) is neither 0 nor 1
    ref_draws = sample(200_000)
    k22 = 404.0
    t0 = time.perf_counter()
    p_ref = float(np.mean(sdea_passivity_batch({**ref_draws, "k22": np.full(200_000, k22)})["passive"]))
    t_ref = time.perf_counter() - t0
    print(f"\nP(stable) against the number of draws (SDEA, k22 = {k22}; reference P = {p_ref:.4f} from 200 000 "
          f"draws in {t_ref:.2f} s)")
    print(f"{'draws':>8s} {'mean |error|':>13s} {'CI half-width':>14s} {'time':>10s} {'ratio':>8s}")
    base = None
    for n in (100, 300, 1000, 3000, 10_000, 30_000):
        errs, halfw, times = [], [], []
        for _ in range(20):
            d = sample(n)
            t0 = time.perf_counter()
            s = sdea_passivity_batch({**d, "k22": np.full(n, k22)})["passive"]
            times.append(time.perf_counter() - t0)
            from hil.certify.statistics import probability_of_stability

            p, lo, hi = probability_of_stability(s, 0.95)
            errs.append(abs(p - p_ref))
            halfw.append((hi - lo) / 2)
        t = float(np.mean(times))
        base = base or t
        print(f"{n:8d} {np.mean(errs):13.4f} {np.mean(halfw):14.4f} {t * 1e3:8.2f}ms {t / base:8.1f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default="", help="comma-separated scene names (default: every built-in scene)")
    ap.add_argument("--no-draws", action="store_true", help="skip the P(stable)-against-draws table")
    a = ap.parse_args()
    stages([s for s in a.scenes.split(",") if s] or None)
    if not a.no_draws:
        draws_error()
