"""Instability witnesses: passive terminations under which a potentially unstable network
delivers energy at its operator port.

With every port but the operator's terminated by passive impedances T (block diagonal), the
impedance seen at the operator port is

    Z_in(s) = Z_oo - Z_or (Z_rr + T)⁻¹ Z_ro        (exact rational arithmetic)

If Z_in is not positive real, a passive operator model plus a state-independent force at a
frequency where Re Z_in(jω) has a negative eigenvalue draws net energy out of the device: the port
energy E_s(t) = ∫ F·V dt goes negative (paper 000 eq. 6), which is what the papers' energy plots
show. :func:`find_witness` searches a family of physically plausible passive terminations
(springs to a wall, dampers, masses, spring-dampers, first-order lags like 1/(s+1) of paper 000)
and returns the one with the most negative positive-realness margin, with the frequency band to
excite.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.errors import ConversionError, ModelError
from hil.stability.criteria import Tolerances, positive_real
from hil.stability.rational import Rational, S, TransferMatrix
from hil.stability.results import StabilityResult

logger = logging.getLogger(__name__)

__all__ = ["Termination", "Witness", "find_witness", "input_impedance", "termination_family"]


@dataclass(frozen=True)
class Termination:
    """A passive scalar impedance applied to every DOF of a port (times a symmetric PSD coupling)."""

    kind: str  # spring | damper | mass | spring_damper | lag
    params: dict[str, float]
    coupling: float = 0.0  # off-diagonal fraction in [0, 1): Z_T = z(s)·[[1, c], [c, 1]] (2-DOF), PSD

    def scalar(self) -> Rational:
        p = self.params
        if self.kind == "spring":
            return p["k"] / S
        if self.kind == "damper":
            return Rational.const(p["b"])
        if self.kind == "mass":
            return p["m"] * S
        if self.kind == "spring_damper":
            return (p["b"] * S + p["k"]) / S
        if self.kind == "lag":  # g/(s + a): passive for g, a > 0 (paper 000's 1/(s+1))
            return p["g"] / (S + p["a"])
        raise ModelError(f"unknown termination kind {self.kind!r}")

    def matrix(self, dofs: int) -> list[list[Rational]]:
        z = self.scalar()
        zero = Rational.const(0.0)
        return [[z if i == j else (self.coupling * z if self.coupling else zero) for j in range(dofs)]
                for i in range(dofs)]

    def describe(self) -> str:
        ps = ", ".join(f"{k}={v:g}" for k, v in self.params.items())
        c = f", coupling={self.coupling:g}" if self.coupling else ""
        return f"{self.kind}({ps}{c})"

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "params": dict(self.params), "coupling": self.coupling}


def input_impedance(Z: TransferMatrix, port: int,
                    terminations: Sequence[Sequence[Sequence[Rational]] | None]) -> TransferMatrix:
    """Impedance at ``port`` with the other ports terminated (``terminations[i]`` is the m×m
    impedance matrix at port i, ``None`` for the operator port). ``Z`` must be an impedance matrix."""
    if Z.kind != "impedance":
        Z = Z.to("impedance")
    offs = np.concatenate(([0], np.cumsum(Z.port_dofs)))
    op = list(range(offs[port], offs[port + 1]))
    rest = [i for i in range(Z.n) if i not in op]
    order = op + rest
    M = [[Z[i, j] for j in order] for i in order]
    # add the terminations on the diagonal blocks of the other ports
    pos = {idx: k for k, idx in enumerate(order)}
    for p, T in enumerate(terminations):
        if p == port or T is None:
            continue
        idx = list(range(offs[p], offs[p + 1]))
        for a, i in enumerate(idx):
            for b, j in enumerate(idx):
                M[pos[i]][pos[j]] = M[pos[i]][pos[j]] + T[a][b]
    grouped = TransferMatrix(M, "impedance", (len(op), len(rest)))
    h = grouped.to("hybrid")  # h11 = Z_oo - Z_or (Z_rr + T)^-1 Z_ro
    m = len(op)
    return TransferMatrix([[h[i, j] for j in range(m)] for i in range(m)], "impedance", (m,),
                          f"Z_in at port {port + 1}")


def termination_family(dofs: int, scale: float = 1.0) -> list[Termination]:
    """Candidate passive terminations, spanning stiffness/damping/mass over several decades."""
    out: list[Termination] = []
    for k in (1.0, 10.0, 45.0, 100.0, 1e3, 1e4):
        out.append(Termination("spring", {"k": k * scale}))
    for b in (0.1, 1.0, 10.0, 100.0):
        out.append(Termination("damper", {"b": b * scale}))
    for m in (0.1, 1.0, 10.0):
        out.append(Termination("mass", {"m": m * scale}))
    for k, b in itertools.product((10.0, 100.0, 1e3), (0.1, 1.0, 10.0)):
        out.append(Termination("spring_damper", {"k": k * scale, "b": b * scale}))
    for g, a in ((1.0, 1.0), (10.0, 1.0), (1.0, 10.0), (100.0, 10.0)):
        out.append(Termination("lag", {"g": g * scale, "a": a}))
    if dofs > 1:
        out += [Termination(t.kind, t.params, c) for t in list(out) for c in (0.5, -0.5)]
    return out


@dataclass
class Witness:
    """A passive termination set under which the operator-port impedance is not positive real."""

    port: int
    terminations: dict[int, Termination]
    z_in: TransferMatrix
    result: StabilityResult
    band_rad_s: tuple[float, float] | None
    drive_frequency: float  # rad/s: where Re Z_in(jω) is most negative (normalized)
    direction: np.ndarray = field(default_factory=lambda: np.zeros(1))  # force direction (unit) to excite

    def to_dict(self) -> dict[str, Any]:
        return {"port": self.port, "terminations": {str(k): v.to_dict() for k, v in self.terminations.items()},
                "verdict": str(self.result.verdict), "margin": self.result.margin,
                "band_rad_s": self.band_rad_s, "drive_frequency_rad_s": self.drive_frequency,
                "direction": self.direction.tolist()}


def _drive_point(z_in: TransferMatrix, res: StabilityResult) -> tuple[float, np.ndarray, tuple[float, float] | None]:
    band = None
    for c in res.conditions:
        bands = c.evidence.get("negative_bands_rad_s") if c.status == "violated" else None
        if bands:
            band = tuple(bands[0])
            break
    lo, hi = (band if band else (1e-2, 1e4))
    hi_eff = hi if math.isfinite(hi) else lo * 100 if lo > 0 else 1e3
    lo_eff = lo if lo > 0 else hi_eff / 1e4
    w = np.geomspace(lo_eff, hi_eff, 400)
    G = z_in.freq(w)
    H = (G + np.conj(np.swapaxes(G, 1, 2))) / 2
    lam, vec = np.linalg.eigh(H)
    norm = np.linalg.norm(G, axis=(1, 2)) + 1e-300
    i = int(np.argmin(lam[:, 0] / norm))
    return float(w[i]), np.real_if_close(vec[i, :, 0]).real, band


def find_witness(Z: TransferMatrix, port: int = 0, candidates: Sequence[Termination] | None = None,
                 max_candidates: int | None = None, first: bool = False) -> Witness | None:
    """Search passive terminations of the non-operator ports (the same candidate at every one)
    for the most non-passive operator-port impedance. Returns ``None`` if every candidate leaves
    Z_in positive real (which a potentially unstable network need not contradict: the family is
    finite). A candidate for which Z_in does not exist (``Z_rr + T`` identically singular) is
    skipped; any other failure propagates (the caller records it, see hil.certify.pipeline)."""
    others = [p for p in range(Z.n_ports) if p != port]
    best: Witness | None = None
    cands = list(candidates or termination_family(max(Z.port_dofs)))
    if max_candidates:
        cands = cands[:max_candidates]
    for cand in cands:
        terms = [None if p == port else cand.matrix(Z.port_dofs[p]) for p in range(Z.n_ports)]
        try:
            zin = input_impedance(Z, port, terms)
        except ConversionError as exc:
            logger.debug("witness candidate %s skipped: %s", cand.describe(), exc)
            continue
        # Z_in is derived in floating point: a witness must survive a relative perturbation of 1e-9
        # of its coefficients (round-off of the derivation is never a witness)
        res = positive_real(zin, Tolerances(rtol=1e-9))
        if res.verdict != "potentially_unstable":
            continue
        if best is None or res.margin < best.result.margin:
            w, d, band = _drive_point(zin, res)
            best = Witness(port, dict.fromkeys(others, cand), zin, res, band, w, d)
            if first:
                break
    return best
