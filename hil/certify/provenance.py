"""Where a certificate's evidence came from: a simulated bench or hardware, on which clock.

:func:`bench_info` builds the certificate's ``bench`` block (:class:`hil.certify.certificate.BenchInfo`)
from the scene and the run outcomes; its ``label`` is the banner the reports print on page 1 and
in every page header, and ``hil verify`` prints it on its OK line:

* ``SIMULATED BENCH — lockstep``: the scene has a ``simulation`` section, so every device was a
  simulated twin behind a real transport, and the plant advanced one period per tick (simulated
  time); ``SIMULATED BENCH — realtime`` when such a scene ran against the wall clock;
* ``HARDWARE — realtime, devices: motor (odrive_can), …``: no simulation, real devices;
* ``NO BENCH RUN — …``: no experiment ran (``hil certify --no-experiments``, or a scene without
  experiments): the certificate rests on the scene's stated parameters only.

The clock is read from the outcomes' loop statistics (``stats["mode"]``, what the runner did),
not from the scene's intent. Defined in docs/CERTIFICATION.md ("Bench").
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any, Literal

from hil.certify.certificate import BenchInfo

logger = logging.getLogger(__name__)

__all__ = ["bench_info", "device_list"]


def device_list(scene: Any) -> list[str]:
    """``name (driver)`` of each of the scene's devices, in scene order."""
    return [f"{d.name} ({d.driver})" for d in getattr(scene, "devices", None) or []]


def bench_info(scene: Any, outcomes: Mapping[str, Any] | None) -> BenchInfo:
    """The ``bench`` block of a certificate of ``scene`` whose runs gave ``outcomes`` (experiment
    name -> :class:`hil.run.runner.ExperimentOutcome`; empty or None: nothing ran)."""
    devices = device_list(scene)
    simulated = getattr(scene, "simulation", None) is not None
    modes = {str((getattr(o, "stats", None) or {}).get("mode", "")) for o in (outcomes or {}).values()}
    modes.discard("")
    if not outcomes:
        return BenchInfo(kind="none", clock=None, devices=devices, label="NO BENCH RUN",
                         note="No experiment ran: the certificate rests on the scene's stated parameters and "
                              "uncertainties only, not on measurements.")
    clock: Literal["lockstep", "realtime"] = "realtime" if "realtime" in modes else "lockstep"
    if not modes:  # outcomes without loop statistics (older reused runs): the scene's own mode
        clock = "lockstep" if getattr(scene, "run_mode", "lockstep") == "lockstep" else "realtime"
    how = (" The plant advanced one control period per tick on the simulated clock (lockstep)." if clock == "lockstep"
           else " The loop ran against the wall clock (realtime).")
    if simulated:
        return BenchInfo(kind="simulated", clock=clock, devices=devices, label=f"SIMULATED BENCH — {clock}",
                         note="Every device was a simulated twin (the scene's simulation section) behind a real "
                              "transport: no hardware was measured." + how)
    return BenchInfo(kind="hardware", clock=clock, devices=devices,
                     label=f"HARDWARE — {clock}, devices: " + (", ".join(devices) or "none"),
                     note="Measured on the devices named." + how)
