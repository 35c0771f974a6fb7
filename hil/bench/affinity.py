"""Which CPU the realtime loop runs on, and so which ones the simulated devices' process gets.

One policy for both sides: :func:`hil.run.realtime.realtime_scheduling` pins the loop to
:func:`loop_cpu`; :class:`hil.bench.runtime.ProcessSimBench` pins the devices' process to the
other CPUs this process may use (as real devices are external, they never compete with the loop).
"""

from __future__ import annotations

import os

__all__ = ["DEVICE_FIFO_PRIORITY", "loop_cpu"]

#: SCHED_FIFO priority of the simulated devices' process (:class:`hil.bench.runtime.ProcessSimBench`, on
#: the CPUs the loop does not use): below the loop (80, :data:`hil.run.realtime.FIFO_PRIORITY`) and its
#: record writer (79), above every ordinary process, so a loaded machine does not starve the
#: "external" devices (a real device has its own CPU)
DEVICE_FIFO_PRIORITY = 70


def loop_cpu() -> int | None:
    """The CPU for the loop: the last one this process may run on (the devices' process gets the
    others), or None when only one is available or affinity is not supported."""
    try:
        cpus = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None
    return cpus[-1] if len(cpus) > 1 else None
