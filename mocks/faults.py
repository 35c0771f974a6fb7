"""Seeded fault injection shared by every simulated device (CAN, serial, Modbus, Dynamixel).

A :class:`FaultPlan` says *which* faults happen and how often; a :class:`FaultInjector` draws the
decisions from a seeded :func:`numpy.random.default_rng`, so a lockstep mocked run with one seed
is bit-identical on any machine. Each fault kind has its **own** random stream (spawned from the
seed), so enabling e.g. corruption does not change which frames get dropped.

What each fault means (a simulated device decides per *outgoing* frame / reply unless noted):

* **drop** (``drop_prob``, ``drop_ticks``): the device does not send this frame/reply at all.
  The adapter sees silence -> it must raise :class:`hil.errors.DeviceTimeout` (polling) or record
  a gap (streams).
* **corrupt** (``corrupt_prob``): one byte of the encoded frame is XOR-ed with a non-zero mask
  (so the frame always changes). Where a frame carries a CRC the damage is detected
  (:class:`hil.errors.ChecksumError` / a counted CRC failure); on CAN the CRC is checked by the
  controllers, so a corrupted frame never reaches the host: CAN devices send an error frame instead
  (the adapter sees an error frame and no data).
* **late** (``late_prob``, ``late_ticks``, ``late_s``): the frame is delivered late: in lockstep
  mode it is held back and sent ``late_ticks`` ticks later (after the next frames of that tick);
  in free-running mode it is delayed by ``late_s`` seconds.
* **stale** (``stale_prob``, or scheduled from tick ``stale_at_tick`` until ``stale_until_tick``
  exclusive, or for ever if ``None``): the device produces no new data. Streaming devices repeat
  their previous frame byte for byte (the same values *and* the same device timestamp); the
  simulated ODrive sends no Get_Encoder_Estimates frame (cyclic or as an answer) while its
  heartbeats go on; other frames repeat their previous payload. A frozen sensor: the host's
  freshness check (device timestamp / frame arrival) and the runner's watchdog must catch it.
* **garbage** (``garbage_prob``, ``garbage_len``): random bytes are inserted *before* the frame on
  byte streams (serial); adapters must resynchronise. Ignored by message-based transports.
* **device error** (``error_code`` from tick ``error_at_tick`` until ``error_until_tick``
  exclusive, or for ever if ``None``): the device reports this raw fault code in its status /
  heartbeat / error field. Adapters raise :class:`hil.errors.DeviceFault` with ``code``.
* **disconnect** (from tick ``disconnect_at_tick`` until ``reconnect_at_tick`` exclusive, or for
  ever): the device is silent (answers nothing, ignores commands). On transports that can signal
  it (pty, socket) the device may additionally close its end.
* **slow device** (``delay_s``): before each frame or reply it sends, the device spends ``delay_s``
  seconds of *wall-clock* time (a slow device, or the machine that runs it too loaded to run it on
  time). It changes no data and draws nothing. On a lockstep bench it changes nothing either: the
  host waits for its simulated devices by a barrier, on simulated time, so only the run gets
  slower (:mod:`hil.protocols.waits`); served free-running (realtime runs, ``hil mock serve``) the
  answers arrive that much later and the host's timeouts and watchdog see it.

Ticks are the device's own counter of processed lockstep steps / emitted frames; each device
documents what it counts (e.g. one ``process_pending()`` call or one ``emit()``).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

logger = logging.getLogger(__name__)

_STREAMS = ("drop", "corrupt", "late", "stale", "garbage")


@dataclass(frozen=True)
class FaultPlan:
    """Which faults to inject. All probabilities are per outgoing frame, in [0, 1].

    The default plan injects nothing.
    """

    drop_prob: float = 0.0
    drop_ticks: frozenset[int] = field(default_factory=frozenset)  # always drop at these ticks
    corrupt_prob: float = 0.0
    corrupt_ticks: frozenset[int] = field(default_factory=frozenset)
    late_prob: float = 0.0
    late_ticks: int = 1  # lockstep: deliver this many ticks later
    late_s: float = 0.005  # free-running: delay in seconds
    stale_prob: float = 0.0
    stale_at_tick: int | None = None
    stale_until_tick: int | None = None
    garbage_prob: float = 0.0
    garbage_len: int = 7  # max number of garbage bytes inserted (1..garbage_len)
    error_code: int = 0
    error_at_tick: int | None = None
    error_until_tick: int | None = None
    disconnect_at_tick: int | None = None
    reconnect_at_tick: int | None = None
    delay_s: float = 0.0  # wall-clock seconds spent before each frame / reply sent (slow device)

    def __post_init__(self) -> None:
        for name in ("drop_prob", "corrupt_prob", "late_prob", "stale_prob", "garbage_prob"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"FaultPlan.{name} must be in [0, 1], got {p!r}")
        if self.late_ticks < 1 or self.late_s < 0 or self.garbage_len < 1:
            raise ValueError("FaultPlan: late_ticks >= 1, late_s >= 0 and garbage_len >= 1 required")
        if not self.delay_s >= 0.0:
            raise ValueError(f"FaultPlan.delay_s must be >= 0 s, got {self.delay_s!r}")
        # accept any iterable for the tick sets (e.g. a list from a YAML scene)
        object.__setattr__(self, "drop_ticks", frozenset(self.drop_ticks))
        object.__setattr__(self, "corrupt_ticks", frozenset(self.corrupt_ticks))

    @classmethod
    def from_dict(cls, d: dict | None) -> FaultPlan:
        """Build from a plain mapping (scene files); unknown keys raise ``ValueError``."""
        if not d:
            return cls()
        known = set(cls.__dataclass_fields__)
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown fault plan keys {sorted(unknown)}; known: {sorted(known)}")
        return cls(**d)

    @property
    def is_null(self) -> bool:
        return self == FaultPlan()


class FaultInjector:
    """Draws fault decisions for one simulated device from ``plan`` and ``seed``.

    Deterministic: the same plan, seed and sequence of calls give the same decisions. Each fault
    kind has an independent random stream. ``injected`` counts what was actually injected
    (keys: ``drop``, ``corrupt``, ``late``, ``stale``, ``garbage``).
    """

    def __init__(self, plan: FaultPlan | None = None, seed: int | None = 0) -> None:
        self.plan = plan or FaultPlan()
        self.seed = seed
        children = np.random.SeedSequence(seed).spawn(len(_STREAMS))
        self._rng = {name: np.random.default_rng(s) for name, s in zip(_STREAMS, children, strict=True)}
        self.injected: Counter[str] = Counter()

    _inactive: tuple[FaultPlan, bool] | None = None

    @property
    def inactive(self) -> bool:
        """True when the plan injects nothing (``plan.is_null``): every decision below is then "no"
        and draws nothing, so a device may skip asking (cached while ``plan`` is the same object)."""
        plan, c = self.plan, self._inactive
        if c is None or c[0] is not plan:
            c = self._inactive = (plan, plan.is_null)
        return c[1]

    # -- per-frame decisions --------------------------------------------------------------
    def _draw(self, kind: str, p: float) -> bool:
        if p <= 0.0:
            return False
        hit = bool(self._rng[kind].random() < p)
        if hit:
            self.injected[kind] += 1
        return hit

    def should_drop(self, tick: int | None = None) -> bool:
        """True if the frame about to be sent must be dropped (scheduled tick or random draw)."""
        if tick is not None and tick in self.plan.drop_ticks:
            self.injected["drop"] += 1
            return True
        return self._draw("drop", self.plan.drop_prob)

    def should_corrupt(self, tick: int | None = None) -> bool:
        if tick is not None and tick in self.plan.corrupt_ticks:
            self.injected["corrupt"] += 1
            return True
        return self._draw("corrupt", self.plan.corrupt_prob)

    def corrupt(self, data: bytes, start: int = 0, stop: int | None = None) -> bytes:
        """Return ``data`` with one byte in ``data[start:stop]`` XOR-ed by a non-zero mask.

        Unconditional (call :meth:`should_corrupt` first, or use :meth:`maybe_corrupt`).
        """
        stop = len(data) if stop is None else stop
        if stop <= start:
            return bytes(data)
        rng = self._rng["corrupt"]
        i = int(rng.integers(start, stop))
        mask = int(rng.integers(1, 256))
        out = bytearray(data)
        out[i] ^= mask
        return bytes(out)

    def maybe_corrupt(
        self, data: bytes, tick: int | None = None, start: int = 0, stop: int | None = None
    ) -> bytes:
        """Corrupt ``data`` if the plan says so for this frame, else return it unchanged."""
        return self.corrupt(data, start, stop) if self.should_corrupt(tick) else data

    def is_late(self) -> bool:
        """True if this frame must be delivered late (see ``late_ticks`` / ``late_s``)."""
        return self._draw("late", self.plan.late_prob)

    def late_delay(self) -> float:
        """Free-running helper: seconds to delay this frame (0.0 = on time)."""
        return self.plan.late_s if self.is_late() else 0.0

    def should_repeat_stale(self, tick: int | None = None) -> bool:
        """True if the device must repeat its previous sample instead of a fresh one (scheduled
        ``stale_at_tick`` .. ``stale_until_tick`` when ``tick`` is given, or a random draw)."""
        if tick is not None and self.is_stale_scheduled(tick):
            self.injected["stale"] += 1
            return True
        return self._draw("stale", self.plan.stale_prob)

    def is_stale_scheduled(self, tick: int) -> bool:
        """True while the plan schedules stale data at ``tick``."""
        p = self.plan
        if p.stale_at_tick is None or tick < p.stale_at_tick:
            return False
        return p.stale_until_tick is None or tick < p.stale_until_tick

    def garbage(self) -> bytes:
        """Bytes to insert before the next frame on a byte stream (usually ``b""``)."""
        if not self._draw("garbage", self.plan.garbage_prob):
            return b""
        rng = self._rng["garbage"]
        n = int(rng.integers(1, self.plan.garbage_len + 1))
        return rng.integers(0, 256, size=n, dtype=np.uint8).tobytes()

    def hold_up(self) -> None:
        """A slow device (``delay_s``): spend that long, on the wall clock, before sending."""
        if self.plan.delay_s > 0.0:
            self.injected["delay"] += 1
            time.sleep(self.plan.delay_s)

    # -- scheduled state ------------------------------------------------------------------
    def error_code(self, tick: int) -> int:
        """Raw device fault code to report at ``tick`` (0 = no fault)."""
        p = self.plan
        if p.error_at_tick is None or not p.error_code:
            return 0
        if tick < p.error_at_tick:
            return 0
        if p.error_until_tick is not None and tick >= p.error_until_tick:
            return 0
        return p.error_code

    def is_disconnected(self, tick: int) -> bool:
        """True while the device is disconnected (silent) at ``tick``."""
        p = self.plan
        if p.disconnect_at_tick is None or tick < p.disconnect_at_tick:
            return False
        return p.reconnect_at_tick is None or tick < p.reconnect_at_tick


class ByteStreamFaults:
    """Per-frame faults of a device that streams frames on a byte line (serial, pty).

    In order, as a real device would show them: the frame is dropped; or the previous frame is
    repeated (stale); one byte at or after ``corrupt_start`` (past the sync bytes) is corrupted;
    garbage bytes are put in front; the frame is held back and sent after the next one (late).
    Counts go to ``stats`` (keys ``dropped``, ``stale``, ``corrupted``, ``garbage``, ``late``).
    """

    def __init__(self, injector: FaultInjector, stats: Counter[str], corrupt_start: int = 0) -> None:
        self.injector = injector
        self.stats = stats
        self.corrupt_start = corrupt_start
        self._last: bytes | None = None
        self._held: bytes | None = None

    def bytes_to_send(self, frame: bytes, tick: int) -> bytes | None:
        """The bytes to write for ``frame`` at ``tick``, or None if nothing goes out now."""
        inj = self.injector
        if inj.inactive and self._held is None:  # nothing to inject: the frame as it is
            self._last = frame
            return frame
        if inj.should_drop(tick):
            self.stats["dropped"] += 1
            return None
        if self._last is not None and inj.should_repeat_stale(tick):
            frame = self._last
            self.stats["stale"] += 1
        self._last = frame
        if inj.should_corrupt(tick):
            frame = inj.corrupt(frame, start=self.corrupt_start)
            self.stats["corrupted"] += 1
        junk = inj.garbage()
        if junk:
            self.stats["garbage"] += 1
        data = junk + frame
        if inj.is_late() and self._held is None:
            self._held = data
            self.stats["late"] += 1
            return None
        if self._held is not None:
            data, self._held = data + self._held, None
        return data

class BoundedLog(list):
    """A list that keeps only its newest ``maxlen`` entries (a simulated device's request log:
    memory stays flat over any run length; ``total`` counts every entry ever appended). Compares
    equal to a plain list with the same entries."""

    def __init__(self, maxlen: int = 1024) -> None:
        super().__init__()
        self.maxlen = int(maxlen)
        self.total = 0

    def append(self, item: object) -> None:
        super().append(item)
        self.total += 1
        if len(self) > self.maxlen:
            del self[: len(self) - self.maxlen]


NO_FAULTS = FaultPlan()
