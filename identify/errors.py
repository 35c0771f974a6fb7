"""Errors raised on purpose by :mod:`hil.identify`.

Every class derives from :class:`hil.errors.HilError` (through :class:`IdentificationError`) and,
where a builtin meaning exists, from that builtin too, so callers can catch them either way.
"""

from __future__ import annotations

from typing import Any

from hil.errors import HilError


class IdentificationError(HilError):
    """Root of the identification errors."""


class DataQualityError(IdentificationError, ValueError):
    """The data are unfit for identification (gaps, saturation, no excitation, nonlinearity...).

    ``diagnoses`` holds the :class:`hil.identify.diagnostics.Diagnosis` objects that failed.
    """

    def __init__(self, message: str, diagnoses: list[Any] | None = None) -> None:
        super().__init__(message)
        self.diagnoses = list(diagnoses or [])


class NotIdentifiableError(IdentificationError):
    """The planned/recorded experiment cannot identify some parameters (rank-deficient Fisher matrix).

    ``report`` holds the :class:`hil.identify.fisher.IdentifiabilityReport`.
    """

    def __init__(self, message: str, report: Any = None) -> None:
        super().__init__(message)
        self.report = report


class ConvergenceError(IdentificationError):
    """A fit or a posterior sampler did not converge; ``result`` holds what was computed (flagged)."""

    def __init__(self, message: str, result: Any = None) -> None:
        super().__init__(message)
        self.result = result


class ModelSpecError(IdentificationError, ValueError):
    """A model was requested with inconsistent options (unknown name, channel, shape...)."""
