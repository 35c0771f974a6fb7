"""Wire formats of the supported devices (frame layouts, scaling tables, CRC framing): pure
functions and constants with no transport library, imported by the adapters (:mod:`hil.protocols`)
and by the simulated devices (:mod:`hil.mocks`) alike."""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType
from typing import Any


def forwarder(codec: ModuleType, module: str) -> Callable[[str], Any]:
    """A module ``__getattr__`` (PEP 562) for an adapter module ``module`` whose wire-format names
    moved to ``codec``: they stay importable from the adapter's module as before."""

    def __getattr__(name: str) -> Any:
        try:
            return getattr(codec, name)
        except AttributeError:
            raise AttributeError(f"module {module!r} has no attribute {name!r}") from None

    return __getattr__
