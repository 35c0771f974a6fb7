"""Benchmark: `hil certify`.

1. **CPU time by stage** of what ``hil certify SCENE`` does (the pipeline's stages, then the HTML
   and PDF reports), measured in a fresh child process per scene: start-up (imports), run, identify,
   nominal, robust, design, decide, witness, html, pdf, and the child's whole CPU time (its own and
   that of the device processes it waited for). With ``--against REV`` the same children run the tree
   of another git revision in the same run, alternating with this tree (best of ``--repeat``), so the
   table shows before / after / ratio side by side, and the decisions (they must be equal).
2. **P(stable) error against run time** (``--draws``): the SDEA with its coupler stiffness near the
   passive limit (the reference P from 200 000 draws is printed in the same run, ≈ 0.6), draws from a
   posterior-like log-normal around Table I; the time column times only what a certification keeps:
   the vectorized verdicts (no critical band: ``sdea_passivity_batch`` computes it only with
   ``band=True``) and the Clopper-Pearson interval.

Run: ``python benchmarks/bench_certify.py [--scenes sdea_bench,bilateral_2dof_B] [--against REV]
[--repeat 1] [--no-draws]``. Not a test; prints tables. CPU times, not wall clock: they hold on a
loaded machine (within cache effects), the wall clock does not.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

STAGES = ("startup", "run", "identify", "nominal", "robust", "design", "decide", "witness", "html", "pdf")
DEFAULT_SCENES = ("sdea_bench", "bilateral_2dof_B")


def _cpu() -> float:
    """CPU seconds of this process and of the children it waited for (device processes)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def child(scene_name: str) -> dict[str, Any]:
    """One ``hil certify SCENE`` in this process (as hil.cli.certify does it: certify_scene, then
    build_reports), every stage wrapped in a CPU timer. Returns the stage times and the decision."""
    c0 = _cpu()
    from hil.certify import pipeline
    from hil.report import render
    from hil.scene.spec import load_scene

    cpu: dict[str, float] = {"startup": _cpu() - c0}

    def timed(mod: Any, attr: str, key: str) -> None:
        fn = getattr(mod, attr)

        def wrapper(*a: Any, **kw: Any) -> Any:
            t0 = _cpu()
            try:
                return fn(*a, **kw)
            finally:
                cpu[key] = cpu.get(key, 0.0) + _cpu() - t0

        setattr(mod, attr, wrapper)

    for st in ("run", "identify", "nominal", "robust", "design", "decide", "witness"):
        timed(pipeline, f"stage_{st}", st)
    timed(render, "render_html", "html")
    timed(render, "render_pdf", "pdf")
    scene = load_scene(scene_name)
    with tempfile.TemporaryDirectory() as d:
        cert = pipeline.certify_scene(scene, Path(d) / "out")
        render.build_reports(cert, Path(d) / "out")
    cpu["total"] = _cpu() - c0
    return {"cpu": cpu, "decision": cert.decision}


def _run_child(scene: str, pythonpath: str | None) -> dict[str, Any]:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    env["MPLBACKEND"] = "Agg"
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", scene], check=True,
                         capture_output=True, text=True, env=env, cwd=tempfile.gettempdir()).stdout
    return dict(json.loads(out.strip().splitlines()[-1]))


def _best(runs: list[dict[str, Any]]) -> dict[str, Any]:
    return min(runs, key=lambda r: r["cpu"]["total"])


def stages(names: list[str], against: str, repeat: int) -> None:
    cols = (*STAGES, "total")
    print("`hil certify` CPU seconds by stage (child process per run; best of "
          f"{repeat} by total{'; before = ' + against if against else ''})")
    print(f"{'scene':18s} {'tree':7s} {'decision':9s} " + " ".join(f"{c:>8s}" for c in cols))
    with tempfile.TemporaryDirectory() as d:
        tree = None
        if against:
            sys.path.insert(0, str(Path(__file__).resolve().parent))
            from bench_lockstep import revision_tree

            tree = str(revision_tree(against, Path(d)))
        for name in names:
            after: list[dict[str, Any]] = []
            before: list[dict[str, Any]] = []
            for _ in range(repeat):  # alternate the trees: drift in machine load hits both
                if tree is not None:
                    before.append(_run_child(name, tree))
                after.append(_run_child(name, None))
            rows = [("before", _best(before)), ("after", _best(after))] if tree is not None else [
                ("this", _best(after))]
            for label, r in rows:
                c = r["cpu"]
                print(f"{name:18s} {label:7s} {r['decision']:9s} " + " ".join(
                    f"{c[k]:8.2f}" if k in c else f"{'-':>8s}" for k in cols))
            if tree is not None:
                b, a = _best(before)["cpu"], _best(after)["cpu"]
                print(f"{name:18s} {'ratio':7s} {'':9s} " + " ".join(
                    f"{a.get(k, 0.0) / b[k]:8.2f}" if b.get(k) else f"{'-':>8s}" for k in cols))
                if _best(before)["decision"] != _best(after)["decision"]:
                    print(f"  !! decision changed: {_best(before)['decision']} -> {_best(after)['decision']}")


def draws_error() -> None:
    from hil.certify.statistics import probability_of_stability
    from hil.models.batch import sdea_passivity_batch
    from hil.models.sdea import SDEA_TABLE1

    rng = np.random.default_rng(0)
    sig = {"K_f": 0.01, "B_f": 0.03, "M": 0.01, "B": 0.02}  # relative posterior spread

    def sample(n: int) -> dict[str, np.ndarray]:
        return {k: SDEA_TABLE1[k] * np.exp(s * rng.standard_normal(n)) for k, s in sig.items()}

    # a k22 near the limit so that P(stable) is neither 0 nor 1
    n_ref = 200_000
    ref_draws = sample(n_ref)
    k22 = 404.0
    t0 = time.process_time()
    p_ref = float(np.mean(sdea_passivity_batch({**ref_draws, "k22": np.full(n_ref, k22)})["passive"]))
    t_ref = time.process_time() - t0
    print(f"\nP(stable) against the number of draws (SDEA, k22 = {k22}; reference P = {p_ref:.4f} from {n_ref} "
          f"draws in {t_ref:.2f} s CPU)")
    print(f"{'draws':>8s} {'mean |error|':>13s} {'CI half-width':>14s} {'CPU time':>10s} {'ratio':>8s}")
    warm = sdea_passivity_batch({**sample(100), "k22": np.full(100, k22)})["passive"]  # warm-up: first-call costs
    probability_of_stability(warm, 0.95)
    base = None
    for n in (100, 300, 1000, 3000, 10_000, 30_000):
        errs, halfw, times = [], [], []
        for _ in range(20):
            d = sample(n)
            t0 = time.process_time()
            s = sdea_passivity_batch({**d, "k22": np.full(n, k22)})["passive"]
            p, lo, hi = probability_of_stability(s, 0.95)
            times.append(time.process_time() - t0)
            errs.append(abs(p - p_ref))
            halfw.append((hi - lo) / 2)
        t = float(np.mean(times))
        base = base or t
        print(f"{n:8d} {np.mean(errs):13.4f} {np.mean(halfw):14.4f} {t * 1e3:8.2f}ms {t / base:8.1f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default=",".join(DEFAULT_SCENES), help="comma-separated scene names")
    ap.add_argument("--against", default="", help="a git revision to compare with, in the same run")
    ap.add_argument("--repeat", type=int, default=1, help="child processes per tree and scene")
    ap.add_argument("--no-draws", action="store_true", help="skip the P(stable)-against-draws table")
    ap.add_argument("--no-stages", action="store_true", help="skip the stage table")
    ap.add_argument("--child", default="", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        import logging

        logging.disable(logging.WARNING)
        print(json.dumps(child(a.child)))
        sys.exit(0)
    if not a.no_stages:
        stages([s for s in a.scenes.split(",") if s], a.against, a.repeat)
    if not a.no_draws:
        draws_error()
