"""The fixed-rate experiment loop, with safety limits, a watchdog and a safe stop.

One tick (period dt = 1/rate_hz):

1. read every device (adapters, with timeouts) -> measurements;
2. controller effort + experiment excitation -> commanded effort;
3. safety check (effort, velocity, position, injected port energy, stale feedback, loop overrun);
   a breach raises :class:`hil.errors.SafetyStop`;
4. command the actuators, set the simulated human's active force;
5. append the sample to the run record (streamed to HDF5, flushed every 0.1 s of run time);
6. lockstep: advance the simulated plant by exactly dt; realtime: sleep until the next absolute
   deadline (monotonic nanosecond clock) and account overruns and jitter.

Everything runs inside :func:`safe_stop_context`: on any exception, limit breach, watchdog miss,
Ctrl-C or SIGTERM every actuator is commanded zero effort, the reason is recorded, and the record
is closed with every sample taken so far.

Port energy. For each network port with a force sensor, the power into the device is F_port · V
with F_port = ``force_sign`` × (the sensor's port axes): the force applied *to* the device,
positive along the port velocity (see ``hil.scene.PortCfg``). E_s(t) = ∫ F_port · V dt (paper 000
eq. 6) is integrated with the trapezoid rule and recorded as ``<port>.energy``.

Each experiment opens its own bench (``bench_factory(variant)``): an SDEA experiment may need the
locked- or free-output plant, and a fresh bench makes every experiment reproducible on its own.
"""

from __future__ import annotations

import contextlib
import logging
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import DeviceDisconnected, DeviceTimeout, HilError, SafetyStop

log = logging.getLogger(__name__)

__all__ = ["ExperimentOutcome", "LoopStats", "Runner", "SafetyMonitor", "safe_stop_context"]


# ---------------------------------------------------------------------------------------------
# safety


class SafetyMonitor:
    """Limits from the scene's ``safety`` section; :meth:`check` raises :class:`SafetyStop`.

    * ``max_effort``: |commanded effort| per DOF (N or N.m) -- a controller asking for more is
      treated as a breach, not clipped (clipping would hide an instability);
    * ``max_velocity`` (m/s or rad/s) and ``position_limits`` [lo, hi] on every actuator DOF;
    * ``max_energy``: |E_s| of any port (J);
    * ``watchdog_ms``: device feedback whose sequence number does not advance for longer than this
      (run time) is stale; a realtime tick later than this past its deadline is a loop overrun.
    """

    def __init__(self, safety: Mapping[str, Any] | None, rate_hz: float) -> None:
        s = dict(safety or {})
        self.max_effort = float(s.get("max_effort", math.inf) or math.inf)
        self.max_velocity = float(s.get("max_velocity", math.inf) or math.inf)
        lim = s.get("position_limits")
        self.pos_lo, self.pos_hi = (float(lim[0]), float(lim[1])) if lim else (-math.inf, math.inf)
        self.max_energy = float(s.get("max_energy", math.inf) or math.inf)
        self.watchdog_s = float(s.get("watchdog_ms", 100.0)) / 1000.0
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
            # one reduction per array (this runs for every device on every tick)
            vmax = float(np.max(np.abs(vel))) if vel.size else 0.0
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
            if not np.all(np.isfinite(u)):
                raise SafetyStop(f"fault: non-finite effort command for {name!r}")
            if np.any(np.abs(u) > self.max_effort):
                raise SafetyStop(f"limit: |effort| command for {name!r} = {np.max(np.abs(u)):.4g} "
                                 f"> {self.max_effort:.4g}")

    def check_energy(self, energies: Mapping[str, float]) -> None:
        for port, e in energies.items():
            if abs(e) > self.max_energy:
                raise SafetyStop(f"limit: |energy| at port {port!r} = {abs(e):.4g} J > {self.max_energy:.4g} J")

    def check_overrun(self, late_s: float) -> None:
        if late_s > self.watchdog_s:
            raise SafetyStop(f"watchdog: loop tick {1e3 * late_s:.1f} ms late (limit {1e3 * self.watchdog_s:.0f} ms)")


# ---------------------------------------------------------------------------------------------
# signals and the safe-stop context


class _SignalGuard:
    """Turn SIGTERM into a SafetyStop in the main thread (Ctrl-C arrives as KeyboardInterrupt)."""

    def __init__(self) -> None:
        self._old: Any = None

    def __enter__(self) -> _SignalGuard:
        if threading.current_thread() is threading.main_thread():
            self._old = signal.getsignal(signal.SIGTERM)

            def handler(signum: int, frame: Any) -> None:
                raise SafetyStop("signal: SIGTERM")

            signal.signal(signal.SIGTERM, handler)
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._old is not None:
            signal.signal(signal.SIGTERM, self._old)


@contextlib.contextmanager
def safe_stop_context(stop: Callable[[], None], on_stop: Callable[[str, str], None]) -> Iterator[None]:
    """Run a block so that any way out of it other than normal completion commands zero effort.

    ``stop()`` must command zero effort and never raise; ``on_stop(reason, status)`` records why
    (status ``"safety_stop"`` for limits/watchdog/signals, ``"interrupted"`` for Ctrl-C,
    ``"error"`` for anything else). Exceptions other than :class:`SafetyStop` and
    KeyboardInterrupt are re-raised after the safe stop.
    """
    try:
        with _SignalGuard():
            yield
    except SafetyStop as exc:
        stop()
        on_stop(str(exc), "safety_stop")
    except KeyboardInterrupt:
        stop()
        on_stop("interrupted (Ctrl-C)", "interrupted")
    except BaseException as exc:
        stop()
        on_stop(f"error: {type(exc).__name__}: {exc}", "error")
        raise


# ---------------------------------------------------------------------------------------------
# loop


@dataclass
class LoopStats:
    """Timing of the loop: ``late`` = how far each tick started after its deadline (s)."""

    ticks: int = 0
    overruns: int = 0
    late: list[float] = field(default_factory=list)

    def summary(self) -> dict[str, float]:
        if not self.late:
            return {"ticks": self.ticks, "overruns": self.overruns}
        a = np.asarray(self.late) * 1e6
        return {"ticks": self.ticks, "overruns": self.overruns, "late_p50_us": float(np.percentile(a, 50)),
                "late_p99_us": float(np.percentile(a, 99)), "late_max_us": float(a.max())}


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
    """Runs a scene's experiments on a :class:`hil.bench.Bench`, one record file per experiment.

    ``realtime=None`` takes the scene's mode (lockstep for simulated benches). ``progress`` is a
    callable ``(name, k, n)`` called every ~0.1 s of run time (the CLI draws a progress bar).
    """

    def __init__(self, scene: Any, out_dir: str | Path, *, bench_factory: Callable[[str | None], Any] | None = None,
                 realtime: bool | None = None, progress: Callable[[str, int, int], None] | None = None,
                 max_ticks: int | None = None) -> None:
        self.scene = scene
        if bench_factory is None:
            from hil.bench import Bench

            def bench_factory(variant: str | None) -> Any:
                return Bench(scene, seed=scene.seed, variant=variant)

        self.bench_factory = bench_factory
        self.bench: Any = None
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.rate_hz = float(scene.rate_hz)
        self.dt = 1.0 / self.rate_hz
        mode = getattr(scene, "mode", None) or ("lockstep" if getattr(scene, "simulation", None) else "realtime")
        self.realtime = (mode == "realtime") if realtime is None else realtime
        self.progress = progress
        self.max_ticks = max_ticks
        self.devices = {d.name: d for d in scene.devices}
        self.devices.update({g.name: scene.device(g.name) for g in getattr(scene, "groups", [])})
        self.ports = list(getattr(getattr(scene, "network", None), "ports", None) or [])

    # -- channels ---------------------------------------------------------------------------------
    def _actuator_like(self) -> list[Any]:
        """Actuators plus device groups (recorded under the group name too)."""
        groups = [self.scene.device(g.name) for g in getattr(self.scene, "groups", [])]
        return [d for d in self.scene.devices if d.role == "actuator"] + groups

    def _channels(self, meas0: Mapping[str, Any]) -> dict[str, Any]:
        """Channel specs; sensor wrench sizes come from a first reading ``meas0``."""
        from hil.record import ChannelSpec

        lin = getattr(self.scene, "units", "rotary") == "linear"
        pu, vu, fu = ("m", "m/s", "N") if lin else ("rad", "rad/s", "N.m")
        ch: dict[str, Any] = {}
        for d in self._actuator_like() + [d for d in self.scene.devices if d.role != "actuator"]:
            n = int(d.dof)
            if d.role == "actuator":
                ch[f"{d.name}.position"] = ChannelSpec((n,), pu, "measured position")
                ch[f"{d.name}.velocity"] = ChannelSpec((n,), vu, "measured velocity")
                ch[f"{d.name}.effort"] = ChannelSpec((n,), fu, "effort reported by the drive (NaN if none)")
                ch[f"{d.name}.effort_cmd"] = ChannelSpec((n,), fu, "commanded effort (controller + excitation)")
                ch[f"{d.name}.excitation"] = ChannelSpec((n,), fu, "experiment part of the commanded effort")
            else:
                nw = int(np.asarray(meas0[d.name].wrench).size)
                ch[f"{d.name}.wrench"] = ChannelSpec((nw,), "N, N.m", "measured wrench (all axes)")
        for p in self.ports:
            if getattr(p, "force_sensor", None):
                ch[f"{p.name}.energy"] = ChannelSpec((1,), "J", "E_s(t) = ∫ F_port·V dt into the device at the port")
                ch[f"{p.name}.human"] = ChannelSpec((int(p.dofs),), fu, "active force of the simulated operator")
        ch["loop.late"] = ChannelSpec((1,), "s", "tick start after its deadline (realtime mode)")
        return ch

    # -- one experiment --------------------------------------------------------------------------
    def run_experiment(self, index: int, cfg: Any) -> ExperimentOutcome:
        """Run one experiment on a fresh bench; see the module docstring."""
        ecfg = _dump(cfg)
        with self.bench_factory(ecfg.get("variant")) as bench:
            self.bench = bench
            try:
                return self._run(index, ecfg)
            finally:
                self.bench = None

    def _run(self, index: int, ecfg: dict[str, Any]) -> ExperimentOutcome:
        from hil.controllers import make_controller
        from hil.experiments import make_experiment
        from hil.record import RecordWriter

        name = f"{index:02d}_{ecfg.get('name') or ecfg.get('type', 'experiment')}"
        exp = make_experiment(ecfg, rate_hz=self.rate_hz)
        exp.check(self.scene)
        ccfg = {"type": "none"} if ecfg.get("controller") == "none" else _dump(getattr(self.scene, "controller", None))
        ctrl = make_controller(ccfg, units=getattr(self.scene, "units", "rotary"), scene=self.scene)
        ctrl.reset()
        n = round(exp.duration * self.rate_hz)
        if self.max_ticks is not None:
            n = min(n, self.max_ticks)
        safety = SafetyMonitor(_dump(getattr(self.scene, "safety", None)), self.rate_hz)
        path = self.out_dir / f"{name}.h5"
        meta = {"scene": self.scene.name, "experiment": ecfg, "seed": getattr(self.scene, "seed", 0),
                "mode": "realtime" if self.realtime else "lockstep", "rate_hz": self.rate_hz,
                "devices": self.bench.device_identities(),
                "network": [p.model_dump() if hasattr(p, "model_dump") else dict(p) for p in self.ports],
                "units": getattr(self.scene, "units", "rotary")}
        writer = RecordWriter(path, scene_text=self.scene.source_text, scene_sha256=self.scene.sha256, meta=meta,
                              channels=self._channels(self.bench.read()), rate_hz=self.rate_hz)
        state = {"status": "completed", "reason": "completed"}
        stats = LoopStats()
        buf: dict[str, list[Any]] = {"t": []}  # the same samples, kept for the experiment's analysis
        energy = {p.name: 0.0 for p in self.ports if getattr(p, "force_sensor", None)}
        last_power: dict[str, float] = {}

        def on_stop(reason: str, status: str) -> None:
            state["status"], state["reason"] = status, reason
            log.warning("%s: safe stop: %s", name, reason)
            with contextlib.suppress(Exception):
                writer.event(stats.ticks * self.dt, status, reason)
                writer.event(stats.ticks * self.dt, "safe_stop", "zero effort commanded on every actuator")

        try:
            with safe_stop_context(self.bench.safe_stop, on_stop):
                t0 = time.monotonic_ns()
                period_ns = round(1e9 / self.rate_hz)
                for k in range(n):
                    t = k * self.dt
                    late = 0.0
                    if self.realtime:
                        deadline = t0 + k * period_ns
                        now = time.monotonic_ns()
                        while now < deadline:
                            rem = deadline - now
                            if rem > 2_000_000:
                                time.sleep((rem - 1_000_000) / 1e9)
                            now = time.monotonic_ns()
                        late = (now - deadline) / 1e9
                        stats.late.append(late)
                        if late > self.dt:
                            stats.overruns += 1
                        safety.check_overrun(late)
                    try:
                        meas = self.bench.read()
                    except (DeviceTimeout, DeviceDisconnected) as exc:  # feedback missed: a watchdog stop
                        raise SafetyStop(f"watchdog: {exc}") from exc
                    safety.check_feedback(t, meas)
                    u = {key: np.asarray(v, float).copy() for key, v in ctrl.update(t, self.dt, meas).items()}
                    exc = exp.excitation(k, t, meas)
                    for key, v in (exc.effort or {}).items():
                        u[key] = u.get(key, np.zeros_like(np.asarray(v, float))) + np.asarray(v, float)
                    safety.check_command(u)
                    self.bench.command(u)
                    for port, f in (exc.human or {}).items():
                        self.bench.set_human_force(port, np.asarray(f, float))
                    values = self._sample_values(meas, u, exc, late)
                    self._port_energy(k, meas, exc, energy, last_power, values)
                    writer.append(t, values)
                    buf["t"].append(t)
                    for key, v in values.items():
                        buf.setdefault(key, []).append(np.array(v, dtype=float, copy=True))
                    safety.check_energy(energy)
                    stats.ticks = k + 1
                    if self.progress and k % max(1, int(self.rate_hz / 10)) == 0:
                        self.progress(name, k, n)
                    self.bench.advance()  # lockstep plant step (no-op on hardware)
            if state["status"] == "completed":
                self.bench.safe_stop()
            results: dict[str, Any] = {}
            if state["status"] != "error":
                data = {key: np.asarray(v) for key, v in buf.items()}
                try:
                    results = exp.finish(data, meta) or {}
                except HilError as exc:
                    results = {"error": str(exc)}
                if results:
                    writer.set_results(name, results)
            writer.close(stop_reason=state["reason"], status=state["status"])
            return ExperimentOutcome(name, state["status"], state["reason"], path, results, stats.summary())
        finally:
            with contextlib.suppress(Exception):
                writer.close(stop_reason=state["reason"], status=state["status"])

    def _sample_values(self, meas: Mapping[str, Any], u: Mapping[str, np.ndarray], exc: Any,
                       late: float) -> dict[str, Any]:
        """The record row of one tick (device channels; ports are added by :meth:`_port_energy`)."""
        values: dict[str, Any] = {"loop.late": late}
        for dname, s in meas.items():
            d = self.devices[dname]
            n = int(d.dof)
            if d.role == "actuator":
                values[f"{dname}.position"] = s.position
                values[f"{dname}.velocity"] = s.velocity
                values[f"{dname}.effort"] = s.effort if s.effort is not None else np.full(n, np.nan)
                values[f"{dname}.effort_cmd"] = u.get(dname, np.zeros(n))
                values[f"{dname}.excitation"] = (exc.effort or {}).get(dname, np.zeros(n))
            else:
                values[f"{dname}.wrench"] = s.wrench
        return values

    def _port_energy(self, k: int, meas: Mapping[str, Any], exc: Any, energy: dict[str, float],
                     last_power: dict[str, float], values: dict[str, Any]) -> None:
        """Advance E_s(t) = ∫ F_port·V dt (trapezoid) at every port with a force sensor."""
        for p in self.ports:
            if p.name not in energy:
                continue
            dofs = int(p.dofs)
            f_port = float(getattr(p, "force_sign", 1)) * np.asarray(self.bench.force(meas, p.force_sensor))[:dofs]
            v_port = np.asarray(meas[p.actuator].velocity)[:dofs]
            power = float(f_port @ v_port)
            if k > 0:
                energy[p.name] += 0.5 * (power + last_power[p.name]) * self.dt
            last_power[p.name] = power
            values[f"{p.name}.energy"] = energy[p.name]
            human = (exc.human or {}).get(p.name, np.zeros(dofs))
            values[f"{p.name}.human"] = np.asarray(human, float)[:dofs]

    def run(self, select: list[int] | None = None) -> list[ExperimentOutcome]:
        outcomes = []
        cfgs = self.scene.experiment_configs() if hasattr(self.scene, "experiment_configs") else self.scene.experiments
        for i, cfg in enumerate(cfgs):
            if select is not None and i not in select:
                continue
            out = self.run_experiment(i, cfg)
            outcomes.append(out)
            if out.status in ("interrupted", "error"):
                break
        return outcomes
