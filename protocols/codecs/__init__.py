"""Wire formats of the supported devices (frame layouts, scaling tables, CRC framing): pure
functions and constants with no transport library, imported by the adapters (:mod:`hil.protocols`)
and by the simulated devices (:mod:`hil.mocks`) alike."""
