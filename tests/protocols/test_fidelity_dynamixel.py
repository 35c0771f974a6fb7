"""DYNAMIXEL X simulator and adapter against a factory-new XM430-W350 (issue 14, item 1).

Spec followed: ROBOTIS e-manual, XM430-W350 control table, "Initial Value" column: Baud Rate(8)
= 1 (57 600 bps), Return Delay Time(9) = 250 (x 2 us), ID(7) = 1; "Baud Rate(8)" table of rates.
The raw-SDK parts are independent clients (only ``dynamixel_sdk``).
"""

from __future__ import annotations

import dynamixel_sdk as sdk
import numpy as np
import pytest
from simtime import served, served_sdk_port

from hil.errors import DeviceTimeout
from hil.mocks.dynamixel_devices import ADDR_BAUD_RATE, ADDR_RETURN_DELAY, DynamixelChain
from hil.mocks.interfaces import FreeJoints
from hil.protocols.dynamixel_x import BAUD_RATES, DynamixelX

pytestmark = pytest.mark.timeout(30)


def _port(chain: DynamixelChain, bps: int):
    """The stock SDK port on the chain, served in this thread, its timeouts on simulated time."""
    port = served_sdk_port(chain)
    assert port.openPort() and port.setBaudRate(bps)
    return port, sdk.PacketHandler(2.0)


def Chain(*args, **kw) -> DynamixelChain:
    """A chain served in the test's thread (the adapter's or the port's waits run it)."""
    return DynamixelChain(*args, threaded=False, **kw)


def test_factory_servo_answers_the_raw_sdk_at_57600_only():
    """Spec: factory Baud Rate(8) = 1 -> 57 600 bps, Return Delay Time(9) = 250. The SDK's own
    default of 1 Mbps gets no answer (as on a real factory servo)."""
    with Chain(FreeJoints(1), ids=[1]) as chain:
        port, ph = _port(chain, 1_000_000)
        _, result, _ = ph.ping(port, 1)
        assert result == sdk.COMM_RX_TIMEOUT and chain.baud_mismatch >= 1
        port.closePort()
        port, ph = _port(chain, 57_600)
        model, result, error = ph.ping(port, 1)
        assert (model, result, error) == (1020, sdk.COMM_SUCCESS, 0)
        assert ph.read1ByteTxRx(port, 1, ADDR_BAUD_RATE)[:2] == (1, sdk.COMM_SUCCESS)
        assert ph.read1ByteTxRx(port, 1, ADDR_RETURN_DELAY)[:2] == (250, sdk.COMM_SUCCESS)
        # Baud Rate(8) takes effect at once: after writing 3 (1 Mbps) only 1 Mbps is understood
        assert ph.write1ByteTxRx(port, 1, ADDR_BAUD_RATE, 3)[0] == sdk.COMM_SUCCESS
        assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
        port.setBaudRate(BAUD_RATES[3])
        assert ph.ping(port, 1)[1] == sdk.COMM_SUCCESS
        port.closePort()


def test_adapter_finds_a_factory_servo_by_default_and_clears_its_return_delay():
    """The adapter's default is the factory 57 600 bps; it writes Return Delay Time(9) = 0."""
    with Chain(FreeJoints(1), ids=[1]) as chain:
        with DynamixelX(chain.port, waits=served(chain), ids=[1], enable=False) as dx:
            assert dx.baudrate == 57_600
        assert chain.servos[1].table[ADDR_RETURN_DELAY] == 0


def test_adapter_scans_the_baud_rates_when_the_given_one_gets_no_answer():
    """A scene that says 1 Mbps against a servo still at 57 600: the scan pings every X rate and
    continues at the one that answers; without the scan, DeviceTimeout."""
    with Chain(FreeJoints(1), ids=[1]) as chain:
        with pytest.raises(DeviceTimeout):
            DynamixelX(chain.port, waits=served(chain), ids=[1], baudrate=1_000_000, scan_baudrates=False, timeout=0.03)
        with DynamixelX(chain.port, waits=served(chain), ids=[1], baudrate=1_000_000, timeout=0.03) as dx:
            assert dx.baudrate == 57_600 and dx.info.extra["baudrate"] == 57_600
            dx.command_effort(np.array([0.0]))
            dx.read()


def test_a_configured_chain_at_4_mbps_is_opened_at_its_rate():
    """Scenes describe configured servos: the bench builds the chain at the scene's baudrate."""
    with Chain(FreeJoints(2), ids=[1, 2], baudrate=4_000_000) as chain:
        assert all(s.table[ADDR_BAUD_RATE] == 6 for s in chain.servos.values())
        with DynamixelX(chain.port, waits=served(chain), ids=[1, 2], baudrate=4_000_000, scan_baudrates=False) as dx:
            assert dx.read().position.shape == (2,)
        assert chain.baud_mismatch == 0
