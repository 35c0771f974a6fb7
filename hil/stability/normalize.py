"""Frequency normalization of a network before its conditions are formed, and the way back.

The criteria rescale s = w0·s̃ with w0 a power of two near the network's characteristic frequency
(:func:`_normalized`), so the condition polynomials stay well inside double range; every
coefficient is scaled exactly (``ldexp``; an entry given exactly is scaled over Q), so the exact
decisions see the given network. :func:`_rescale` takes the reported frequencies back to rad/s.
"""

from __future__ import annotations

import logging
import math
from typing import Any, cast

import numpy as np
from flint import fmpq, fmpq_poly

from hil.errors import ModelError
from hil.stability.conditions import _band_detail
from hil.stability.rational import Rational, TransferMatrix
from hil.stability.results import Condition

logger = logging.getLogger(__name__)


def _as_tm(g: TransferMatrix | Rational) -> TransferMatrix:
    if isinstance(g, Rational):
        return TransferMatrix([[g]])
    if not isinstance(g, TransferMatrix):
        raise ModelError("expected a TransferMatrix or a Rational")
    return g


def _netinfo(tm: TransferMatrix, w0: float = 1.0) -> dict[str, Any]:
    return {"name": tm.name, "type": tm.kind, "ports": list(tm.port_dofs), "size": tm.n, "omega_scale": w0}


def _normalized(tm: TransferMatrix) -> tuple[TransferMatrix, float]:
    cached = getattr(tm, "_normalized_cache", None)
    if cached is not None:
        return cast("tuple[TransferMatrix, float]", cached)
    out = _normalize(tm)
    tm._normalized_cache = out  # type: ignore[attr-defined]  # entries are never mutated in place
    return out


def _normalize(tm: TransferMatrix) -> tuple[TransferMatrix, float]:
    """Rescale frequency s = w0·s̃ so the condition polynomials stay well inside double range.

    w0 is the geometric mean of the smallest and largest non-zero pole/zero magnitudes. Verdicts
    are invariant (x̃ = x/w0² is a positive rescaling); reported frequencies are multiplied back.
    """
    # characteristic frequencies from the coefficients (|c_0/c_n|^(1/n) per polynomial): the
    # geometric mean of the root magnitudes, without root finding
    mags = []
    for row in tm.entries:
        for e in row:
            if e.is_zero:
                continue
            for arr in (e.num, e.den):
                c = arr.tolist()  # cleaned: the last coefficient is non-zero
                k = 0
                while c[k] == 0:
                    k += 1
                top = len(c) - 1
                if top > k:
                    mags.append((abs(c[k]) / abs(c[top])) ** (1.0 / (top - k)))
    if not mags:
        return tm, 1.0
    w0 = float(math.sqrt(min(mags) * max(mags)))
    if not (math.isfinite(w0) and w0 > 0):
        return tm, 1.0
    # a power of two: the scaled coefficients c_k·w0^k / 2^e are then *exact* (no rounding), so
    # exact relations between the entries' coefficients (common factors, imaginary-axis poles,
    # cancellations) survive the normalization and the exact decisions see the given network.
    # Always applied (w0 = 1 included): a network and its power-of-two scalings in frequency and
    # impedance then normalize to the same floats, and get bit-for-bit the same margins (issue 31,
    # item 6; before, a network with w0 within half a decade of 1 was left as given while its
    # scalings were normalized: margins differed by up to 2e-7 relative, more when tiny)
    e0 = round(math.log2(w0))
    w0 = 2.0**e0
    ent = [[e if e.is_zero else _scaled_exact(e, e0) for e in row] for row in tm.entries]
    return TransferMatrix(ent, tm.kind, tm.port_dofs, tm.name), w0


def _scaled_exact(e: Rational, e0: int) -> Rational:
    """e(w0·s̃) with w0 = 2^e0, divided by a power of two near den's largest coefficient: every
    coefficient is scaled exactly (``ldexp``), barring under/overflow (then the checked
    constructor). Pure Python on the (short) coefficient lists first, the same two ``ldexp`` steps
    as the array version below, which runs only when a step overflows. An entry given exactly
    (:meth:`Rational.of_exact`, e.g. a converted immittance) is scaled exactly as well."""
    if e.exact_given:
        return _scaled_given(e, e0)
    try:
        dl = [math.ldexp(v, e0 * k) for k, v in enumerate(e.den.tolist())]
        es_ = round(math.log2(max(abs(v) for v in dl)))
        dl = [math.ldexp(v, -es_) for v in dl]
        nl = [math.ldexp(v, e0 * k - es_) for k, v in enumerate(e.num.tolist())]
        if nl[-1] != 0 and dl[-1] != 0:
            return Rational.trusted(np.array(nl), np.array(dl))
    except (OverflowError, ValueError):
        pass
    den = np.ldexp(e.den, e0 * np.arange(e.den.size))
    es = round(math.log2(float(np.max(np.abs(den)))))
    den = np.ldexp(den, -es)
    num = np.ldexp(e.num, e0 * np.arange(e.num.size) - es)
    if num[-1] != 0 and den[-1] != 0 and np.isfinite(num).all() and np.isfinite(den).all():
        return Rational.trusted(num, den)
    return Rational(num, den)


def _scaled_given(e: Rational, e0: int) -> Rational:
    """:func:`_scaled_exact` of an entry given exactly: its exact polynomials times 2^(e0·k - es)
    (es from its rounded denominator, as there), rounded once."""
    n, d = e.exact
    es = round(math.log2(max(abs(float(d[k])) * 2.0 ** (e0 * k) for k in range(d.degree() + 1))))

    def sc(p: fmpq_poly) -> fmpq_poly:
        return fmpq_poly([p[k] * fmpq(2) ** (e0 * k - es) for k in range(p.degree() + 1)])

    return Rational.of_exact(sc(n), sc(d))


def _rescale(conds: list[Condition], w0: float) -> list[Condition]:
    if w0 == 1.0:
        return conds
    for c in conds:
        if c.worst_frequency is not None and math.isfinite(c.worst_frequency):
            c.worst_frequency *= w0
        ev = c.evidence
        if "negative_bands_rad_s" in ev:
            ev["negative_bands_rad_s"] = [(a * w0, b * w0) for a, b in ev["negative_bands_rad_s"]]
            if c.status == "violated" and ev["negative_bands_rad_s"] and c.detail.startswith("negative for ω"):
                c.detail = _band_detail(ev)
        if "touching_rad_s" in ev:
            ev["touching_rad_s"] = [x * w0 for x in ev["touching_rad_s"]]
        if "pole" in ev:
            ev["pole"] = ev["pole"] * w0
        if "poles" in ev:
            ev["poles"] = [p * w0 for p in ev["poles"]]
        if "rhp_poles" in ev:
            for r in ev["rhp_poles"]:
                r["pole"] *= w0
        if c.name.startswith("D[ω="):
            c.name = f"D[ω={float(c.name[4:-1]) * w0:.6g}]"
        if "polynomial_x_desc" in ev:
            ev["x_scale"] = w0 * w0
    return conds
