"""Realtime at the bench: a loop that holds its deadlines, lateness as evidence, the machine's latency.

Pieces (each usable on its own; :class:`hil.run.runner.Runner` uses them in realtime mode):

* :class:`Pacer` -- absolute deadlines ``t0 + k * period`` on a nanosecond monotonic clock
  (``time.perf_counter_ns``, CLOCK_MONOTONIC on Linux); a *hybrid wait*: sleep until
  ``spin_ns`` (default 200 µs) before the deadline, then spin on the clock. Tick ``k``'s
  *lateness* is ``start_k - deadline_k`` (s, >= 0): how long after its deadline the tick began.
  An *overrun* is a tick later than one period. Clock and sleep are injectable (tests use a fake
  clock; nothing here reads the wall clock behind their back).
* :class:`LatenessGuard` -- the safety rule "a late loop is a safe stop": a tick later than
  ``max_lateness_s`` (scene ``safety.max_lateness_ms``, default ``watchdog_ms``), or more than
  ``max_overrun_fraction`` of the ticks of any window of ``window`` ticks (1 s of ticks, at least
  100) overrunning, raises :class:`hil.errors.SafetyStop` naming the tick and the numbers.
* :func:`realtime_scheduling` -- SCHED_FIFO (``os.sched_setscheduler``), ``mlockall`` (libc via
  ctypes) and CPU affinity for the loop, each where permitted; whatever is refused gives ONE
  one-line warning (logged, and kept in :attr:`Scheduling.warning` for the record). It also
  shortens the interpreter's GIL switch interval (``sys.setswitchinterval``, default 5 ms, to
  :data:`GIL_SWITCH_INTERVAL_S`) for the block: another thread of the loop's process holding the
  GIL (the record writer inside h5py) is then made to hand it back to a waiting loop within about
  one C call, instead of after up to 5 ms.
* :func:`gc_paused` -- ``gc.collect(); gc.freeze(); gc.disable()`` for an experiment,
  ``gc.enable(); gc.unfreeze(); gc.collect()`` after it.
* :func:`measure_wakeup` -- the machine's wake-up latency the way cyclictest measures it:
  periodic absolute-deadline sleeps (``clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`` through
  libc, else ``time.sleep``), lateness of each wake-up; :func:`run_cyclictest` runs rt-tests'
  ``cyclictest`` when it is installed; :func:`holdable_rates` says which loop rates the
  measured latency allows; :func:`check_realtime` is ``hil check-realtime``.
* :func:`hil.certify.lateness.lateness_measurements` -- the certificate rows (p50/p99/max lateness, overruns, sample
  timing) of the experiments' outcomes, with limits from the scene.

Definitions (also in docs/guide/realtime.md): percentiles are of the per-tick lateness
of one experiment (``numpy.percentile``, linear interpolation, on the recorded ``loop.late``
channel; :class:`hil.run.runner.LoopStats` keeps a ±2.4 % histogram estimate in bounded memory);
overruns count ticks with lateness > one period; the overrun fraction is overruns / ticks.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import dataclasses
import gc
import json
import logging
import math
import os
import re
import shutil
import subprocess
import sys
import time
import types
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from hil.bench.affinity import DEVICE_FIFO_PRIORITY, loop_cpu
from hil.errors import EXIT_NOT_HELD, SafetyStop

logger = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_MAX_OVERRUN_FRACTION",
    "DEVICE_FIFO_PRIORITY",
    "GIL_SWITCH_INTERVAL_S",
    "SPIN_NS",
    "SPIN_NS_FIFO",
    "WRITER_PROCESS_FIFO_PRIORITY",
    "LatenessGuard",
    "Pacer",
    "Scheduling",
    "WakeupStats",
    "check_realtime",
    "gc_paused",
    "holdable_rates",
    "measure_wakeup",
    "realtime_scheduling",
    "run_cyclictest",
    "steal_time_s",
]

#: the hybrid wait spins for the last 200 µs before a deadline (an ordinary thread's sleep wakes up
#: late by its 50 µs timer slack plus tens of µs)
SPIN_NS = 200_000
#: ... and for the last 100 µs under SCHED_FIFO (no timer slack; wake-up p99 ~50 µs measured on the
#: 2-core KVM guest). The spin is CPU the loop takes from everything else on its CPU: at 2 kHz 200 µs
#: is 40 % of it, and ordinary tasks starved on the loop's CPU get the kernel's fair server (50 ms per
#: second in one piece, Linux >= 6.12), a 50 ms stall of the loop.
SPIN_NS_FIFO = 100_000
#: the interpreter's GIL switch interval during a realtime experiment [s] (CPython default 5 ms)
GIL_SWITCH_INTERVAL_S = 0.0002
#: default ``safety.max_overrun_fraction``: more than 1 % of the ticks of a 1 s window overrunning
DEFAULT_MAX_OVERRUN_FRACTION = 0.01
#: SCHED_FIFO priority of the loop (cyclictest's customary ``-p 80``: above the kernel's threaded IRQs at 50)
FIFO_PRIORITY = 80
#: SCHED_FIFO priority of the record's writer process (the h5py calls; its thread stays at
#: ``FIFO_PRIORITY - 1``): below the devices' process it shares the other CPUs with, so a block
#: write (milliseconds of HDF5 CPU) never delays a device's reply; above ordinary load, so the
#: writer does not fall behind
WRITER_PROCESS_FIFO_PRIORITY = 60


# ---------------------------------------------------------------------------------------------
# the loop's clock


class Pacer:
    """Absolute deadlines ``t0 + k * period_ns`` and a hybrid wait (see the module docstring).

    ``clock_ns``: a monotonic clock in ns (default ``time.perf_counter_ns``); ``sleep``: sleeps
    for a number of seconds (default ``time.sleep``). :meth:`start` fixes ``t0`` (deadline of tick
    0); :meth:`wait` ``(k)`` returns when tick ``k``'s deadline has passed and gives its lateness
    [ns]; :attr:`start_ns` is then the tick's actual start on ``clock_ns``. Per tick: integer
    arithmetic only, no allocation beyond CPython's own ints.
    """

    __slots__ = ("clock_ns", "period_ns", "sleep", "spin_ns", "start_ns", "t0")

    def __init__(self, rate_hz: float, *, clock_ns: Callable[[], int] | None = None,
                 sleep: Callable[[float], Any] | None = None, spin_ns: int = SPIN_NS) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.period_ns = round(1e9 / rate_hz)
        self.clock_ns = clock_ns or time.perf_counter_ns
        self.sleep = sleep or time.sleep
        self.spin_ns = int(spin_ns)
        self.t0 = 0
        self.start_ns = 0

    def start(self) -> int:
        """Deadline of tick 0 = now (ns on ``clock_ns``)."""
        self.t0 = self.clock_ns()
        self.start_ns = self.t0
        return self.t0

    def wait(self, k: int) -> int:
        """Wait for tick ``k``'s deadline: sleep until ``spin_ns`` before it, then spin. Returns the
        lateness [ns] (>= 0) of the tick's start."""
        deadline = self.t0 + k * self.period_ns
        clock = self.clock_ns
        now = clock()
        rem = deadline - now
        if rem > self.spin_ns:
            self.sleep((rem - self.spin_ns) * 1e-9)
            now = clock()
        while now < deadline:
            now = clock()
        self.start_ns = now
        return now - deadline


class LatenessGuard:
    """"A late loop is a safe stop" (see the module docstring).

    ``max_lateness_s``: a tick starting later than this after its deadline is a stop;
    ``max_overrun_fraction``: more than ``floor(fraction * window)`` overruns (lateness > one
    period) among the last ``window`` ticks is a stop (``window`` default: one second of ticks, at
    least 100). Per tick: one comparison, and a ring buffer of preallocated bytes.
    """

    def __init__(self, rate_hz: float, max_lateness_s: float,
                 max_overrun_fraction: float = DEFAULT_MAX_OVERRUN_FRACTION, window: int | None = None) -> None:
        self.period_s = 1.0 / float(rate_hz)
        self.max_lateness_s = float(max_lateness_s)
        self.max_overrun_fraction = float(max_overrun_fraction)
        self.window = int(window if window is not None else max(100, round(rate_hz)))
        self.allowed = math.floor(self.max_overrun_fraction * self.window + 1e-9)
        self._ring = bytearray(self.window)
        self._in_window = 0
        self.overruns = 0

    def check(self, k: int, late_s: float) -> None:
        """Account tick ``k`` started ``late_s`` seconds after its deadline; raise SafetyStop on a breach."""
        if not late_s <= self.max_lateness_s:  # NaN-safe
            raise SafetyStop(f"late loop: tick {k} started {1e3 * late_s:.3f} ms after its deadline "
                             f"(limit max_lateness_ms = {1e3 * self.max_lateness_s:g} ms)")
        over = 1 if late_s > self.period_s else 0
        i = k % self.window
        self._in_window += over - self._ring[i]
        self._ring[i] = over
        if over:
            self.overruns += 1
            if self._in_window > self.allowed:
                raise SafetyStop(f"late loop: {self._in_window} overruns (ticks later than one period, "
                                 f"{1e3 * self.period_s:g} ms) in the {self.window} ticks up to tick {k} "
                                 f"(limit max_overrun_fraction = {self.max_overrun_fraction:g}: "
                                 f"{self.allowed} per {self.window} ticks)")


# ---------------------------------------------------------------------------------------------
# scheduling


@dataclasses.dataclass
class Scheduling:
    """What the loop got. ``policy``: ``"SCHED_FIFO 80"`` or ``"SCHED_OTHER"``; ``memlock``: memory
    locked (``mlockall``); ``cpus``: the loop's CPU affinity; ``other_cpus``: the CPUs the process
    may use besides the loop's (its helper threads and the devices' process go there; empty when
    the loop was not pinned); ``switch_interval_s``: the GIL switch interval in force [s];
    ``warning``: the one-line warning (None when everything was granted)."""

    policy: str = "SCHED_OTHER"
    memlock: bool = False
    cpus: tuple[int, ...] = ()
    warning: str | None = None
    other_cpus: tuple[int, ...] = ()
    switch_interval_s: float = dataclasses.field(default_factory=sys.getswitchinterval)

    @property
    def fifo(self) -> bool:
        """SCHED_FIFO was granted."""
        return self.policy.startswith("SCHED_FIFO")

    def to_dict(self) -> dict[str, Any]:
        return {"policy": self.policy, "memlock": self.memlock, "cpus": list(self.cpus), "warning": self.warning,
                "other_cpus": list(self.other_cpus), "switch_interval_s": self.switch_interval_s}

    def describe(self) -> str:
        cpus = ",".join(map(str, self.cpus)) or "any"
        return f"{self.policy}, memory {'locked' if self.memlock else 'not locked'}, CPU {cpus}"


_MCL_CURRENT, _MCL_FUTURE = 1, 2
_WARNED: set[str] = set()


def _libc() -> Any:
    name = ctypes.util.find_library("c")
    return ctypes.CDLL(name, use_errno=True) if name else None


def spin_for(sched: Scheduling) -> int:
    """The hybrid wait's spin window [ns] for the scheduling the loop got: :data:`SPIN_NS_FIFO`
    under SCHED_FIFO, :data:`SPIN_NS` otherwise."""
    return SPIN_NS_FIFO if sched.fifo else SPIN_NS


@contextlib.contextmanager
def realtime_scheduling(*, enabled: bool = True, priority: int = FIFO_PRIORITY,
                        cpu: int | None = -1,
                        switch_interval_s: float | None = GIL_SWITCH_INTERVAL_S) -> Iterator[Scheduling]:
    """Give the calling thread SCHED_FIFO ``priority``, lock the process's memory, pin it to
    ``cpu`` (-1: :func:`loop_cpu`; None: no pinning) and set the GIL switch interval to
    ``switch_interval_s`` (None: unchanged) for the block; restore all four after it.

    What is refused (no CAP_SYS_NICE / rtprio limit, RLIMIT_MEMLOCK, not Linux) is skipped with ONE
    warning line listing it and how to grant it (logged once per process; always in
    :attr:`Scheduling.warning`, which the runner records as a ``realtime`` event). ``enabled=False``
    changes nothing (tests)."""
    got = Scheduling()
    if not enabled:
        yield got
        return
    missing: list[str] = []
    old_policy: int | None = None
    old_param: os.sched_param | None = None
    old_aff: set[int] | None = None
    libc = None
    try:
        old_policy, old_param = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        got.policy = f"SCHED_FIFO {priority}"
    except (AttributeError, OSError) as exc:
        old_policy = None
        missing.append(f"SCHED_FIFO ({getattr(exc, 'strerror', None) or exc})")
    try:
        libc = _libc()
        if libc is None or libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
            err = ctypes.get_errno() if libc is not None else 0
            missing.append(f"mlockall ({os.strerror(err) if err else 'no libc'})")
            libc = None
        else:
            got.memlock = True
    except (AttributeError, OSError) as exc:
        missing.append(f"mlockall ({exc})")
        libc = None
    if cpu == -1:
        cpu = loop_cpu()
    try:
        old_aff = os.sched_getaffinity(0)
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})
        got.cpus = tuple(sorted(os.sched_getaffinity(0)))
        got.other_cpus = tuple(sorted(set(old_aff) - set(got.cpus))) if cpu is not None else ()
    except (AttributeError, OSError) as exc:
        old_aff = None
        missing.append(f"CPU affinity ({exc})")
    old_switch = sys.getswitchinterval()
    if switch_interval_s is not None:
        sys.setswitchinterval(float(switch_interval_s))
    got.switch_interval_s = sys.getswitchinterval()
    if missing:
        got.warning = (f"realtime loop without {', '.join(missing)}: lateness is not bounded by the scheduler "
                       "(grant CAP_SYS_NICE and CAP_IPC_LOCK, or rtprio/memlock in /etc/security/limits.conf)")
        if got.warning not in _WARNED:  # one line per process, not one per experiment
            _WARNED.add(got.warning)
            logger.warning("%s", got.warning)
    try:
        yield got
    finally:
        sys.setswitchinterval(old_switch)
        if old_policy is not None and old_param is not None:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, old_policy, old_param)
        if got.memlock and libc is not None:
            with contextlib.suppress(OSError):
                libc.munlockall()
        if old_aff is not None:
            with contextlib.suppress(OSError):
                os.sched_setaffinity(0, old_aff)


@contextlib.contextmanager
def gc_paused(enabled: bool = True) -> Iterator[None]:
    """No garbage collection inside the block: collect, freeze what exists (it is never scanned
    again), disable; after the block re-enable, unfreeze and collect (between experiments)."""
    if not enabled:
        yield
        return
    was = gc.isenabled()
    gc.collect()
    gc.freeze()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()
        gc.unfreeze()
        gc.collect()


# ---------------------------------------------------------------------------------------------
# the machine's wake-up latency (cyclictest's method)


@dataclasses.dataclass
class WakeupStats:
    """Lateness of periodic absolute-deadline wake-ups. Times in seconds."""

    method: str
    rate_hz: float
    samples: int
    p50: float
    p99: float
    max: float
    overruns: int  # wake-ups later than one period

    @classmethod
    def from_lateness(cls, method: str, rate_hz: float, late_s: np.ndarray) -> WakeupStats:
        a = np.asarray(late_s, dtype=float)
        if a.size == 0:
            return cls(method, rate_hz, 0, math.nan, math.nan, math.nan, 0)
        return cls(method, float(rate_hz), int(a.size), float(np.percentile(a, 50)), float(np.percentile(a, 99)),
                   float(a.max()), int(np.count_nonzero(a > 1.0 / rate_hz)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (an unknown statistic, e.g. cyclictest's p99, is None)."""
        return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in dataclasses.asdict(self).items()}


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


_CLOCK_MONOTONIC, _TIMER_ABSTIME = 1, 1


def _abs_sleeper() -> Callable[[int], None] | None:
    """``sleep_until(deadline_ns)`` on CLOCK_MONOTONIC with TIMER_ABSTIME (libc clock_nanosleep;
    ``time.monotonic_ns`` reads the same clock), or None where unavailable."""
    if not sys.platform.startswith("linux"):
        return None
    libc = _libc()
    fn = getattr(libc, "clock_nanosleep", None) if libc is not None else None
    if fn is None:
        return None
    ts = _Timespec()
    ref = ctypes.byref(ts)

    def sleep_until(deadline_ns: int) -> None:
        ts.tv_sec, ts.tv_nsec = divmod(deadline_ns, 1_000_000_000)
        while fn(_CLOCK_MONOTONIC, _TIMER_ABSTIME, ref, None) == 4:  # EINTR: sleep on
            pass

    return sleep_until


def measure_wakeup(rate_hz: float, seconds: float, *, method: str = "sleep",
                   clock_ns: Callable[[], int] | None = None,
                   sleep_until: Callable[[int], None] | None = None, spin_ns: int = SPIN_NS) -> WakeupStats:
    """Wake up at ``t0 + k / rate_hz`` for ``seconds`` and measure how late each wake-up is.

    ``method="sleep"``: absolute-deadline sleeps (cyclictest's measurement: the kernel's timer and
    scheduling latency); ``"hybrid"``: :class:`Pacer`'s sleep-then-spin wait (what the loop does).
    ``clock_ns`` / ``sleep_until`` are injectable (tests); defaults: ``time.monotonic_ns`` and
    clock_nanosleep(TIMER_ABSTIME) on the same clock. ``spin_ns``: the hybrid wait's spin window
    (the loop's: :func:`spin_for` its scheduling)."""
    n = max(1, round(rate_hz * seconds))
    late = np.empty(n, dtype=np.int64)  # preallocated: nothing allocated per wake-up but ints
    if method == "hybrid":
        pacer = Pacer(rate_hz, clock_ns=clock_ns or time.monotonic_ns, spin_ns=spin_ns)
        pacer.start()
        for k in range(n):
            late[k] = pacer.wait(k + 1)
    elif method == "sleep":
        clock = clock_ns or time.monotonic_ns
        until = sleep_until or _abs_sleeper()
        if until is None:
            def until(d: int) -> None:
                time.sleep(max(0.0, (d - clock()) * 1e-9))
        period = round(1e9 / rate_hz)
        t0 = clock()
        for k in range(n):
            d = t0 + (k + 1) * period
            until(d)
            late[k] = clock() - d
    else:
        raise ValueError(f"method must be 'sleep' or 'hybrid', got {method!r}")
    return WakeupStats.from_lateness(method, rate_hz, np.maximum(late, 0) * 1e-9)


def run_cyclictest(rate_hz: float, seconds: float, *, which: Callable[[str], str | None] | None = None,
                   run: Callable[..., Any] = subprocess.run) -> WakeupStats | str:
    """rt-tests' ``cyclictest`` at the same interval (``-m -p 80 -q -i <us> -l <loops> -h <us>``) as
    :class:`WakeupStats`, or a one-line reason when it is not installed or fails.

    With its latency histogram (1 µs bins up to one period, ``-h``): p50 and p99 are the smallest
    bin whose cumulative count reaches 50 % / 99 % of the wake-ups (nearest rank, 1 µs resolution;
    p99 is NaN when it falls among the histogram's overflows, i.e. ≥ one period), max is
    cyclictest's Max, overruns its histogram overflows (wake-ups at least one period late). Without
    a histogram in the output (older rt-tests): p50 := Avg, p99 NaN, overruns 0/1 from Max."""
    exe = (which or shutil.which)("cyclictest")  # looked up at call time (tests replace shutil.which)
    if exe is None:
        return "cyclictest (rt-tests) is not installed: only the built-in measurement (apt install rt-tests)"
    interval = max(1, round(1e6 / rate_hz))
    loops = max(1, round(rate_hz * seconds))
    cmd = [exe, "-m", "-q", "-p", str(FIFO_PRIORITY), "-i", str(interval), "-l", str(loops), "-h", str(interval)]
    try:
        cp = run(cmd, capture_output=True, text=True, timeout=seconds + 30)
    except (OSError, subprocess.SubprocessError) as exc:
        return f"cyclictest failed: {' '.join(str(exc).split())}"
    out = cp.stdout or ""
    hist = [(int(a), int(b)) for a, b in re.findall(r"^(\d+) (\d+)\s*$", out, flags=re.M)]
    mx = re.search(r"^# Max Latencies:\s*(\d+)", out, flags=re.M)
    ovf = re.search(r"^# Histogram Overflows:\s*(\d+)", out, flags=re.M)
    if cp.returncode == 0 and hist and mx and ovf:
        us = np.array([h[0] for h in hist], dtype=float)
        counts = np.array([h[1] for h in hist], dtype=np.int64)
        over = int(ovf.group(1))
        total = int(counts.sum()) + over
        cum = np.cumsum(counts)

        def rank(q: float) -> float:
            i = int(np.searchsorted(cum, q * total, side="left"))
            return float(us[i]) * 1e-6 if i < us.size else math.nan

        return WakeupStats("cyclictest", float(rate_hz), total, rank(0.5), rank(0.99), int(mx.group(1)) * 1e-6, over)
    m = re.search(r"Min:\s*(\d+)\s+Act:\s*\d+\s+Avg:\s*(\d+)\s+Max:\s*(\d+)", out)
    if cp.returncode != 0 or m is None:
        err = " ".join((cp.stderr or cp.stdout or "").split())[:200]
        return f"cyclictest failed (exit {cp.returncode}): {err}"
    _mn, avg, mxv = (int(x) * 1e-6 for x in m.groups())
    return WakeupStats("cyclictest", float(rate_hz), loops, avg, math.nan, mxv,
                       int(mxv > 1.0 / rate_hz))


#: loop rates :func:`holdable_rates` judges [Hz]
CANDIDATE_RATES = (250.0, 500.0, 1000.0, 2000.0, 4000.0, 8000.0)
#: a rate is held when the p99 wake-up lateness is at most this fraction of its period ...
P99_FRACTION = 0.1
#: ... and the worst one is shorter than one period (no overrun)


#: where the kernel accounts each CPU's time (Linux)
PROC_STAT = "/proc/stat"


def steal_time_s(path: str = PROC_STAT) -> float:
    """The machine's steal time so far [s], summed over its CPUs: time a virtual CPU of this guest
    wanted to run while the hypervisor ran something else (the 8th value of the ``cpu`` line of
    ``/proc/stat``, in clock ticks of ``SC_CLK_TCK``). A monotone counter: the steal time of an
    interval is the difference of two readings. NaN where it cannot be read (not Linux). Nothing in
    the guest runs while its CPU is stolen, so no loop (cyclictest included) is on time then."""
    try:
        with open(path, encoding="ascii") as f:
            fields = f.readline().split()
        if fields[0] != "cpu":
            return math.nan
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, AttributeError):
        return math.nan


def holdable_rates(stats: WakeupStats, rates: Sequence[float] = CANDIDATE_RATES) -> dict[float, bool]:
    """Which loop rates the measured wake-up latency allows: rate R is held when p99 lateness
    <= :data:`P99_FRACTION` / R and max lateness < 1 / R. The lateness of a wake-up does not depend
    on the period it was asked for, so one measurement judges every rate; a loop's own per-tick
    work (reading devices, the controller, the record) comes on top."""
    p99 = stats.p99 if math.isfinite(stats.p99) else stats.max
    return {float(r): bool(p99 <= P99_FRACTION / r and stats.max < 1.0 / r) for r in rates}


def check_realtime(rate_hz: float = 2000.0, seconds: float = 5.0, *, rt: bool = True, as_json: bool = False) -> int:
    """``hil check-realtime [--rate HZ] [--seconds S] [--no-rt] [--json]``: the machine's wake-up
    latency (absolute-deadline sleeps, and the loop's hybrid wait) under the scheduling the loop
    would get, cyclictest's figures side by side when installed, and which loop rates it can hold
    (:func:`holdable_rates`, judged on the hybrid wait). Prints a table (or one JSON object);
    exit 0 when ``rate_hz`` is held, :data:`EXIT_NOT_HELD` (21) when not."""
    a = types.SimpleNamespace(rate=float(rate_hz), seconds=float(seconds), no_rt=not rt, json=as_json)
    steal0, t0 = steal_time_s(), time.monotonic()
    with realtime_scheduling(enabled=not a.no_rt) as sched:
        rows = [measure_wakeup(a.rate, a.seconds, method="sleep"),
                measure_wakeup(a.rate, a.seconds, method="hybrid", spin_ns=spin_for(sched))]
    cyc = run_cyclictest(a.rate, a.seconds)
    steal, elapsed = steal_time_s() - steal0, time.monotonic() - t0
    note = None
    if isinstance(cyc, str):
        note = cyc
    else:
        rows.append(cyc)
    held = holdable_rates(rows[1])  # the loop waits with the hybrid wait
    ok = holdable_rates(rows[1], [a.rate])[float(a.rate)]
    if a.json:
        print(json.dumps({"scheduling": sched.to_dict(), "rows": [r.to_dict() for r in rows], "note": note,
                          "steal_s": steal if math.isfinite(steal) else None, "elapsed_s": elapsed,
                          "holdable": {f"{r:g}": v for r, v in held.items()}, "rate_held": ok}))
        return 0 if ok else EXIT_NOT_HELD
    from rich.console import Console  # lazy: only to print (the loop imports this module)
    from rich.table import Table

    con = Console()
    con.print(f"scheduling: {sched.describe()}", highlight=False)
    if sched.warning:
        con.print(f"warning: {sched.warning}", highlight=False)
    tab = Table(title=f"wake-up lateness at {a.rate:g} Hz, {a.seconds:g} s", header_style="bold")
    for col in ("method", "wake-ups", "p50 µs", "p99 µs", "max µs", "overruns"):
        tab.add_column(col, justify="left" if col == "method" else "right")
    label = {"sleep": "abs. sleep", "hybrid": "sleep+spin", "cyclictest": "cyclictest"}
    for r in rows:
        tab.add_row(label[r.method], str(r.samples), f"{1e6 * r.p50:.1f}",
                    "—" if math.isnan(r.p99) else f"{1e6 * r.p99:.1f}", f"{1e6 * r.max:.1f}", str(r.overruns))
    con.print(tab)
    con.print("abs. sleep: clock_nanosleep to each absolute deadline (cyclictest's measurement); sleep+spin: the "
              f"loop's wait (sleep, then spin the last {spin_for(sched) // 1000} µs); cyclictest: from its 1 µs "
              "histogram",
              highlight=False)
    if note:
        con.print(note, highlight=False)
    if math.isfinite(steal):
        con.print(f"steal time: {1e3 * steal:.0f} ms over the {elapsed:.1f} s of measurement (summed over the CPUs)"
                  + (": a virtual machine whose host runs other work; nothing here runs while its CPU is stolen, "
                     "so lateness up to the host's bursts cannot be removed in this machine" if steal > 0 else ""),
                  highlight=False)
    good = [f"{r:g}" for r, v in held.items() if v]
    con.print(f"holds (p99 ≤ {P99_FRACTION:.0%} of the period, max < 1 period): "
              f"{', '.join(good) + ' Hz' if good else 'none of ' + ', '.join(f'{r:g}' for r in held) + ' Hz'}",
              highlight=False)
    con.print(f"{a.rate:g} Hz: {'held' if ok else 'NOT held'}", highlight=False)
    return 0 if ok else EXIT_NOT_HELD
