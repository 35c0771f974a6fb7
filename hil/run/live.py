"""A live view of a run: ``hil run SCENE --live [PORT]`` streams the run's channels, its safety state and its
events over the Foxglove WebSocket protocol (``foxglove-sdk``; extra ``live``) on localhost, for Foxglove
or PlotJuggler (``ws://127.0.0.1:PORT``).

Never on the loop's critical path:

* the runner's record writer is wrapped by a tee (:meth:`LiveView.tee`): each sample the loop appends is
  also *offered* to the live view -- copied into one float64 array ``[t, *values]`` (its layout, the keys
  and shapes, is sent once per experiment; the consumer builds the JSON: ~8 µs of the loop's CPU per
  offered sample of sdea_bench's size, against ~175 µs for building the JSON in the tick) and put into a
  bounded queue with ``put_nowait``; when the queue is full the sample is dropped and counted, the tick
  never waits;
* a consumer (a thread in lockstep mode; in realtime mode a separate process, so the Foxglove server's
  work never takes the loop's interpreter lock) takes the samples from the queue and logs them to the
  server; in realtime mode the "queue" is a non-blocking datagram socket the loop's own thread writes
  (no helper thread in the loop's process that could hold its interpreter lock);
* in realtime mode the offers are decimated to :data:`REALTIME_RATE_HZ` (a person watching a plot needs
  no more; the queue and the pipe to the process carry that much);
* what the tee forwards to the writer is what the loop gave it, unchanged: records are bit-identical with
  and without ``--live`` (tested).

Topics (JSON messages, JSON schemas): one per device, ``/<device>`` with ``{"t", "<quantity>": value}``
as ``hil export --format mcap`` writes them (:func:`hil.record.export.device_topics`); ``/events``
(``foxglove.Log`` fields); ``/safety``: ``{"t", "experiment", "state", "reason"}`` with state ``running``
at an experiment's start, then the record's stop status (``completed``, ``safety_stop``, ``interrupted``,
``error``) at its end, and ``safety_stop``/``error`` as soon as such an event is recorded. Message log
times are the wall clock at the experiment's start plus the run time ``t``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import queue
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["DEFAULT_PORT", "MISSING", "QUEUE_SIZE", "REALTIME_RATE_HZ", "LiveError", "LiveView"]

#: the Foxglove WebSocket default port
DEFAULT_PORT = 8765
#: samples the queue holds before it drops (a few seconds at 1 kHz)
QUEUE_SIZE = 4096
#: realtime mode: samples per second offered to the live view at most
REALTIME_RATE_HZ = 50.0
#: largest item the realtime process reads from its socket [bytes] (a sample is ~1 kB of JSON)
_MAX_DATAGRAM = 1 << 20
#: messages the server queues per client before it drops (the SDK's own bounded queue)
BACKLOG = 16384
MISSING = "the live view needs foxglove-sdk: pip install 'hil-certify[live]'"
_STOP_KINDS = {"safety_stop", "error", "interrupted"}
#: first byte of a packed sample's datagram (the JSON items start with "[" or "n")
_PACKED = b"S"
_LOG_FIELDS = ("t", "kind", "message", "level", "name", "file", "line", "timestamp")


class LiveError(HilError):
    """The live view cannot start (missing extra, port in use)."""


def _json(a: Any) -> Any:
    if np.ndim(a) == 0:
        v = float(a)
        return v if np.isfinite(v) else None
    return [_json(x) for x in np.asarray(a).tolist()] if np.ndim(a) > 1 else \
        [float(x) if np.isfinite(x) else None for x in np.asarray(a, dtype=float).reshape(-1)]


class _Server:
    """The consumer side: the Foxglove server and its channels, fed from a queue (thread or process)."""

    def __init__(self, host: str, port: int) -> None:
        try:
            import foxglove
            from foxglove.websocket import ServerListener
        except ImportError:
            raise LiveError(MISSING) from None
        self.foxglove = foxglove
        #: topics a client subscribed to (under ``changed``, notified on each subscription)
        self.subscribed_topics: set[str] = set()
        self.changed = threading.Condition()
        outer = self

        class _Listener(ServerListener):  # type: ignore[misc]  # foxglove-sdk's base class
            def on_subscribe(self, client: Any, channel: Any) -> None:
                with outer.changed:
                    outer.subscribed_topics.add(str(channel.topic))
                    outer.changed.notify_all()

        try:
            self.server = foxglove.start_server(name="hil-certify", host=host, port=port,
                                                server_listener=_Listener(), message_backlog_size=BACKLOG)
        except Exception as exc:  # the SDK raises its own error for a port in use
            raise LiveError(f"live view: cannot listen on {host}:{port} ({' '.join(str(exc).split())[:120]})") \
                from None
        self.port = int(self.server.port)
        self.channels: dict[str, Any] = {}
        self.t_wall0 = time.time_ns()
        self.experiment = ""
        self.sent = 0
        #: (key, shape) of the values of a packed sample, in order (set by a "layout" item)
        self.layout: list[tuple[str, tuple[int, ...]]] = []
        # the run's own topics exist before any client connects (the device topics come with the first sample)
        self._channel("/safety", "hil.Safety", {k: {} for k in ("t", "experiment", "state", "reason")})
        self._channel("/events", "foxglove.Log", {k: {} for k in _LOG_FIELDS})

    def _channel(self, topic: str, schema_name: str, props: Mapping[str, Any]) -> Any:
        ch = self.channels.get(topic)
        if ch is None:
            schema = self.foxglove.Schema(name=schema_name, encoding="jsonschema",
                                          data=json.dumps({"type": "object", "properties": dict(props)}).encode())
            ch = self.foxglove.Channel(topic, schema=schema, message_encoding="json")
            self.channels[topic] = ch
        return ch

    def _log(self, topic: str, schema_name: str, msg: dict[str, Any], t: float) -> None:
        props: dict[str, Any] = {k: {} for k in msg}
        self._channel(topic, schema_name, props).log(msg, log_time=self.t_wall0 + max(0, round(t * 1e9)))
        self.sent += 1

    def handle(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        if kind == "experiment":
            self.experiment = str(item[1])
            self.t_wall0 = time.time_ns()
            self._log("/safety", "hil.Safety", {"t": 0.0, "experiment": self.experiment, "state": "running",
                                                "reason": ""}, 0.0)
        elif kind == "layout":  # the keys and shapes of the packed samples that follow
            self.layout = [(str(k), tuple(int(n) for n in shape)) for k, shape in item[1]]
        elif kind == "packed":  # (t, the values in layout order) as float64
            t, values = unpack(self.layout, item[1])
            self.handle(("sample", t, _device_fields(values)))
        elif kind == "sample":
            _, t, topics = item
            for topic, fields in topics.items():
                self._log(topic, f"hil.{topic.strip('/')}", {"t": t, **fields}, t)
        elif kind == "event":
            _, t, ev_kind, message = item
            stamp = self.t_wall0 + max(0, round(t * 1e9))
            level = 4 if ev_kind == "error" else 3 if ev_kind in _STOP_KINDS | {"safe_stop"} else 2
            self._log("/events", "foxglove.Log", {"t": t, "kind": ev_kind, "message": message, "level": level,
                                                  "name": ev_kind, "file": "", "line": 0, "timestamp": {
                                                      "sec": stamp // 1_000_000_000,
                                                      "nsec": stamp % 1_000_000_000}}, t)
            if ev_kind in _STOP_KINDS:
                self._log("/safety", "hil.Safety", {"t": t, "experiment": self.experiment, "state": ev_kind,
                                                    "reason": message}, t)
        elif kind == "stop":
            _, t, reason, status = item
            self._log("/safety", "hil.Safety", {"t": t, "experiment": self.experiment, "state": str(status),
                                                "reason": str(reason)}, t)

    def drain(self, q: Any) -> None:
        while True:
            item = q.get()
            if item is None:
                return
            try:
                self.handle(item)
            except Exception as exc:  # the live view never fails the run
                logger.warning("live view: %s", " ".join(str(exc).split())[:200])

    def stop(self) -> None:
        for ch in self.channels.values():
            ch.close()
        self.server.stop()


class _DatagramQueue:
    """The child's end of the datagram socket, read like a queue (``None``: the parent closed the view)."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock

    def get(self) -> tuple[Any, ...] | None:
        data = self.sock.recv(_MAX_DATAGRAM)
        if data[:1] == _PACKED:  # a sample: t and the values as float64, in the last layout's order
            return ("packed", np.frombuffer(data, dtype="<f8", offset=1))
        item = json.loads(data)
        return None if item is None else tuple(item)


def child_main(fd: int, host: str, port: int) -> None:  # pragma: no cover - runs in the live view's process
    """The live view's process (realtime mode): serve the items arriving on the datagram socket ``fd``;
    the port, then the number of messages sent, are printed as JSON lines on stdout for the parent."""
    sock = socket.socket(fileno=fd)
    try:
        srv = _Server(host, port)
    except LiveError as exc:
        print(json.dumps({"error": str(exc)}), flush=True)
        return
    print(json.dumps({"port": srv.port}), flush=True)
    try:
        srv.drain(_DatagramQueue(sock))
    finally:
        print(json.dumps({"sent": srv.sent}), flush=True)
        srv.stop()


#: niceness of the live view's process (realtime mode): below every ordinary process
NICE = 10


def _place(pid: int) -> None:
    """Run the live view's process (every thread of ``pid``) at niceness :data:`NICE`: below every
    ordinary process. It is not pinned off the realtime loop's CPU: the other CPUs hold the simulated
    devices' process at SCHED_FIFO 70 (:class:`hil.bench.runtime.ProcessSimBench`), which starved a pinned
    server completely in the suite (a client received nothing in 480 s); on the loop's CPU it runs only
    while the loop (SCHED_FIFO 80) sleeps. Where refused, left as it is."""
    import os

    try:
        for tid in (int(x) for x in os.listdir(f"/proc/{pid}/task")):
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, tid, NICE)
    except (AttributeError, OSError, ValueError) as exc:
        logger.debug("live view: process niceness not set: %s", exc)


def unpack(layout: list[tuple[str, tuple[int, ...]]], packed: Any) -> tuple[float, dict[str, Any]]:
    """``(t, values)`` of a packed sample (:meth:`LiveView.offer`): float64 ``[t, *values]`` in the order
    of ``layout`` ((key, shape) per value; a scalar's shape is ``()``)."""
    arr = np.asarray(packed, float)
    t, o, values = float(arr[0]), 1, {}
    for key, shape in layout:
        n = int(np.prod(shape, dtype=int)) if shape else 1
        values[key] = float(arr[o]) if not shape else arr[o:o + n].reshape(shape)
        o += n
    if o != arr.size:
        raise ValueError(f"a packed sample of {arr.size - 1} values for a layout of {o - 1}")
    return t, values


def _device_fields(values: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for name, v in values.items():
        dev, dot, qty = name.partition(".")
        topic, field = (f"/{dev}", qty) if dot else ("/record", name)
        out.setdefault(topic, {})[field] = _json(v)
    return out


class LiveView:
    """The live view of a run (module docstring). ``port`` 0: any free port (:attr:`port` after
    :meth:`start`); ``process``: run the server in a separate process (realtime mode);
    ``max_rate_hz``: offer at most this many samples per second of run time (None: every sample)."""

    def __init__(self, port: int = DEFAULT_PORT, *, host: str = "127.0.0.1", process: bool = False,
                 max_rate_hz: float | None = None, queue_size: int = QUEUE_SIZE) -> None:
        self.host, self.requested_port, self.process = host, int(port), bool(process)
        self.max_rate_hz = max_rate_hz
        self.queue_size = int(queue_size)
        self.port: int | None = None
        self.offered = 0
        self.dropped = 0
        self._q: Any = None
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None
        self._proc: subprocess.Popen[str] | None = None
        self._sock: socket.socket | None = None
        self._started = False
        self._next_t = -np.inf
        # the packed samples' layout: the keys of the last offered sample, their sizes, the buffer
        self._keys: tuple[str, ...] = ()
        self._sizes: list[int] = []
        self._buf = np.zeros(1)

    def wait_subscribed(self, topic: str, timeout: float) -> bool:
        """Wait until a client subscribed to ``topic`` (thread mode; for tests and tools that must not
        miss the start of a run); False after ``timeout`` seconds."""
        if self._server is None:
            raise LiveError("the live view's server runs in another process (or has not started)")
        srv = self._server
        with srv.changed:
            return srv.changed.wait_for(lambda: topic in srv.subscribed_topics, timeout)

    def start(self) -> LiveView:
        """Start the server (raises :class:`LiveError` with one line when it cannot)."""
        if self.process:
            # a datagram socket pair: the loop's end is non-blocking, each item is one datagram written by
            # the loop's own thread (no queue feeder thread in the loop's process to hold its interpreter
            # lock); a full socket buffer drops the item. The server runs in `python -c` (as the record
            # writer process does: nothing of the loop's process is inherited but the socket).
            ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
            ours.setblocking(False)
            code = f"from hil.run.live import child_main; child_main({theirs.fileno()}, {self.host!r}, " \
                   f"{self.requested_port})"
            self._proc = subprocess.Popen([sys.executable, "-c", code], pass_fds=[theirs.fileno()],
                                          stdout=subprocess.PIPE, text=True)
            theirs.close()
            self._sock = ours
            _place(self._proc.pid)  # before it starts its server's threads (they inherit it) ...
            line = self._proc.stdout.readline() if self._proc.stdout is not None else ""
            try:
                answer = json.loads(line)
            except ValueError:
                self._proc.wait(10)
                raise LiveError(f"live view: its process did not start (exit code {self._proc.returncode})") \
                    from None
            if "error" in answer:
                self._proc.wait(10)
                raise LiveError(str(answer["error"]))
            self.port = int(answer["port"])
            _place(self._proc.pid)  # ... and every thread it has now
        else:
            self._server = _Server(self.host, self.requested_port)
            self.port = self._server.port
            self._q = queue.Queue(maxsize=self.queue_size)
            self._thread = threading.Thread(target=self._server.drain, args=(self._q,), name="hil-live", daemon=True)
            self._thread.start()
        self._started = True
        logger.info("live view on ws://%s:%d", self.host, self.port)
        return self

    def _put(self, item: tuple[Any, ...]) -> bool:
        """Queue ``item`` without waiting; False (counted in ``dropped``) when the queue is full."""
        if self._sock is not None:
            return self._send(json.dumps(item).encode())
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.dropped += 1
            return False
        return True

    def _send(self, data: bytes) -> bool:
        try:
            self._sock.send(data)  # type: ignore[union-attr]  # process mode only
        except (BlockingIOError, OSError):  # the socket's buffer is full (or the process is gone): dropped
            self.dropped += 1
            return False
        return True

    def offer(self, t: float, values: Mapping[str, Any]) -> None:
        """One sample from the loop: copied (the loop reuses its arrays) and queued, or dropped when the
        queue is full or the sample comes sooner than ``max_rate_hz`` allows. Never blocks."""
        if not self._started:
            return
        if self.max_rate_hz is not None:
            if t < self._next_t:
                return
            self._next_t = t + 1.0 / self.max_rate_hz
        self.offered += 1
        try:
            self._put_packed(t, values)
        except (TypeError, ValueError):  # a value of another shape than the layout's: a new layout
            self._keys = ()
            self._put_packed(t, values)

    def _put_packed(self, t: float, values: Mapping[str, Any]) -> None:
        """The sample as ``t`` and its values in the layout's order, float64 (one array copy; the
        consumer turns it into the topics' JSON): ~10x less of the loop's CPU than building the JSON
        in the tick. A new set of keys first sends its layout."""
        keys = tuple(values)
        if keys != self._keys:
            shapes = [np.shape(values[k]) for k in keys]
            # a scalar's size is 0 here: set as one element (a (1,)-array goes through a slice)
            self._sizes = [int(np.prod(sh, dtype=int)) if sh else 0 for sh in shapes]
            self._buf = np.empty(1 + sum(max(n, 1) for n in self._sizes))
            if not self._put(("layout", [[k, list(sh)] for k, sh in zip(keys, shapes, strict=True)])):
                return  # no sample without its layout: the next offer sends it again
            self._keys = keys
        buf, o = self._buf, 1
        buf[0] = t
        for k, n in zip(keys, self._sizes, strict=True):
            if n == 0:
                buf[o] = values[k]
                o += 1
            else:
                buf[o:o + n] = np.ravel(values[k])
                o += n
        if self._sock is not None:
            self._send(_PACKED + buf.tobytes())
        else:
            self._put(("packed", buf.copy()))

    def event(self, t: float, kind: str, message: str) -> None:
        if self._started:
            self._put(("event", float(t), str(kind), str(message)))

    def experiment(self, name: str) -> None:
        self._next_t = -np.inf
        self._keys = ()  # each experiment's first sample sends its layout
        if self._started:
            self._put(("experiment", name))

    def stopped(self, t: float, reason: str, status: str) -> None:
        if self._started:
            self._put(("stop", float(t), str(reason), str(status)))

    def tee(self, writer: Any, experiment: str) -> _Tee:
        """``writer`` with every append, event and close also offered to the live view."""
        self.experiment(experiment)
        return _Tee(writer, self)

    def close(self) -> dict[str, int]:
        """Stop the server after the queued items are sent; returns ``{"offered", "dropped", "sent"}``."""
        sent = 0
        if not self._started:
            return {"offered": self.offered, "dropped": self.dropped, "sent": 0}
        self._started = False
        if self._thread is not None and self._server is not None:
            self._q.put(None)
            self._thread.join(30)
            sent = self._server.sent
            self._server.stop()
        elif self._proc is not None and self._sock is not None:
            self._sock.setblocking(True)
            self._sock.settimeout(30)
            with contextlib.suppress(OSError):
                self._sock.send(b"null")  # the end: the process sends what is queued, reports, exits
            out = ""
            with contextlib.suppress(subprocess.TimeoutExpired):
                out, _ = self._proc.communicate(timeout=30)
            if self._proc.poll() is None:
                self._proc.kill()
                self._proc.wait(10)
            sent = next((int(json.loads(ln)["sent"]) for ln in out.splitlines() if ln.startswith('{"sent"')), 0)
            self._sock.close()
            self._sock = None
        self._q = None
        if self.dropped:
            logger.warning("live view: %d of %d samples dropped (the viewer or the machine was slower than the run)",
                           self.dropped, self.offered)
        return {"offered": self.offered, "dropped": self.dropped, "sent": sent}


class _Tee:
    """A record writer whose samples, events and close are also offered to a :class:`LiveView`; every
    other attribute is the writer's."""

    def __init__(self, writer: Any, live: LiveView) -> None:
        self._writer = writer
        self._live = live
        self._last_t = 0.0
        self._closed = False

    def append(self, t: float, values: Mapping[str, Any]) -> None:
        self._writer.append(t, values)
        self._last_t = t
        self._live.offer(t, values)

    def event(self, t: float, kind: str, message: str) -> None:
        self._writer.event(t, kind, message)
        self._live.event(t, kind, message)

    def close(self, *args: Any, **kwargs: Any) -> Any:
        first = not self._closed
        out = self._writer.close(*args, **kwargs)
        if first:
            self._closed = True
            self._live.stopped(self._last_t, str(kwargs.get("stop_reason", args[0] if args else "")),
                               str(kwargs.get("status", args[1] if len(args) > 1 else "")))
        return out

    def __getattr__(self, name: str) -> Any:
        return getattr(self._writer, name)
