"""The package's error hierarchy: every error the suite raises on purpose derives from :class:`HilError`.

Errors that have a natural builtin meaning also derive from that builtin, so callers can catch
them either way (e.g. :class:`DeviceTimeout` is a :class:`TimeoutError`).

It also holds the one table of exit codes (:class:`ExitCode`, :data:`EXIT_MEANINGS`): it sits here,
at the bottom of the import graph, so every package (identify/ and mocks/ too) can use it.
"""

from __future__ import annotations

from enum import IntEnum


class HilError(Exception):
    """Root of every error raised on purpose by the suite."""


class ModelError(HilError, ValueError):
    """A network model is malformed (bad coefficients, wrong shape, non-proper entries, ...)."""


class ConversionError(ModelError):
    """An immittance conversion does not exist for this network (e.g. singular h22 for h -> z)."""


class SceneError(HilError, ValueError):
    """A scene or network description file is invalid. The message names the file and the field."""


class DeviceError(HilError):
    """Root of errors raised by device adapters and transports."""


class DeviceTimeout(DeviceError, TimeoutError):
    """A device did not answer within the call's timeout."""


class ProtocolError(DeviceError):
    """A frame could not be decoded (bad header, length, CRC, unexpected reply)."""


class ChecksumError(ProtocolError):
    """A frame's checksum / CRC did not match."""


class DeviceFault(DeviceError):
    """The device reported a fault code. ``code`` holds the device's raw code."""

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.code = code


class DeviceDisconnected(DeviceError, ConnectionError):
    """The transport was closed or lost."""


class BenchUnavailable(DeviceError):
    """The bench could not be opened before any experiment ran (a device absent or unreachable): no
    record was written, so the command stops with one line, exit 2 (the scene names hardware that is
    not there), and leaves no folder behind."""


class SafetyStop(HilError):
    """An experiment was stopped by a safety limit, the watchdog or a signal."""


class ExitCode(IntEnum):
    """The exit codes of every ``hil`` command: the one table (docs/guide/troubleshooting.md "exit code | meaning" shows
    :data:`EXIT_MEANINGS`, and a test compares them)."""

    OK = 0
    INTERNAL = 1
    USAGE = 2
    MARGINAL = 10
    UNSTABLE = 11
    NOT_APPLICABLE = 12
    ERROR = 13
    SAFETY_STOP = 20
    NOT_HELD = 21
    INTERRUPTED = 130


#: what each exit code means, word for word as in docs/guide/troubleshooting.md's exit-code table
EXIT_MEANINGS: dict[ExitCode, str] = {
    ExitCode.OK: "stable; `hil certify`: GO; `hil verify`: the certificate and its evidence match",
    ExitCode.MARGINAL: "marginal: only with `hil stability --rtol R`, the verdict can flip within a relative "
                       "perturbation R of the coefficients (docs/VERDICTS.md); `hil certify`: MARGINAL",
    ExitCode.UNSTABLE: "potentially unstable; `hil certify`: NO-GO",
    ExitCode.ERROR: "`hil certify`: ERROR (evidence missing or broken)",
    ExitCode.NOT_APPLICABLE: "criterion not applicable (e.g. Theorem 1's symmetrization conditions fail)",
    ExitCode.SAFETY_STOP: "`hil run`: a safe stop ended the run (limit, non-finite value, watchdog, late loop, "
                          "device or record failure, SIGTERM/SIGHUP)",
    ExitCode.NOT_HELD: "`hil check-realtime`: this machine cannot hold `--rate` (docs/guide/realtime.md)",
    ExitCode.INTERRUPTED: "`hil run`: interrupted (Ctrl-C / SIGINT); every record is closed with the reason",
    ExitCode.USAGE: "usage or input error; the message is one line and names the file and field, or the flag; "
                    "`hil verify` / `hil report`: the certificate does not match its digest, an evidence file or "
                    "its signature (one line naming what)",
    ExitCode.INTERNAL: "internal error (a bug: one line; rerun with `hil --debug …` and report the traceback)",
}

EXIT_OK = ExitCode.OK
EXIT_INTERNAL = ExitCode.INTERNAL
EXIT_USAGE = ExitCode.USAGE
EXIT_MARGINAL = ExitCode.MARGINAL
EXIT_UNSTABLE = ExitCode.UNSTABLE
EXIT_NOT_APPLICABLE = ExitCode.NOT_APPLICABLE
EXIT_ERROR = ExitCode.ERROR
EXIT_SAFETY_STOP = ExitCode.SAFETY_STOP
EXIT_NOT_HELD = ExitCode.NOT_HELD
EXIT_INTERRUPTED = ExitCode.INTERRUPTED

#: ``hil stability``: the exit code of each verdict (docs/VERDICTS.md)
VERDICT_EXIT: dict[str, ExitCode] = {"stable": ExitCode.OK, "marginal": ExitCode.MARGINAL,
                                     "potentially_unstable": ExitCode.UNSTABLE,
                                     "not_applicable": ExitCode.NOT_APPLICABLE}
#: ``hil certify`` (and a fleet's worst scene): the exit code of each decision
DECISION_EXIT: dict[str, ExitCode] = {"GO": ExitCode.OK, "MARGINAL": ExitCode.MARGINAL,
                                      "NO-GO": ExitCode.UNSTABLE, "ERROR": ExitCode.ERROR}
