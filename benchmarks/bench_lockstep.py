"""Benchmark: lockstep throughput of the mocked bench (issue 15).

For every built-in scene, the first experiment runs through the full :class:`hil.run.runner.Runner`
in lockstep (every device read over its real transport: python-can virtual bus, pty, loopback
Modbus; controller, safety, record, plant advance) for ``--ticks`` ticks; the table prints runner
ticks per second (bench opening and record included), the bench alone (read/command/advance with
zero effort, no runner; wall clock, and per second of this process's CPU time, which a loaded
machine disturbs less) and, as the baseline measured in the same run, the scene's physics alone
(``Simulator.tick``).

``--digest`` also prints the SHA-256 over every record channel and ``/t`` of each run (the
bit-identity check: the same seed must give the same digest before and after an optimisation).

``--phases`` prints, per scene, the bench tick's CPU time (this thread's ``time.thread_time``, which
the other jobs of a loaded machine disturb less than the wall clock) by phase: each device's read,
the commands, the devices' flush, the plant step and each simulated device's tick.

``--against REV`` compares with another revision of this repository in the same run: the tree of
``REV`` (``git archive``, laid out as installed: ``hil/``, ``hil/mocks``, ``hil/protocols``,
``hil/identify``) is imported through ``PYTHONPATH`` by child processes that alternate with children
running this tree, ``--repeat`` times each per scene; the table shows the best of each (ticks per
second of the child's CPU time, for the bench alone and for the runner: a loaded machine disturbs
the wall clock far more) and the ratio this tree / REV.

``--costs`` prints, per scene, what a bench tick costs in CPU time (this thread's
``time.thread_time``, best of ``--repeat`` blocks of ``--ticks`` ticks) and how it splits by where
the code lives, measured directly (:func:`account`: the entry points of each category timed on this
thread's CPU clock, exclusive time, the timer's own cost taken off): the adapters under test and the
libraries they call (their ``read``/``command_effort``/``wait_rx``), the transports (the virtual
CAN buses' send/receive, the pty and socket system calls, pyserial's included), the simulated
devices (their twins' ``tick``/``flush``, a CAN node's answer in the sender's thread), the plant
(``Simulator.tick``) and the bench (the rest: measurement points, barriers, group assembly). The
**ceiling** is the tick rate if only the adapters, the transports and the plant cost anything:
1 / (adapters + transports + plant). With ``--against REV`` the same run also prints this tree
against ``REV`` (bench ticks per CPU-second, best of ``--repeat`` alternating child processes each);
for sdea_bench it ends with the floor with the avoidable work removed (:func:`adapter_floor`: the
unchanged adapters, canned devices, the plant; on the lockstep transports and in memory), each part
also timed alone.

Run: ``python benchmarks/bench_lockstep.py [--ticks 2000] [--scenes sdea_bench,...] [--digest]
[--phases] [--floor] [--costs] [--against REV [--repeat 3]]``. Not a test; prints tables.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hil.bench.runtime import Bench
from hil.run.runner import Runner
from hil.scene.spec import builtin_scenes, load_scene


def record_digest(out_dir: Path) -> str:
    """SHA-256 over ``/t`` and every ``/channels/*`` dataset (name, dtype, shape, bytes) of every
    record file under ``out_dir``, in sorted order."""
    h = hashlib.sha256()
    for p in sorted(out_dir.rglob("*.h5")):
        with h5py.File(p, "r") as f:
            names = ["t"] + [f"channels/{k}" for k in sorted(f["channels"])]
            for n in names:
                a = np.ascontiguousarray(f[n][()])
                h.update(n.encode() + str(a.dtype).encode() + str(a.shape).encode())
                h.update(a.tobytes())
    return h.hexdigest()


def runner_tps(name: str, ticks: int, digest: bool) -> tuple[float, str, str]:
    r, _, status, dig = runner_rates(name, ticks, digest)
    return r, status, dig


def runner_rates(name: str, ticks: int, digest: bool) -> tuple[float, float, str, str]:
    """(runner ticks/s wall clock, runner ticks/s of this process's CPU time, status, record digest)."""
    sc = load_scene(name)
    with tempfile.TemporaryDirectory() as d:
        t0, c0 = time.perf_counter(), time.process_time()
        o = Runner(sc, d, realtime=False, max_ticks=ticks).run(select=[0])[0]
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        dig = record_digest(Path(d)) if digest else ""
    return ticks / dt, ticks / dc, o.status, dig


def bench_tps(name: str, ticks: int) -> tuple[float, float, float]:
    """(bench ticks/s wall clock, bench ticks/s of this process's CPU time, plant-only ticks/s of
    this thread's CPU time)."""
    sc = load_scene(name)
    with Bench(sc, seed=sc.seed) as bench:
        zero = {a: np.zeros(sc.device(a).dof) for a in bench.actuators}
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(ticks):
            bench.read()
            bench.command(zero)
            bench.advance()
        b, c = time.perf_counter() - t0, time.process_time() - c0
        bench.safe_stop()
    with Bench(sc, seed=sc.seed) as bench:
        sim = bench.simulator
        c0 = time.thread_time()
        for _ in range(ticks):
            sim.tick()
        p = time.thread_time() - c0
    return ticks / b, ticks / c, ticks / p


def phases(name: str, ticks: int) -> dict[str, float]:
    """CPU µs per bench tick by phase (this thread's CPU time), in tick order."""
    sc = load_scene(name)
    clk = time.thread_time_ns
    acc: dict[str, int] = {}
    with Bench(sc, seed=sc.seed) as bench:
        zero = {a: np.zeros(sc.device(a).dof) for a in bench.actuators}
        devs = bench._devs
        plan = bench._sim_plan()
        for _ in range(ticks):
            bench._cache = None
            for d in devs:
                t0 = clk()
                bench._read_device(d, bench.timeout)
                acc[f"read {d.name}"] = acc.get(f"read {d.name}", 0) + clk() - t0
            t0 = clk()
            bench.command(zero)
            t1 = clk()
            bench._ticks += 1
            bench._flush_devices()
            t2 = clk()
            bench.simulator.tick()
            t3 = clk()
            acc["command"] = acc.get("command", 0) + t1 - t0
            acc["flush"] = acc.get("flush", 0) + t2 - t1
            acc["plant"] = acc.get("plant", 0) + t3 - t2
            for twin, sim, _ in plan:
                k = f"tick {type(sim).__name__}"
                t0 = clk()
                twin.tick(sim)
                acc[k] = acc.get(k, 0) + clk() - t0
        bench.safe_stop()
    return {k: v / ticks / 1e3 for k, v in acc.items()}


#: categories of the direct accounting (:func:`account`), in table order
ACCOUNT = ("adapters", "transports", "devices", "plant", "bench")


def account(name: str, ticks: int, repeat: int) -> tuple[float, dict[str, float], float]:
    """What a bench tick of scene ``name`` costs, measured directly: (CPU s per tick untimed, best
    of ``repeat`` blocks of ``ticks`` ticks; CPU s per tick by category; timed calls per tick).

    The entry points of each category are wrapped with a timer of this thread's CPU time that keeps
    each call's *exclusive* time (time spent in a nested timed call goes to the nested one's
    category): adapters, every adapter's ``read``/``command_effort``/``wait_rx`` (the code under
    test and the libraries it calls); transports, ``os.read``/``os.write``/``select.select``/
    ``fcntl.ioctl`` (pty and socket system calls, pyserial's included) and the virtual CAN buses'
    ``send``/``_recv_internal``; devices, every simulated device's ``tick``/``flush`` (its twin)
    and a CAN node's delivery of a host frame (``SimCanNode._deliver_sync``, which answers in the
    sender's thread); plant, ``Simulator.tick``; bench, the rest of ``Bench.read/command/advance``
    (measurement points, barriers, group assembly). Unlike a cProfile run's shares (which weigh code
    of many small calls more), nothing is apportioned but the timer's own cost: a
    per-thread CPU clock read is a system call (~1 µs here), so the timed block costs more than the
    untimed one; that excess per timed call is taken off half from the category of the call and
    half from the category it was called from (one clock read lands in each). The categories of the
    best timed block then add up to the untimed tick of the same block count."""
    import fcntl
    import select as select_mod

    from can.interfaces import virtual

    from hil.mocks.can_devices import LockstepVirtualBus, SimCanNode

    clk = time.thread_time_ns
    acc = dict.fromkeys(ACCOUNT, 0)
    ends = dict.fromkeys(ACCOUNT, 0)  # clock reads landing in each category
    stack: list[int] = []
    cats: list[str] = []

    def timed(fn: Any, cat: str) -> Any:
        def w(*a: Any, **kw: Any) -> Any:
            t0 = clk()
            stack.append(0)
            cats.append(cat)
            try:
                return fn(*a, **kw)
            finally:
                el = clk() - t0
                acc[cat] += el - stack.pop()
                cats.pop()
                ends[cat] += 1
                ends[cats[-1]] += 1
                stack[-1] += el
        return w

    patched: list[tuple[Any, str, Any]] = []

    def patch(owner: Any, attr: str, cat: str) -> None:
        if any(o is owner and a == attr for o, a, _ in patched):  # shared (a twin of several devices)
            return
        patched.append((owner, attr, owner.__dict__.get(attr, None) if isinstance(owner, type) else None))
        setattr(owner, attr, timed(getattr(owner, attr), cat))

    sc = load_scene(name)
    with Bench(sc, seed=sc.seed) as bench:
        zero = {a: np.zeros(sc.device(a).dof) for a in bench.actuators}

        def block() -> float:
            c0 = time.thread_time()
            for _ in range(ticks):
                bench.read()
                bench.command(zero)
                bench.advance()
            return time.thread_time() - c0

        block()  # warm up
        best = min(block() for _ in range(repeat))
        modules = [(os, "read"), (os, "write"), (select_mod, "select"), (fcntl, "ioctl")]
        originals = [(m, a, getattr(m, a)) for m, a in modules]
        chosen: dict[str, float] = {}
        timed_calls = 0.0
        try:
            for m, a in modules:
                setattr(m, a, timed(getattr(m, a), "transports"))
            for cls in (LockstepVirtualBus, virtual.VirtualBus):
                for a in ("send", "_recv_internal"):
                    if a in cls.__dict__:
                        patch(cls, a, "transports")
            patch(SimCanNode, "_deliver_sync", "devices")
            for d in bench._devs:
                for a in ("read", "command_effort", "wait_rx"):
                    if d.adapter is not None and hasattr(d.adapter, a):
                        patch(d.adapter, a, "adapters")
            for twin, _, _ in bench._sim_plan():
                for a in ("tick", "flush"):
                    patch(twin, a, "devices")
            patch(bench.simulator, "tick", "plant")
            best_timed = float("inf")
            for _ in range(repeat):
                acc.update(dict.fromkeys(ACCOUNT, 0))
                ends.update(dict.fromkeys(ACCOUNT, 0))
                c0 = time.thread_time_ns()
                for _ in range(ticks):
                    stack.append(0)
                    cats.append("bench")
                    t0 = clk()
                    bench.read()
                    bench.command(zero)
                    bench.advance()
                    acc["bench"] += clk() - t0 - stack.pop()
                    cats.pop()
                cpu = time.thread_time_ns() - c0
                assert not stack and not cats
                if cpu < best_timed:
                    best_timed = cpu
                    n_ends = sum(ends.values())
                    per_read = max(0.0, cpu - best * 1e9) / n_ends if n_ends else 0.0
                    chosen = {c: max(0.0, v - ends[c] * per_read) for c, v in acc.items()}
                    timed_calls = n_ends / 2 / ticks
        finally:
            for m, a, f in originals:
                setattr(m, a, f)
            for owner, a, f in reversed(patched):
                if isinstance(owner, type):
                    setattr(owner, a, f)
                else:
                    delattr(owner, a)
        bench.safe_stop()
    return best / ticks, {c: v / ticks / 1e9 for c, v in chosen.items()}, timed_calls


def cost_table(names: list[str], ticks: int, repeat: int, against_rev: str = "") -> None:
    """Per scene: the bench tick's CPU by category (:func:`account`), the ceiling, and with
    ``against_rev`` that revision's and this tree's bench ticks per CPU-second (child processes,
    alternating, best of ``repeat``); then, for sdea_bench, the floor with the avoidable work
    removed (:func:`adapter_floor`, on the lockstep and on in-memory transports)."""
    before: dict[str, float] = {}
    after: dict[str, float] = {}
    if against_rev:  # the same measurement for both trees: child processes, alternating, best of `repeat`
        with tempfile.TemporaryDirectory() as d:
            tree = str(revision_tree(against_rev, Path(d)))
            for name in names:
                for _ in range(repeat):
                    before[name] = max(before.get(name, 0.0), child(name, ticks, tree)["cpu"])
                    after[name] = max(after.get(name, 0.0), child(name, ticks, None)["cpu"])
    print(f"Lockstep bench tick, CPU µs by category, measured directly ({ticks} ticks, best of {repeat}; timed "
          "entry points, exclusive CPU time, the timer's own cost taken off; adapters: the adapters' read/command "
          "and the libraries they call; transports: virtual CAN bus send/receive, pty/socket system calls; "
          "devices: the simulated devices; plant: Simulator.tick; bench: the rest)")
    head = f"{'scene':26s} {'µs/tick':>8s} {'ticks/CPU-s':>11s}" + "".join(f" {c:>10s}" for c in ACCOUNT)
    head += f" {'ceiling':>8s} {'of ceil.':>8s}"
    if before:
        head += f" {against_rev[:8]:>9s} {'this':>7s} {'ratio':>6s}"
    print(head)
    for name in names:
        total, per, _ = account(name, ticks, repeat)
        ceiling = 1.0 / (per["adapters"] + per["transports"] + per["plant"])
        row = f"{name:26s} {1e6 * total:8.1f} {1.0 / total:11.0f}" + "".join(f" {1e6 * per[c]:10.1f}" for c in ACCOUNT)
        row += f" {ceiling:8.0f} {100.0 / total / ceiling:7.0f}%"
        if before:
            row += f" {before[name]:9.0f} {after[name]:7.0f} {after[name] / before[name]:5.2f}x"
        print(row, flush=True)
    print("(µs/tick: the tick untimed, best of the blocks; the categories add up to it; ceiling: ticks per CPU-second "
          f"if only the adapters, the transports and the plant cost anything; {against_rev[:8] or 'REV'} / this: "
          f"bench ticks per CPU-second of that revision / this tree, process CPU, best of {repeat} alternating "
          "child processes run now)")
    if "sdea_bench" in names:
        floor_lines(ticks, repeat)


def floor_lines(ticks: int, repeat: int) -> None:
    """sdea_bench's tick with the avoidable work removed (:func:`adapter_floor`), on the lockstep
    transports and on in-memory ones."""
    for memory in (False, True):
        p = adapter_floor(ticks, repeat, memory=memory)
        where = ("in-memory transports (ODrive: a deque BusABC; Bota: pyserial loop://)" if memory
                 else "lockstep transports (LockstepVirtualBus, pty)")
        print(f"sdea_bench with the avoidable work removed, {where}: {1e6 * p['tick']:.1f} µs per tick = "
              f"{1 / p['tick']:.0f} ticks per CPU-second; each part alone: ODrive poll + command "
              f"{1e6 * p['odrive']:.1f} µs, Bota read {1e6 * p['bota']:.1f} µs, plant {1e6 * p['plant']:.1f} µs "
              f"(sum {1e6 * (p['odrive'] + p['bota'] + p['plant']):.1f} µs)", flush=True)


def revision_tree(rev: str, dest: Path) -> Path:
    """``rev`` of this repository laid out as installed (package-dir mapping of pyproject.toml)."""
    repo = Path(__file__).resolve().parents[1]
    src = dest / "src"
    src.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(repo), "archive", rev], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    pkg = dest / "pkg"
    shutil.copytree(src / "hil", pkg / "hil")
    for sub in ("identify", "protocols", "mocks"):
        shutil.copytree(src / sub, pkg / "hil" / sub)
    return pkg


def child(name: str, ticks: int, pythonpath: str | None) -> dict[str, float]:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", name, "--ticks", str(ticks)],
                         check=True, capture_output=True, text=True, env=env, cwd=tempfile.gettempdir()).stdout
    return dict(json.loads(out.strip().splitlines()[-1]))


def against(rev: str, names: list[str], ticks: int, repeat: int) -> None:
    with tempfile.TemporaryDirectory() as d:
        tree = str(revision_tree(rev, Path(d)))
        print(f"Lockstep throughput, this tree against {rev}, {ticks} ticks per scene, best of {repeat} "
              f"alternating child processes each")
        print(f"{'scene':28s} {'bench ticks/s (CPU)':>27s} {'runner ticks/s (CPU)':>27s}")
        print(f"{'':28s} {'before':>8s} {'after':>8s} {'ratio':>9s} {'before':>8s} {'after':>8s} {'ratio':>9s}")
        for name in names:
            runs: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
            for _ in range(repeat):
                runs["before"].append(child(name, ticks, tree))
                runs["after"].append(child(name, ticks, None))
            best = {k: {m: max(r[m] for r in v) for m in ("cpu", "runner")} for k, v in runs.items()}
            b, a = best["before"], best["after"]
            print(f"{name:28s} {b['cpu']:8.0f} {a['cpu']:8.0f} {a['cpu'] / b['cpu']:8.2f}x"
                  f" {b['runner']:8.0f} {a['runner']:8.0f} {a['runner'] / b['runner']:8.2f}x")


def transport_counts(name: str, ticks: int) -> tuple[float, float]:
    """(CAN frames sent, pty writes) per bench tick of scene ``name`` (zero effort, ``ticks`` ticks),
    counted on the real bench: every ``LockstepVirtualBus.send`` and every ``os.write`` of the
    process during the ticks (no record is written: the bench alone)."""
    from hil.mocks.can_devices import LockstepVirtualBus

    sc = load_scene(name)
    n = {"can": 0, "pty": 0}
    send, write = LockstepVirtualBus.send, os.write

    def counting_send(self: object, *a: object, **kw: object) -> object:
        n["can"] += 1
        return send(self, *a, **kw)  # type: ignore[arg-type]

    def counting_write(fd: int, data: bytes) -> int:
        n["pty"] += 1
        return write(fd, data)

    with Bench(sc, seed=sc.seed) as bench:
        zero = {a: np.zeros(sc.device(a).dof) for a in bench.actuators}
        LockstepVirtualBus.send, os.write = counting_send, counting_write  # type: ignore[method-assign, assignment]
        try:
            for _ in range(ticks):
                bench.read()
                bench.command(zero)
                bench.advance()
        finally:
            LockstepVirtualBus.send, os.write = send, write  # type: ignore[method-assign]
        bench.safe_stop()
    return n["can"] / ticks, n["pty"] / ticks


def primitive_costs(reps: int = 20000) -> dict[str, float]:
    """CPU seconds (this thread) of one CAN frame (LockstepVirtualBus, one receiver: ``Message`` +
    ``send`` + ``recv(timeout=0)``) and of one 37-byte pty frame (``os.write`` on the master, ``select``
    + ``os.read`` on the slave), best of 5 blocks of ``reps``."""
    import pty
    import select

    import can

    from hil.mocks.can_devices import LockstepVirtualBus

    clk = time.thread_time_ns
    a, b = LockstepVirtualBus(channel="floor"), LockstepVirtualBus(channel="floor")
    data = bytes(8)
    best_can = best_pty = float("inf")
    try:
        for _ in range(5):
            t0 = clk()
            for i in range(reps):
                a.send(can.Message(arbitration_id=0x0C | (i & 0x3F) << 5, data=data, is_extended_id=False))
                b.recv(timeout=0.0)
            best_can = min(best_can, (clk() - t0) / reps * 1e-9)
    finally:
        a.shutdown()
        b.shutdown()
    master, slave = pty.openpty()
    frame = bytes(37)
    try:
        import tty

        tty.setraw(slave)
        for _ in range(5):
            t0 = clk()
            for _ in range(reps // 4):
                os.write(master, frame)
                got = 0
                while got < len(frame):
                    select.select([slave], [], [], 1.0)
                    got += len(os.read(slave, 4096))
            best_pty = min(best_pty, (clk() - t0) / (reps // 4) * 1e-9)
    finally:
        os.close(master)
        os.close(slave)
    return {"can": best_can, "pty": best_pty}


def adapter_floor(ticks: int, repeat: int, memory: bool = False) -> dict[str, float]:
    """CPU s per tick of sdea_bench's lockstep tick with the avoidable work removed: the unchanged
    adapters (``ODriveCAN`` polling, ``BotaSerial``) on their lockstep transports and simulated-time
    waits, the plant (``Simulator.tick``), and *canned* devices instead of the simulated ones: the
    ODrive's Get_Encoder_Estimates answer is a pre-built frame put in the adapter's queue in the
    sender's thread (a ``sync`` node's delivery, nothing computed), the Bota frames are pre-encoded
    (1004 Hz on the 2 kHz loop: one every other tick) and written to the pty master; no bench, no
    measurement point, no runner. Returns the best of ``repeat`` blocks, and each part alone.

    ``memory``: the same adapters on the cheapest transports there are, in memory: the ODrive on a
    ``can.BusABC`` whose frames go through a deque (python-can's ``BusABC.send``/``recv`` and
    ``Message`` kept: the adapter's code path), the Bota on pyserial's ``loop://`` port (the frame
    written to the port comes back to its reader: no system call). The difference to the lockstep
    transports is the transports' cost; what is left is the adapters' own code and the plant."""
    import pty
    import select
    import tty
    from collections import deque

    import can

    from hil.bench.runtime import Bench
    from hil.mocks.can_devices import LockstepVirtualBus
    from hil.protocols.can_odrive import ODriveCAN
    from hil.protocols.codecs import odrive as od
    from hil.protocols.codecs.bota import encode_frame
    from hil.protocols.serial_bota import BotaSerial
    from hil.protocols.waits import LockstepWaits

    clk = time.thread_time
    sc = load_scene("sdea_bench")
    ch = f"floor-{os.getpid()}"
    reply = can.Message(arbitration_id=od.arbitration_id(3, od.CMD_GET_ENCODER_ESTIMATES),
                        data=od.encode_f32x2(0.25, -1.5), is_extended_id=False)
    poll_id = reply.arbitration_id
    from can.interfaces import virtual

    class MemoryBus(can.BusABC):  # a deque: the device answers the poll in the sender's thread
        def __init__(self) -> None:
            self.frames: deque[can.Message] = deque()
            self.channel_info = "memory"
            super().__init__(channel="memory")

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            if msg.arbitration_id == poll_id and msg.is_remote_frame:
                self.frames.append(reply)

        def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
            return (self.frames.popleft() if self.frames else None), False

    host: can.BusABC
    if memory:
        host = MemoryBus()
    else:
        lockstep_bus = LockstepVirtualBus(ch)
        host = lockstep_bus

        class CannedODrive:  # the device end of the channel: answers the poll in the sender's thread
            def put(self, msg: can.Message, block: bool = True, timeout: float | None = None) -> None:
                if msg.arbitration_id == poll_id and msg.is_remote_frame:
                    lockstep_bus.queue.put_nowait(reply)

        with virtual.channels_lock:
            virtual.channels[ch].append(CannedODrive())  # type: ignore[arg-type]
    waits = LockstepWaits(lambda: 0.0, lambda: None)
    motor = ODriveCAN(3, ch, "virtual", bus=host, enable=False, timeout=0.05, waits=waits)
    master, slave = pty.openpty()
    tty.setraw(slave)
    # every frame new (its device timestamp advances: a fresh sample), for every block of the run
    frames = iter([encode_frame(0, [0, 0, 0, 0, 0, 0.01 * (k % 7)], round(k * 996.09375), 25.0)
                   for k in range(2 * repeat * ticks + 2)])
    bota = BotaSerial("loop://" if memory else os.ttyname(slave), configure=False, period_s=51 / 51200,
                      timeout=0.05, waits=waits)
    port = bota._ser

    def push() -> None:  # the device's frame reaches the host's port
        if memory:
            port.write(next(frames))
        else:
            os.write(master, next(frames))
            select.select([slave], [], [], 0.0)  # the device's push (n_tty_poll)

    zero = np.zeros(1)
    parts = {"odrive": float("inf"), "bota": float("inf"), "plant": float("inf"), "tick": float("inf")}
    try:
        with Bench(sc, seed=sc.seed) as bench:
            sim = bench.simulator
            for _ in range(repeat):
                c0 = clk()
                for k in range(ticks):
                    motor.read()
                    motor.command_effort(zero)
                    if k % 2 == 0:
                        push()
                    bota.read(timeout=0.0)
                    sim.tick()
                parts["tick"] = min(parts["tick"], (clk() - c0) / ticks)
                c0 = clk()
                for _ in range(ticks):
                    motor.read()
                    motor.command_effort(zero)
                parts["odrive"] = min(parts["odrive"], (clk() - c0) / ticks)
                c0 = clk()
                for k in range(ticks):
                    if k % 2 == 0:
                        push()
                    bota.read(timeout=0.0)
                parts["bota"] = min(parts["bota"], (clk() - c0) / ticks)
                c0 = clk()
                for _ in range(ticks):
                    sim.tick()
                parts["plant"] = min(parts["plant"], (clk() - c0) / ticks)
            bench.safe_stop()
    finally:
        motor.close()
        bota.close()
        host.shutdown()
        with virtual.channels_lock:
            virtual.channels.pop(ch, None)
        os.close(master)
        os.close(slave)
    return parts


def floor_table(names: list[str], ticks: int) -> None:
    cost = primitive_costs()
    print(f"Transport floor per lockstep tick (CPU time; a CAN frame {1e6 * cost['can']:.1f} µs, "
          f"a 37-byte pty frame {1e6 * cost['pty']:.1f} µs, measured in this run)")
    print(f"{'scene':28s} {'CAN/tick':>9s} {'pty/tick':>9s} {'plant µs':>9s} {'floor µs':>9s} {'max ticks/s':>12s}"
          f" {'bench CPU t/s':>14s}")
    for name in names:
        can_n, pty_n = transport_counts(name, ticks)
        _, c, p = bench_tps(name, ticks)
        floor = can_n * cost["can"] + pty_n * cost["pty"] + 1.0 / p
        print(f"{name:28s} {can_n:9.2f} {pty_n:9.2f} {1e6 / p:9.1f} {1e6 * floor:9.1f} {1.0 / floor:12.0f} {c:14.0f}")
    print("(floor: the transports' and the plant's cost alone, no adapter, device, bench or runner code; "
          "plant µs: CPU time of Simulator.tick alone; every number CPU time of this thread)")
    if "sdea_bench" in names:
        floor_lines(ticks, 3)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=2000, help="lockstep ticks per scene")
    ap.add_argument("--scenes", default="", help="comma-separated scene names (default: every built-in scene)")
    ap.add_argument("--digest", action="store_true", help="print the SHA-256 of each run's record channels")
    ap.add_argument("--phases", action="store_true", help="print the bench tick's CPU time by phase")
    ap.add_argument("--floor", action="store_true", help="the transports' lower bound on a tick, per scene")
    ap.add_argument("--costs", action="store_true", help="CPU per tick by where the code lives, and the ceiling "
                    "(with --against: also that revision's ticks per CPU-second)")
    ap.add_argument("--against", default="", help="a git revision to compare with, in the same run")
    ap.add_argument("--repeat", type=int, default=3, help="child processes per tree and scene (--against)")
    ap.add_argument("--child", default="", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:  # one scene, one line of JSON (--against)
        _, rc, _, _ = runner_rates(a.child, a.ticks, False)
        _, c, _ = bench_tps(a.child, a.ticks)
        print(json.dumps({"runner": rc, "cpu": c}))
        return
    names = [s for s in a.scenes.split(",") if s] or [n for n, _ in builtin_scenes()]
    if a.costs:
        cost_table(names, a.ticks, a.repeat, a.against)
        return
    if a.against:
        against(a.against, names, a.ticks, a.repeat)
        return
    if a.floor:
        floor_table(names, a.ticks)
        return
    if a.phases:
        for name in names:
            ph = phases(name, a.ticks)
            total = sum(ph.values())
            print(f"\n{name}: bench tick CPU time by phase, {a.ticks} ticks ({total:.1f} µs per tick)")
            for k, v in ph.items():
                print(f"  {k:34s} {v:8.1f} µs {100 * v / total:6.1f} %")
        return
    print(f"Lockstep throughput, {a.ticks} ticks per scene (first experiment of each scene)")
    print(f"{'scene':28s} {'runner ticks/s':>15s} {'bench ticks/s':>14s} {'bench CPU t/s':>14s} {'plant ticks/s':>14s}"
          f" {'plant/bench':>12s} status" + ("   record sha256" if a.digest else ""))
    for name in names:
        r, status, dig = runner_tps(name, a.ticks, a.digest)
        b, c, p = bench_tps(name, a.ticks)
        print(f"{name:28s} {r:15.0f} {b:14.0f} {c:14.0f} {p:14.0f} {p / b:12.1f} {status}"
              + (f"   {dig[:16]}" if dig else ""))


if __name__ == "__main__":
    main()
