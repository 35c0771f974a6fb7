"""Ratios evaluated on the transfer functions at given frequencies: plots, benchmarks and the
screening of parameter draws (not the reported margins, which are formed exactly: docs/VERDICTS.md)."""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable

import numpy as np

from hil.stability.rational import Rational

logger = logging.getLogger(__name__)


# ------------------------------------------------------------------------------------------
# ratios evaluated on the transfer functions (plots; not the reported margins, docs/VERDICTS.md)


def _freq_range(entries: list[list[Rational]]) -> tuple[float, float]:
    """A plotting band: the non-zero pole and zero magnitudes of the entries, widened by two
    decades on each side (used by plots and benchmarks; margins are computed over all ω exactly,
    docs/VERDICTS.md)."""
    mags = [abs(r) for row in entries for e in row if not e.is_zero for r in (*e.poles(), *e.zeros())
            if abs(r) > 0 and np.isfinite(abs(r))]
    if not mags:
        return 1e-2, 1e2
    return min(mags) * 1e-2, max(mags) * 1e2


def _freq_values(sub: list[list[Rational]], w: np.ndarray) -> np.ndarray:
    k = len(sub)
    G = np.empty((w.size, k, k), complex)
    for i in range(k):
        for j in range(k):
            G[:, i, j] = 0.0 if sub[i][j].is_zero else sub[i][j].freq(w)
    return G


def _perm_batch(A: np.ndarray) -> np.ndarray:
    k = A.shape[-1]
    out = np.zeros(A.shape[0])
    for p in itertools.permutations(range(k)):
        term = np.ones(A.shape[0])
        for i in range(k):
            term = term * A[:, i, p[i]]
        out += term
    return out


def _hermitian_ratio(sub: list[list[Rational]], values: Callable[[np.ndarray], np.ndarray] | None = None
                     ) -> Callable[[np.ndarray], np.ndarray]:
    """ω ↦ det(H)/perm(|G|+|Gᵀ|) with H = G + Gᴴ on the index set: in [-1, 1], scale invariant,
    identical for every immittance form that describes the same passive quantity. ``values``
    (ω ↦ G(jω)) replaces the plain frequency response (e.g. by its regular part)."""

    def f(w: np.ndarray) -> np.ndarray:
        G = _freq_values(sub, w) if values is None else values(w)
        H = G + np.conj(np.swapaxes(G, 1, 2))
        S_ = np.abs(G) + np.abs(np.swapaxes(G, 1, 2))
        finite = np.all(np.isfinite(G), axis=(1, 2))  # only at an exact pole frequency
        H = np.where(finite[:, None, None], H, 0.0)
        S_ = np.where(finite[:, None, None], S_, 0.0)
        det = np.linalg.det(H).real if H.shape[1] > 1 else H[:, 0, 0].real
        sc = _perm_batch(S_)
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.where(sc > 0, det / np.where(sc > 0, sc, 1.0), 0.0)
        return r if values is None else np.where(finite, r, np.inf)

    return f


def _eta_ratio(sub: list[list[Rational]], scale_values: Callable[[np.ndarray], np.ndarray] | None = None
               ) -> Callable[[np.ndarray], np.ndarray]:
    """ω ↦ η/(2|p11||p22| + 2|p12 p21|), Llewellyn's η normalized to [-1, 1]. ``scale_values``
    (ω ↦ G_reg(jω), the regular part) supplies the scale when imaginary-axis poles were cancelled;
    η itself is always evaluated on G."""

    def f(w: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            G = _freq_values(sub, w)
            c = G[:, 0, 1] * G[:, 1, 0]
            eta = 2 * G[:, 0, 0].real * G[:, 1, 1].real - c.real - np.abs(c)
            Gs = G if scale_values is None else scale_values(w)
            cs = Gs[:, 0, 1] * Gs[:, 1, 0]
            sc = 2 * np.abs(Gs[:, 0, 0]) * np.abs(Gs[:, 1, 1]) + 2 * np.abs(cs)
            r = np.where(sc > 0, eta / np.where(sc > 0, sc, 1.0), 0.0)
        if scale_values is None:
            return r
        r = np.clip(r, -1.0, 1.0)
        return np.where(np.isfinite(r) & np.isfinite(sc), r, np.inf)

    return f
