"""The device base classes' template methods (protocols/base.py): what every adapter inherits."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil.errors import DeviceDisconnected, DeviceTimeout
from hil.protocols.base import Actuator, JointSample, run_steps


class FakeActuator(Actuator):
    """Records every hook call; ``fail_stop`` / ``fail_release`` make those hooks raise."""

    dof = 2
    units = "rotary"

    def __init__(self, *, effort_limit: float | None = None, timeout: float = 0.25) -> None:
        self.effort_limit = effort_limit
        self.timeout = timeout
        self.calls: list[tuple[str, object]] = []
        self.fail_stop: BaseException | None = None
        self.fail_release: BaseException | None = None
        self.armed = True
        self.last: JointSample | None = None

    def _send_effort(self, effort: np.ndarray, timeout: float) -> None:
        self.calls.append(("effort", (effort.tolist(), timeout)))

    def _read_sample(self, timeout: float) -> JointSample:
        self.calls.append(("read", timeout))
        return JointSample(t=0.0, seq=self._next_seq(), position=np.zeros(2), velocity=np.zeros(2))

    def _stop_steps(self) -> tuple:
        def first() -> None:
            self.calls.append(("stop1", None))
            if self.fail_stop is not None:
                raise self.fail_stop

        return (first, lambda: self.calls.append(("stop2", None)))

    def _close_steps(self) -> tuple:
        return (lambda: self.calls.append(("close_step", None)),)

    def _armed(self) -> bool:
        return self.armed

    def _release(self) -> None:
        self.calls.append(("release", None))
        if self.fail_release is not None:
            raise self.fail_release


def names(dev: FakeActuator) -> list[str]:
    return [c[0] for c in dev.calls]


def test_command_effort_checks_size_finiteness_and_clamps_before_the_hook() -> None:
    dev = FakeActuator(effort_limit=1.5)
    dev.command_effort(np.array([3.0, -0.5]), timeout=0.02)
    assert dev.calls == [("effort", ([1.5, -0.5], 0.02))]  # clamped to +-effort_limit
    with pytest.raises(ValueError, match="2 effort values"):
        dev.command_effort(np.array([1.0]))
    with pytest.raises(ValueError, match="non-finite"):
        dev.command_effort(np.array([math.nan, 0.0]))
    assert len(dev.calls) == 1  # nothing sent for a refused command


def test_read_resolves_the_timeout() -> None:
    dev = FakeActuator(timeout=0.25)
    dev.read(None)
    dev.read(-1.0)
    dev.read(0.07)
    assert [c[1] for c in dev.calls] == [0.25, 0.0, 0.07]  # None -> the adapter's, negative -> 0
    with pytest.raises(ValueError, match="NaN"):
        dev.read(math.nan)
    assert dev.read(0.0).seq == 4  # one sequence number per sample


def test_close_stops_then_releases_once_and_io_is_refused_after() -> None:
    dev = FakeActuator()
    dev.close()
    dev.close()
    assert names(dev) == ["stop1", "stop2", "close_step", "release"]
    assert dev.closed
    with pytest.raises(DeviceDisconnected, match="FakeActuator is closed"):
        dev.read()
    with pytest.raises(DeviceDisconnected):
        dev.command_effort(np.zeros(2))


def test_an_unarmed_device_is_released_without_a_stop() -> None:
    dev = FakeActuator()
    dev.armed = False
    dev.close()
    assert names(dev) == ["release"]


def test_safe_stop_attempts_every_step_and_never_raises() -> None:
    dev = FakeActuator()
    dev.fail_stop = RuntimeError("bus off")
    dev.safe_stop()
    assert names(dev) == ["stop1", "stop2"]


def test_an_interrupted_stop_still_runs_every_step_and_releases_the_bus() -> None:
    dev = FakeActuator()
    dev.fail_stop = KeyboardInterrupt()
    with pytest.raises(KeyboardInterrupt):  # the interruption is not lost ...
        dev.close()
    # ... but only after the rest of the stop ran and the transport was released
    assert names(dev) == ["stop1", "stop2", "release"]
    assert dev.closed


def test_a_failing_release_is_logged_not_raised() -> None:
    dev = FakeActuator()
    dev.fail_release = OSError("port vanished")
    dev.close()
    assert dev.closed and names(dev)[-1] == "release"


def test_run_steps_holds_the_first_interruption() -> None:
    seen: list[int] = []

    def interrupt(k: int) -> None:
        seen.append(k)
        raise KeyboardInterrupt(k)

    with pytest.raises(KeyboardInterrupt) as info:
        run_steps([lambda: interrupt(1), lambda: seen.append(2), lambda: interrupt(3)], "test")
    assert seen == [1, 2, 3] and info.value.args == (1,)


def test_stale_repeats_the_last_sample_or_times_out_before_the_first() -> None:
    dev = FakeActuator()
    with pytest.raises(DeviceTimeout, match="nothing yet"):
        dev._stale(None, 1.0, "nothing yet")
    first = dev.read(0.0)
    again = dev._stale(first, 2.5, "unused")
    assert (again.seq, again.t) == (first.seq, 2.5)  # the same data, read later
    assert again.position is first.position and again.velocity is first.velocity
    assert (dev._timeouts, dev._stale_reads) == (1, 1)


def test_a_real_adapter_closes_when_its_bus_fails_to_shut_down(monkeypatch: pytest.MonkeyPatch) -> None:
    from hil.protocols.can_odrive import ODriveCAN

    dev = ODriveCAN(node_id=1, channel="base-lifecycle", interface="virtual", enable=False)
    bus = dev._bus
    real = bus.shutdown

    def shutdown_then_fail() -> None:
        real()  # the channel is freed (the leak fixture checks), then the driver reports an error
        raise OSError("gone")

    monkeypatch.setattr(bus, "shutdown", shutdown_then_fail)
    dev.close()
    assert dev.closed
    with pytest.raises(DeviceDisconnected, match="ODrive node 1 is closed"):
        dev.read()
