"""The bench: devices behind their protocol adapters, real or simulated behind real transports.

* :mod:`hil.bench.runtime` -- :class:`~hil.bench.runtime.Bench` (open, read, command, safe stop),
  the simulated scene (twins on virtual CAN, ptys, Modbus servers) and the bench whose simulated
  devices run in another process (realtime mode);
* :mod:`hil.bench.serve` -- ``hil mock serve SCENE``: a scene's simulated devices served for an
  outside client;
* :mod:`hil.bench.probe` -- ``hil probe``: identify a connected device;
* :mod:`hil.bench.stopflag` -- the process-wide stop flag signals set and the loop reads at safe
  points, and the critical sections a signal cannot cut short.
"""


def __getattr__(name: str) -> object:
    """The names of the former module ``hil.bench`` (a façade: import them from their module)."""
    from hil import moved_attribute

    return moved_attribute(__name__, name)
