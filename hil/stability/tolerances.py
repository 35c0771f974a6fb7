"""The tolerances the stability criteria accept (:class:`Tolerances`; docs/VERDICTS.md)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from hil.stability.exact import DEFAULT_TOL

logger = logging.getLogger(__name__)

POLE_TOL = 1e-9
RESIDUE_TOL = 1e-9


@dataclass(frozen=True)
class Tolerances:
    """Tolerances (all relative; docs/VERDICTS.md).

    ``rtol`` (default 0): a relative tolerance on the coefficients; a condition whose status can
    flip under such a perturbation is ``marginal``. With 0 every verdict is the exact one for the
    given coefficients. ``poly``, ``pole`` and ``residue``: unused (every condition is formed and
    decided exactly: Theorem 1's Z' over Q, poles by Routh-Hurwitz over Q, residues in Q[x]/(f),
    :mod:`hil.stability.residues`), kept for compatibility."""

    poly: float = DEFAULT_TOL
    pole: float = POLE_TOL
    residue: float = RESIDUE_TOL
    rtol: float = 0.0


TOL = Tolerances()
