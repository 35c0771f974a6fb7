"""Simulated time for the tests of an adapter against its simulated device (issue 26).

A test builds the simulated device to be served in the test's own thread (``threaded=False``: a
DYNAMIXEL chain, a Bota sensor, a streaming FT-300; CAN nodes with ``sync=True``) and gives the
adapter ``waits=served(device)``: every wait of the adapter first runs the device (the lockstep
barrier of :class:`hil.protocols.waits.LockstepWaits`), then ends at once with the answer, or, when
the device sends none, after its timeout of *simulated* time (``waits.waited``). So what a test
sees never depends on how fast the machine runs a device thread, and "no hang" is asserted as the
simulated time the wait took, never as wall-clock time.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hil.protocols.waits import LockstepWaits

#: how much slower than an idle machine a test may run before its timeout calls it hung: the suite's
#: hang guards (pytest-timeout markers and the pyproject default) are multiplied by it in
#: tests/conftest.py, so a loaded CI box (two CPU-bound processes beside two workers: ~4x slower)
#: passes; a guard is never a measure of speed
TIMEOUT_SCALE = 4


def served(*devices: Any, clock: Callable[[], float] | None = None) -> LockstepWaits:
    """Simulated-time waits whose barrier serves ``devices`` (``serve_pending()`` each, in order;
    a Modbus/TCP server: ``settle()``). ``clock``: the simulated clock (default: 0, so
    ``monotonic()`` is the time spent waiting)."""

    def barrier() -> None:
        for d in devices:
            (d.serve_pending if hasattr(d, "serve_pending") else d.settle)()

    return LockstepWaits(clock or (lambda: 0.0), barrier)


def served_sdk_port(chain: Any) -> Any:
    """dynamixel_sdk's stock ``PortHandler`` on a DYNAMIXEL chain served in this thread
    (``threaded=False``): each read lets the chain answer first; the SDK's clock (ms, its packet
    timeouts) is simulated and moves by 1 ms per read that finds nothing."""
    import dynamixel_sdk as sdk

    class ServedPort(sdk.PortHandler):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__(chain.port)
            self.now_ms = 0.0

        def readPort(self, length: int) -> bytes:
            chain.serve_pending()
            data: bytes = super().readPort(length)
            if not data:
                self.now_ms += 1.0
            return data

        def getCurrentTime(self) -> float:
            return self.now_ms

    return ServedPort()


def served_modbus(sim: Any) -> LockstepWaits:
    """Simulated-time waits for an FT-300 adapter (or a pymodbus client wrapped by
    ``hil.protocols.modbus_robotiq._waiting_client``) talking to the Modbus/TCP server ``sim``
    (a :class:`hil.mocks.modbus_devices.SimulatedFT300`): the adapter's link counts its requests,
    the barrier waits until the server has answered each (``sim.settle``), as on a lockstep bench."""
    link = LockstepWaits(lambda: 0.0, sim.settle).link()
    sim.link = link
    return link


def served_streaming(sim: Any, rate_hz: float | None = None) -> LockstepWaits:
    """Like :func:`served` for a streaming sensor that streams on its own (a stream left running):
    before serving it, the barrier emits the frames due at ``rate_hz`` (default ``sim.rate_hz``)
    on the simulated time the host has spent so far (``monotonic()``: frames at 0, 1/rate, ...)."""
    rate = float(rate_hz if rate_hz is not None else sim.rate_hz)
    emitted = [0]
    box: list[LockstepWaits] = []

    def barrier() -> None:
        due = int(box[0].monotonic() * rate) + 1 - emitted[0]
        for _ in range(max(0, due)):
            sim.emit()
        emitted[0] += max(0, due)
        sim.serve_pending()

    box.append(LockstepWaits(lambda: 0.0, barrier))
    return box[0]
