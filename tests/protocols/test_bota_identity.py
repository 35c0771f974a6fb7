"""Bota serial sensor identity (product name, serial number, firmware): Bota's own
``rokubimini_serial`` driver resets the sensor (``#``) and reads them from its boot text after
``App Init`` with the regexes ``name:\\s(.*)\\r``, ``S/N:\\s(.*)\\r``, ``FW version:\\s(.*)\\r``
(RokubiminiSerialCommunication.hpp; RokubiminiSerialImpl.cpp ``parseCommunicationMsgs``). The
simulated sensor answers a raw pyserial client the same way, and ``hil probe`` reports them."""

from __future__ import annotations

import re

import pytest
from simtime import served

from hil.bench.probe import parse_bota_boot, probe_serial
from hil.bench.serve import serve, shutdown
from hil.mocks.interfaces import FreeJoints
from hil.mocks.serial_devices import SimBota

serial = pytest.importorskip("serial")

pytestmark = pytest.mark.timeout(30)

# the driver's regexes, verbatim (std::regex ECMAScript = Python re for these)
DRIVER = {"name": r"name:\s(.*)\r", "serial": r"S/N:\s(.*)\r", "firmware": r"FW version:\s(.*)\r"}


def test_hardware_reset_prints_the_identity_to_a_raw_client():
    sim = SimBota(FreeJoints(1), serial_number=4711, product_name="BFT-MEDS-SER-M8", firmware="2.3.1",
                  threaded=False)  # served in this thread: it answers when the test lets it
    try:
        with serial.Serial(sim.path, 460800, timeout=0) as ser:
            ser.write(b"#")
            ser.flush()
            sim.serve_pending()  # the sensor takes the reset and prints its boot text
            buf = ser.read(ser.in_waiting)
        text = buf.decode("ascii", errors="replace")
        assert text.index("App Init") < text.index("name:") < text.index("S/N:") < text.index("FW version:")
        got = {k: re.search(rx, text).group(1) for k, rx in DRIVER.items()}  # type: ignore[union-attr]
        assert got == {"name": "BFT-MEDS-SER-M8", "serial": "4711", "firmware": "2.3.1"}
        assert int(got["serial"]) == 4711  # the driver reads it as %u
        assert sim.commands[-1] == "#" and sim.running  # rebooted into RUN mode
    finally:
        sim.close()


def test_parse_bota_boot_ignores_frames_and_needs_app_init():
    text = b"\xaa\x01garbage App Init\r\nname: X-1\r\nS/N: 12\r\nFW version: 0.9\r\n\xaa\x00"
    assert parse_bota_boot(text) == {"name": "X-1", "serial": "12", "firmware": "0.9"}
    assert parse_bota_boot(b"name: X-1\r\nS/N: 12\r\n") == {}  # not a boot text


def test_probe_reports_the_bota_serial_number():
    eps = serve([{"kind": "bota", "rate_hz": 1000}])
    try:
        sim = eps[0].device
        (f,) = probe_serial(eps[0].params["url"], listen_s=0.3)
        assert f.family == "bota"
        assert f.details["serial"] == str(sim.serial_number)
        assert f.details["model"] == sim.product_name and f.details["firmware"] == sim.firmware
        (g,) = probe_serial(eps[0].params["url"], listen_s=0.3, bota_reset_s=0)  # asked not to reset it
        assert g.details["serial"].startswith("(not asked")
    finally:
        shutdown(eps)


def test_adapter_reads_the_identity_and_restores_its_configuration():
    from hil.protocols.serial_bota import BotaSerial

    sim = SimBota(FreeJoints(1), serial_number=31337, firmware="1.4.2", threaded=False)
    try:
        dev = BotaSerial(sim.path, sinc_length=64, timeout=0.5, waits=served(sim))
        try:
            assert sim.config["sinc_length"] == 64
            got = dev.read_identity()
            assert got == {"name": sim.product_name, "serial": "31337", "firmware": "1.4.2"}
            assert (dev.info.serial, dev.info.model, dev.info.firmware) == ("31337", sim.product_name, "1.4.2")
            # the reset restored the saved (default) configuration; the adapter sent its own again
            assert sim.commands[-5:] == ["#", "C", "c,0,1,0,4", "f,64,0,0,1", "R"]
            assert sim.config["sinc_length"] == 64 and sim.running
        finally:
            dev.close()
    finally:
        sim.close()
