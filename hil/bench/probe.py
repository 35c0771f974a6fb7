"""Discovery: what answers on a CAN channel, a serial port or a Modbus address (``hil probe``).

``hil probe --can CHANNEL [--interface socketcan|virtual|udp_multicast ...] [--can-port PORT]``
    *Passive* first: listens ``--listen`` seconds (default 0.5) and classifies what it hears:

    * ODrive CANSimple heartbeats (id ``node << 5 | 0x01``, 8 bytes): node id, axis state, axis
      error; then an RTR Get_Version (0x00) to each such node for the firmware version (firmware
      0.6; no answer: 0.5.x), which selects the table naming the axis error bits
      (:data:`hil.protocols.codecs.odrive.AXIS_ERRORS`);
    * CANopen boot-up / heartbeat (id ``0x700 + node``, 1 byte; CiA 301 §7.2.8.3.2): node id, NMT
      state; then, by SDO (canopen's client, no object dictionary needed), device type 0x1000,
      identity 0x1018 (vendor id, product code, revision, serial number), name 0x1008, software
      version 0x100A and, for CiA 402 drives (profile 402 in 0x1000), supported modes 0x6502,
      encoder resolution 0x608F and rated torque 0x6076;
    * CubeMars MIT replies seen on the bus (8 bytes on id 0, first byte = motor id; not when an
      ODrive node 0 is there: id 0 is its Get_Version, which firmware 0.6.10 sends every 100 ms).

    *Active*, only when asked (they send frames that other devices may act on):
    ``--cubemars-ids 1,2`` sends the MIT "exit motor mode" frame (motor disabled; the motor answers
    with its state) to those ids -- ids 1..31 are also ODrive node 0's command ids (id 2 would be
    its Estop); ``--sdo-scan`` sends an SDO read of 0x1000 to every node 1..127 (finds CANopen nodes
    without a heartbeat; ids 0x601..0x67F are also ODrive nodes 48..51's command ids).

    On ``udp_multicast`` a channel is a multicast group *and* a UDP port (``--can-port``; python-can's
    default 43113): a channel served by ``hil mock serve`` has its own port, and the probe hears
    only the channel it names.

``hil probe --serial PORT [--baud 57600,1000000]``
    Listens for streams (Bota binary frames with a valid CRC; Robotiq FT-300 stream frames 0x20
    0x4E), then a DYNAMIXEL Protocol 2.0 broadcast ping at each baud rate (ids, model numbers,
    firmware versions), then a Modbus RTU read of an FT-300's firmware (registers 500-502) and
    serial number (510-513) at 19200 baud, slave ``--unit`` (default 9).

``hil probe --modbus URL --unit N``
    An FT-300 over Modbus (``tcp://HOST:PORT``, ``rtu-over-tcp://...``, a serial device): firmware
    and serial number registers.

Output: a table (family, driver, address, details) or, with ``--json``, one JSON object
``{"devices": [...]}`` whose entries carry the ``open_device`` parameters; ``--scene OUT.yaml``
writes a scene stub with one device per find (refused if OUT exists, unless ``--overwrite``).
A Bota sensor found streaming is then asked who it is (:func:`bota_identity`): the hardware reset
``#`` makes it reboot and print ``name: PRODUCT``, ``S/N: N`` and ``FW version: V`` after ``App Init``
(Bota's ``rokubimini_serial`` driver, ``RokubiminiSerialCommunication.hpp`` / ``RokubiminiSerialImpl.cpp``
``parseCommunicationMsgs``; its binary stream carries no identity); the sensor comes back streaming
with its saved configuration. ``--bota-reset 0`` skips it.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import re
import struct
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from hil.errors import DeviceDisconnected, DeviceError, HilError
from hil.protocols.codecs.bota import BOTA_BOOT, parse_bota_boot

logger = logging.getLogger(__name__)

__all__ = ["Found", "add_arguments", "bota_identity", "parse_bota_boot", "probe_can", "probe_modbus", "probe_serial",
           "run", "scene_stub"]


@dataclass
class Found:
    """One device that answered. ``params``: what ``open_device(driver, **params)`` needs."""

    family: str  # odrive | cubemars | cia402 | canopen | dynamixel | robotiq_ft300 | robotiq_ft300_stream | bota
    driver: str  # registry driver name ("" when the suite has no adapter for it)
    address: str
    ident: str
    details: dict[str, Any] = field(default_factory=dict)
    params: dict[str, Any] = field(default_factory=dict)
    role: str = "actuator"
    dof: int = 1


# ---------------------------------------------------------------------------------------------
# CAN


def _odrive_state_name(state: int) -> str:
    from hil.protocols.codecs.odrive import AxisState

    names = {1: "IDLE", 2: "STARTUP_SEQUENCE", 3: "FULL_CALIBRATION_SEQUENCE", 4: "MOTOR_CALIBRATION",
             6: "ENCODER_INDEX_SEARCH", 7: "ENCODER_OFFSET_CALIBRATION", 8: "CLOSED_LOOP_CONTROL",
             9: "LOCKIN_SPIN", 10: "ENCODER_DIR_FIND", 11: "HOMING", 12: "ENCODER_HALL_POLARITY_CALIBRATION",
             13: "ENCODER_HALL_PHASE_CALIBRATION"}
    with contextlib.suppress(ValueError):
        return AxisState(state).name
    return names.get(state, str(state))


def _collect(bus: Any, seconds: float) -> list[Any]:
    out = []
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        msg = bus.recv(timeout=left)
        if msg is not None:
            out.append(msg)
    return out


def _sdo_u(node: Any, index: int, sub: int, fmt: str) -> int | None:
    try:
        data = node.sdo.upload(index, sub)
        return struct.unpack_from(fmt, data.ljust(struct.calcsize(fmt), b"\0"))[0]
    except Exception as exc:  # abort or timeout: object absent or node gone
        logger.debug("SDO 0x%04X:%d of node %d: %s", index, sub, node.id, exc)
        return None


def _sdo_str(node: Any, index: int) -> str:
    try:
        return node.sdo.upload(index, 0).decode("latin-1").rstrip("\0 ")
    except Exception:
        return ""


def _canopen_details(network: Any, node_id: int, timeout: float) -> dict[str, Any]:
    import canopen

    node = network.add_node(node_id, canopen.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = timeout
    d: dict[str, Any] = {}
    dtype = _sdo_u(node, 0x1000, 0, "<I")
    if dtype is not None:
        d["device_type"] = f"0x{dtype:08X}"
        d["profile"] = dtype & 0xFFFF
    for sub, key in ((1, "vendor_id"), (2, "product_code"), (3, "revision"), (4, "serial")):
        v = _sdo_u(node, 0x1018, sub, "<I")
        if v is not None:
            d[key] = v if key == "serial" else f"0x{v:08X}"
    if name := _sdo_str(node, 0x1008):
        d["name"] = name
    if sw := _sdo_str(node, 0x100A):
        d["firmware"] = sw
    if d.get("profile") == 402:
        modes = _sdo_u(node, 0x6502, 0, "<I")
        if modes is not None:
            d["supported_modes"] = f"0x{modes:08X}"
            d["torque_modes"] = [m for m, bit in ((4, 3), (10, 9)) if modes >> bit & 1]
        inc, rev = _sdo_u(node, 0x608F, 1, "<I"), _sdo_u(node, 0x608F, 2, "<I")
        if inc:
            d["counts_per_rev"] = inc // max(rev or 1, 1)
        rated = _sdo_u(node, 0x6076, 0, "<I")
        if rated:
            d["rated_torque_mNm"] = rated
    return d


def probe_can(channel: str, interface: str = "socketcan", *, bitrate: int | None = None, listen_s: float = 0.5,
              sdo_scan: bool = False, cubemars_ids: list[int] | tuple[int, ...] = (), cubemars_model: str = "AK80-9",
              timeout: float = 0.1, **bus_kwargs: Any) -> list[Found]:
    """Devices on one CAN channel (module docstring); ``timeout`` (s) per request."""
    import can  # lazy: the 'can' extra

    from hil.protocols.codecs import cubemars as cm  # lazy: hil probe is parsed by every hil command
    from hil.protocols.codecs import odrive as od

    kw = dict(bus_kwargs)
    if bitrate is not None:
        kw["bitrate"] = bitrate
    try:
        bus = can.Bus(interface=interface, channel=channel, **kw)
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        raise DeviceDisconnected(f"cannot open CAN bus {interface}:{channel}: {exc}") from exc
    where = f"can {interface}:{channel}" + (f" port {bus_kwargs['port']}" if "port" in bus_kwargs else "")
    reopen = dict(bus_kwargs)  # what open_device needs to reach the same bus (e.g. a udp_multicast port)
    found: list[Found] = []
    try:
        heard = _collect(bus, listen_s)
        canopen_nodes: dict[int, dict[str, Any]] = {}
        odrive_nodes: dict[int, tuple[int, int]] = {}
        cubemars: dict[int, Any] = {}
        zero: list[bytes] = []  # frames on id 0: CubeMars replies, or ODrive node 0's Get_Version
        limits = cm.model_limits(cubemars_model)

        def classify(msg: Any) -> None:
            if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                return
            arb, data = msg.arbitration_id, bytes(msg.data)
            if arb & 0x780 == 0x700 and 1 <= arb & 0x7F <= 127 and len(data) == 1:
                rec = canopen_nodes.setdefault(arb & 0x7F, {"bootup": False})
                if data[0] == 0:
                    rec["bootup"] = True
                else:
                    rec["nmt_state"] = data[0] & 0x7F
            elif arb & 0x1F == od.CMD_HEARTBEAT and len(data) == 8:
                odrive_nodes[arb >> 5] = od.decode_heartbeat(data)
            elif arb == 0 and len(data) in (6, 8) and data[0] != 0:
                zero.append(data)

        def cubemars_replies(frames: list[bytes]) -> None:
            for data in frames:
                with contextlib.suppress(Exception):
                    cubemars[data[0]] = cm.unpack_reply(data, limits)

        for msg in heard:
            classify(msg)
        if 0 not in odrive_nodes:
            # id 0 is also ODrive node 0's Get_Version (cyclic on 0.6.10, 8 bytes): with that node on
            # the bus, frames heard on it are not taken for CubeMars replies (the asked motors' are)
            cubemars_replies(zero)
        # a CANopen EMCY (0x80 + node, 8 bytes) looks like an ODrive heartbeat (node 4..7, cmd 1)
        for n in list(odrive_nodes):
            if (n << 5 | 1) - 0x80 in canopen_nodes:
                del odrive_nodes[n]
        for dxl in cubemars_ids:
            bus.send(can.Message(arbitration_id=int(dxl), data=cm.SPECIAL_FRAMES["exit"], is_extended_id=False))
        if cubemars_ids:
            zero.clear()
            for msg in _collect(bus, timeout):
                classify(msg)
            cubemars_replies([d for d in zero if d[0] in cubemars_ids])  # the asked motors answer with their id
        for n in sorted(odrive_nodes):
            err, state = odrive_nodes[n]
            details: dict[str, Any] = {"axis_state": _odrive_state_name(state), "axis_error": f"0x{err:08X}"}
            bus.send(can.Message(arbitration_id=n << 5, is_remote_frame=True, dlc=8, is_extended_id=False))
            fw: tuple[int, int, int] | None = None
            for msg in _collect(bus, timeout):
                if msg.arbitration_id == n << 5 and not msg.is_remote_frame and len(msg.data) == 8:
                    _, hw, fw, dev = od.decode_version(msg.data)
                    details["hardware"] = "{}.{}.{}".format(*hw)
                    details["firmware"] = "{}.{}.{}".format(*fw) + ("-dev" if dev else "")
                classify(msg)
            line = od.firmware_line(fw)  # no Get_Version answer: 0.5.x, whose error bits differ
            details.setdefault("firmware", "0.5.x (no Get_Version answer)")
            details["errors"] = od.describe_axis_error(err, line)
            found.append(Found("odrive", "odrive_can", f"{where} node {n}", f"node {n}", details,
                               {"interface": interface, "channel": channel, "node_id": n, **reopen}))
        for mid in sorted(cubemars):
            r = cubemars[mid]
            found.append(Found("cubemars", "cubemars_mit", f"{where} motor {mid}", f"motor {mid}",
                               {"position": round(r.position, 4), "velocity": round(r.velocity, 4),
                                "torque": round(r.torque, 4), "temperature": r.temperature, "error": r.error},
                               {"interface": interface, "channel": channel, "motor_id": mid,
                                "model": cubemars_model, **reopen}))
        if canopen_nodes or sdo_scan:
            found += _probe_canopen(bus, where, interface, channel, canopen_nodes, sdo_scan, timeout, listen_s)
            for f in found:
                if f.family in ("cia402", "canopen"):
                    f.params.update(reopen)
    finally:
        bus.shutdown()
    return found


def _probe_canopen(bus: Any, where: str, interface: str, channel: str, nodes: dict[int, dict[str, Any]],
                   sdo_scan: bool, timeout: float, listen_s: float) -> list[Found]:
    import canopen

    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    out: list[Found] = []
    try:
        if sdo_scan:
            network.scanner.search()
            time.sleep(max(timeout, 0.05))
            for n in network.scanner.nodes:
                nodes.setdefault(n, {"bootup": False})
        for n in sorted(nodes):
            rec = nodes[n]
            node_d = _canopen_details(network, n, timeout)
            state = rec.get("nmt_state")
            details = {"nmt_state": canopen.nmt.NMT_STATES.get(state, str(state)) if state is not None else "",
                       "bootup_seen": rec["bootup"], **node_d}
            is402 = node_d.get("profile") == 402
            params: dict[str, Any] = {"interface": interface, "channel": channel, "node_id": n}
            if is402:
                for k in ("counts_per_rev", "rated_torque_mNm"):
                    if k in node_d:
                        params[k] = node_d[k]
            out.append(Found("cia402" if is402 else "canopen", "cia402" if is402 else "", f"{where} node {n}",
                             f"node {n}", details, params))
    finally:
        with contextlib.suppress(Exception):
            if network.notifier is not None:
                network.notifier.stop(1.0)
    return out


# ---------------------------------------------------------------------------------------------
# serial / Modbus


def probe_modbus(url: str, unit: int = 9, timeout: float = 0.5) -> list[Found]:
    """An FT-300 over Modbus at ``url`` / slave ``unit``: firmware and serial number registers."""
    from hil.protocols.modbus_robotiq import RobotiqFT300

    try:
        with RobotiqFT300(url=url, slave=unit, timeout=timeout) as dev:
            info = dev.info
            return [Found("robotiq_ft300", "robotiq_ft300", f"modbus {url} unit {unit}", f"unit {unit}",
                          {"firmware": info.firmware, "serial": info.serial}, {"url": url, "slave": unit},
                          role="force_sensor", dof=6)]
    except DeviceError as exc:
        logger.debug("no FT-300 at %s unit %d: %s", url, unit, exc)
        return []




def bota_identity(port: str, *, baudrate: int = 460800, timeout: float = 2.0) -> dict[str, str]:
    """Ask a Bota serial sensor who it is: the hardware reset ``#`` (as Bota's rokubimini_serial
    driver does at every start) makes it reboot and print its product name, serial number and
    firmware (:func:`parse_bota_boot`); it then streams again with its *saved* configuration (an
    adapter's unsaved ``c``/``f`` setup is gone: run the probe before the bench opens). ``{}`` if
    no boot text arrives within ``timeout`` s (2 s: the driver's own wait)."""
    import serial

    try:
        ser = serial.serial_for_url(port, baudrate=baudrate, timeout=0.05)
    except (serial.SerialException, OSError, ValueError) as exc:
        logger.debug("Bota identity: cannot open %s: %s", port, exc)
        return {}
    buf = bytearray()
    try:
        ser.reset_input_buffer()
        ser.write(b"#")
        ser.flush()
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            buf += ser.read(4096)
            got = parse_bota_boot(bytes(buf))
            if len(got) == len(BOTA_BOOT):
                return got
        return parse_bota_boot(bytes(buf))
    except (serial.SerialException, OSError) as exc:
        logger.debug("Bota identity on %s: %s", port, exc)
        return parse_bota_boot(bytes(buf))
    finally:
        ser.close()


def probe_serial(port: str, *, baudrates: tuple[int, ...] = (57600, 1000000), listen_s: float = 0.3,
                 unit: int = 9, timeout: float = 0.3, bota_reset_s: float = 2.0) -> list[Found]:
    """Devices on one serial port (module docstring). ``bota_reset_s``: how long to wait for a Bota
    sensor's boot text after the identity reset (0: do not reset it; no serial number then)."""
    import serial  # lazy: the 'serial' extra

    from hil.protocols.codecs.bota import FrameParser
    from hil.protocols.codecs.robotiq import StreamParser

    try:
        ser = serial.serial_for_url(port, baudrate=460800, timeout=0.05)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise DeviceDisconnected(f"cannot open serial port {port}: {exc}") from exc
    bota, ft = FrameParser(), StreamParser()
    frames: list[Any] = []
    n_ft = 0
    try:
        end = time.monotonic() + listen_s
        while time.monotonic() < end:
            data = ser.read(4096)
            if data:
                frames += bota.feed(data)
                n_ft += len(ft.feed(data))
    finally:
        ser.close()
    found: list[Found] = []
    if len(frames) >= 2:
        ts = [f.timestamp for f in frames]
        dt_us = (ts[-1] - ts[0]) / (len(ts) - 1)
        ident = bota_identity(port, timeout=bota_reset_s) if bota_reset_s > 0 else {}
        found.append(Found("bota", "bota_serial", port, "stream",
                           {"frames": len(frames), "status": f"0x{frames[-1].status:04X}",
                            "temperature": round(frames[-1].temperature, 2),
                            "frame_period_us": round(dt_us, 1),
                            "model": ident.get("name", ""), "firmware": ident.get("firmware", ""),
                            "serial": ident.get("serial", "(no boot text after a reset)" if bota_reset_s > 0
                                                else "(not asked: --bota-reset 0)")},
                           {"url": port, "period_s": round(dt_us * 1e-6, 9) if dt_us > 0 else 0.001},
                           role="force_sensor", dof=6))
        return found
    if n_ft >= 2:
        found.append(Found("robotiq_ft300_stream", "robotiq_ft300_stream", port, "stream", {"frames": n_ft},
                           {"url": port, "slave": unit}, role="force_sensor", dof=6))
        return found
    found += _dynamixel_ping(port, baudrates)
    if not found:
        for f in probe_modbus(port, unit, timeout):
            f.family = f.driver = "robotiq_ft300"
            found.append(f)
    return found


def _dynamixel_ping(port: str, baudrates: tuple[int, ...]) -> list[Found]:
    try:
        import dynamixel_sdk as sdk
    except ImportError:
        logger.info("dynamixel-sdk not installed: no DYNAMIXEL ping")
        return []
    for baud in baudrates:
        ph_port = sdk.PortHandler(port)
        try:
            if not ph_port.openPort():
                return []
            with contextlib.suppress(Exception):
                ph_port.setBaudRate(int(baud))
            ph = sdk.PacketHandler(2.0)
            data, result = ph.broadcastPing(ph_port)
        except Exception as exc:
            logger.debug("DYNAMIXEL ping at %d baud failed: %s", baud, exc)
            data, result = {}, -1
        finally:
            with contextlib.suppress(Exception):
                ph_port.closePort()
        if result == sdk.COMM_SUCCESS and data:
            ids = sorted(int(i) for i in data)
            details = {"baudrate": int(baud),
                       "servos": {str(i): {"model_number": int(data[i][0]), "firmware": int(data[i][1])} for i in ids}}
            return [Found("dynamixel", "dynamixel_x", f"{port} ids {ids}", f"ids {ids}", details,
                          {"port": port, "ids": ids, "baudrate": int(baud)}, dof=len(ids))]
    return []


# ---------------------------------------------------------------------------------------------
# scene stub, CLI


def scene_stub(found: list[Found], name: str = "probed_bench") -> dict[str, Any]:
    """A scene mapping with one device per find (drivers the suite has); bodies, limits and
    experiments are left for the user (see the comments written with it)."""
    devices = []
    used: set[str] = set()
    for f in found:
        if not f.driver:
            continue
        base = f"{f.family}_{re.sub(r'[^A-Za-z0-9]+', '_', f.ident).strip('_')}"
        dev_name = base
        k = 2
        while dev_name in used:
            dev_name, k = f"{base}_{k}", k + 1
        used.add(dev_name)
        dof = 6 if f.role == "force_sensor" else f.dof
        dev: dict[str, Any] = {"name": dev_name, "role": f.role, "driver": f.driver, "params": dict(f.params),
                               "dof": 1 if f.role == "force_sensor" else dof}
        if f.role == "force_sensor":
            dev["axes"] = [2]
        devices.append(dev)
    from hil.protocols.link_budget import over_budget

    rate = 1000
    while rate > 100 and over_budget([SimpleNamespace(**{"sim": None, **d}) for d in devices], rate):
        rate //= 2  # the links found (at their factory bit/baud rates) carry the loop at this rate
    note = "" if rate == 1000 else (f" (rate_hz {rate}: what the links carry at their current bit/baud rates; "
                                   "raise them to run faster)")
    return {"name": name, "description": "scene stub written by hil probe: add the bodies, safety limits, "
            f"controller and experiments{note}", "seed": 0, "rate_hz": rate, "mode": "realtime", "units": "rotary",
            "devices": devices,
            "safety": {"max_effort": 0.1, "max_velocity": 1.0, "position_limits": [-0.5, 0.5], "max_energy": 1.0,
                       "watchdog_ms": 50},
            "controller": {"type": "none"}, "experiments": []}


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``hil probe`` (module docstring)."""
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--can", metavar="CHANNEL", help="CAN channel to listen on (e.g. can0)")
    g.add_argument("--serial", metavar="PORT", help="serial port (e.g. /dev/ttyUSB0, a pty path)")
    g.add_argument("--modbus", metavar="URL", help="FT-300 Modbus address: tcp://HOST:PORT or a serial device")
    p.add_argument("--interface", default="socketcan", help="python-can interface of --can (default socketcan)")
    p.add_argument("--bitrate", type=int, default=None, help="CAN bit rate (interfaces that set it)")
    p.add_argument("--can-port", type=int, default=None, metavar="PORT",
                   help="--interface udp_multicast: the channel's UDP port (each served channel has its own; "
                        "see hil mock serve)")
    p.add_argument("--listen", type=float, default=0.5, help="seconds to listen before any request (default 0.5)")
    p.add_argument("--sdo-scan", action="store_true", help="CAN: SDO read of 0x1000 to nodes 1..127 (active)")
    p.add_argument("--cubemars-ids", default="", help="CAN: comma-separated MIT motor ids to send 'exit motor mode' "
                   "(active: disables those motors)")
    p.add_argument("--cubemars-model", default="AK80-9", help="CAN: model whose MIT ranges decode the replies")
    p.add_argument("--unit", type=int, default=9, help="Modbus slave id of --modbus / --serial (default 9)")
    p.add_argument("--baud", default="57600,1000000", help="--serial: DYNAMIXEL baud rates to ping")
    p.add_argument("--timeout", type=float, default=0.2, help="seconds per request (default 0.2)")
    p.add_argument("--bota-reset", type=float, default=2.0, metavar="S",
                   help="--serial: reset a Bota sensor found streaming ('#') and wait up to S s for its boot text "
                        "(name, S/N, firmware); 0: do not reset (default 2)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--scene", metavar="OUT.yaml", help="write a scene stub with the devices found")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --scene file")


def _ints(text: str, flag: str) -> list[int]:
    try:
        return [int(x, 0) for x in text.split(",") if x.strip()]
    except ValueError:
        raise HilError(f"{flag} expects comma-separated integers, got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    """``hil probe``: probe, print, optionally write the scene stub. Exit 0 (even when nothing
    answered: the table says so), 2 on bad input (raised as HilError for the CLI's guard)."""
    for flag, v in (("--listen", args.listen), ("--timeout", args.timeout)):
        if not (v >= 0 and v < 3600):
            raise HilError(f"{flag} must be a number of seconds in [0, 3600), got {v}")
    if args.scene and Path(args.scene).exists() and not args.overwrite:
        raise HilError(f"--scene {args.scene}: file exists (use --overwrite to replace it)")
    if args.can:
        port = getattr(args, "can_port", None)
        if port is not None and not 0 < port < 65536:
            raise HilError(f"--can-port must be a UDP port 1..65535, got {port}")
        found = probe_can(args.can, args.interface, bitrate=args.bitrate, listen_s=args.listen,
                          sdo_scan=args.sdo_scan, cubemars_ids=_ints(args.cubemars_ids, "--cubemars-ids"),
                          cubemars_model=args.cubemars_model, timeout=args.timeout,
                          **({"port": port} if port is not None else {}))
        where = f"can {args.interface}:{args.can}" + (f" port {port}" if port is not None else "")
    elif args.serial:
        found = probe_serial(args.serial, baudrates=tuple(_ints(args.baud, "--baud")), listen_s=args.listen,
                             unit=args.unit, timeout=args.timeout, bota_reset_s=args.bota_reset)
        where = args.serial
    else:
        found = probe_modbus(args.modbus, args.unit, args.timeout)
        where = f"modbus {args.modbus} unit {args.unit}"
    if args.scene:
        import yaml  # lazy: hil probe is parsed by every hil command

        stub = scene_stub(found)
        text = ("# written by hil probe from " + where + ": check every device, then add bodies (simulation),\n"
                "# safety limits, a controller and experiments before running it\n"
                + yaml.safe_dump(stub, sort_keys=False))
        Path(args.scene).write_text(text, encoding="utf-8")
    if args.json:
        print(json.dumps({"probed": where, "devices": [asdict(f) for f in found]}, separators=(",", ":")))
        return 0
    from rich.console import Console
    from rich.table import Table

    tab = Table("family", "driver", "address", "details", title=f"hil probe {where}: {len(found)} device(s)")
    for f in found:
        tab.add_row(f.family, f.driver or "(none)", f.address,
                    ", ".join(f"{k}={v}" for k, v in f.details.items()))
    Console(file=sys.stdout, soft_wrap=True).print(tab)
    if args.scene:
        print(f"scene stub: {args.scene}")
    return 0
