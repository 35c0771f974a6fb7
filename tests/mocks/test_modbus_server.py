"""The simulated FT-300 is a real Modbus server: a plain pymodbus client reads it over loopback.

A client that expects an answer waits up to 10 s for it (a bound a loaded machine never reaches,
not a pace: the read returns with the answer); one that expects none waits 0.1 s (the outcome
does not depend on the wait). The seeded drop pattern is read through the lockstep barrier
(``tests/simtime.served_modbus``): a reply counts as dropped only when the server dropped it."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pymodbus")

from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient
from simtime import served_modbus

from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints
from hil.mocks.modbus_devices import (
    SimulatedFT300,
    firmware_registers,
    serial_registers,
    wrench_to_registers,
)

pytestmark = pytest.mark.timeout(20)

WRENCH = np.array([1.5, -2.25, 300.0, -0.5, 0.125, -32.0])


def _plain_client(sim: SimulatedFT300, timeout: float = 10.0) -> ModbusTcpClient:
    framer = FramerType.RTU if sim.framing == "rtu" else FramerType.SOCKET
    client = ModbusTcpClient("127.0.0.1", port=sim.port, framer=framer, timeout=timeout, retries=0)
    assert client.connect()
    return client


# register encoding, as a table: (N or N.m, axis index) -> raw uint16 register
ENCODING = [
    (1.0, 0, 100),
    (-1.0, 0, 0xFF9C),  # -100 two's complement
    (327.67, 2, 32767),
    (400.0, 2, 32767),  # saturates
    (-400.0, 1, 0x8000),
    (1.0, 3, 1000),  # torques: N.m * 1000
    (-0.001, 5, 0xFFFF),
    (0.0004, 4, 0),  # rounds to nearest count
]


@pytest.mark.parametrize(("value", "axis", "raw"), ENCODING)
def test_wrench_register_encoding(value: float, axis: int, raw: int) -> None:
    w = np.zeros(6)
    w[axis] = value
    assert wrench_to_registers(w)[axis] == raw


def test_info_register_layout() -> None:
    assert firmware_registers((1, 0, 3)) == [0x4654, 0x5301, 0x0003]  # "FT" "S"+1, 0.3
    assert serial_registers("SIM", 70000) == [0x5349, 0x4D00, 70000 & 0xFFFF, 1]


@pytest.mark.parametrize("framing", ["tcp", "rtu"])
def test_plain_pymodbus_client_reads_registers(framing: str) -> None:
    plant = FreeJoints(dof=6)
    plant.apply_effort(WRENCH)
    with SimulatedFT300(plant, framing=framing) as sim:
        client = _plain_client(sim)
        try:
            rr = client.read_holding_registers(180, count=6, device_id=9)
            assert not rr.isError()
            assert rr.registers == wrench_to_registers(WRENCH)
            signed = client.convert_from_registers(rr.registers[:1], client.DATATYPE.INT16)
            assert signed == 150
            ir = client.read_input_registers(180, count=6, device_id=9)  # FC04 sees the same block
            assert ir.registers == rr.registers
            fw = client.read_holding_registers(500, count=3, device_id=9)
            assert fw.registers == firmware_registers()
            wr = client.write_register(410, 0x0200, device_id=9)
            assert not wr.isError()
            assert sim.streaming_requested
            assert (410, [0x0200]) in sim.written
        finally:
            client.close()


def test_rtu_request_bytes_match_manual_example() -> None:
    # FT-300 manual: read the 6 force/torque registers of slave 9 = 09 03 00 B4 00 06 84 A6
    with SimulatedFT300(framing="rtu") as sim:
        client = _plain_client(sim)
        try:
            client.read_holding_registers(180, count=6, device_id=9)
        finally:
            client.close()
        assert sim.last_request == bytes.fromhex("090300B4000684A6")


def test_lockstep_registers_follow_the_plant_state() -> None:
    plant = FreeJoints(dof=3)
    with SimulatedFT300(plant) as sim:
        client = _plain_client(sim)
        try:
            for k in range(5):
                plant.apply_effort(np.array([k * 1.0, -k * 0.5, 2.0]))
                plant.step(0.001)
                regs = client.read_holding_registers(180, count=6, device_id=9).registers
                assert regs == wrench_to_registers(np.array([k * 1.0, -k * 0.5, 2.0, 0, 0, 0]))
        finally:
            client.close()


def test_explicit_update_mode() -> None:
    plant = FreeJoints(dof=1)
    plant.apply_effort(np.array([5.0]))
    with SimulatedFT300(plant, auto_update=False) as sim:
        client = _plain_client(sim)
        try:
            assert client.read_holding_registers(180, count=1, device_id=9).registers == [500]
            plant.apply_effort(np.array([7.0]))
            assert client.read_holding_registers(180, count=1, device_id=9).registers == [500]
            sim.update()
            assert client.read_holding_registers(180, count=1, device_id=9).registers == [700]
        finally:
            client.close()


def test_other_slave_ids_are_ignored() -> None:
    from pymodbus.exceptions import ModbusIOException

    with SimulatedFT300(framing="rtu") as sim:
        client = _plain_client(sim, timeout=0.1)
        try:
            with pytest.raises(ModbusIOException):
                client.read_holding_registers(180, count=6, device_id=1)
        finally:
            client.close()


def test_fault_injection_exception_and_stale() -> None:
    plant = FreeJoints(dof=1)
    plan = FaultPlan(error_code=7, error_at_tick=1, error_until_tick=2, stale_prob=1.0)
    with SimulatedFT300(plant, faults=plan) as sim:
        client = _plain_client(sim)
        try:
            plant.apply_effort(np.array([1.0]))
            assert client.read_holding_registers(180, count=1, device_id=9).registers == [0]  # stale
            err = client.read_holding_registers(180, count=1, device_id=9)
            assert err.isError() and err.exception_code == 4
            assert sim.last_error_code == 7 and sim.exception_replies == 1
            assert sim.stale_replies == 1
        finally:
            client.close()


def _drop_pattern(seed: int) -> list[bool]:
    from pymodbus.exceptions import ModbusIOException

    from hil.protocols.modbus_robotiq import _waiting_client

    out = []
    with SimulatedFT300(faults=FaultPlan(drop_prob=0.3), seed=seed) as sim:
        client = _waiting_client(ModbusTcpClient, served_modbus(sim))(  # pymodbus' client, waits simulated
            "127.0.0.1", port=sim.port, framer=FramerType.SOCKET, timeout=0.2, retries=0)
        assert client.connect()
        try:
            for _ in range(8):
                try:
                    client.read_holding_registers(180, count=6, device_id=9)
                    out.append(False)
                except ModbusIOException:
                    out.append(True)
        finally:
            client.close()
    return out


def test_fault_pattern_is_deterministic_for_a_seed() -> None:
    a = _drop_pattern(3)
    assert a == _drop_pattern(3)
    assert any(a) and not all(a)


def test_close_is_idempotent() -> None:
    sim = SimulatedFT300()
    sim.close()
    sim.close()
