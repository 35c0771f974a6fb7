"""The bench: the devices of a scene behind their protocol adapters, real or simulated.

``Bench(scene, seed=None)`` opens every device of the scene through
:func:`hil.protocols.registry.open_device`. When the scene has a ``simulation`` block it first

1. builds the physics (:class:`hil.mocks.physics.Scene` -> :class:`~hil.mocks.physics.Plant`:
   bodies, the SDEA, springs, terminations, humans) and a lockstep
   :class:`hil.mocks.simulator.Simulator` at the scene's control period ``1 / rate_hz``;
2. starts each device's simulated counterpart on a real transport, attached to the DOFs of its body
   (``devices[].body`` / ``dofs``): ODrive and CubeMars nodes on a python-can *virtual* bus (one
   private channel per scene channel and bench, synchronous replies), a Bota sensor streaming into
   a pty, a Robotiq FT-300 behind a pymodbus server on a free loopback port (``robotiq_ft300``) or
   streaming on a pty (``robotiq_ft300_stream``: one frame per control period), a DYNAMIXEL chain on
   a pty;
3. opens the real adapters with the endpoint parameters filled in (pty path, URL, private CAN
   channel) and the simulated clock as their ``clock``, so sample times are ``k * dt``.

Lockstep tick (what the runner does once per control period)::

    meas = bench.read()            # every device; a second read in the same tick returns the same samples
    bench.command({"motor": u})    # efforts (N or N.m) per actuator
    bench.set_human_force("master", f)
    bench.advance()                # devices process pending frames, the plant steps exactly dt,
                                   # simulated sensors publish the new state

Nothing depends on the wall clock: with one seed, the measurements are bit-identical from run to
run and on any machine load (noise and fault injection use seeded generators; ``math.fsum`` state
updates; every adapter waits on simulated time, :attr:`Bench.waits`, behind a barrier that serves
its simulated device: :mod:`hil.protocols.waits`).

Simulated force sensors report, on the wrench components ``devices[].axes``, either the force the
body exerts on everything attached to it (``sim.measure: body``; for an SDEA motor this is the
series spring-damper torque ``F = K_f (x_m - x_e) + B_f (v_m - v_e)``) or the force the simulated
operator's hand exerts on the device (``human``: ``F_h = f_act - Z_h(s) v``, positive along the port
velocity, so ``F_h^T v`` is the power the operator injects).

Without ``simulation`` the adapters are opened with the scene's params as they are (real bench) and
:meth:`Bench.advance` is a no-op.

:class:`SimulatedScene` (what ``hil mock serve SCENE`` runs) builds the same physics and simulated
devices with the same code but opens no adapter: the devices run free (own threads, plant stepped
against the wall clock) and :attr:`SimulatedScene.endpoints` says where each one listens.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hil.bench.mechanics import device_mechanics, plant_mechanics
from hil.bench.stopflag import STOP
from hil.errors import DeviceDisconnected, DeviceTimeout, HilError, ModelError, SceneError
from hil.mocks.friction import quantize
from hil.mocks.twins import Twin, TwinContext
from hil.protocols.base import JointSample, WrenchSample
from hil.protocols.registry import device_kind, open_device, resolve_twin, simulated_drivers
from hil.protocols.waits import NO_BARRIER, WALL, LockstepWaits, Waits
from hil.scene.spec import (
    HumanCfg,
    ImpedanceTermination,
    NamedTermination,
    Scene,
    WallTermination,
)

__all__ = ["LOCKSTEP_WAIT_FACTOR", "SIMULATED_DRIVERS", "Bench", "Measurements", "ProcessSimBench", "SimEndpoint",
           "SimulatedScene"]

logger = logging.getLogger(__name__)

#: Device name -> latest sample (JointSample for actuators, WrenchSample for force sensors).
Measurements = dict[str, JointSample | WrenchSample]

#: Drivers for which the bench has a simulated counterpart (registered with a twin in
#: :mod:`hil.protocols.registry`; :func:`hil.protocols.registry.simulated_drivers` includes the
#: kinds registered later or through entry points).
SIMULATED_DRIVERS = tuple(simulated_drivers())

#: A lockstep bench's per-call device timeout in units of ``watchdog_ms`` (see :class:`Bench`): 1, as
#: at a real bench, because its waits are simulated (:class:`hil.protocols.waits.LockstepWaits`). It
#: was 20 while lockstep waits were wall-clock waits bounded by it (issue 26).
LOCKSTEP_WAIT_FACTOR = 1.0

_BENCH_IDS = itertools.count(1)
_BENCH_IDS_LOCK = threading.Lock()


def _seed_for(seed: int, *path: int) -> int:
    """A 32-bit seed derived from the bench seed and a path of integers (stable across runs)."""
    return int(np.random.SeedSequence([seed & 0xFFFFFFFF, *path]).generate_state(1)[0])


def _with_viscous(B: Any, dof: int, extra: np.ndarray | None) -> Any:
    """A body's damping ``B`` (number, diagonal list or matrix) plus ``diag(extra)``; ``B`` itself
    when nothing is added."""
    if extra is None or not np.any(extra):
        return B
    Bm = np.asarray(B, dtype=float)
    Bm = Bm * np.eye(dof) if Bm.ndim == 0 else (np.diag(Bm) if Bm.ndim == 1 else Bm)
    return Bm + np.diag(extra)


class _Noise:
    """Seeded additive Gaussian noise, drawn at most once per simulator tick (cached)."""

    def __init__(self, std: float, seed: int) -> None:
        self.std = float(std)
        self.rng = np.random.default_rng(seed)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return x + self.std * self.rng.standard_normal(x.shape) if self.std > 0 else x


class _BodyDrive:
    """Assembles the efforts several devices apply to DOF subsets of one body into the body's
    :class:`hil.mocks.simulator.Joints` handle (zero-order hold until changed).

    ``writes`` counts the writes (:meth:`set`, :meth:`reset`): a device that finds it unchanged
    since its own last write, and the handle not reset since (``handle.resets``), knows the
    handle still holds what it wrote (see :meth:`SimPoint.apply_effort`)."""

    def __init__(self, handle: Any) -> None:
        self.handle = handle
        self.effort = np.zeros(handle.dof)
        self.writes = 0
        self._lock = threading.Lock()

    def set(self, sel: list[int], effort: np.ndarray) -> None:
        with self._lock:
            self.effort[sel] = np.asarray(effort, dtype=float).reshape(len(sel))
            self.handle.apply_effort(self.effort)
            self.writes += 1

    def reset(self) -> None:
        with self._lock:
            self.effort[:] = 0.0
            self.handle.apply_effort(self.effort)
            self.writes += 1


class SimPoint:
    """The :class:`hil.mocks.interfaces.SimulatedJoints` a simulated device sees: DOFs ``sel`` of one
    body, with seeded measurement noise drawn once per simulator tick (repeated reads within a tick
    return the same values, as a sampled sensor would)."""

    def __init__(self, sim: Any, drive: _BodyDrive, sel: list[int], force_fn: Callable[[], np.ndarray], *,
                 position_std: float = 0.0, velocity_std: float = 0.0, force_std: float = 0.0,
                 seed: int = 0, encoder_step: float = 0.0, velocity_from: str = "estimate") -> None:
        self._sim = sim
        #: the encoder's quantization step (m or rad; 0: none) and how velocity is reported
        #: (``estimate``: the joint's; ``difference``: of the quantized positions over one period)
        self.encoder_step = float(encoder_step)
        self.velocity_from = velocity_from
        self._drive = drive
        self.sel = list(sel)
        self.dof = len(self.sel)
        # the same elements as indexing with the list `sel`, as a view when they are contiguous
        lo = self.sel[0] if self.sel else 0
        self._take: list[int] | slice = slice(lo, lo + self.dof) if self.sel == list(range(lo, lo + self.dof)) \
            else self.sel
        self._force_fn = force_fn
        self._noise = {
            "position": _Noise(position_std, _seed_for(seed, 1)),
            "velocity": _Noise(velocity_std, _seed_for(seed, 2)),
            "force": _Noise(force_std, _seed_for(seed, 3)),
        }
        self._cache: dict[str, tuple[int, np.ndarray]] = {}
        self._lock = threading.Lock()
        #: (effort, drive writes, handle resets) right after this point last wrote
        self._written: tuple[list[float], int, Any] | None = None

    @property
    def sample_index(self) -> int:
        return int(self._sim.step_count)

    def _read(self, key: str, raw: Callable[[], np.ndarray]) -> np.ndarray:
        with self._lock:
            k = self._sim.step_count
            hit = self._cache.get(key)
            if hit is not None and hit[0] == k:
                return hit[1].copy()
            value = self._noise[key](np.asarray(raw(), dtype=float).reshape(self.dof))
            if key == "position" and self.encoder_step > 0.0:
                value = quantize(value, self.encoder_step)
            self._cache[key] = (k, value)
            return value.copy()

    def apply_effort(self, effort: np.ndarray) -> None:
        """Effort (N or N.m) on the selected DOFs, held from the next tick on. Writing again what
        this point wrote last, with nothing written to or reset on the body since, changes nothing
        and is skipped (a CAN node re-applies its torque on every tick)."""
        e = np.asarray(effort, dtype=float).reshape(-1)
        vals = e.tolist()
        drive = self._drive
        w = self._written
        if w is not None and w[0] == vals and w[1] == drive.writes and w[2] == getattr(drive.handle, "resets", None):
            return
        drive.set(self.sel, e)
        self._written = (vals, drive.writes, getattr(drive.handle, "resets", None))

    def apply_uniform(self, value: float) -> None:
        """:meth:`apply_effort` of ``value`` on every selected DOF (``np.full(dof, value)``), with no
        array built when it changes nothing (a CAN drive re-applies its torque on every tick)."""
        vals = [float(value)] * self.dof
        drive = self._drive
        w = self._written
        if w is not None and w[0] == vals and w[1] == drive.writes and w[2] == getattr(drive.handle, "resets", None):
            return
        drive.set(self.sel, np.array(vals))
        self._written = (vals, drive.writes, getattr(drive.handle, "resets", None))

    def position(self) -> np.ndarray:
        return self._read("position", self._raw_position)

    def velocity(self) -> np.ndarray:
        return self._read("velocity", self._raw_velocity)

    def _raw_position(self) -> np.ndarray:
        return self._drive.handle.position()[self._take]

    def _raw_velocity(self) -> np.ndarray:
        if self.velocity_from == "difference":  # the drive differentiates its (quantized) encoder
            h, step = self._drive.handle, self.encoder_step
            dq = quantize(h.position()[self._take], step) - quantize(h.previous_position()[self._take], step)
            return dq / float(self._sim.dt)
        return self._drive.handle.velocity()[self._take]

    def measured_force(self) -> np.ndarray:
        return self._read("force", self._force_fn)


@dataclasses.dataclass
class _Dev:
    """One opened device: scene config, adapter and (simulated bench) its counterpart."""

    name: str
    cfg: Any
    adapter: Any = None
    sim: Any = None  # simulated device owned by this device (node / SimBota / SimulatedFT300 / DynamixelChain)
    point: SimPoint | None = None
    twin: Twin | None = None  # its kind's simulated twin (hil.mocks.twins)
    host: Any = None  # the simulated device serving it (its own sim, or one shared with other devices)

    @property
    def chain(self) -> Any:
        """The simulated device serving this one (a DYNAMIXEL chain may serve several)."""
        return self.host


class Bench:
    """All devices of a scene, opened; simulated behind real transports when the scene says so.

    Parameters
    ----------
    scene: a validated :class:`hil.scene.spec.Scene`.
    seed: seed of every simulated noise/fault generator (default: ``scene.seed``).
    variant: plant configuration of a simulated SDEA: ``"locked"`` (output fixed), ``"free"``
        (output inertia ``m_out``) or ``None`` (as the scene says: free iff ``m_out`` is set).
        Experiments with a different ``variant`` need their own bench.
    timeout: per-call device timeout (s) for reads and commands. Default (``None``): the scene's
        ``safety.watchdog_ms`` (a read never blocks longer than the runner's watchdog allows). A real
        bench measures it on the host's clock; a simulated bench on simulated time: its adapters
        wait through :attr:`waits` (:class:`hil.protocols.waits.LockstepWaits`), whose barrier
        (:meth:`settle`) serves every simulated device until it has processed what the host sent and
        its answers are readable, however long the machine takes, so a wait ends at once with its
        answer or, when the device sends none, after its timeout of simulated time. Nothing a
        lockstep run does depends on the wall clock or the machine's load.

    Attributes: ``actuators`` / ``sensors`` (name -> adapter), ``simulated`` (bool), ``simulator``
    (the :class:`hil.mocks.simulator.Simulator` or None), ``plant``, ``dt``, ``time``.
    """

    #: install the stop-request signal handlers while open (a SimulatedScene keeps the caller's)
    _install_stop = True
    #: a simulated bench's adapters wait on simulated time (a SimulatedScene runs free, without adapters)
    _simulated_time = True

    def __init__(self, scene: Scene, *, seed: int | None = None, variant: str | None = None,
                 timeout: float | None = None) -> None:
        self.scene = scene
        self.seed = int(scene.seed if seed is None else seed)
        self.dt = scene.dt
        self.simulated = scene.simulation is not None
        self.watchdog_s = float(getattr(getattr(scene, "safety", None), "watchdog_ms", 50.0)) / 1000.0
        if timeout is None:
            timeout = self.watchdog_s * (LOCKSTEP_WAIT_FACTOR if self.simulated else 1.0)
        self.timeout = float(timeout)
        #: per-actuator bound (s, wall clock) of :meth:`safe_stop` at a real bench (None on a lockstep
        #: bench: its adapters' waits are simulated, the stop ends when the devices have answered)
        self.safe_stop_timeout: float | None = max(1.0, 10.0 * self.timeout)
        #: the adapters' waits (:mod:`hil.protocols.waits`): simulated time on a lockstep bench
        self.waits: Waits = WALL
        self.variant = variant
        self.simulator: Any = None
        self.plant: Any = None
        self._devs: list[_Dev] = []
        self._drives: dict[str, _BodyDrive] = {}
        self._humans: dict[str, tuple[str, list[int], int]] = {}  # human name -> (body, sel, body dof)
        self._closed = False
        self._ticks = 0
        self._cache: tuple[int, Measurements] | None = None
        self._command_plan: Any = None  # see _build_command_plan
        self._sim_plan_cache: list[tuple[Twin, Any, list[Any]]] | None = None  # see _sim_plan
        with _BENCH_IDS_LOCK:
            self._bench_id = next(_BENCH_IDS)
        if variant not in (None, "locked", "free"):
            raise SceneError(f"{scene.name}: variant must be 'locked', 'free' or None, got {variant!r}")
        # Stop requests (SIGINT/SIGTERM/SIGHUP) are flags from here until close() has closed every
        # device: a signal while opening (actuators possibly armed) is a safe stop once opened.
        self._stop_held = False
        if self._install_stop:
            STOP.acquire()
            self._stop_held = True
        try:
            if self.simulated:
                self._build_simulation()
                if self._simulated_time:
                    self.waits = LockstepWaits(self._sim_clock(), self._flush_devices)
                    self.safe_stop_timeout = None
            self._open_devices()
            STOP.check()
        except BaseException:
            self.safe_stop()
            self.close()
            raise
        logger.info("bench for scene %r opened (%s, %d devices, seed %d)", scene.name,
                    "simulated" if self.simulated else "hardware", len(self._devs), self.seed)

    # -- public API -----------------------------------------------------------------------------

    @property
    def actuators(self) -> dict[str, Any]:
        """Actuator adapters by device name."""
        return {d.name: d.adapter for d in self._devs if d.cfg.role == "actuator" and d.adapter is not None}

    @property
    def sensors(self) -> dict[str, Any]:
        """Force-sensor adapters by device name."""
        return {d.name: d.adapter for d in self._devs if d.cfg.role == "force_sensor" and d.adapter is not None}

    @property
    def time(self) -> float:
        """Simulated time ``k * dt`` (s) in a simulated bench; ticks advanced * dt otherwise."""
        return self.simulator.time if self.simulator is not None else self._ticks * self.dt

    @property
    def ticks(self) -> int:
        """Number of :meth:`advance` calls so far."""
        return self._ticks

    @property
    def lockstep(self) -> bool:
        """True when the plant is simulated (the runner must call :meth:`advance` once per tick)."""
        return self.simulated

    def read(self, timeout: float | None = None) -> Measurements:
        """Latest sample of every device (raises the adapter's DeviceTimeout / DeviceFault / ...).

        In a simulated bench a second call within the same tick returns the cached samples: the
        devices publish one sample per control period.
        """
        self._check_open()
        if self.simulated and self._cache is not None and self._cache[0] == self._ticks:
            return dict(self._cache[1])
        t = self.timeout if timeout is None else float(timeout)
        # the pty byte barrier of a simulated stream: generous on the bench's own (lockstep) timeout,
        # never longer than a timeout the caller gives (a realtime loop: watchdog_ms, issue 27)
        barrier = max(t, 1.0) if timeout is None else t
        out: Measurements = {}
        for d in self._devs:
            out[d.name] = self._read_device(d, t, barrier)
        for g in self.scene.groups:
            out[g.name] = _group_sample([out[m] for m in g.devices])
        if self.simulated:
            self._cache = (self._ticks, dict(out))
        return out

    def _read_device(self, d: _Dev, t: float, barrier: float = 1.0) -> Any:
        """One adapter read; a timeout or lost device names the scene device. A simulated stream
        (Bota, FT-300 stream) is read behind a byte-count barrier: first every byte the simulated
        device wrote is received (``wait_rx``, on the adapter's simulated-time ``waits``: its bound
        never passes on the wall clock), then the read decides what is new without waiting, so the
        outcome does not depend on how fast the kernel moves pty bytes."""
        try:
            if (self.simulated and hasattr(d.sim, "tx_bytes") and hasattr(d.adapter, "wait_rx")
                    and d.adapter.wait_rx(d.sim.tx_bytes, barrier)):
                t = 0.0
            return d.adapter.read(timeout=t)
        except (DeviceTimeout, DeviceDisconnected) as exc:
            raise type(exc)(f"device {d.name!r}: {exc}") from exc

    def device_counters(self) -> dict[str, dict[str, int]]:
        """Fault counters of every device's adapter (:meth:`hil.protocols.base.Device.counters`:
        CRC errors, resyncs, dropped, late, stale frames, retries, ... as its protocol has them),
        by device name; plain ints, JSON-ready."""
        out: dict[str, dict[str, int]] = {}
        for d in self._devs:
            fn = getattr(d.adapter, "counters", None)
            try:
                counts = fn() if callable(fn) else {}
            except Exception:  # never let diagnostics break a stop or a close
                logger.warning("counters of %s failed", d.name, exc_info=True)
                counts = {}
            out[d.name] = {str(k): int(v) for k, v in counts.items()}
        return out

    def force(self, meas: Mapping[str, Any], sensor: str) -> np.ndarray:
        """The components of ``sensor``'s wrench that measure its DOFs (``devices[].axes``), (dof,)."""
        cfg = self.scene.device(sensor)
        return np.asarray(meas[sensor].wrench, dtype=float)[cfg.wrench_axes]

    def command(self, efforts: Mapping[str, Any], timeout: float | None = None) -> None:
        """Command efforts (N or N.m; arrays of the actuator's ``dof``) on the named actuators.

        Actuators not named keep their previous command. Unknown names or wrong sizes raise
        ValueError before anything is sent.
        """
        self._check_open()
        plan = self._command_plan
        if plan is None:  # built once the devices are open (name lookups, not per tick)
            plan = self._command_plan = self._build_command_plan()
        acts, groups, dofs_of = plan
        t = self.timeout if timeout is None else float(timeout)
        checked: list[tuple[Any, np.ndarray]] = []
        expanded: Mapping[str, Any] = efforts if not groups else {}
        for name, e in (efforts.items() if groups else ()):  # a group's effort is split over its members
            assert isinstance(expanded, dict)
            g = groups.get(name)
            if g is None:
                expanded[name] = e
                continue
            members, dofs, split = g
            arr = np.asarray(e, dtype=float).reshape(-1)
            if arr.size != sum(dofs):
                raise ValueError(f"command: group {name!r} has {sum(dofs)} DOF, got {arr.size} efforts")
            for m, part in zip(members, np.split(arr, split), strict=True):
                expanded[m] = part
        for name, e in expanded.items():
            if name not in acts:
                raise ValueError(f"command: {name!r} is not an actuator of scene {self.scene.name!r}; "
                                 f"actuators: {sorted(acts)}")
            arr = np.asarray(e, dtype=float).reshape(-1)
            dof = dofs_of[name]
            if arr.size != dof:
                raise ValueError(f"command: {name!r} has {dof} DOF, got {arr.size} efforts")
            if not all(map(math.isfinite, arr.tolist())):
                raise ValueError(f"command: non-finite effort for {name!r}: {arr}")
            checked.append((acts[name], arr))
        for adapter, arr in checked:
            adapter.command_effort(arr, timeout=t)

    def _build_command_plan(self) -> tuple[dict[str, Any], dict[str, tuple[list[str], list[int], Any]],
                                           dict[str, int]]:
        """(actuator adapters by name, group name -> (members, member dofs, split indices), actuator
        name -> dof): what :meth:`command` looks up, computed once per opened bench."""
        sc = self.scene
        groups: dict[str, tuple[list[str], list[int], Any]] = {}
        for g in sc.groups:
            dofs = [sc.device(m).dof for m in g.devices]
            groups[g.name] = (list(g.devices), dofs, np.cumsum(dofs)[:-1])
        acts = self.actuators
        return acts, groups, {name: sc.device(name).dof for name in acts}

    def set_human_force(self, port_or_body: str | Mapping[str, Any], force: Any = None) -> None:
        """Set the active force (N or N.m) of the simulated human at a port, held until changed.

        ``port_or_body``: the human's name, the body it holds, or a network port whose actuator is
        attached to that body. A mapping ``{port: force, ...}`` sets several at once (the
        ``Excitation.human`` of an experiment). No-op on a real bench (logged once).
        """
        if isinstance(port_or_body, Mapping):
            for k, v in port_or_body.items():
                self.set_human_force(k, v)
            return
        self._check_open()
        if not self.simulated:
            if not getattr(self, "_warned_human", False):
                logger.warning("set_human_force ignored: the bench is not simulated")
                self._warned_human = True
            return
        name = self._human_name(port_or_body)
        sl = self.plant.inputs[f"{name}.active"]
        f = np.asarray(force, dtype=float).reshape(-1)
        n = sl.stop - sl.start
        if f.size == 1 and n > 1:
            f = np.full(n, float(f[0]))
        if f.size != n:
            raise ValueError(f"human {name!r} has {n} DOF, got {f.size} force values")
        self.simulator.set_input(f"{name}.active", f)

    def advance(self) -> None:
        """One lockstep period: devices process pending frames, the plant steps exactly ``dt``,
        simulated devices publish the new state. No-op on a real bench (only counts ticks)."""
        self._check_open()
        self._ticks += 1
        if not self.simulated:
            return
        self._flush_devices()
        self.simulator.tick()
        for twin, sim, _ in self._sim_plan():
            twin.tick(sim)

    def safe_stop(self) -> dict[str, str]:
        """Zero effort on every actuator (and disable where the adapter does so). Never raises.

        Runs as a :meth:`hil.bench.stopflag.StopRequest.critical` section: a signal cannot cut it short.
        Every actuator is attempted, even when an earlier one raises or hangs: each adapter's
        ``safe_stop`` (whose bus calls have short timeouts of their own, 0.05 s per frame) runs in a
        worker thread given at most :attr:`safe_stop_timeout` s (default ``max(1 s, 10 x timeout)``;
        on a lockstep bench no wall-clock bound: its waits are simulated) before the next actuator
        is attempted. Returns, per actuator, ``"ok"``, ``"timeout after
        T s"`` or the one-line error (also logged).
        """
        done: dict[str, str] = {}
        limit = self.safe_stop_timeout
        with STOP.critical():
            for d in self._devs:
                if d.cfg.role != "actuator" or d.adapter is None:
                    continue
                box: list[str] = []

                def zero(adapter: Any = d.adapter, box: list[str] = box) -> None:
                    try:
                        adapter.safe_stop()
                        box.append("ok")
                    except BaseException as exc:
                        box.append(f"{type(exc).__name__}: {exc}")

                worker = threading.Thread(target=zero, name=f"safe-stop-{d.name}", daemon=True)
                worker.start()
                worker.join(limit)  # signals are handled meanwhile (they only count, see STOP)
                done[d.name] = box[0] if box else f"timeout after {limit or 0.0:g} s"
                if done[d.name] != "ok":
                    logger.error("safe_stop of %s failed: %s", d.name, done[d.name])
            with contextlib.suppress(Exception):
                self._flush_devices()
        return done

    def device_identities(self) -> dict[str, dict[str, Any]]:
        """Per device: driver, transport, vendor, model, serial, firmware, extra, role, simulated."""
        out: dict[str, dict[str, Any]] = {}
        for d in self._devs:
            info = getattr(d.adapter, "info", None)
            rec = (dataclasses.asdict(info) if dataclasses.is_dataclass(info) and not isinstance(info, type)
                   else {"driver": d.cfg.driver})
            rec["role"] = d.cfg.role
            rec["simulated"] = self.simulated
            out[d.name] = _jsonable(rec)
        return out

    def close(self) -> None:
        """Close the adapters, then the simulated devices. Idempotent, never raises."""
        if self._closed:
            return
        self._closed = True
        try:
            for d in self._devs:
                if d.adapter is not None:
                    try:
                        d.adapter.close()
                    except Exception:
                        logger.warning("closing adapter %s failed", d.name, exc_info=True)
            for d in self._devs:
                if d.sim is not None:
                    try:
                        d.sim.close()
                    except Exception:
                        logger.warning("closing simulated device %s failed", d.name, exc_info=True)
        finally:
            if getattr(self, "_stop_held", False):  # every device closed: signals back to the caller's
                self._stop_held = False
                STOP.release()
        logger.debug("bench for scene %r closed after %d ticks", self.scene.name, self._ticks)

    def __enter__(self) -> Bench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort
        with contextlib.suppress(Exception):
            if not self._closed:
                self.close()

    # -- internals: physics ---------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._closed:
            raise HilError(f"bench for scene {self.scene.name!r} is closed")

    def _human_name(self, key: str) -> str:
        if key in self._humans:
            return key
        for name, (body, _, _) in self._humans.items():
            if body == key:
                return name
        with contextlib.suppress(KeyError):
            port = self.scene.port(key)
            held = self.scene.device(port.actuator).body
            for name, (b, _, _) in self._humans.items():
                if b == held:
                    return name
        raise ValueError(f"no simulated human at {key!r}; humans: "
                         f"{ {n: b for n, (b, _, _) in self._humans.items()} }")

    def _build_simulation(self) -> None:
        from hil.lti import tf_matrix
        from hil.mocks import physics, terminations
        from hil.mocks.simulator import Simulator

        sc = self.scene
        sim = sc.simulation
        assert sim is not None
        label = sc.path or sc.name
        ps = physics.Scene(sc.units)
        # what the actuators add: their viscous damping (into the bodies' B) and dry friction
        extra_b, friction = plant_mechanics(sc, sim.body_dofs(self.variant), label)
        try:
            for b in sim.bodies:
                ps.add_body(b.name, _arr(b.M), _with_viscous(_arr(b.B), b.dof, extra_b.get(b.name)), _arr(b.K))
            if sim.sdea is not None:
                s = sim.sdea
                m_out = None if self.variant == "locked" else s.m_out
                if self.variant == "free" and m_out is None:
                    raise SceneError(f"{label}: simulation.sdea.m_out: variant 'free' needs the output inertia")
                b_motor = s.B + float(extra_b[s.name][0]) if s.name in extra_b else s.B
                ps.add_sdea(s.name, s.M, b_motor, s.K_f, s.B_f, m_out, s.b_out)
            bodies = set(ps.bodies)

            def port(body: str, dofs: list[int] | None, where: str) -> Any:
                if body not in bodies:
                    raise SceneError(f"{label}: {where}: body {body!r} does not exist in this configuration"
                                     f" (variant {self.variant!r})")
                return body if dofs is None else (body, list(dofs))

            for i, sp in enumerate(sim.springs):
                pa = port(sp.a, sp.a_dofs, f"simulation.springs[{i}].a")
                pb = None if sp.b is None else port(sp.b, sp.b_dofs, f"simulation.springs[{i}].b")
                ps.add_spring(pa, pb, _arr(sp.stiffness), _arr(sp.damping), name=sp.name or f"spring{i}")
            for i, t in enumerate(sim.terminations):
                p = port(t.port, t.dofs, f"simulation.terminations[{i}].port")
                tname = t.name if not isinstance(t, NamedTermination) else f"{t.name}_{t.port}"
                tname = tname or f"{t.type}_{t.port}_{i}"
                if isinstance(t, ImpedanceTermination):
                    entries = [[(e.num, e.den) for e in row] for row in t.tf]
                    ps.add_termination(p, terminations.Impedance(tf_matrix(entries), tname), tname)
                elif isinstance(t, WallTermination):
                    ps.add_termination(p, terminations.WallSpring(_arr(t.stiffness), _arr(t.damping), name=tname),
                                       tname)
                else:
                    term = terminations.t2_termination() if t.name == "T2" else _t1_termination()
                    ps.add_termination(p, term, tname)
            humans = sim.humans
            for i, h in enumerate(humans):
                hname = h.name or ("human" if len(humans) == 1 else f"human_{h.port}")
                where = "simulation.human" if isinstance(sim.human, HumanCfg) else f"simulation.human[{i}]"
                p = port(h.port, h.dofs, f"{where}.port")
                ps.add_human(p, terminations.Human(_arr(h.mass), _arr(h.damping), _arr(h.stiffness), None, hname),
                             hname)
                body_dof = ps.bodies[h.port].dof
                self._humans[hname] = (h.port, list(h.dofs) if h.dofs is not None else list(range(body_dof)),
                                       body_dof)
            self.plant = ps.build()
            self.simulator = Simulator(self.plant, self.dt, friction=friction or None)
        except ModelError as exc:
            raise SceneError(f"{label}: simulation: {exc}") from None
        self._drives = {name: _BodyDrive(h) for name, h in self.simulator.handles.items()}
        logger.debug("simulation built: %d bodies, %d states, dt = %g s", len(ps.bodies), self.plant.system.n,
                     self.dt)

    def _point(self, index: int, cfg: Any) -> SimPoint:
        sc = self.scene
        sim = sc.simulation
        label = sc.path or sc.name
        if cfg.body not in self._drives:
            raise SceneError(f"{label}: devices[{index}].body: body {cfg.body!r} does not exist in this "
                             f"configuration (variant {self.variant!r})")
        drive = self._drives[cfg.body]
        sel = list(cfg.dofs) if cfg.dofs is not None else list(range(drive.handle.dof))
        assert sim is not None  # only a simulated bench has measurement points
        noise = sim.sensor_noise
        dev_seed = cfg.sim.seed if cfg.sim.seed is not None else _seed_for(self.seed, 100 + index)
        if cfg.role == "force_sensor":
            measure = cfg.sim.measure
            human = next((n for n, (b, _, _) in self._humans.items() if b == cfg.body), None)
            if measure == "auto":
                measure = "human" if human is not None else "body"
            if measure == "human":
                if human is None:
                    raise SceneError(f"{label}: devices[{index}].sim.measure: no human holds body {cfg.body!r}")
                force_fn = self._human_force_fn(human, sel)
            else:
                handle = drive.handle
                force_fn = lambda: handle.measured_force()[sel]  # noqa: E731
            f_std = float(np.hypot(noise.force_std, cfg.sim.noise_std))
            return SimPoint(self.simulator, drive, sel, force_fn, force_std=f_std, seed=dev_seed)
        p_std = float(np.hypot(noise.position_std, cfg.sim.noise_std))
        mech = device_mechanics(cfg, sc.path or sc.name, index)
        return SimPoint(self.simulator, drive, sel, lambda: np.zeros(len(sel)), position_std=p_std,
                        velocity_std=noise.velocity_std, seed=dev_seed, encoder_step=mech.encoder_step,
                        velocity_from=mech.velocity)

    def _human_force_fn(self, human: str, sel: list[int]) -> Callable[[], np.ndarray]:
        _, hsel, body_dof = self._humans[human]
        simulator = self.simulator

        def f() -> np.ndarray:
            full = np.zeros(body_dof)
            # the element force is what the device exerts on the hand; the hand exerts its negative
            full[hsel] = -simulator.output(f"{human}.force")
            return full[sel]

        return f

    # -- internals: devices ---------------------------------------------------------------------

    def _open_devices(self) -> None:
        sc = self.scene
        channels: dict[tuple[str, str], str] = {}
        self._devs = [_Dev(cfg.name, cfg) for cfg in sc.devices]
        if self.simulated:
            for i, d in enumerate(self._devs):
                d.point = self._point(i, d.cfg)
        for i, d in enumerate(self._devs):
            cfg = d.cfg
            params = dict(cfg.params)
            if self.simulated:
                params = self._start_sim(i, d, params, channels)
            else:
                params.setdefault("timeout", self.timeout)
            device_kind(cfg.driver).watchdog_params(params, self.watchdog_s, self.simulated)
            try:
                d.adapter = open_device(cfg.driver, **params)
            except HilError:
                raise
            except (TypeError, ValueError) as exc:
                raise SceneError(f"{sc.path or sc.name}: devices[{i}].params: {exc}") from None
            if self.simulated:
                self._flush_devices()
        if self.simulated:
            for d in self._devs:  # first samples: publish the state at t = 0
                if d.sim is not None and d.twin is not None:
                    d.twin.publish(d.sim)

    def _start_sim(self, index: int, d: _Dev, params: dict[str, Any],
                   channels: dict[tuple[str, str], str]) -> dict[str, Any]:
        """Start the simulated counterpart of device ``d`` (its kind's twin); return the adapter params."""
        cfg = d.cfg
        label = self.scene.path or self.scene.name
        sims = simulated_drivers()
        if cfg.driver not in sims:
            raise SceneError(f"{label}: devices[{index}].driver: no simulated counterpart for driver {cfg.driver!r} "
                             f"(simulated: {', '.join(sims)})")
        seed, faults = self._sim_seed_faults(index, cfg)
        ctx = self._twin_context(index, d, seed, faults, channels)
        d.twin = resolve_twin(cfg.driver)
        d.sim, params = d.twin.start(ctx, params)
        d.host = d.twin.host(ctx, d.sim)
        if ctx.waits is not None:  # a wait of this device's adapter serves this device only
            ctx.waits.barrier = self._device_barrier(d.twin, d.host)
        logger.debug("simulated %s for device %s (seed %d)", type(d.host).__name__, cfg.name, seed)
        return params

    def _twin_context(self, index: int, d: _Dev, seed: int, faults: Any,
                      channels: dict[tuple[str, str], str]) -> TwinContext:
        """Lockstep: CAN nodes on python-can's virtual bus, one private channel per scene channel
        and bench; the adapters read the simulated clock."""
        waits = self.waits.link() if isinstance(self.waits, LockstepWaits) else None
        clock = self._sim_clock() if self.simulator is not None else self._clock
        return TwinContext(index, d.cfg, d.point, seed, faults, self.dt, float(self.scene.rate_hz), clock,
                           self.timeout, True, "virtual",
                           lambda iface, ch: channels.setdefault((iface, ch), f"{ch}.bench{self._bench_id}"),
                           self._devs, str(self.scene.path or self.scene.name), waits=waits)

    def _device_barrier(self, twin: Twin, host: Any) -> Callable[[], None]:
        """The lockstep barrier of one simulated device (``host``, which may serve several adapters,
        a DYNAMIXEL chain): its twin's ``flush``, or nothing when the twin says its device answers
        in the sender's thread (:meth:`hil.mocks.twins.Twin.answers_in_sender_thread`: a ``sync``
        CAN node). A wait of an adapter needs only its own device served (devices do not talk to
        each other within a wait); :meth:`advance` flushes all."""
        if twin.answers_in_sender_thread(host):
            return NO_BARRIER
        devs = self._devs
        wait = max(1.0, 10 * self.timeout)
        served: list[Any] = []  # the adapters on this device, once they are all open

        def barrier() -> None:
            adapters = served or [x.adapter for x in devs if x.host is host and x.adapter is not None]
            if not served and all(x.adapter is not None for x in devs):
                served.extend(adapters)
            twin.flush(host, adapters, wait)

        return barrier

    def _sim_seed_faults(self, index: int, cfg: Any) -> tuple[int, Any]:
        """Seed and :class:`hil.mocks.faults.FaultPlan` of the simulated counterpart of device
        ``index``."""
        from hil.mocks.faults import FaultPlan

        seed = cfg.sim.seed if cfg.sim.seed is not None else _seed_for(self.seed, 200 + index)
        return seed, FaultPlan.from_dict(cfg.sim.faults)

    def _sim_clock(self) -> Callable[[], float]:
        """The simulated clock as a plain function: ``step_count * dt`` of the simulator, the same
        float as :attr:`hil.mocks.simulator.Simulator.time` (read ~10 times a tick by the adapters
        and their waits: no property, no branch)."""
        sim = self.simulator
        dt = sim.dt
        return lambda: sim.step_count * dt

    def _clock(self) -> float:
        return self.simulator.time if self.simulator is not None else 0.0

    def _flush_devices(self) -> None:
        """The lockstep barrier (:attr:`waits`' ``settle``, and before each plant step): every simulated
        device processes what the host has sent and makes its answers readable (each twin's
        ``flush``: pty devices served in this thread, the Modbus server's answers counted)."""
        wait = max(1.0, 10 * self.timeout)
        for twin, sim, adapters in self._sim_plan():
            twin.flush(sim, adapters, wait)

    def _sim_plan(self) -> list[tuple[Twin, Any, list[Any]]]:
        """(twin, simulated device, adapters it serves) of every simulated device, in device order.
        While the devices are being opened it is rebuilt on each call (adapters appear one by
        one); once every device is open it is computed once (the per-tick loops use it)."""
        plan = self._sim_plan_cache
        if plan is not None:
            return plan
        plan = [(d.twin, d.sim, [x.adapter for x in self._devs if x.host is d.sim and x.adapter is not None])
                for d in self._devs if d.sim is not None and d.twin is not None]
        if self._devs and all(d.adapter is not None for d in self._devs):
            self._sim_plan_cache = plan
        return plan


@dataclasses.dataclass(frozen=True)
class SimEndpoint:
    """Where one simulated device of a :class:`SimulatedScene` listens.

    ``open_device(driver, **params)`` (:mod:`hil.protocols.registry`) connects an adapter to it;
    ``address`` is the same for humans; ``cross_process`` is False when only the serving process
    can reach it (python-can's ``virtual`` interface).
    """

    name: str
    driver: str
    role: str
    params: dict[str, Any]
    address: str
    cross_process: bool = True


#: python-can's default UDP multicast group; served CAN channels use 239.74.163.2, .3, ...
_UDP_MULTICAST_BASE = "239.74.163."
#: python-can's default UDP multicast port; served CAN channels use 43113, 43114, ... (one each)
_UDP_MULTICAST_BASE_PORT = 43113


class SimulatedScene(Bench):
    """A scene's simulated devices on their own, free-running in real time, without adapters.

    What ``hil mock serve SCENE`` runs so that another program (a bench GUI, a third-party client)
    can talk to the devices: the physics, the measurement points and the simulated devices are built
    by the same code as :class:`Bench` (same seeds, noise and fault plans), but

    * no adapter is opened: :attr:`endpoints` says where each device listens (pty path, TCP URL,
      CAN interface + channel) with the exact ``open_device`` parameters a client needs;
    * after :meth:`start`, a thread steps the plant at the scene's rate against the wall clock and
      the devices run on their own threads: CAN nodes tick at the scene rate (cyclic frames, requests
      answered as they arrive) on ``can_interface`` (``virtual``: this process only;
      ``udp_multicast``: any process on the host, each scene channel its own multicast group *and*
      UDP port, 239.74.163.2 / 43113, .3 / 43114, ..., unless ``can_channels`` / ``can_ports`` map
      scene channel -> group / port: python-can binds a channel's socket to its port on every
      address, so two channels on one port would hear each other's frames), the Bota sensor streams
      at the scene rate,
      the streaming FT-300 at ``stream_rate_hz`` once a client starts its stream, the Modbus FT-300
      refreshes its registers on every request, DYNAMIXEL chains answer as before.

    :meth:`read`, :meth:`command` and :meth:`advance` are not available (there are no adapters);
    :meth:`set_human_force` works. :meth:`close` stops every thread and closes every transport.
    """

    _install_stop = False  # ``hil mock serve`` handles its own SIGINT/SIGTERM
    _simulated_time = False  # free-running on the wall clock: no lockstep barrier

    def __init__(self, scene: Scene, *, seed: int | None = None, variant: str | None = None,
                 can_interface: str = "virtual", can_channels: Mapping[str, str] | None = None,
                 stream_rate_hz: float = 100.0, can_ports: Mapping[str, int] | None = None) -> None:
        if scene.simulation is None:
            raise SceneError(f"{scene.path or scene.name}: no 'simulation' block: nothing to simulate")
        self.can_interface = str(can_interface)
        self._can_map = {str(k): str(v) for k, v in (can_channels or {}).items()}
        self._port_map = {str(k): int(v) for k, v in (can_ports or {}).items()}
        self._chan_order: dict[str, int] = {}  # scene channel -> its rank (default group and port)
        self.stream_rate_hz = float(stream_rate_hz)
        self.endpoints: list[SimEndpoint] = []
        self.overruns = 0
        self._run_stop = threading.Event()
        self._stepper: threading.Thread | None = None
        super().__init__(scene, seed=seed, variant=variant)

    # -- public ---------------------------------------------------------------------------------
    def start(self) -> None:
        """Start the device threads and the real-time plant stepper (idempotent)."""
        self._check_open()
        if self._stepper is not None:
            return
        rate = float(self.scene.rate_hz)
        for d in self._devs:
            if d.sim is not None and d.twin is not None:
                d.twin.run_free(d.sim, rate, self.stream_rate_hz)
        self._stepper = threading.Thread(target=self._run, name=f"sim-scene-{self.scene.name}", daemon=True)
        self._stepper.start()

    def stop(self) -> None:
        """Stop the plant stepper (devices keep their transports open until :meth:`close`)."""
        self._run_stop.set()
        if self._stepper is not None and self._stepper is not threading.current_thread():
            self._stepper.join(timeout=2.0)

    def close(self) -> None:
        """Stop every thread, close every simulated device and transport. Idempotent."""
        self.stop()
        super().close()

    def read(self, timeout: float | None = None) -> Measurements:
        raise HilError("a SimulatedScene has no adapters: open them on .endpoints")

    def command(self, efforts: Mapping[str, Any], timeout: float | None = None) -> None:
        raise HilError("a SimulatedScene has no adapters: open them on .endpoints")

    def advance(self) -> None:
        raise HilError("a SimulatedScene runs in real time once started: there is no lockstep advance")

    # -- internals ------------------------------------------------------------------------------
    def _run(self) -> None:
        period = self.dt
        next_t = time.monotonic()
        while not self._run_stop.is_set():
            try:
                self.simulator.tick()
            except Exception:
                logger.exception("scene %r: simulation stopped", self.scene.name)
                return
            self._ticks += 1
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                self._run_stop.wait(delay)
            elif delay < -10 * period:  # fell far behind (loaded machine): skip, do not burst
                self.overruns += 1
                next_t = time.monotonic()

    def _open_devices(self) -> None:
        sc = self.scene
        channels: dict[tuple[str, str], str] = {}
        self._devs = [_Dev(cfg.name, cfg) for cfg in sc.devices]
        for i, d in enumerate(self._devs):
            d.point = self._point(i, d.cfg)
        for i, d in enumerate(self._devs):
            params = self._start_sim(i, d, dict(d.cfg.params), channels)
            for host_side in ("clock", "timeout", "waits"):  # the client's own choice
                params.pop(host_side, None)
            self.endpoints.append(self._endpoint(d, params))

    def _twin_context(self, index: int, d: _Dev, seed: int, faults: Any,
                      channels: dict[tuple[str, str], str]) -> TwinContext:
        """Free-running: CAN nodes on ``can_interface`` (channels from ``can_channels`` or one
        multicast group each), devices answering as requests arrive."""
        ctx = super()._twin_context(index, d, seed, faults, channels)
        ctx.lockstep = False
        ctx.waits = None
        ctx.can_interface = self.can_interface
        ctx.channel = lambda iface, ch: channels.setdefault((iface, ch), self._can_channel(ch))
        ctx.can_port = self._can_port
        return ctx

    def _rank(self, scene_ch: str) -> int:
        return self._chan_order.setdefault(scene_ch, len(self._chan_order))

    def _can_channel(self, scene_ch: str) -> str:
        k = self._rank(scene_ch)
        if scene_ch in self._can_map:
            return self._can_map[scene_ch]
        if self.can_interface == "udp_multicast":
            return f"{_UDP_MULTICAST_BASE}{2 + k}"
        return scene_ch

    def _can_port(self, scene_ch: str) -> int | None:
        """The UDP port of a served udp_multicast channel: given, else 43113 + its rank; None on
        other interfaces."""
        if scene_ch in self._port_map:
            return self._port_map[scene_ch]
        if self.can_interface != "udp_multicast":
            return None
        return _UDP_MULTICAST_BASE_PORT + self._rank(scene_ch)

    def _endpoint(self, d: _Dev, params: dict[str, Any]) -> SimEndpoint:
        assert d.twin is not None
        address, cross = d.twin.address(d.cfg.driver, params)
        return SimEndpoint(d.name, d.cfg.driver, d.cfg.role, _jsonable(params), address, cross)


def _arr(value: Any) -> Any:
    """A scene matrix/number as something :mod:`hil.mocks.physics` accepts."""
    return value if isinstance(value, int | float) else np.asarray(value, dtype=float)


def _t1_termination() -> Any:
    """Paper 000 eq. (1): the 2x2 termination T1 (not passive), velocity -> force."""
    from hil.mocks.terminations import Impedance

    entries = [[([8.0], [1.0, 3.0]), ([-5.0], [1.0, 1.0])], [([-5.0], [1.0, 1.0]), ([1.0], [1.0, 3.0])]]
    return Impedance.from_tf(entries, name="T1")


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return obj


def _group_sample(samples: list[Any]) -> Any:
    """One JointSample for a group: members' positions/velocities/efforts concatenated in order;
    ``seq`` is the smallest member sequence number and ``produced_at`` the oldest member's, so one
    stale member makes the group stale (the runner's watchdog sees it), ``fault`` the first non-zero
    member fault."""
    from hil.protocols.base import JointSample

    eff = None if any(s.effort is None for s in samples) else np.concatenate([s.effort for s in samples])
    produced = [float(getattr(s, "produced_at", np.nan)) for s in samples]
    return JointSample(t=samples[0].t, seq=min(int(s.seq) for s in samples),
                       produced_at=min(produced) if not any(np.isnan(produced)) else np.nan,
                       position=np.concatenate([s.position for s in samples]),
                       velocity=np.concatenate([s.velocity for s in samples]), effort=eff,
                       fault=next((s.fault for s in samples if s.fault), 0))


# ---------------------------------------------------------------------------------------------
# realtime mode of a simulated scene: the devices in another process (issue 17)


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        return int(s.getsockname()[1])


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """The served devices end when the bench process dies (Linux PR_SET_PDEATHSIG = SIGTERM)."""
    import ctypes
    import ctypes.util
    import signal

    with contextlib.suppress(Exception):
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").prctl(1, int(signal.SIGTERM))


def _child_setup(cpus: list[int] | None) -> Callable[[], None]:
    """``preexec_fn`` of the devices' process: die with the parent, and run on ``cpus`` from its
    first instruction (every thread it starts inherits the mask; setting it after the start would
    miss threads already running)."""
    import os

    def setup() -> None:  # pragma: no cover - runs in the child between fork and exec
        _die_with_parent()
        if cpus:
            with contextlib.suppress(Exception):
                os.sched_setaffinity(0, set(cpus))

    return setup


def _fifo_process(pid: int, priority: int) -> str | None:
    """SCHED_FIFO ``priority`` for every thread of process ``pid`` (threads it starts later inherit
    it); None on success, else a one-line reason (threads already changed keep it)."""
    import os

    try:
        tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
        for tid in tids:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(priority)))
    except (AttributeError, OSError, ValueError) as exc:
        return f"devices' process SCHED_FIFO {priority} not set: {getattr(exc, 'strerror', None) or exc}"
    return None


#: IP multicast hop limit (TTL) of the simulated CAN buses between the loop and the devices' process:
#: 0 keeps every frame on this host (Linux loops a multicast datagram back to local members, then
#: drops a TTL-0 one instead of transmitting it). With python-can's default 1 each frame is also sent
#: out of the network interface: on a KVM guest a virtio-net transmit per frame (a VM exit: ~35 % of
#: the send's CPU) and, when the host is slow to complete transmits, a full socket send buffer that
#: blocks the loop's send for milliseconds; and simulated CAN traffic on the LAN.
MULTICAST_HOP_LIMIT = 0


class ProcessSimBench(Bench):
    """A simulated scene whose devices run in a separate process, as a real bench's devices are external.

    What the runner uses in realtime mode for a simulated scene: a child process (multiprocessing,
    ``spawn``; pinned to the CPUs the loop does not use) runs the scene's :class:`SimulatedScene`
    (plant stepped at the scene's rate against the wall clock; CAN nodes on python-can's UDP
    multicast bus, each scene channel with this bench's own multicast group and UDP port, Bota/FT-300 streams and
    DYNAMIXEL chains on ptys, Modbus on loopback TCP), and this process opens the real adapters on
    those endpoints exactly as on hardware: no lockstep, :meth:`advance` is a no-op, sample ages
    are judged on the adapters' monotonic clock, timeouts are ``watchdog_ms``. The simulated
    operator (``set_human_force``) is not reachable across the process boundary (ignored, as on a
    real bench). :meth:`close` closes the adapters, then stops the child.

    Placement (a real bench's devices have their own processors): the child runs on ``cpus``
    (default: every CPU of this process but :func:`hil.bench.affinity.loop_cpu`, set before it starts, so
    all its threads stay off the loop's CPU, where a SCHED_FIFO loop would starve them), and, once
    it has started, under SCHED_FIFO ``rt_priority`` (default
    :data:`hil.bench.affinity.DEVICE_FIFO_PRIORITY`, below the loop and its record writer; None: left
    ordinary) where permitted, so other load on those CPUs does not delay the devices' replies and
    streams beyond the watchdog. What was refused is in :attr:`placement` (and logged at debug).
    """

    #: seconds to wait for the child to report its endpoints (start + imports on a loaded machine)
    START_TIMEOUT_S = 60.0

    def __init__(self, scene: Scene, *, seed: int | None = None, variant: str | None = None,
                 timeout: float | None = None, cpus: list[int] | None = None,
                 rt_priority: int | None = -1) -> None:
        import json
        import os
        import secrets
        import select
        import subprocess
        import sys
        import tempfile
        from pathlib import Path

        if scene.simulation is None:
            raise SceneError(f"{scene.path or scene.name}: no 'simulation' block: nothing to serve")
        from hil.bench.affinity import DEVICE_FIFO_PRIORITY, loop_cpu

        if rt_priority == -1:
            rt_priority = DEVICE_FIFO_PRIORITY
        if cpus is None:
            lc = loop_cpu()
            with contextlib.suppress(OSError, AttributeError):
                cpus = sorted(set(os.sched_getaffinity(0)) - ({lc} if lc is not None else set())) or None
        self._proc: Any = None
        self._tmp = tempfile.TemporaryDirectory(prefix="hil-sim-")
        chans = sorted({str(d.params.get("channel", "hil0")) for d in scene.devices
                        if resolve_twin(d.driver).udp_multicast})
        # a private multicast group (239.255/16: site-local scope) and a private UDP port per scene
        # channel: python-can binds to the port on every address, so a shared port would join the channels
        groups = {ch: f"239.255.{secrets.randbelow(254) + 1}.{secrets.randbelow(254) + 1}" for ch in chans}
        ports: dict[str, int] = {}
        for ch in chans:
            while (port := _free_udp_port()) in ports.values():
                pass
            ports[ch] = port
        src = Path(self._tmp.name) / f"{scene.name}.yaml"
        src.write_text(scene.source_text, encoding="utf-8")
        cmd = [sys.executable, "-m", "hil", "mock", "serve", str(src), "--json", "--can-interface", "udp_multicast",
               "--seed", str(scene.seed if seed is None else seed)]
        cmd += [a for ch, g in groups.items() for a in ("--can-channel", f"{ch}={g}")]
        cmd += [a for ch, p in ports.items() for a in ("--can-port", f"{ch}={p}")]
        if variant is not None:
            cmd += ["--variant", variant]
        # python-can: hop limit 0 for the served buses (the frames never leave the host: see _open_devices)
        env = {**os.environ, "CAN_CONFIG": json.dumps({"hop_limit": MULTICAST_HOP_LIMIT})}
        self._err = open(Path(self._tmp.name) / "stderr.txt", "w+b")  # noqa: SIM115 - closed in _stop_child
        try:
            self._proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=self._err,
                                          env=env, start_new_session=True,  # Ctrl-C reaches the bench only
                                          preexec_fn=_child_setup(cpus))
            ready, _, _ = select.select([self._proc.stdout], [], [], self.START_TIMEOUT_S)
            line = self._proc.stdout.readline() if ready else b""
            if not line:
                self._err.seek(0)
                why = " ".join(self._err.read().decode(errors="replace").split())[-300:] or "no output"
                raise HilError(f"simulated devices of {scene.name!r} did not start in another process: {why}")
            report = json.loads(line)
            # started (imports done, device threads running): now above ordinary load
            refused = _fifo_process(self._proc.pid, rt_priority) if rt_priority is not None else None
            #: where the devices' process runs: CPUs and scheduling (with what was refused)
            self.placement = (f"devices' process on CPU {','.join(map(str, cpus or [])) or 'any'}, " + (
                refused or (f"SCHED_FIFO {rt_priority}" if rt_priority is not None else "SCHED_OTHER")))
            if refused:
                logger.debug("%s", refused)
        except BaseException:
            self._stop_child()
            raise
        self._endpoint_params = {d["name"]: (d["driver"], d["params"]) for d in report["devices"]}
        #: UDP port of each served scene CAN channel
        self.can_ports = dict(ports)
        self._sim_scene = scene
        hardware = scene.model_copy(update={"simulation": None})  # private attrs (source text) are copied
        try:
            super().__init__(hardware, seed=seed, variant=variant, timeout=timeout)
            self._warm_up()
        except BaseException:
            self._stop_child()
            raise

    def _warm_up(self, attempts: int = 5) -> None:
        """First reads with a generous timeout: the served devices answer once their threads run."""
        for i in range(attempts):
            try:
                self.read(timeout=1.0)
                return
            except (DeviceTimeout, DeviceDisconnected):
                if i == attempts - 1:
                    raise

    def _open_devices(self) -> None:
        sc = self.scene
        self._devs = [_Dev(cfg.name, cfg) for cfg in sc.devices]
        for i, d in enumerate(self._devs):
            driver, params = self._endpoint_params[d.name]
            params = dict(params)
            if resolve_twin(driver).udp_multicast:  # the channel's own port is in the endpoint's params
                params["hop_limit"] = MULTICAST_HOP_LIMIT
            params.setdefault("timeout", self.timeout)
            device_kind(d.cfg.driver).watchdog_params(params, self.watchdog_s, self.simulated)
            try:
                d.adapter = open_device(d.cfg.driver, **params)
            except HilError:
                raise
            except (TypeError, ValueError) as exc:
                raise SceneError(f"{sc.path or sc.name}: devices[{i}].params: {exc}") from None

    def _stop_child(self) -> None:
        """SIGTERM the serving process (it closes every thread, pty, socket and bus), wait, kill if stuck."""
        import subprocess

        proc, self._proc = self._proc, None
        if proc is not None:
            with contextlib.suppress(OSError):
                proc.terminate()
            try:
                proc.wait(5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(2.0)
            with contextlib.suppress(OSError):
                proc.stdout.close()
        with contextlib.suppress(Exception):
            self._err.close()
        with contextlib.suppress(Exception):
            self._tmp.cleanup()

    def close(self) -> None:
        """Close the adapters, then stop the devices' process. Idempotent, never raises."""
        try:
            super().close()
        finally:
            self._stop_child()
