"""hil run --live (hil.run.live, issue 30): a Foxglove WebSocket client receives the run's channels during a
lockstep run; the records are bit-identical with and without the live view."""

from __future__ import annotations

import json
import struct
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hil.record.hdf5 import RunRecord

pytest.importorskip("foxglove", reason="the 'live' extra is not installed")
pytest.importorskip("websockets", reason="the 'test' extra is not installed")

TICKS = 300


def _scene() -> Any:
    from hil.scene.spec import load_scene, scene_from_dict

    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = d["experiments"][:1]
    d.pop("certification", None)
    return scene_from_dict(d, label="live-test")


class _Client(threading.Thread):
    """A Foxglove WebSocket client (subprotocol foxglove.sdk.v1, which foxglove-sdk 0.30 speaks): subscribes
    to every advertised channel and keeps each message's payload (binary opcode 1: subscription id u32, log
    time u64)."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.topics: dict[int, str] = {}
        self.received: dict[str, list[dict]] = {}
        self.cond = threading.Condition()
        self.error: BaseException | None = None
        self.stop_flag = threading.Event()

    def run(self) -> None:
        from websockets.exceptions import ConnectionClosed
        from websockets.sync.client import connect

        try:
            with connect(f"ws://127.0.0.1:{self.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
                next_id = 1
                while not self.stop_flag.is_set():
                    try:
                        frame = ws.recv(timeout=0.5)
                    except TimeoutError:
                        continue
                    if isinstance(frame, str):
                        msg = json.loads(frame)
                        if msg.get("op") == "advertise":
                            subs = []
                            for ch in msg["channels"]:
                                self.topics[next_id] = ch["topic"]
                                subs.append({"id": next_id, "channelId": ch["id"]})
                                next_id += 1
                            ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        continue
                    if frame[0] == 0x01:
                        sub_id, _log_time = struct.unpack_from("<IQ", frame, 1)
                        with self.cond:
                            self.received.setdefault(self.topics[sub_id], []).append(json.loads(frame[13:]))
                            self.cond.notify_all()
        except ConnectionClosed:
            pass
        except BaseException as exc:  # reported by the test
            self.error = exc

    def wait_for(self, pred: Any, timeout: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: pred(self.received), timeout)


@pytest.mark.timeout(180)
@pytest.mark.leaks_ok  # foxglove-sdk's server runtime threads (Rust) stay for the process; ours are checked below
def test_a_websocket_client_receives_the_channels_and_records_are_unchanged(tmp_path: Path) -> None:
    from hil.run.live import LiveView
    from hil.run.runner import Runner

    live = LiveView(0).start()
    client = _Client(live.port)
    client.start()
    waited: list[bool] = []

    def progress(name: str, k: int, n: int) -> None:
        if not waited:  # the first tick: hold the loop until the viewer listens (an event, not a clock)
            waited.append(live.wait_subscribed("/motor", timeout=60))

    try:
        # /safety exists before any client connects and its "running" goes out when the experiment starts,
        # before the first tick: the run starts only once the viewer listens to it (an event, not a clock)
        assert live.wait_subscribed("/safety", timeout=60)
        out_live = Runner(_scene(), tmp_path / "live", max_ticks=TICKS, live=live, progress=progress).run()[0]
        assert waited == [True]
        done = client.wait_for(lambda r: any(m.get("state") == "completed" for m in r.get("/safety", [])), 60)
        stats = live.close()
    finally:
        client.stop_flag.set()
        client.join(10)
    assert client.error is None, client.error
    assert done, sorted(client.received)
    assert not [t for t in threading.enumerate() if t.name == "hil-live" or t is client]  # the consumer has ended
    out_plain = Runner(_scene(), tmp_path / "plain", max_ticks=TICKS).run()[0]

    a, b = RunRecord.open(out_live.record), RunRecord.open(out_plain.record)
    np.testing.assert_array_equal(a.t, b.t)
    assert set(a.channels) == set(b.channels)
    for name in a.channels:
        np.testing.assert_array_equal(a.channels[name], b.channels[name], err_msg=name)  # bit-identical
    assert a.events == b.events and (a.stop_reason, a.status) == (b.stop_reason, b.status)

    # what the viewer received: the motor's channels, sample by sample, equal to the record's
    motor = client.received["/motor"]
    assert stats["dropped"] == 0 and stats["offered"] == a.t.size
    # the channel is advertised with the first sample, which goes out before a client can subscribe to it;
    # the loop waited for the subscription at that first tick: every later sample arrived, in order
    k0 = a.t.size - len(motor)
    assert k0 == 1
    t = np.array([m["t"] for m in motor])
    np.testing.assert_array_equal(t, a.t[k0:])
    np.testing.assert_array_equal(np.array([m["position"] for m in motor]), a.channels["motor.position"][k0:])
    np.testing.assert_array_equal(np.array([m["effort_cmd"] for m in motor]), a.channels["motor.effort_cmd"][k0:])
    assert {"/motor", "/loop", "/safety"} <= set(client.received)
    states = [m["state"] for m in client.received["/safety"]]
    assert states[0] == "running" and states[-1] == "completed"


def test_a_full_queue_drops_and_counts_never_blocks() -> None:
    """The loop's offer never waits: with the consumer not draining, offers past the queue's size are
    dropped and counted."""
    import queue

    from hil.run.live import LiveView

    live = LiveView(0, queue_size=5)
    live._q, live._started = queue.Queue(maxsize=5), True  # started without a server: nothing drains the queue
    for k in range(12):
        live.offer(k * 1e-3, {"motor.position": np.array([float(k)])})
    # the queue holds the samples' layout (keys and shapes, sent before the first sample) and 4 samples
    assert (live.offered, live.dropped) == (12, 8)
    assert live._q.get_nowait()[0] == "layout" and [live._q.get_nowait()[0] for _ in range(4)] == ["packed"] * 4
    # decimation: at most max_rate_hz samples per second of run time
    live = LiveView(0, max_rate_hz=50.0, queue_size=1000)
    live._q, live._started = queue.Queue(maxsize=1000), True
    for k in range(1000):  # 1 s at 1 kHz
        live.offer(k * 1e-3, {"motor.position": np.array([float(k)])})
    assert live.offered == 50 and live.dropped == 0


@pytest.mark.timeout(120)
def test_realtime_mode_serves_from_a_separate_process() -> None:
    """Realtime runs host the server in a separate process (the loop's interpreter lock never serves a
    client): samples offered in this process reach a client of that process's server."""
    import os

    from hil.run.live import LiveView

    live = LiveView(0, process=True).start()
    assert live._proc is not None and live._proc.pid != os.getpid()
    # no thread of the loop's process carries the items (a queue feeder thread could hold its GIL)
    assert not [t for t in threading.enumerate() if "Feeder" in t.name or t.name == "hil-live"]
    # every thread of the server's process below ordinary processes
    from hil.run.live import NICE

    for tid in (int(x) for x in os.listdir(f"/proc/{live._proc.pid}/task")):
        assert os.getpriority(os.PRIO_PROCESS, tid) == NICE
    client = _Client(live.port)
    client.start()
    try:
        # the client subscribes to what is advertised; offer until a sample arrives (each offer is a new
        # sample, so nothing here waits on a clock: the loop ends on the client's receipt)
        k = 0
        while not client.wait_for(lambda r: "/motor" in r, 0.05) and k < 20000:
            live.offer(k * 1e-3, {"motor.position": np.array([float(k)])})
            k += 1
        live.event(k * 1e-3, "safety_stop", "test stop")
        assert client.wait_for(lambda r: any(m.get("state") == "safety_stop" for m in r.get("/safety", [])), 30)
        stats = live.close()
    finally:
        client.stop_flag.set()
        client.join(10)
    got = client.received["/motor"]
    assert all(m["position"] == [round(m["t"] * 1e3)] for m in got)  # each sample's value with its time
    assert stats["sent"] >= len(got) > 0 and stats["offered"] == k
    assert live._proc.poll() is not None


def test_packed_samples_carry_every_value_and_shape() -> None:
    """The loop offers a sample as float64 ``[t, *values]`` after its layout (keys, shapes): what the
    consumer unpacks equals what was offered (scalars, a (1,)-array, a wrench, a matrix, NaN), and a
    value whose shape changes sends a new layout rather than a wrong sample."""
    import queue

    from hil.run.live import LiveView, unpack

    live = LiveView(0, queue_size=100)
    live._q, live._started = queue.Queue(maxsize=100), True
    sample = {"loop.late": 1.5e-5, "motor.position": np.array([0.25]), "spring_ft.wrench": np.arange(6.0) - 2,
              "arm.jacobian": np.array([[1.0, 2.0], [3.0, np.nan]]), "motor.flag": np.True_}
    live.offer(0.125, sample)
    changed = {**sample, "motor.position": np.array([0.5, 0.75])}
    live.offer(0.25, changed)
    items = [live._q.get_nowait() for _ in range(live._q.qsize())]
    assert [i[0] for i in items] == ["layout", "packed", "layout", "packed"]
    for (_, layout), (_, packed), want, t_want in ((items[0], items[1], sample, 0.125),
                                                     (items[2], items[3], changed, 0.25)):
        t, got = unpack([(k, tuple(sh)) for k, sh in layout], packed)
        assert t == t_want and list(got) == list(want)
        for k, v in want.items():
            np.testing.assert_array_equal(np.asarray(got[k]), np.asarray(v, float), err_msg=k)
            assert np.shape(got[k]) == np.shape(v), k
    with pytest.raises(ValueError, match="packed sample of 3 values for a layout of 2"):
        unpack([("a", ()), ("b", ())], np.zeros(4))
