"""A live view of a run: ``hil run SCENE --live [PORT]`` streams the run's channels, its safety state and its
events over the Foxglove WebSocket protocol (``foxglove-sdk``; extra ``live``) on localhost, for Foxglove
or PlotJuggler (``ws://127.0.0.1:PORT``).

Never on the loop's critical path:

* the runner's record writer is wrapped by a tee (:meth:`LiveView.tee`): each sample the loop appends is
  also *offered* to the live view -- copied and put into a bounded queue with ``put_nowait``; when the
  queue is full the sample is dropped and counted, the tick never waits;
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
        else:
            self._server = _Server(self.host, self.requested_port)
            self.port = self._server.port
            self._q = queue.Queue(maxsize=self.queue_size)
            self._thread = threading.Thread(target=self._server.drain, args=(self._q,), name="hil-live", daemon=True)
            self._thread.start()
        self._started = True
        logger.info("live view on ws://%s:%d", self.host, self.port)
        return self

    def _put(self, item: tuple[Any, ...]) -> None:
        if self._sock is not None:
            try:
                self._sock.send(json.dumps(item).encode())
            except (BlockingIOError, OSError):  # the socket's buffer is full (or the process is gone): dropped
                self.dropped += 1
            return
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.dropped += 1

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
        self._put(("sample", float(t), _device_fields(values)))

    def event(self, t: float, kind: str, message: str) -> None:
        if self._started:
            self._put(("event", float(t), str(kind), str(message)))

    def experiment(self, name: str) -> None:
        self._next_t = -np.inf
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
