"""Benchmark: memory over a long lockstep run (issue 10 item 7; goal < 50 MB RSS growth over 1 h at 2 kHz).

Runs ``sdea_bench``'s locked-output chirp in lockstep (the full runner: simulated ODrive on a
virtual CAN bus, Bota sensor on a pty, controller, safety, the record streamed to HDF5) with the
chirp stretched to ``--seconds`` of simulated time, and reads the process's resident set size
(``VmRSS`` in /proc/self/status) every ``--every`` simulated seconds from inside the loop (a
wrapper around the bench's ``advance``). Prints one row per sample: simulated time, ticks, RSS,
growth since the first sample and the growth rate extrapolated to one simulated hour (least-squares
slope of RSS over the samples after the first ``--warmup`` seconds, so start-up allocations --
imports, buffers, HDF5 chunk cache -- do not count as growth).

``--tracemalloc`` also traces Python allocations and prints the allocation sites that grew most
between the end of the warm-up and the end of the run (much slower: use a short run).

``--writer-only`` measures :class:`hil.record.hdf5.RecordWriter` alone streaming a record of the same
size (no runner, no devices): the record's own share of the growth.

Run: ``python benchmarks/bench_memory.py [--seconds 20] [--every 5] [--tracemalloc] [--writer-only]``.
Not a test; prints tables. Linux only (/proc).
"""

from __future__ import annotations

import argparse
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hil.bench.runtime import Bench
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict


def rss_mb() -> float:
    """Resident set size of this process [MB = 1e6 bytes] from /proc/self/status."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024 / 1e6
    raise RuntimeError("no VmRSS in /proc/self/status")


class _Probe:
    """Wraps a bench: samples RSS (and optionally a tracemalloc snapshot) every ``every`` ticks."""

    def __init__(self, inner: Any, every: int, rate_hz: float, rows: list[dict[str, float]],
                 warmup_ticks: int, end_ticks: int, snaps: dict[str, Any]) -> None:
        self._inner, self._every, self._rate, self._rows = inner, every, rate_hz, rows
        self._warmup, self._end, self._snaps = warmup_ticks, end_ticks, snaps
        self._k = 0
        self._t0 = time.perf_counter()

    def __enter__(self) -> _Probe:
        self._inner.__enter__()
        self._sample()
        return self

    def __exit__(self, *exc: Any) -> Any:
        return self._inner.__exit__(*exc)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def _sample(self) -> None:
        self._rows.append({"t": self._k / self._rate, "ticks": self._k, "rss": rss_mb(),
                           "wall": time.perf_counter() - self._t0})

    def advance(self) -> None:
        self._inner.advance()
        self._k += 1
        if tracemalloc.is_tracing() and self._k in (self._warmup, self._end):  # end: before the runner frees
            self._snaps["warm" if self._k == self._warmup else "end"] = tracemalloc.take_snapshot()
        if self._k % self._every == 0:
            self._sample()


def stretched_scene(seconds: float) -> Any:
    """``sdea_bench`` with its locked chirp lasting ``seconds`` of simulated time."""
    base = load_scene("sdea_bench")
    data = yaml.safe_load(base.source_text)
    data["experiments"][0]["duration"] = float(seconds)
    text = yaml.safe_dump(data, sort_keys=False)
    return scene_from_dict(yaml.safe_load(text), label="sdea_bench (stretched)", source_text=text)


def run(seconds: float, every_s: float, warmup_s: float, trace: bool) -> tuple[list[dict[str, float]], Any, Any]:
    sc = stretched_scene(seconds)
    rate = float(sc.rate_hz)
    rows: list[dict[str, float]] = []
    snaps: dict[str, Any] = {}
    every = max(1, round(every_s * rate))
    warm = max(1, round(warmup_s * rate))

    end = round(seconds * rate) - 1

    def factory(variant: str | None) -> _Probe:
        return _Probe(Bench(sc, seed=sc.seed, variant=variant), every, rate, rows, warm, end, snaps)

    if trace:
        tracemalloc.start(1)
    with tempfile.TemporaryDirectory() as d:
        out = Runner(sc, d, realtime=False, bench_factory=factory).run(select=[0])[0]
        tracemalloc.stop()
        size = sum(p.stat().st_size for p in Path(d).rglob("*.h5"))
    return rows, (out, size), snaps


def writer_only(seconds: float, every_s: float, rate: float = 2000.0) -> list[dict[str, float]]:
    """The record alone: :class:`hil.record.hdf5.RecordWriter` streaming ``seconds`` of ``rate`` samples of
    40 scalar channels and one 6-vector (about the runner's sdea_bench record), RSS every ``every_s``."""
    from hil.record.hdf5 import ChannelSpec, RecordWriter

    specs = {f"c{i}": ChannelSpec((), "1") for i in range(40)}
    specs["wrench"] = ChannelSpec((6,), "N")
    rows: list[dict[str, float]] = []
    every = max(1, round(every_s * rate))
    values: dict[str, Any] = {k: 0.0 for k in specs}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d, RecordWriter(Path(d) / "w.h5", scene_text="", scene_sha256="",
                                                           meta={}, channels=specs, rate_hz=rate) as w:
        for k in range(round(seconds * rate)):
            if k % every == 0:
                rows.append({"t": k / rate, "ticks": k, "rss": rss_mb(), "wall": time.perf_counter() - t0})
            values["c0"] = float(k)
            values["wrench"] = np.full(6, k * 1e-3)
            w.append(k / rate, values)
    rows.append({"t": seconds, "ticks": round(seconds * rate), "rss": rss_mb(), "wall": time.perf_counter() - t0})
    return rows


def _table(rows: list[dict[str, float]], warmup: float) -> float:
    """Print the RSS table; return the slope after the warm-up [MB per simulated s]."""
    r0 = rows[0]["rss"]
    late = [r for r in rows if r["t"] >= warmup]
    slope = float(np.polyfit([r["t"] for r in late], [r["rss"] for r in late], 1)[0]) if len(late) >= 2 else np.nan
    print(f"{'sim s':>7s} {'ticks':>8s} {'wall s':>7s} {'RSS MB':>8s} {'growth MB':>10s} {'MB/sim h':>9s}")
    for r in rows:
        dt = r["t"] - late[0]["t"] if late else 0.0
        rate_h = (r["rss"] - late[0]["rss"]) / dt * 3600 if dt > 0 else np.nan
        print(f"{r['t']:7.1f} {r['ticks']:8d} {r['wall']:7.1f} {r['rss']:8.1f} {r['rss'] - r0:10.1f} {rate_h:9.1f}")
    print(f"slope after {warmup:g} s warm-up: {slope:.4f} MB per simulated s = {slope * 3600:.0f} MB per "
          f"simulated hour (goal < 50 MB/h); {rows[-1]['ticks'] / max(rows[-1]['wall'], 1e-9):.0f} ticks/s")
    return slope


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated run length [s] (default 20)")
    ap.add_argument("--every", type=float, default=5.0, help="RSS sample period in simulated time [s]")
    ap.add_argument("--warmup", type=float, default=5.0, help="simulated seconds excluded from the slope")
    ap.add_argument("--tracemalloc", action="store_true", help="also report the allocation sites that grew")
    ap.add_argument("--writer-only", action="store_true", help="measure the record writer alone (no runner)")
    a = ap.parse_args()
    if a.writer_only:
        print(f"RecordWriter alone, 2 kHz, {a.seconds:g} s simulated")
        _table(writer_only(a.seconds, a.every), a.warmup)
        return
    rows, (out, size), snaps = run(a.seconds, a.every, a.warmup, a.tracemalloc)
    print(f"sdea_bench chirp_locked, lockstep at 2 kHz, {a.seconds:g} s simulated: status {out.status}, "
          f"record {size / 1e6:.1f} MB on disk{' (tracemalloc on)' if a.tracemalloc else ''}")
    _table(rows, a.warmup)
    if a.tracemalloc and "warm" in snaps and "end" in snaps:
        print("\nallocation sites that grew most after the warm-up (tracemalloc, by line):")
        for st in snaps["end"].compare_to(snaps["warm"], "lineno")[:12]:
            fr = st.traceback[0]
            print(f"  {st.size_diff / 1e6:+8.2f} MB {st.count_diff:+8d} blocks  {fr.filename}:{fr.lineno}")


if __name__ == "__main__":
    main()
