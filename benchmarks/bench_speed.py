"""Benchmark: issue 15's speed table in one run.

1. Exact verdicts (the rows of :mod:`bench_verdicts`: one-port degree 4, SDEA two-port passivity and
   Llewellyn, MCET 3-port, 2-DOF bilateral 4×4): warm median process CPU time of the exact criterion
   against a 10⁴-point numpy grid of the same conditions, measured in the same run, as the ratio
   exact/grid (the goal: ≤ 0.2, i.e. 5× faster than the grid).
2. ``hil stability --model sdea`` as a whole process (interpreter start, imports, parsing, verdict,
   printing): best and median wall time and child CPU time of 10 runs, against two baselines timed
   in the same run: ``python -c pass`` and ``python -c "import numpy, flint"`` (what the verdict
   cannot do without). The goal is ≤ 0.25 s. The child runs with bytecode caching on
   (``PYTHONDONTWRITEBYTECODE`` removed from its environment, one warm-up run first), as an
   installed ``hil`` runs.
3. ``hil certify`` on the default scene (the mocked SDEA bench) as a process: its wall time and the
   stage times the certificate records (measurement ``run time``, whose description lists each
   stage to 0.1 s; its value is their sum). ``--quick`` passes ``--no-experiments`` (no mocked
   runs: the default scene then ends in ERROR, "no record", after the identify and nominal stages).

Not a test: prints tables, asserts nothing. Run: ``python benchmarks/bench_speed.py [--quick]
[--reps N]`` (about 1 min with the full ``hil certify`` on a 2-core machine). Results:
docs/BENCHMARKS.md, "Interactive speed (issue 15): one table".
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path
from types import ModuleType
from typing import Any


def _bench_verdicts() -> ModuleType:
    """benchmarks/bench_verdicts.py (a script, not a package: loaded from its file)."""
    path = Path(__file__).with_name("bench_verdicts.py")
    spec = importlib.util.spec_from_file_location("bench_verdicts", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def verdicts(reps: int) -> None:
    bv = _bench_verdicts()
    print("1. Exact verdict, warm median process CPU time per call on a freshly built network (its build not timed);")
    print("   'verdict only': margins=False (what the robust stage and the goal ask for); 'w/ margins': the full path")
    hdr = (f"{'work':34s} {'verdict':22s} {'verdict only':>12s} {'w/ margins':>10s} {'grid 1e4':>10s} "
           f"{'only/grid':>9s} {'goal':>8s}")
    print(hdr)
    print("-" * len(hdr))
    goals = [50e-6, 200e-6, 200e-6, 400e-6, 2e-3]  # issue 15's targets, in the order of bench_verdicts.rows()
    for (name, make, crit, kind), goal in zip(bv.rows(), goals, strict=True):
        verdict = crit(make()).verdict
        if crit(make(), margins=False).verdict != verdict:  # the fast path must give the same answer
            verdict = f"{verdict} (verdict-only path DIFFERS)"
        tn = bv.median_time_fresh(make, crit, reps, margins=False)
        te = bv.median_time_fresh(make, crit, reps)
        tg = bv.median_time(partial(bv.grid, make(), kind), max(5, reps // 4))
        print(f"{name:34s} {verdict!s:22s} {tn * 1e6:10.0f}µs {te * 1e6:8.0f}µs {tg * 1e6:8.0f}µs "
              f"{tn / tg:9.2f} {goal * 1e6:6.0f}µs", flush=True)


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # an installed hil has its bytecode cached
    return env


def time_process(cmd: list[str], n: int = 10) -> dict[str, float]:
    """Best and median wall time and child CPU time (user + system) of ``n`` runs of ``cmd``
    [s], after one warm-up run (which also writes the bytecode caches)."""
    env = _child_env()
    subprocess.run(cmd, capture_output=True, env=env, check=False)
    walls, cpus = [], []
    for _ in range(n):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(cmd, capture_output=True, env=env, check=False)
        walls.append(time.perf_counter() - t0)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime)
    return {"best": min(walls), "median": statistics.median(walls), "cpu_best": min(cpus),
            "cpu_median": statistics.median(cpus)}


def stability_process() -> None:
    py = sys.executable
    print("\n2. `hil stability --model sdea` as a whole process, 10 runs (goal: ≤ 0.25 s)")
    hdr = f"{'process':44s} {'wall best':>10s} {'median':>8s} {'CPU best':>9s} {'median':>8s}"
    print(hdr)
    print("-" * len(hdr))
    for label, cmd in (("python -c pass", [py, "-c", "pass"]),
                       ("python -c 'import numpy, flint'", [py, "-c", "import numpy, flint"]),
                       ("hil stability --model sdea", [py, "-m", "hil", "stability", "--model", "sdea"])):
        t = time_process(cmd)
        print(f"{label:44s} {t['best']:9.3f}s {t['median']:7.3f}s {t['cpu_best']:8.3f}s {t['cpu_median']:7.3f}s")
    print("(CPU: user + system time of the child; numpy's thread pool can make it exceed the wall time)")


def _stages(cert: dict[str, Any]) -> tuple[dict[str, float], float]:
    """The stage times (s) of a certificate: measurement ``run time``'s description
    ``"<stage> <seconds> s, ..."`` and its value (their sum, unrounded)."""
    for m in cert["measurements"]:
        if m["name"] == "run time":
            parts = [p.split(" ") for p in m["description"].split(", ") if p]
            return {p[0]: float(p[1]) for p in parts}, float(m["value"])
    return {}, float("nan")


def certify_process(quick: bool) -> None:
    extra = ["--no-experiments"] if quick else []
    print(f"\n3. `{' '.join(['hil certify', *extra])}` on the default scene (sdea_bench), one run (goal: ≤ 8 s)")
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "cert"
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "hil", "certify", *extra, "--out", str(out), "--json"],
                           capture_output=True, text=True, env=_child_env(), check=False)
        wall = time.perf_counter() - t0
        cert = json.loads((out / "certificate.json").read_text(encoding="utf-8"))
    stages, total = _stages(cert)
    print(f"decision {cert['decision']} (exit {r.returncode}); process wall time {wall:.1f} s")
    if quick:
        print("(--no-experiments in an empty directory: no record to identify, so the decision is ERROR by design;"
              " this row times start-up, the nominal check and the reports only)")
    print(f"{'stage':12s} {'time [s]':>9s}")
    for k, v in stages.items():
        print(f"{k:12s} {v:9.1f}")
    print(f"{'stages':12s} {total:9.2f}")
    print(f"{'the rest':12s} {wall - total:9.2f}  (start-up, scene loading, reports: HTML, PDF, figures)")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--reps", type=int, default=41, help="calls per verdict median (default 41)")
    ap.add_argument("--quick", action="store_true", help="hil certify --no-experiments (no mocked runs)")
    args = ap.parse_args(argv)
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores, load average "
          + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    verdicts(args.reps)
    stability_process()
    certify_process(args.quick)
    print("load average at the end " + " ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
