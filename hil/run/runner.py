"""The fixed-rate experiment loop, with safety limits, a watchdog and a safe stop.

One tick (period dt = 1/rate_hz):

0. safe point: a stop request (SIGINT / SIGTERM / SIGHUP, :mod:`hil.bench.stopflag`) raises here;
1. read every device (adapters, with timeouts; realtime mode on external devices: timeout 0, the
   newest sample that has arrived, its age recorded as ``<device>.age``) -> measurements;
2. controller effort + experiment excitation -> commanded effort;
3. append the sample to the run record (streamed to HDF5, flushed every 0.1 s of run time; in
   realtime mode written by the record's writer thread, off the tick), so
   the sample that breaches a limit is in the record;
4. safety check (non-finite feedback, effort, velocity, position, injected port energy, stale
   feedback, loop overrun); a breach raises :class:`hil.errors.SafetyStop`;
5. command the actuators, set the simulated human's active force;
6. lockstep: advance the simulated plant by exactly dt.

Realtime mode (:mod:`hil.run.realtime`): before step 0 of each tick the loop waits for the tick's
absolute deadline (``t0 + k / rate_hz`` on ``time.perf_counter_ns``; sleep, then spin for the last
200 µs); the tick's actual start (``loop.tick_start``, s since t0) and lateness (``loop.late``, s)
go into the record. A tick later than ``safety.max_lateness_ms`` (default ``watchdog_ms``), or
more than ``max_overrun_fraction`` of a 1 s window of ticks overrunning (later than one period),
is a safe stop ("late loop: ..."; the late tick's timing is in the record, its device channels
NaN). The loop runs with SCHED_FIFO, locked memory and its own CPU where permitted (one warning
line otherwise, also a ``realtime`` event in the record), and without garbage collection (frozen
and disabled during an experiment, collected between experiments). A simulated scene in
realtime mode serves its devices from a separate process (:class:`hil.bench.runtime.ProcessSimBench`),
so the loop under test talks to external devices as at a real bench.

Everything runs inside :func:`safe_stop_context`: on a limit breach, watchdog miss, signal, device
failure (DeviceFault, CRC/protocol error past the adapter's tolerance, timeout, OSError or termios
error of a lost port), record write error or any other exception, every actuator is commanded
zero effort (an uninterruptible :meth:`hil.bench.stopflag.StopRequest.critical` section), the reason is
recorded, and the record is closed with every sample taken so far. A stop ends the whole
:meth:`Runner.run`: no further experiment starts (:attr:`Runner.stop_status` / ``stop_reason``).

Memory is bounded: the runner keeps no per-sample copies. Experiments' ``finish()`` read the
channels they need back from the flushed record (h5py datasets, read in blocks where possible);
loop-timing percentiles come from a fixed log-spaced histogram.

Port energy. For each network port with a force sensor, the power into the device is F_port · V
with F_port = ``force_sign`` × (the sensor's port axes): the force applied *to* the device,
positive along the port velocity (see ``hil.scene.spec.PortCfg``). E_s(t) = ∫ F_port · V dt (paper 000
eq. 6) is integrated with the trapezoid rule and recorded as ``<port>.energy``.

Each experiment opens its own bench (``bench_factory(variant)``): an SDEA experiment may need the
locked- or free-output plant, and a fresh bench makes every experiment reproducible on its own.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.bench.stopflag import STOP, StopRequested
from hil.errors import DeviceDisconnected, DeviceError, DeviceTimeout, HilError, SafetyStop
from hil.protocols.base import sample_age

try:  # a vanished serial port raises termios.error (not an OSError) from pyserial
    import termios

    _PORT_ERRORS: tuple[type[BaseException], ...] = (OSError, termios.error)
except ImportError:  # pragma: no cover - Windows
    _PORT_ERRORS = (OSError,)
#: what ends an experiment while the bench opens: a stop request, a device failure, a vanished port
_OPEN_ERRORS: tuple[type[BaseException], ...] = (SafetyStop, DeviceError, *_PORT_ERRORS)

logger = logging.getLogger(__name__)

#: per-tick device read timeout (s) of the realtime loop on external devices: 0, never wait for a
#: sample (a device that falls silent is a watchdog stop on its samples' age, ``watchdog_ms``)
REALTIME_READ_TIMEOUT_S = 0.0

__all__ = ["ExperimentOutcome", "LoopStats", "Runner", "SafetyMonitor", "one_line", "safe_stop_context"]


# ---------------------------------------------------------------------------------------------
# safety


def _all_finite(a: np.ndarray) -> bool:
    """No NaN or inf in the float array ``a``: a NaN or an inf makes ``a . a`` non-finite, so one
    dot product decides the usual case; only a non-finite one (or a value so large its square
    overflows) takes the exact ``isfinite`` check."""
    flat = a if a.ndim == 1 else a.reshape(-1)
    return math.isfinite(float(np.dot(flat, flat))) or bool(np.isfinite(a).all())


class SafetyMonitor:
    """Limits from the scene's ``safety`` section; :meth:`check` raises :class:`SafetyStop`.

    * ``max_effort``: |commanded effort| per DOF (N or N.m) -- a controller asking for more is
      treated as a breach, not clipped (clipping would hide an instability);
    * ``max_velocity`` (m/s or rad/s) and ``position_limits`` [lo, hi] on every actuator DOF;
    * ``max_energy``: |E_s| of any port (J);
    * ``watchdog_ms``: device feedback whose sequence number does not advance for longer than this
      (run time) is stale; a realtime tick later than this past its deadline is a loop overrun.

    Every comparison is NaN-safe (written as ``not value <= limit``): a NaN never passes a limit.
    :meth:`check_finite` stops on any NaN/inf reading, naming the channel and the tick.
    """

    def __init__(self, safety: Mapping[str, Any] | None, rate_hz: float) -> None:
        s = dict(safety or {})
        self.max_effort = float(s.get("max_effort", math.inf) or math.inf)
        self.max_velocity = float(s.get("max_velocity", math.inf) or math.inf)
        lim = s.get("position_limits")
        self.pos_lo, self.pos_hi = (float(lim[0]), float(lim[1])) if lim else (-math.inf, math.inf)
        self.max_energy = float(s.get("max_energy", math.inf) or math.inf)
        self.watchdog_s = float(s.get("watchdog_ms", 100.0)) / 1000.0
        ml = s.get("max_lateness_ms")
        self.max_lateness_s = float(ml) / 1000.0 if ml else self.watchdog_s
        self.max_overrun_fraction = float(s.get("max_overrun_fraction", 0.01) if s.get("max_overrun_fraction")
                                          is not None else 0.01)
        self.dt = 1.0 / rate_hz
        self._last_seq: dict[str, tuple[int, float]] = {}

    def check_feedback(self, t: float, meas: Mapping[str, Any]) -> None:
        """Freshness and limits of one tick's feedback (``t``: run time, s).

        Freshness comes from the device, not from the read: each sample carries ``produced_at``
        (when the device produced the data, on the adapter's clock) and ``t`` (when it was read,
        same clock), so its age is ``sample.t - sample.produced_at``. Data older than
        ``watchdog_ms`` is a watchdog stop naming the device. On a simulated bench the adapters'
        clock is the simulated one, so a lockstep run stops on the same tick on every machine:
        the first tick whose data is more than ``watchdog_ms`` old, i.e. within ``watchdog_ms`` +
        one tick of the last fresh data. Samples without ``produced_at`` (NaN) fall back to their
        sequence number: one that does not advance for longer than ``watchdog_ms`` of run time.
        """
        limit = self.watchdog_s + 1e-9
        for name, sample in meas.items():
            produced = float(getattr(sample, "produced_at", math.nan))
            if not math.isnan(produced):
                age = float(getattr(sample, "t", produced)) - produced
                if not age <= limit:  # also catches a NaN age
                    raise SafetyStop(f"watchdog: feedback of {name!r} is {1e3 * age:.1f} ms old "
                                     f"(limit {1e3 * self.watchdog_s:.0f} ms, seq {getattr(sample, 'seq', '?')})")
            else:
                seq = int(getattr(sample, "seq", -1))
                prev = self._last_seq.get(name)
                if prev is None or seq != prev[0]:
                    self._last_seq[name] = (seq, t)
                elif t - prev[1] > limit:
                    raise SafetyStop(f"watchdog: feedback of {name!r} stale for {1e3 * (t - prev[1]):.0f} ms "
                                     f"(limit {1e3 * self.watchdog_s:.0f} ms)")
            pos = getattr(sample, "position", None)
            if pos is None:
                continue
            vel = sample.velocity
            # this runs for every device on every tick: a one-DOF device's values are read directly
            if vel.size == 1:
                vmax = abs(float(vel.item()))
            else:
                vmax = max(float(vel.max()), -float(vel.min())) if vel.size else 0.0
                if math.isnan(float(vel.sum())):  # max() of a NaN and a number may give the number
                    vmax = math.nan
            if pos.size == 1:
                pmin = pmax = float(pos.item())
            else:
                pmin, pmax = (float(pos.min()), float(pos.max())) if pos.size else (0.0, 0.0)
            if not (math.isfinite(vmax) and math.isfinite(pmin) and math.isfinite(pmax)):
                raise SafetyStop(f"fault: non-finite feedback from {name!r}")
            if vmax > self.max_velocity:
                raise SafetyStop(f"limit: |velocity| of {name!r} = {vmax:.4g} > {self.max_velocity:.4g}")
            if pmin < self.pos_lo or pmax > self.pos_hi:
                raise SafetyStop(f"limit: position of {name!r} = {np.array2string(np.asarray(pos), precision=4)} "
                                 f"outside [{self.pos_lo:.4g}, {self.pos_hi:.4g}]")

    def check_command(self, efforts: Mapping[str, np.ndarray]) -> None:
        for name, u in efforts.items():
            if type(u) is np.ndarray and u.size == 1:  # the per-tick case: one scalar comparison
                x = float(u.item())
                if math.isfinite(x) and abs(x) <= self.max_effort:
                    continue
            if not np.all(np.isfinite(u)):
                raise SafetyStop(f"fault: non-finite effort command for {name!r}")
            if not np.all(np.abs(u) <= self.max_effort):
                raise SafetyStop(f"limit: |effort| command for {name!r} = {np.max(np.abs(u)):.4g} "
                                 f"> {self.max_effort:.4g}")

    def check_finite(self, k: int, t: float, meas: Mapping[str, Any]) -> None:
        """Any NaN or inf in a device's position, velocity, reported effort or wrench is a stop naming
        the channel and the tick (a drive that reports no effort has ``effort`` None, not NaN)."""
        for name, sample in meas.items():
            for field_ in ("position", "velocity", "effort", "wrench"):
                v = getattr(sample, field_, None)
                if v is None:
                    continue
                a = v if type(v) is np.ndarray and v.dtype == np.float64 else np.asarray(v, dtype=float)
                if not _all_finite(a):
                    raise SafetyStop(f"fault: non-finite {name}.{field_} at tick {k} (t = {t:.6g} s): "
                                     f"{np.array2string(a.reshape(-1), precision=4)}")

    def check_energy(self, energies: Mapping[str, float]) -> None:
        for port, e in energies.items():
            if not abs(e) <= self.max_energy:  # NaN-safe: a NaN energy is a stop, not a pass
                raise SafetyStop(f"limit: |energy| at port {port!r} = {abs(e):.4g} J > {self.max_energy:.4g} J"
                                 if math.isfinite(e) else f"fault: non-finite energy at port {port!r} ({e})")

    def check_overrun(self, late_s: float) -> None:
        """A tick later than ``max_lateness_ms`` (default ``watchdog_ms``) is a stop (NaN-safe)."""
        if not late_s <= self.max_lateness_s:
            raise SafetyStop(f"late loop: tick {1e3 * late_s:.1f} ms late "
                             f"(limit max_lateness_ms = {1e3 * self.max_lateness_s:g} ms)")


# ---------------------------------------------------------------------------------------------
# signals and the safe-stop context


def one_line(exc: BaseException) -> str:
    """``"Type: message"`` on one line (device and record errors as they go into a stop reason)."""
    msg = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


def classify(exc: BaseException) -> tuple[str, str]:
    """``(status, reason)`` of the exception that ended an experiment.

    SafetyStop: its own status (a signal's StopRequested: ``interrupted`` for SIGINT) and message;
    KeyboardInterrupt (Ctrl-C outside the installed handlers): ``interrupted``; device errors
    (DeviceFault, ProtocolError/ChecksumError past the adapter's tolerance), OSError/termios errors
    of a lost port: ``safety_stop`` with reason ``"device: ..."``; a DeviceTimeout /
    DeviceDisconnected: ``"watchdog: ..."``; any other HilError (e.g. a RecordError):
    ``safety_stop`` with ``"fault: ..."``; anything else: ``error`` (a bug).
    """
    if isinstance(exc, SafetyStop):
        return getattr(exc, "status", "safety_stop"), str(exc) or type(exc).__name__
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted", "interrupted (Ctrl-C)"
    if isinstance(exc, DeviceTimeout | DeviceDisconnected):
        return "safety_stop", f"watchdog: {one_line(exc)}"
    if isinstance(exc, (DeviceError, *_PORT_ERRORS)):
        return "safety_stop", f"device: {one_line(exc)}"
    if isinstance(exc, HilError):
        return "safety_stop", f"fault: {one_line(exc)}"
    return "error", f"error: {one_line(exc)}"


@contextlib.contextmanager
def safe_stop_context(stop: Callable[[], Any], on_stop: Callable[[str, str], None]) -> Iterator[None]:
    """Run a block so that any way out of it other than normal completion commands zero effort.

    ``stop()`` must command zero effort and never raise (:meth:`hil.bench.runtime.Bench.safe_stop`: an
    uninterruptible section); ``on_stop(reason, status)`` records why (see :func:`classify`).
    Signals are stop requests (:data:`hil.bench.stopflag.STOP`, installed for the block) that the block
    turns into a :class:`~hil.bench.stopflag.StopRequested` at its safe points. Only exceptions
    classified ``error`` (bugs) are re-raised after the safe stop; safety stops, interrupts,
    device and record failures end the block normally.
    """
    with STOP.install():
        try:
            yield
        except BaseException as exc:
            status, reason = classify(exc)
            if status != "error" and not isinstance(exc, StopRequested) and not STOP.requested:
                STOP.request(reason, status)  # a stop ends the whole run
            try:
                stop()
            finally:
                on_stop(reason, status)
            if status == "error":
                raise


# ---------------------------------------------------------------------------------------------
# loop


_LATE_BINS_PER_DECADE = 50
_LATE_MIN_S = 1e-7  # 0.1 us .. 100 s: 9 decades


@dataclass
class LoopStats:
    """Timing of the loop: how far each tick started after its deadline (s), in bounded memory.

    ``late_max`` is exact; the percentiles come from a log-spaced histogram (50 bins per decade,
    0.1 us .. 100 s: within ±2.4 % of the exact value). Every tick's lateness is in the record
    (``loop.late``).
    """

    ticks: int = 0
    overruns: int = 0
    mode: str = "lockstep"
    scheduling: str = ""
    late_n: int = 0
    late_max: float = 0.0
    #: realtime: the machine's steal time during the loop [s] (:func:`hil.run.realtime.steal_time_s`)
    steal_s: float | None = None
    hist: np.ndarray = field(default_factory=lambda: np.zeros(9 * _LATE_BINS_PER_DECADE + 2, dtype=np.int64))

    def add_late(self, late: float) -> None:
        """Account one tick's lateness ``late`` (s)."""
        self.late_n += 1
        self.late_max = max(self.late_max, late)
        if late <= _LATE_MIN_S:
            i = 0
        else:
            i = min(self.hist.size - 1, 1 + int(math.log10(late / _LATE_MIN_S) * _LATE_BINS_PER_DECADE))
        self.hist[i] += 1

    def _percentile(self, q: float) -> float:
        c = np.cumsum(self.hist)
        i = int(np.searchsorted(c, q / 100.0 * self.late_n, side="left"))
        if i == 0:
            return 0.0
        lo = _LATE_MIN_S * 10 ** ((i - 1) / _LATE_BINS_PER_DECADE)  # geometric bin centre
        return min(self.late_max, lo * 10 ** (0.5 / _LATE_BINS_PER_DECADE))

    def summary(self) -> dict[str, Any]:
        """``ticks``, ``overruns``, ``mode``; realtime: ``scheduling``, ``steal_ms`` (the machine's
        steal time during the loop, ms, summed over its CPUs, where readable) and ``late_p50_us`` /
        ``late_p99_us`` / ``late_max_us`` (µs)."""
        out: dict[str, Any] = {"ticks": self.ticks, "overruns": self.overruns, "mode": self.mode}
        if self.scheduling:
            out["scheduling"] = self.scheduling
        if self.steal_s is not None:
            out["steal_ms"] = 1e3 * self.steal_s
        if not self.late_n:
            return out
        return {**out, "late_p50_us": 1e6 * self._percentile(50),
                "late_p99_us": 1e6 * self._percentile(99), "late_max_us": 1e6 * self.late_max}


@dataclass
class ExperimentOutcome:
    """What one experiment produced. ``status``: completed | safety_stop | interrupted | error."""

    name: str
    status: str
    stop_reason: str
    record: Path | None
    results: dict[str, Any]
    stats: dict[str, float]

    @property
    def completed(self) -> bool:
        return self.status == "completed"

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "status": self.status, "stop_reason": self.stop_reason,
                "record": str(self.record) if self.record else None, "results": self.results, "loop": self.stats}


def _dump(cfg: Any) -> dict[str, Any]:
    if cfg is None:
        return {"type": "none"}
    if hasattr(cfg, "model_dump"):
        return cfg.model_dump()
    return dict(cfg)


class Runner:
    """Runs a scene's experiments on a :class:`hil.bench.runtime.Bench`, one record file per experiment.

    ``realtime=None`` takes the scene's mode (lockstep for simulated benches). ``progress`` is a
    callable ``(name, k, n)`` called every ~0.1 s of run time (the CLI draws a progress bar).

    Realtime options: ``clock_ns`` / ``sleep`` (the loop's clock in ns and its sleep in s; defaults
    ``time.perf_counter_ns`` / ``time.sleep``; tests inject a fake clock), ``rt_scheduling``
    (False: no SCHED_FIFO / mlockall / affinity, e.g. in tests), ``gc_pause`` (False: leave the
    garbage collector alone), ``spin_ns`` (the hybrid wait's spin window; None: 100 µs under
    SCHED_FIFO, 200 µs otherwise, :func:`hil.run.realtime.spin_for`; 0: sleep only), ``read_timeout``
    (s, passed to every tick's ``bench.read``; None: the bench's own, ``watchdog_ms`` on hardware).
    The default bench of a simulated scene in realtime mode serves its devices from another process
    (:class:`hil.bench.runtime.ProcessSimBench`).
    """

    #: realtime mode: the record is written by a writer thread (:class:`hil.record.hdf5.RecordWriter`
    #: ``background=True``), so no HDF5 write or flush runs inside a tick; False: synchronous flushes
    #: in the tick (as in lockstep mode, which always writes synchronously)
    record_thread: bool = True
    #: ... and its h5py calls by a writer process (``background="process"``, blocks in shared
    #: memory): the loop never waits for the GIL held by h5py (a 100-sample block costs ~4 ms of
    #: HDF5 CPU on the 2-core KVM guest, all of it with the GIL held); False: in the writer thread
    record_process: bool = True

    def __init__(self, scene: Any, out_dir: str | Path, *, bench_factory: Callable[[str | None], Any] | None = None,
                 realtime: bool | None = None, progress: Callable[[str, int, int], None] | None = None,
                 max_ticks: int | None = None, overwrite: bool = False,
                 clock_ns: Callable[[], int] | None = None, sleep: Callable[[float], Any] | None = None,
                 rt_scheduling: bool = True, gc_pause: bool = True, spin_ns: int | None = None,
                 read_timeout: float | None = None, live: Any = None) -> None:
        self.scene = scene
        #: ``hil run --live``: a :class:`hil.run.live.LiveView` the records are teed to (None: off)
        self.live = live
        #: replace an existing record of the same name (``hil run --overwrite``); refused otherwise
        self.overwrite = bool(overwrite)
        mode = getattr(scene, "mode", None) or ("lockstep" if getattr(scene, "simulation", None) else "realtime")
        self.realtime = (mode == "realtime") if realtime is None else realtime
        if bench_factory is None:
            from hil.bench.runtime import Bench, ProcessSimBench

            cls = ProcessSimBench if self.realtime and getattr(scene, "simulation", None) is not None else Bench

            def bench_factory(variant: str | None) -> Any:
                return cls(scene, seed=scene.seed, variant=variant)

        self.bench_factory = bench_factory
        # _as_sent: whether the current bench has an adapter that quantizes its effort (per bench)
        self._wire_checked: Any = None
        self._wire_any = False
        self.bench: Any = None
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.rate_hz = float(scene.rate_hz)
        self.dt = 1.0 / self.rate_hz
        self.clock_ns = clock_ns
        self.sleep = sleep
        self.rt_scheduling = bool(rt_scheduling)
        self.gc_pause = bool(gc_pause)
        self.spin_ns = spin_ns
        self.read_timeout = read_timeout
        self.progress = progress
        self.max_ticks = max_ticks
        self.devices = {d.name: d for d in scene.devices}
        self.devices.update({g.name: scene.device(g.name) for g in getattr(scene, "groups", [])})
        self.ports = list(getattr(getattr(scene, "network", None), "ports", None) or [])
        #: per port: name, dofs, force sign, sensor, actuator, energy / human channel, zero force
        self._port_plan = [(p.name, int(p.dofs), float(getattr(p, "force_sign", 1)), p.force_sensor, p.actuator,
                            f"{p.name}.energy", f"{p.name}.human", np.zeros(int(p.dofs))) for p in self.ports]

    # -- channels ---------------------------------------------------------------------------------
    def _actuator_like(self) -> list[Any]:
        """Actuators plus device groups (recorded under the group name too)."""
        groups = [self.scene.device(g.name) for g in getattr(self.scene, "groups", [])]
        return [d for d in self.scene.devices if d.role == "actuator"] + groups

    def _channels(self, meas0: Mapping[str, Any]) -> dict[str, Any]:
        """Channel specs; sensor wrench sizes come from a first reading ``meas0``."""
        from hil.controllers import DEFAULT_UNITS
        from hil.record.hdf5 import ChannelSpec

        lin = getattr(self.scene, "units", DEFAULT_UNITS) == "linear"
        pu, vu, fu = ("m", "m/s", "N") if lin else ("rad", "rad/s", "N.m")
        ch: dict[str, Any] = {}
        for d in self._actuator_like() + [d for d in self.scene.devices if d.role != "actuator"]:
            n = int(d.dof)
            if d.role == "actuator":
                ch[f"{d.name}.position"] = ChannelSpec((n,), pu, "measured position")
                ch[f"{d.name}.velocity"] = ChannelSpec((n,), vu, "measured velocity")
                ch[f"{d.name}.effort"] = ChannelSpec((n,), fu, "effort reported by the drive (NaN if none)")
                ch[f"{d.name}.effort_cmd"] = ChannelSpec((n,), fu, "commanded effort (controller + excitation), "
                                                         "as encoded on the wire (adapter effort_on_wire)")
                ch[f"{d.name}.excitation"] = ChannelSpec((n,), fu, "experiment part of the commanded effort")
            else:
                nw = int(np.asarray(meas0[d.name].wrench).size)
                ch[f"{d.name}.wrench"] = ChannelSpec((nw,), "N, N.m", "measured wrench (all axes)")
        for p in self.ports:
            if getattr(p, "force_sensor", None):
                ch[f"{p.name}.energy"] = ChannelSpec((1,), "J", "E_s(t) = ∫ F_port·V dt into the device at the port")
                ch[f"{p.name}.human"] = ChannelSpec((int(p.dofs),), fu, "active force of the simulated operator")
        if self.realtime:  # realtime records only (a lockstep record's channels are unchanged)
            for d in self.scene.devices:
                ch[f"{d.name}.age"] = ChannelSpec((1,), "s", "age of the device's sample when the tick read it "
                                                  "(sample.t - produced_at, adapter clock; 0 if unknown)")
        ch["loop.late"] = ChannelSpec((1,), "s", "tick start after its deadline (realtime mode; 0 in lockstep)")
        ch["loop.tick_start"] = ChannelSpec((1,), "s", "actual start of the tick on the loop's monotonic clock, "
                                            "since the deadline of tick 0 (lockstep: the simulated time)")
        return ch

    # -- one experiment --------------------------------------------------------------------------
    @staticmethod
    def _name(index: int, ecfg: Mapping[str, Any]) -> str:
        return f"{index:02d}_{ecfg.get('name') or ecfg.get('type', 'experiment')}"

    def run_experiment(self, index: int, cfg: Any) -> ExperimentOutcome:
        """Run one experiment on a fresh bench; see the module docstring.

        A stop request or device failure while the bench opens (the bench commands zero effort to
        what it opened, then closes) gives an outcome without a record."""
        ecfg = _dump(cfg)
        name = self._name(index, ecfg)
        try:
            bench = self.bench_factory(ecfg.get("variant"))
        except _OPEN_ERRORS as exc:
            status, reason = classify(exc)
            reason = f"{reason} (while the bench was opening)"
            STOP.request(reason, status)
            logger.warning("%s: safe stop: %s", name, reason)
            return ExperimentOutcome(name, status, reason, None, {}, {"ticks": 0, "overruns": 0})
        with bench:
            self.bench = bench
            try:
                return self._run(index, ecfg, cfg)
            finally:
                self.bench = None

    @staticmethod
    def _append_event(writer: Any, t: float, kind: str, message: str) -> None:
        """An event in the record; a write error is a safe stop (as for samples)."""
        try:
            writer.event(t, kind, message)
        except (HilError, OSError) as exc:
            raise SafetyStop(f"record: {one_line(exc)}") from exc

    def _append(self, writer: Any, t: float, values: Mapping[str, Any]) -> None:
        """Append one sample; a record write error (RecordError, OSError: full disk, ...) is a safe stop."""
        try:
            writer.append(t, values)
        except (HilError, OSError) as exc:
            raise SafetyStop(f"record: {one_line(exc)}") from exc

    def _run(self, index: int, ecfg: dict[str, Any], cfg: Any = None) -> ExperimentOutcome:
        from hil.controllers import DEFAULT_UNITS, make_controller
        from hil.experiments import make_experiment
        from hil.record.hdf5 import RecordWriter

        name = self._name(index, ecfg)
        # the validated scene entry (hil.experiments schemas) when there is one; a mapping is validated once
        exp = make_experiment(cfg if cfg is not None else ecfg, rate_hz=self.rate_hz)
        exp.check(self.scene)
        ccfg = None if ecfg.get("controller") == "none" else getattr(self.scene, "controller", None)
        units = getattr(self.scene, "units", DEFAULT_UNITS)
        ctrl = make_controller(ccfg, units=units, scene=self.scene)
        ctrl.reset()
        n = round(exp.duration * self.rate_hz)
        if self.max_ticks is not None:
            n = min(n, self.max_ticks)
        safety = SafetyMonitor(_dump(getattr(self.scene, "safety", None)), self.rate_hz)
        path = self.out_dir / f"{name}.h5"
        state = {"status": "completed", "reason": "completed"}
        stats = LoopStats(mode="realtime" if self.realtime else "lockstep")
        held: list[Any] = []  # the record writer, once created
        energy = {p.name: 0.0 for p in self.ports if getattr(p, "force_sensor", None)}
        last_power: dict[str, float] = {}

        zeroed: dict[str, str] = {}
        now = {"t": 0.0}  # run time [s] of the tick in progress: a stop's events are dated by it

        def stop() -> None:
            zeroed.update(self.bench.safe_stop() or {})

        def on_stop(reason: str, status: str) -> None:
            state["status"], state["reason"] = status, reason
            logger.warning("%s: safe stop: %s", name, reason)
            if held:
                per = ", ".join(f"{k}: {v}" for k, v in zeroed.items()) or "no actuator"
                with contextlib.suppress(Exception):
                    held[0].event(now["t"], status, reason)
                    held[0].event(now["t"], "safe_stop", f"zero effort commanded ({per})")

        with safe_stop_context(stop, on_stop):  # first reading: channel sizes
            STOP.check()
            first_wait = self._realtime_wait_s()
            meas0 = self.bench.read() if first_wait is None else self.bench.read(first_wait)
        if state["status"] != "completed":
            return ExperimentOutcome(name, state["status"], state["reason"], None, {}, stats.summary())
        meta = {"scene": self.scene.name, "experiment": ecfg, "seed": getattr(self.scene, "seed", 0),
                "mode": "realtime" if self.realtime else "lockstep", "rate_hz": self.rate_hz,
                "devices": self.bench.device_identities(),
                "network": [p.model_dump() if hasattr(p, "model_dump") else dict(p) for p in self.ports],
                "units": units}
        try:
            # realtime: blocks are written by the record's writer thread, off the tick (a write error or a
            # writer that falls behind is raised by the next tick's append: a safe stop with the reason)
            writer = RecordWriter(path, scene_text=self.scene.source_text, scene_sha256=self.scene.sha256,
                                  meta=meta, channels=self._channels(meas0), rate_hz=self.rate_hz,
                                  overwrite=self.overwrite, planned_samples=n,
                                  background=(("process" if self.record_process else "thread")
                                              if self.realtime and self.record_thread else False))
        except BaseException:
            self.bench.safe_stop()
            raise
        if self.live is not None:  # samples and events also offered to the live view (never blocks a tick)
            writer = self.live.tee(writer, name)
        held.append(writer)
        no_exc = _NoExcitation()
        steal0 = math.nan
        try:
            with contextlib.ExitStack() as rt, safe_stop_context(stop, on_stop):
                pacer = guard = None
                if self.realtime:
                    from hil.run.realtime import (
                        LatenessGuard,
                        Pacer,
                        gc_paused,
                        realtime_scheduling,
                        spin_for,
                        steal_time_s,
                    )

                    sched = rt.enter_context(realtime_scheduling(enabled=self.rt_scheduling))
                    stats.scheduling = sched.describe()
                    if writer.background and sched.fifo:  # below the loop's priority, off the loop's CPU
                        from hil.run.realtime import FIFO_PRIORITY, WRITER_PROCESS_FIFO_PRIORITY

                        why = writer.set_writer_scheduling(FIFO_PRIORITY - 1, sched.other_cpus,
                                                           process_priority=WRITER_PROCESS_FIFO_PRIORITY)
                        if why:
                            logger.warning("%s: record writer thread: %s", name, why)
                    self._append_event(writer, 0.0, "realtime", f"loop scheduling: {sched.describe()}"
                                       + (f"; warning: {sched.warning}" if sched.warning else ""))
                    rt.enter_context(gc_paused(self.gc_pause))
                    pacer = Pacer(self.rate_hz, clock_ns=self.clock_ns, sleep=self.sleep,
                                  spin_ns=spin_for(sched) if self.spin_ns is None else self.spin_ns)
                    guard = LatenessGuard(self.rate_hz, safety.max_lateness_s, safety.max_overrun_fraction)
                    steal0 = steal_time_s()
                    pacer.start()
                read_timeout = self._tick_read_timeout()
                cmd_wait = self._realtime_wait_s()
                row = _TickRow(self, meas0)  # the record row's keys and constant arrays, built once
                for k in range(n):
                    t = k * self.dt
                    now["t"] = t
                    STOP.check()  # the safe point of a stop request (signal)
                    late = 0.0
                    start = t
                    if pacer is not None and guard is not None:  # realtime: both set together
                        late = pacer.wait(k) * 1e-9
                        start = (pacer.start_ns - pacer.t0) * 1e-9
                        stats.add_late(late)
                        if late > self.dt:
                            stats.overruns += 1
                        assert guard is not None  # created with the pacer
                        try:
                            guard.check(k, late)
                        except SafetyStop:  # the late tick's timing is in the record (device channels NaN)
                            self._append(writer, t, {"loop.late": late, "loop.tick_start": start})
                            stats.ticks = k + 1
                            raise
                    # DeviceTimeout/Disconnected -> "watchdog: ...", faults -> "device: ..."
                    meas = self.bench.read() if read_timeout is None else self.bench.read(read_timeout)
                    try:
                        safety.check_finite(k, t, meas)
                    except SafetyStop:  # the breach sample goes into the record (nothing computed from it)
                        self._append(writer, t, row.fill(meas, row.nan_u, no_exc, late, start))
                        stats.ticks = k + 1
                        raise
                    u = {key: np.asarray(v, float).copy() for key, v in ctrl.update(t, self.dt, meas).items()}
                    exc = exp.excitation(k, t, meas)
                    for key, v in (exc.effort or {}).items():
                        u[key] = u.get(key, np.zeros_like(np.asarray(v, float))) + np.asarray(v, float)
                    values = row.fill(meas, self._as_sent(u), exc, late, start)
                    self._port_energy(k, meas, exc, energy, last_power, values)
                    self._append(writer, t, values)  # before the checks: a breach sample is recorded
                    stats.ticks = k + 1
                    safety.check_feedback(t, meas)
                    safety.check_command(u)
                    safety.check_energy(energy)
                    if cmd_wait is None:
                        self.bench.command(u)
                    else:  # realtime: bounded by the watchdog (see _realtime_wait_s)
                        self.bench.command(u, timeout=cmd_wait)
                    for port, f in (exc.human or {}).items():
                        self.bench.set_human_force(port, np.asarray(f, float))
                    if self.progress and k % max(1, int(self.rate_hz / 10)) == 0:
                        self.progress(name, k, n)
                    self.bench.advance()  # lockstep plant step (no-op on hardware)
                if state["status"] == "completed":
                    self.bench.safe_stop()
                    try:
                        writer.flush()  # a full disk here is still a safe stop of this experiment
                    except (HilError, OSError) as exc:
                        raise SafetyStop(f"record: {one_line(exc)}") from exc
            if math.isfinite(steal0):  # realtime: what the machine's host took during the loop (evidence)
                from hil.run.realtime import steal_time_s

                stolen = steal_time_s() - steal0
                if math.isfinite(stolen):
                    stats.steal_s = stolen
                    with contextlib.suppress(HilError, OSError):
                        writer.event(now["t"], "realtime", f"steal time during the loop: {1e3 * stolen:.0f} ms "
                                     "(summed over the CPUs: the hypervisor ran other work while this machine "
                                     "wanted to run; lateness no setting removes)")
            counters = self._device_counters()
            if counters:
                with contextlib.suppress(HilError, OSError):  # evidence of tolerated faults, kept in the record
                    writer.set_device_counters(counters)
            results: dict[str, Any] = {}
            if state["status"] != "error":
                results = self._finish(exp, path, writer, meta, name)
                if results:
                    with contextlib.suppress(HilError):
                        writer.set_results(name, results)
            if writer.samples == 0 and state["status"] != "completed":  # say so: an empty record is not a run
                state["reason"] = f"{state['reason']} (before the first sample: the record holds none)"
            try:
                writer.close(stop_reason=state["reason"], status=state["status"])
            except (HilError, OSError) as exc:  # the record could not be closed: still a safe stop
                reason = f"record: {one_line(exc)}"
                if state["status"] == "completed":
                    state["status"], state["reason"] = "safety_stop", reason
                else:
                    state["reason"] = f"{state['reason']}; {reason}"
                STOP.request(state["reason"], state["status"])
                logger.error("%s: %s", name, reason)
            if counters:
                results = {**results, "device_counters": counters}
            return ExperimentOutcome(name, state["status"], state["reason"], path, results, stats.summary())
        finally:
            with contextlib.suppress(Exception):
                writer.close(stop_reason=state["reason"], status=state["status"])

    def _device_counters(self) -> dict[str, dict[str, int]]:
        """Per-device fault counters (CRC errors, resyncs, dropped, late, stale frames, retries) of the
        bench, or {} when the bench does not report them."""
        get = getattr(self.bench, "device_counters", None)
        if get is None:
            return {}
        try:
            return {str(d): {str(k): int(v) for k, v in c.items()} for d, c in (get() or {}).items() if c}
        except Exception as exc:  # counters are evidence, never a reason to lose the record
            logger.warning("device counters not read: %s", one_line(exc))
            return {}

    def _finish(self, exp: Any, path: Path, writer: Any, meta: Mapping[str, Any], name: str) -> dict[str, Any]:
        """The experiment's ``finish()`` on the channels read back from the flushed record."""
        try:
            writer.flush()
            with _RecordChannels(path) as data:
                return dict(exp.finish(data, meta) or {})
        except HilError as exc:
            return {"error": str(exc)}
        except Exception as exc:  # partial data of a stopped run, an unreadable record: not the loop's concern
            logger.warning("%s: results not computed: %s", name, one_line(exc), exc_info=True)
            return {"error": one_line(exc)}

    def _as_sent(self, u: Mapping[str, np.ndarray]) -> Mapping[str, np.ndarray]:
        """The commanded efforts as the adapters put them on the wire: an adapter that quantizes or
        clamps its command (``effort_on_wire(effort) -> effort``, e.g. CiA 402 per-mille torque,
        CubeMars 12-bit torque, DYNAMIXEL 2.69 mA current units) reports what it encodes, so the
        record's ``effort_cmd`` is the effort the drive applies; others are recorded as commanded.
        A group's effort is mapped member by member (in the group's order). A bench none of whose
        adapters quantizes gets ``u`` back unchanged (decided once per bench: the tick path)."""
        acts = getattr(self.bench, "actuators", None) or {}
        if self._wire_checked is not self.bench:
            self._wire_checked = self.bench
            self._wire_any = any(hasattr(a, "effort_on_wire") for a in acts.values())
        if not self._wire_any:
            return u
        out: dict[str, np.ndarray] = {}
        for key, v in u.items():
            group = self.scene.group(key) if hasattr(self.scene, "group") else None
            members = list(group.devices) if group is not None else [key]
            if not any(hasattr(acts.get(m), "effort_on_wire") for m in members):
                out[key] = v
                continue
            arr = np.asarray(v, float).reshape(-1)
            dofs = [int(self.scene.device(m).dof) for m in members]
            if arr.size != sum(dofs) or not np.all(np.isfinite(arr)):  # refused after the record row: as is
                out[key] = v
                continue
            parts = np.split(arr, np.cumsum(dofs)[:-1])
            out[key] = np.concatenate([np.asarray(acts[m].effort_on_wire(p), float).reshape(-1)
                                       if hasattr(acts.get(m), "effort_on_wire") else p
                                       for m, p in zip(members, parts, strict=True)])
        return out

    def _tick_read_timeout(self) -> float | None:
        """The per-tick read timeout (s): ``read_timeout`` when given; otherwise, in realtime mode on
        a bench whose devices are external (hardware, :class:`hil.bench.runtime.ProcessSimBench`),
        :data:`REALTIME_READ_TIMEOUT_S` (0: take the newest sample that has arrived, never wait;
        a device that stops sending is the watchdog's, on the samples' age); None (the bench's own,
        ``watchdog_ms``-based) in lockstep mode, whose devices publish one sample per tick."""
        if self.read_timeout is not None:
            return self.read_timeout
        if self.realtime and not getattr(self.bench, "lockstep", False):
            return REALTIME_READ_TIMEOUT_S
        return self._realtime_wait_s()

    def _realtime_wait_s(self) -> float | None:
        """Realtime mode: the longest a device call of the loop may wait, ``watchdog_ms`` (or the
        bench's own timeout when shorter). A device that answers later than that is lost whatever the
        bench: an in-process simulated bench (``lockstep``, whose own timeout is
        ``LOCKSTEP_WAIT_FACTOR`` x ``watchdog_ms`` for lockstep runs) then stops within about
        ``watchdog_ms`` too (issue 27). None in lockstep mode: the bench's own timeouts."""
        if not self.realtime:
            return None
        w = float(getattr(getattr(self.scene, "safety", None), "watchdog_ms", 50.0)) / 1000.0
        own = getattr(self.bench, "timeout", None)
        return min(w, float(own)) if isinstance(own, int | float) else w

    def _port_energy(self, k: int, meas: Mapping[str, Any], exc: Any, energy: dict[str, float],
                     last_power: dict[str, float], values: dict[str, Any]) -> None:
        """Advance E_s(t) = ∫ F_port·V dt (trapezoid) at every port with a force sensor."""
        human_by_port = exc.human
        for pname, dofs, sign, sensor, actuator, ke, kh, zeros in self._port_plan:
            if pname not in energy:
                continue
            f_port = sign * np.asarray(self.bench.force(meas, sensor))[:dofs]
            v_port = np.asarray(meas[actuator].velocity)[:dofs]
            power = float(f_port @ v_port)
            if k > 0:
                energy[pname] += 0.5 * (power + last_power[pname]) * self.dt
            last_power[pname] = power
            values[ke] = energy[pname]
            human = human_by_port.get(pname, zeros) if human_by_port else zeros
            values[kh] = np.asarray(human, float)[:dofs]

    def run(self, select: list[int] | None = None) -> list[ExperimentOutcome]:
        """Run the scene's experiments (or the indices ``select``) in order, one bench each.

        Signal handlers (:data:`hil.bench.stopflag.STOP`) are installed for the whole run. Any stop
        (limit, watchdog, device or record failure, signal, error) ends the run: no further
        experiment starts. A stop requested between experiments or while a bench closes adds an
        outcome for the next experiment (``"<reason> (before it started)"``, no record); after
        the last one it is in :attr:`stop_status` / :attr:`stop_reason` (None when nothing stopped).
        """
        outcomes: list[ExperimentOutcome] = []
        self.stop_status: str | None = None
        self.stop_reason: str | None = None
        cfgs = self.scene.experiment_models() if hasattr(self.scene, "experiment_models") else self.scene.experiments
        with STOP.install():
            for i, cfg in enumerate(cfgs):
                if select is not None and i not in select:
                    continue
                if STOP.requested:
                    status, reason = STOP.status or "safety_stop", STOP.reason or "stop requested"
                    outcomes.append(ExperimentOutcome(self._name(i, _dump(cfg)), status,
                                                      f"{reason} (before it started)", None, {},
                                                      {"ticks": 0, "overruns": 0}))
                    logger.warning("%s not started: %s", outcomes[-1].name, reason)
                    break
                out = self.run_experiment(i, cfg)
                outcomes.append(out)
                if out.status != "completed":
                    break
            if STOP.requested:
                self.stop_status, self.stop_reason = STOP.status or "safety_stop", STOP.reason
        return outcomes


class _TickRow:
    """One record row, reused on every tick: its channel names and constant arrays (zero commands,
    NaN efforts of a drive that reports none) are built once, so the per-tick path creates no keys,
    dicts or arrays of its own (the record writer copies the values into its preallocated chunk)."""

    def __init__(self, runner: Runner, meas0: Mapping[str, Any]) -> None:
        self.values: dict[str, Any] = {"loop.late": 0.0, "loop.tick_start": 0.0}
        self.act: list[tuple[str, str, str, str, str, str, np.ndarray, np.ndarray]] = []
        self.sensors: list[tuple[str, str]] = []
        for dname in meas0:
            d = runner.devices[dname]
            if d.role == "actuator":
                n = int(d.dof)
                zeros = np.zeros(n)
                zeros.flags.writeable = False  # shared by every row: nobody may change it
                nans = np.full(n, np.nan)
                nans.flags.writeable = False
                self.act.append((dname, f"{dname}.position", f"{dname}.velocity", f"{dname}.effort",
                                 f"{dname}.effort_cmd", f"{dname}.excitation", zeros, nans))
            else:
                self.sensors.append((dname, f"{dname}.wrench"))
        self.nan_u = {a.name: np.full(int(a.dof), np.nan) for a in runner._actuator_like()}
        self.ages: list[tuple[str, str]] = ([(d.name, f"{d.name}.age") for d in runner.scene.devices]
                                            if runner.realtime else [])

    def fill(self, meas: Mapping[str, Any], u: Mapping[str, np.ndarray], exc: Any, late: float,
             start: float) -> dict[str, Any]:
        """The row of one tick (device channels; ports are added by :meth:`Runner._port_energy`)."""
        values = self.values
        values["loop.late"] = late
        values["loop.tick_start"] = start
        exc_effort = exc.effort
        for dname, kp, kv, ke, kc, kx, zeros, nans in self.act:
            s = meas[dname]
            values[kp] = s.position
            values[kv] = s.velocity
            values[ke] = s.effort if s.effort is not None else nans
            values[kc] = u.get(dname, zeros)
            values[kx] = exc_effort.get(dname, zeros) if exc_effort else zeros
        for dname, kw in self.sensors:
            values[kw] = meas[dname].wrench
        for dname, ka in self.ages:
            values[ka] = sample_age(meas[dname])
        return values


class _NoExcitation:
    """The excitation of a tick whose feedback was unusable (nothing computed)."""

    effort = None
    human = None


class _RecordChannels(Mapping[str, Any]):
    """``t`` and the channels of a flushed record as h5py datasets (read lazily, in blocks by the
    experiments that can; ``np.asarray(ds)`` reads one whole channel)."""

    def __init__(self, path: Path) -> None:
        import h5py

        try:
            self._f = h5py.File(path, "r")
        except OSError:  # held open by a writer process (SWMR write): read it as a SWMR reader
            self._f = h5py.File(path, "r", swmr=True)
        g = self._f["channels"]
        self._n = min([self._f["t"].shape[0], *(g[k].shape[0] for k in g)])

    def __enter__(self) -> _RecordChannels:
        return self

    def __exit__(self, *exc: object) -> None:
        self._f.close()

    def _ds(self, key: str) -> Any:
        return self._f["t"] if key == "t" else self._f["channels"][key]

    def __getitem__(self, key: str) -> Any:
        try:
            ds = self._ds(key)
        except KeyError:
            raise KeyError(key) from None
        return ds if ds.shape[0] == self._n else ds[: self._n]

    def __iter__(self) -> Iterator[str]:
        return iter(["t", *self._f["channels"]])

    def __len__(self) -> int:
        return 1 + len(self._f["channels"])


def bench_never_opened(outcomes: Sequence[Any], runner: Any) -> str | None:
    """The reason when the run ended while its bench was still opening (a device absent or
    unreachable) and no experiment wrote a record: then nothing ran, and ``hil run`` / ``hil
    certify`` stop with :class:`hil.errors.BenchUnavailable`. None otherwise (a signal while opening
    is the person's stop, not a missing device)."""
    reason = str(getattr(runner, "stop_reason", "") or "")
    if not reason.endswith("(while the bench was opening)") or reason.startswith("signal"):
        return None
    if any(getattr(o, "record", None) is not None for o in outcomes):
        return None
    return reason.removesuffix(" (while the bench was opening)").removeprefix("watchdog: ")
