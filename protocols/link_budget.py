"""Link budgets: can the bus a scene describes carry the traffic it asks for?

A scene is refused at load time (``hil.scene.spec``: one line with the numbers, exit 2) when a link
would need more than it can carry; the simulated serial links enforce the same budget
(:class:`hil.mocks.pty.LinkBudget`). Pure arithmetic, no driver imports.

Serial lines (8N1: start + 8 data + stop = 10 bit times per byte): capacity ``baud / 10`` bytes/s.

* ``bota_serial``: one 37-byte frame (0xAA, 34 payload bytes, CRC-16) per sample; the sample rate
  is set by the sinc filter, ``f = 51200 / sinc_length`` Hz (Bota's ``bota_serial_example.py``:
  ``time_step = 0.00001953125 * SINC_LENGTH``), so ``bytes/s = 37 * f``. ``sinc_length`` comes from
  the params, else from ``period_s`` (``round(51200 * period_s)``), else the example's 512. Baud
  rate: ``baudrate`` (default 460 800, the fastest of Bota's ``c,...`` baud codes 0..4 = 9 600,
  57 600, 115 200, 230 400, 460 800). At 460 800 baud: 46 080 B/s = 1 245 frames/s at most.
* ``robotiq_ft300_stream``: 16-byte frames at the sensor's fixed 100 Hz (manual, "Data stream")
  on its 19 200 baud line: 1 600 of 1 920 B/s.
* ``robotiq_ft300`` polled over a serial line (``rtu://`` or a device path): request 8 bytes +
  reply 17 bytes per read at the scene rate (Modbus RTU inter-frame gaps ignored: optimistic).
  Modbus/TCP (``tcp://``) is not checked: the gateway's serial side is not in the scene.
* ``dynamixel_x`` (per port; several devices may share one): per tick one sync write of Goal
  Current (``14 + 3 n`` bytes) and one sync read of the 10-byte present block (``14 + n`` bytes
  out, ``n`` status packets of 21 bytes back) for ``n`` servos of each device: ``28 + 25 n`` bytes,
  at ``baudrate`` (default 57 600, a factory servo).

CAN (classic, 11-bit ids): worst-case bits of one frame with ``s`` data bytes including bit
stuffing and the 3-bit interframe space (Davis et al., "Controller Area Network schedulability
analysis: refuted, revisited and revised", 2007, eq. (1)): ``55 + 10 s`` is the usual bound;
exactly ``47 + 8 s + floor((34 + 8 s - 1) / 4)``: 135 bits for 8 bytes, 95 for 4, 55 for an
empty or remote frame. Per channel the bits per second of every device on it must stay below the
bit rate (``bitrate``: the largest given on the channel; default the devices' factory rate,
ODrive 250 kbit/s, CubeMars 1 Mbit/s).

* ``odrive_can`` per tick: Set_Input_Torque (8 bytes: the float32 in the DBC's 8-byte frame);
  ``feedback: poll`` adds the RTR request
  (55) and the 8-byte answer, ``read_torque`` another RTR + 8-byte answer; ``cyclic`` adds one
  8-byte estimate frame. Plus the 8-byte heartbeat every 100 ms (factory rate).
* ``cubemars_mit`` per tick: one 8-byte command, one 8-byte reply.
* ``cia402`` per tick: SYNC (0 bytes), TPDO1 (8), TPDO2 (5), RPDO1 (4); plus the 1-byte heartbeat
  every ``heartbeat_ms`` (default 100); default bit rate 1 Mbit/s.

The simulated CAN channels enforce the same budget at run time
(:class:`hil.mocks.can_devices.CanBusBudget`: frames that do not fit wait, in arbitration order,
and a sender with a full transmit queue loses frames).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

BOTA_FRAME_BYTES = 37
BOTA_BASE_HZ = 51200.0  # 1 / 0.00001953125 s: sample rate = BOTA_BASE_HZ / sinc_length
BOTA_DEFAULT_SINC = 512
BOTA_DEFAULT_BAUD = 460_800
FT300_STREAM_FRAME_BYTES = 16
FT300_STREAM_HZ = 100.0
FT300_BAUD = 19_200
FT300_POLL_BYTES = 8 + 17
DXL_DEFAULT_BAUD = 57_600
ODRIVE_DEFAULT_BITRATE = 250_000
CUBEMARS_DEFAULT_BITRATE = 1_000_000
#: CiA 402 drive without a ``bitrate`` param: 1 Mbit/s, the highest CiA 301 bit rate (set
#: ``bitrate`` for a drive configured slower)
CIA402_DEFAULT_BITRATE = 1_000_000
#: CiA 402 per tick (hil.protocols.cia402): SYNC (0 bytes), TPDO1 statusword + position actual +
#: torque actual (8), TPDO2 velocity actual + modes display (5), RPDO1 controlword + target torque (4)
CIA402_TICK_FRAME_BYTES = (0, 8, 5, 4)
ODRIVE_HEARTBEAT_HZ = 10.0


def serial_capacity(baud: float) -> float:
    """Bytes per second a UART carries at ``baud`` with 8N1 framing (10 bit times per byte)."""
    return float(baud) / 10.0


def can_frame_bits(data_bytes: int) -> int:
    """Worst-case bits on the wire of one classic CAN frame with an 11-bit id and ``data_bytes``
    data bytes (0 for a remote frame), stuffing and interframe space included."""
    s = int(data_bytes)
    if not 0 <= s <= 8:
        raise ValueError(f"a classic CAN frame has 0..8 data bytes, got {s}")
    return 47 + 8 * s + (34 + 8 * s - 1) // 4


def bota_sinc_length(params: Mapping[str, Any]) -> int:
    """The sinc filter length a Bota sensor is configured with (see the module docstring)."""
    if params.get("sinc_length") is not None:
        return int(params["sinc_length"])
    if params.get("period_s") is not None:
        return max(1, round(BOTA_BASE_HZ * float(params["period_s"])))
    return BOTA_DEFAULT_SINC


def bota_rate_hz(params: Mapping[str, Any]) -> float:
    """Frames per second of a Bota sensor with these scene params."""
    return BOTA_BASE_HZ / bota_sinc_length(params)


@dataclass(frozen=True)
class LinkUse:
    """One link: what it must carry and what it can (both per second, in ``unit``)."""

    link: str  # e.g. "serial /dev/ttyUSB0" or "CAN hil0"
    devices: tuple[str, ...]
    need: float
    capacity: float
    unit: str  # "B/s" or "bit/s"
    detail: str

    @property
    def load(self) -> float:
        """need / capacity (1.0 = the link is full)."""
        return self.need / self.capacity if self.capacity > 0 else math.inf

    def message(self) -> str:
        return (f"{self.link} ({', '.join(self.devices)}): needs {self.need:,.0f} {self.unit} "
                f"({self.detail}) but carries at most {self.capacity:,.0f} {self.unit} ({100 * self.load:.0f} %)")


def _is_serial_url(url: str) -> bool:
    return not url.startswith(("tcp://", "rtu-over-tcp://", "socket://"))


def link_uses(devices: Iterable[Any], rate_hz: float) -> list[LinkUse]:
    """Every link the devices use, with its need and capacity. ``devices``: objects with
    ``name``, ``driver``, ``params`` (a mapping), ``dof`` (scene devices)."""
    serial: list[LinkUse] = []
    dxl: dict[str, list[tuple[str, int, int]]] = {}
    can_: dict[tuple[str, str], list[tuple[str, float, int]]] = {}
    for d in devices:
        p = dict(d.params or {})
        drv = d.driver
        if drv == "bota_serial":
            baud = int(p.get("baudrate", BOTA_DEFAULT_BAUD))
            sinc = bota_sinc_length(p)
            f = BOTA_BASE_HZ / sinc
            serial.append(LinkUse(f"serial {p.get('url', '?')}", (d.name,), BOTA_FRAME_BYTES * f, serial_capacity(baud),
                                  "B/s", f"{BOTA_FRAME_BYTES}-byte frames at {f:,.1f} Hz (sinc {sinc}) over "
                                         f"{baud} baud"))
        elif drv == "robotiq_ft300_stream":
            baud = int(p.get("baudrate", FT300_BAUD))
            serial.append(LinkUse(f"serial {p.get('url', '?')}", (d.name,), FT300_STREAM_FRAME_BYTES * FT300_STREAM_HZ,
                                  serial_capacity(baud), "B/s", f"{FT300_STREAM_FRAME_BYTES}-byte frames at "
                                  f"{FT300_STREAM_HZ:.0f} Hz over {baud} baud"))
        elif drv == "robotiq_ft300" and _is_serial_url(str(p.get("url", "/dev/ttyUSB0"))):
            url = str(p.get("url", "/dev/ttyUSB0"))
            baud = FT300_BAUD
            if "baudrate=" in url:
                baud = int(url.split("baudrate=")[1].split("&")[0])
            serial.append(LinkUse(f"serial {url}", (d.name,), FT300_POLL_BYTES * rate_hz, serial_capacity(baud), "B/s",
                                  f"{FT300_POLL_BYTES} bytes per Modbus RTU poll at {rate_hz:g} Hz over {baud} baud"))
        elif drv == "dynamixel_x":
            n = len(p.get("ids", [1]))
            dxl.setdefault(str(p.get("port", "?")), []).append((d.name, n, int(p.get("baudrate", DXL_DEFAULT_BAUD))))
        elif drv in ("odrive_can", "cubemars_mit", "cia402"):
            key = (str(p.get("interface", "socketcan")), str(p.get("channel", "can0")))
            if drv == "cia402":  # plus the 1-byte heartbeat every heartbeat_ms (default 100)
                hb_ms = float(p.get("heartbeat_ms", 100) or 0)
                per_s = (sum(can_frame_bits(b) for b in CIA402_TICK_FRAME_BYTES) * rate_hz
                         + (can_frame_bits(1) * 1000.0 / hb_ms if hb_ms > 0 else 0.0))
                default = CIA402_DEFAULT_BITRATE
            elif drv == "odrive_can":
                bits = can_frame_bits(8)  # Set_Input_Torque: 8 data bytes (odrive-cansimple DBCs)
                if p.get("feedback", "poll") == "poll":
                    bits += can_frame_bits(0) + can_frame_bits(8)
                    if p.get("read_torque"):
                        bits += can_frame_bits(0) + can_frame_bits(8)
                else:
                    bits += can_frame_bits(8)
                per_s = bits * rate_hz + can_frame_bits(8) * ODRIVE_HEARTBEAT_HZ
                default = ODRIVE_DEFAULT_BITRATE
            else:
                per_s = 2 * can_frame_bits(8) * rate_hz
                default = CUBEMARS_DEFAULT_BITRATE
            can_.setdefault(key, []).append((d.name, per_s, int(p.get("bitrate") or default)))
    out = list(serial)
    for port, devs in dxl.items():
        baud = max(b for _, _, b in devs)
        per_tick = sum(28 + 25 * n for _, n, _ in devs)
        out.append(LinkUse(f"serial {port}", tuple(n for n, _, _ in devs), per_tick * rate_hz, serial_capacity(baud),
                           "B/s", f"{per_tick} bytes per tick (sync write + sync read) at {rate_hz:g} Hz over "
                                  f"{baud} baud"))
    for (iface, ch), cdevs in can_.items():
        bitrate = max(b for _, _, b in cdevs)
        need = sum(b for _, b, _ in cdevs)
        out.append(LinkUse(f"CAN {iface}:{ch}", tuple(n for n, _, _ in cdevs), need, float(bitrate), "bit/s",
                           f"{need / rate_hz:,.0f} worst-case bits per tick at {rate_hz:g} Hz incl. heartbeats "
                           f"at {bitrate:,} bit/s"))
    return out


def over_budget(devices: Iterable[Any], rate_hz: float) -> list[LinkUse]:
    """The links whose need exceeds their capacity."""
    return [u for u in link_uses(devices, rate_hz) if u.need > u.capacity]


__all__ = ["LinkUse", "bota_rate_hz", "bota_sinc_length", "can_frame_bits", "link_uses", "over_budget",
           "serial_capacity"]
