"""Screened robust verdicts over many parameter draws for any built-in model (not only the SDEA).

The per-draw exact path (build the network, run the exact criterion) costs 2-10 ms a draw. This
module decides as many draws as it can *rigorously* without it and sends the rest to it, so the
per-draw stability it returns is the exact path's on every draw:

1. **Coefficient map.** The network's entries n_ij(s)/d_ij(s) of the built-in models have
   coefficients affine in the drawn parameters (masses, dampings, gains). The map θ → (all
   numerator and denominator coefficients) is measured once with d + 1 builds (the draws' mean
   and one step per parameter, to the farthest draw along its axis) and checked against real
   builds at three more draws (the first, the last and the farthest from the mean): a map that is
   not affine, or whose builds change shape or fail, is refused and every draw takes the exact
   path. The map's measured mismatch (relative, per coefficient) enters
   the error bound below.
2. **Vectorized screen.** Z(jω) of all draws on a log-spaced grid (from the centre network's poles
   and zeros, two decades beyond each side) is evaluated in float, with a first-order bound on its
   error per entry: (2(L+1)·u + ε_map)·Σ|c_k|ω^k for numerator and denominator (L: coefficient
   count, u: unit round-off), propagated through n/d. At every grid point the screen evaluates
   *necessary* conditions of the criterion:

   * every criterion: Re z_ii(jω) ≥ 0;
   * ``absolute_stability`` / ``llewellyn`` (impedance form): for every pair i < j the principal
     2×2 minor of Re Z'(jω), 2·Re z_ii·Re z_jj − Re w − |w| ≥ 0 with w = z_ij z_ji (it does not
     depend on the sign choice of z'_ij = ±√w; for a 1-DOF two-port it is Llewellyn's η ≥ 1);
   * ``positive_real`` / ``passivity``: the 2×2 principal minors of the Hermitian part,
     Re z_ii·Re z_jj − |z_ij + conj(z_ji)|²/4 ≥ 0.

   At s = ∞ (entries with a simple pole there): the residue matrix's diagonal ≥ 0 and, for
   positive realness, its symmetric part's 2×2 minors ≥ 0.

   A draw with a condition below −:data:`SAFETY` × its error bound at some grid point has a real
   violation of a necessary condition, so the exact criterion cannot call it ``stable``: it is
   **rejected** without the exact path.
3. **Vectorized acceptance** (:mod:`hil.models.batch_accept`): a draw is *accepted* (stable,
   without the exact path) when a sufficient condition of the criterion is certified for it with
   rigorous float error bounds (pole locations by a Routh table, residue matrices at 0 and ∞,
   positivity of the condition polynomials on x = ω² > 0 by their coefficients or a Pólya
   certificate; see that module for the bounds and the proof), and *rejected* when one of those
   condition polynomials is certainly negative at a sample frequency. The grid screen (2.) runs
   only on the draws neither accepted nor rejected there.
4. **Exact decision.** Every draw neither rejected nor accepted (near the boundary, or where a
   condition only holds with equality in a way the float bounds cannot certify) goes through the
   exact criterion per draw. See docs/BENCHMARKS.md ("Robust certification, general networks").
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["GRID_POINTS", "SAFETY", "CoefficientMap", "coefficient_map", "screen", "screened_stability"]

#: a condition must be below −SAFETY × its first-order error bound for the screen to reject
SAFETY = 64.0
#: grid points of the screen (log-spaced)
GRID_POINTS = 160
#: the builder's deviation from the affine coefficient map is taken as at most this many times the
#: largest deviation measured at the check builds (CoefficientMap.intervals)
MAP_SAFETY = 64.0
#: draws evaluated at once (bounds the screen's memory: chunk × grid × n² complex values)
_CHUNK = 512
_U = float(np.finfo(float).eps) / 2.0


@dataclass(frozen=True)
class CoefficientMap:
    """θ → entry coefficients, affine: ``num = num0 + Σ_k (θ_k − c_k)·dnum_k`` (arrays (n, n, L),
    ascending powers of s; the same for ``den``), ``names`` the columns of θ, ``centre`` c, ``eps``
    the largest relative mismatch against real builds at the check points (relative to each
    coefficient's term magnitude |num0| + Σ_k |θ_k − c_k|·|dnum_k|), ``kind`` the immittance
    type, ``freq`` the screen's grid band (rad/s), ``port_dofs`` the network's port sizes."""

    names: tuple[str, ...]
    centre: np.ndarray
    num0: np.ndarray
    den0: np.ndarray
    dnum: np.ndarray  # (d, n, n, L)
    dden: np.ndarray
    eps: float
    kind: str
    freq: tuple[float, float]
    port_dofs: tuple[int, ...] = ()
    #: coefficients that are copies of one drawn parameter: index of the parameter (−1: not a
    #: copy) and the factor (a signed power of two), arrays (n, n, L) for num and den
    copies: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None

    def coefficients(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(num, den) coefficient arrays (N, n, n, L) for the rows of X (N, d)."""
        D = np.asarray(X, float) - self.centre
        num = self.num0 + np.tensordot(D, self.dnum, axes=(1, 0))
        den = self.den0 + np.tensordot(D, self.dden, axes=(1, 0))
        return num, den

    def intervals(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(num, num bound, den, den bound), arrays (N, n, n, L): the predicted coefficients and a
        bound on their distance to the real builds' (hil.models.batch_accept's inputs).

        A coefficient constant over the draws (all its steps exactly 0, and equal to ``num0``
        bit for bit in every check build) is exact: bound 0; so is one the builder copies from a
        drawn parameter (``copies``: f·θ_k bit for bit at the centre and at every check build). Any other one gets
        ``MAP_SAFETY·(eps + (d + 8)·u)·mag`` with mag = |num0| + Σ_k |θ_k − c_k|·|dnum_k|: the
        prediction's own rounding (a sum of d + 1 terms and the subtraction θ − c) is within
        (d + 3)·u·mag, and the builder's deviation from the affine map is taken as at most
        MAP_SAFETY times the largest deviation measured at the check builds (an assumption on the
        builder, tested at every parameter's extreme draws, not a proof)."""
        X = np.asarray(X, float)
        D = X - self.centre
        num, den = self.coefficients(X)
        d = len(self.names)
        rel = MAP_SAFETY * (self.eps + (d + 8) * _U)
        A = np.abs(D)
        nmag = np.abs(self.num0) + np.tensordot(A, np.abs(self.dnum), axes=(1, 0))
        dmag = np.abs(self.den0) + np.tensordot(A, np.abs(self.dden), axes=(1, 0))
        nconst = ~np.any(self.dnum != 0, axis=0)
        dconst = ~np.any(self.dden != 0, axis=0)
        ne = np.where(nconst, 0.0, rel * nmag)
        de = np.where(dconst, 0.0, rel * dmag)
        # constant coefficients are the centre build's, exactly (not re-rounded)
        num = np.where(nconst, self.num0, num)
        den = np.where(dconst, self.den0, den)
        if self.copies is not None:
            # a coefficient the builder copies from a drawn parameter (times a power of two) is
            # that parameter exactly: bound 0
            for arr, err, (ck, cf) in ((num, ne, self.copies[:2]), (den, de, self.copies[2:])):
                for idx in zip(*np.nonzero(ck >= 0), strict=True):
                    arr[(slice(None), *idx)] = cf[idx] * X[:, ck[idx]]
                    err[(slice(None), *idx)] = 0.0
        return num, ne, den, de


def _arrays(tm: Any, L: int) -> tuple[np.ndarray, np.ndarray] | None:
    n = tm.n
    num, den = np.zeros((n, n, L)), np.zeros((n, n, L))
    for i in range(n):
        for j in range(n):
            e = tm.entries[i][j]
            if e.num.size > L or e.den.size > L:
                return None
            num[i, j, :e.num.size] = e.num
            den[i, j, :e.den.size] = e.den
    return num, den


def coefficient_map(build: Callable[[Mapping[str, float]], Any], names: list[str], X: np.ndarray,
                    check_rtol: float = 1e-9) -> CoefficientMap | None:
    """Measure the affine coefficient map of ``build`` (params → TransferMatrix) over the draws X
    (N, d; columns ``names``) (module docstring), or None when it is not affine to ``check_rtol``
    (relative to each entry's coefficient magnitude) at the check points, or a build fails."""
    from hil.stability.criteria import _freq_range

    X = np.asarray(X, float)
    centre = X.mean(axis=0)
    try:
        tm0 = build(dict(zip(names, centre.tolist(), strict=True)))
        L = 2 + max(max(e.num.size, e.den.size) for row in tm0.entries for e in row)
        base = _arrays(tm0, L)
        if base is None:
            return None
        num0, den0 = base
        d = len(names)
        dnum, dden = np.zeros((d, *num0.shape)), np.zeros((d, *den0.shape))
        for k in range(d):
            # a step inside the draws' range (a parameter with a bound, e.g. alpha ≤ 1, may refuse a
            # step beyond it): towards the draw farthest from the centre along this axis
            lo_k, hi_k = float(X[:, k].min()), float(X[:, k].max())
            h = (hi_k - centre[k]) if hi_k - centre[k] >= centre[k] - lo_k else (lo_k - centre[k])
            if h == 0:
                h = 0.25 * abs(centre[k]) if centre[k] != 0 else 1.0
            th = centre.copy()
            th[k] += h
            got = _arrays(build(dict(zip(names, th.tolist(), strict=True))), L)
            if got is None:
                return None
            dnum[k], dden[k] = (got[0] - num0) / h, (got[1] - den0) / h
        cmap = CoefficientMap(tuple(names), centre, num0, den0, dnum, dden, 0.0, tm0.kind,
                              _freq_range(tm0.entries), tuple(tm0.port_dofs))
        copies = [_copy_candidates(c0, dc, centre) for c0, dc in ((num0, dnum), (den0, dden))]
        # check points: the first and last draws, the one farthest from the centre and, per
        # parameter, the draws with its smallest and largest value (the builder's parameter
        # constraints, intervals per parameter, then hold on every draw's box)
        sd = X.std(axis=0)
        sd[sd == 0] = 1.0
        far = int(np.argmax((((X - centre) / sd) ** 2).sum(axis=1)))
        checks = {0, X.shape[0] - 1, far, *np.argmin(X, axis=0).tolist(), *np.argmax(X, axis=0).tolist()}
        eps = 0.0
        for i in sorted(checks):
            got = _arrays(build(dict(zip(names, X[i].tolist(), strict=True))), L)
            if got is None:
                return None
            pn, pd = cmap.coefficients(X[i:i + 1])
            Dabs = np.abs(X[i] - centre)
            for want, pred, c0, dc, cp in ((got[0], pn[0], num0, dnum, copies[0]),
                                           (got[1], pd[0], den0, dden, copies[1])):
                ck, cf = cp
                bad = (ck >= 0) & (want != cf * X[i, np.maximum(ck, 0)])
                ck[bad] = -1  # not a copy after all: the general bound applies
                const = ~np.any(dc != 0, axis=0)
                if np.any(const & (want != c0)):
                    logger.info("a coefficient constant at the probes changed at a check build: "
                                "exact path for all draws")
                    return None
                scale = np.abs(want).max(axis=-1, keepdims=True) + np.abs(pred).max(axis=-1, keepdims=True)
                err = np.abs(want - pred)
                if np.any(err > check_rtol * scale):
                    logger.info("coefficient map not affine (mismatch %.3g): exact path for all draws",
                                float((err / np.where(scale > 0, scale, 1.0)).max()))
                    return None
                mag = np.abs(c0) + np.tensordot(Dabs, np.abs(dc), axes=(0, 0))
                with np.errstate(invalid="ignore", divide="ignore"):
                    rel = np.where(const, 0.0, np.where(mag > 0, err / np.where(mag > 0, mag, 1.0),
                                                        np.where(err > 0, np.inf, 0.0)))
                eps = max(eps, float(rel.max()))
        if not np.isfinite(eps):
            return None
    except HilError as exc:
        logger.info("coefficient map not measured (%s): exact path for all draws", exc)
        return None
    return CoefficientMap(cmap.names, centre, num0, den0, dnum, dden, eps, cmap.kind, cmap.freq, cmap.port_dofs,
                          (copies[0][0], copies[0][1], copies[1][0], copies[1][1]))


def _copy_candidates(c0: np.ndarray, dc: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(parameter index or −1, factor) per coefficient: the coefficient looks like f·θ_k with f a
    signed power of two (its only step is ≈ f along θ_k and the centre build's value is f·c_k bit
    for bit); confirmed or dropped at the check builds (want == f·θ_k exactly)."""
    nzk = dc != 0
    one = nzk.sum(axis=0) == 1
    k = np.argmax(nzk, axis=0)
    step = np.take_along_axis(dc, k[None], axis=0)[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(step != 0, np.sign(step) * 2.0 ** np.round(np.log2(np.abs(np.where(step != 0, step, 1.0)))), 0.0)
    ok = one & (np.abs(step - f) <= 1e-9 * np.abs(f)) & (c0 == f * centre[k])
    return np.where(ok, k, -1), np.where(ok, f, 0.0)


def _eval(c: np.ndarray, S: np.ndarray, A: np.ndarray, gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """Values Σ c_k s^k (…, G) and their error bounds gamma·Σ|c_k|·|s|^k."""
    val = c @ S.T
    mag = np.abs(c) @ A.T
    return val, gamma * mag


def _infinity_rejects(num: np.ndarray, den: np.ndarray, gamma: float, hermitian: bool) -> np.ndarray:
    """(N,) bool: a necessary condition at s = ∞ clearly violated. For entries with a simple pole at
    ∞ in every draw (den of degree k at the centre's structure, num of degree k + 1: the residue
    R_ij = num_{k+1}/den_k), the residue matrix must have R_ii ≥ 0 (every criterion: its diagonal
    is a principal minor) and, for ``hermitian`` (positive realness: R Hermitian PSD), the 2×2
    minors of (R + Rᵀ)/2 ≥ 0. Entries without that structure give no condition."""
    N, n, _, L = num.shape
    R = np.zeros((N, n, n))
    eR = np.full((N, n, n), np.inf)
    for i in range(n):
        for j in range(n):
            dn, dd = num[:, i, j], den[:, i, j]
            nz = np.nonzero(np.any(dd != 0, axis=0))[0]
            if nz.size == 0:
                continue
            k = int(nz[-1])
            if k + 1 >= L or np.any(num[:, i, j, k + 2:] != 0):
                continue
            lead_n, lead_d = dn[:, k + 1], dd[:, k]
            ok = lead_d != 0
            with np.errstate(invalid="ignore", divide="ignore"):
                R[:, i, j] = np.where(ok, lead_n / np.where(ok, lead_d, 1.0), 0.0)
                eR[:, i, j] = np.where(ok, 4.0 * gamma * np.abs(R[:, i, j]) + 1e-300, np.inf)
    bad = np.zeros(N, bool)
    for i in range(n):
        bad |= np.isfinite(eR[:, i, i]) & (R[:, i, i] < -SAFETY * eR[:, i, i])
    if hermitian:
        for i in range(n):
            for j in range(i + 1, n):
                h = 0.5 * (R[:, i, j] + R[:, j, i])
                eh = 0.5 * (eR[:, i, j] + eR[:, j, i])
                val = R[:, i, i] * R[:, j, j] - h * h
                err = (np.abs(R[:, i, i]) * eR[:, j, j] + np.abs(R[:, j, j]) * eR[:, i, i] + eR[:, i, i] * eR[:, j, j]
                       + eh * (2.0 * np.abs(h) + eh))
                bad |= np.isfinite(err) & (val < -SAFETY * err)
    return bad


def screen(cmap: CoefficientMap, X: np.ndarray, criterion: str,
           grid_points: int = GRID_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(rejected (N,) bool, screen margin (N,)): a draw is rejected when a necessary condition of
    ``criterion`` is below −:data:`SAFETY` × its error bound at a grid point (module docstring);
    the margin is the smallest condition value over the grid divided by its magnitude scale (a
    ranking number in [−1, 1]-ish, not a certificate margin)."""
    X = np.atleast_2d(np.asarray(X, float))
    N = X.shape[0]
    lo, hi = cmap.freq
    w = np.geomspace(lo, hi, grid_points)
    L = cmap.num0.shape[-1]
    pw = np.arange(L)
    S = (1j * w[:, None]) ** pw[None, :]  # (G, L)
    A = w[:, None] ** pw[None, :]
    gamma = 2.0 * (L + 1) * _U + cmap.eps
    n = cmap.num0.shape[0]
    pairs_mode = {"absolute_stability": "z", "llewellyn": "z", "positive_real": "h", "passivity": "h"}.get(criterion)
    if criterion in ("absolute_stability", "llewellyn") and cmap.kind != "impedance":
        pairs_mode = None  # the pair condition above is stated for the impedance form only
    rejected = np.zeros(N, bool)
    margin = np.full(N, np.inf)
    for a in range(0, N, _CHUNK):
        num, den = cmap.coefficients(X[a:a + _CHUNK])
        rejected[a:a + _CHUNK] |= _infinity_rejects(num, den, gamma, pairs_mode == "h")
        nv, ne = _eval(num, S, A, gamma)
        dv, de = _eval(den, S, A, gamma)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            ad = np.abs(dv)
            z = nv / dv
            # first-order error of n/d, doubled; no bound (inf) where |d| is within its error of 0
            ez = np.where(ad > 2 * de, 2.0 * (ne + np.abs(z) * de) / ad, np.inf)
            conds: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (value, error bound, scale)
            for i in range(n):
                conds.append((z[:, i, i].real, ez[:, i, i], np.abs(z[:, i, i])))
            if pairs_mode is not None:
                for i in range(n):
                    for j in range(i + 1, n):
                        zi, zj, ei, ej = z[:, i, i], z[:, j, j], ez[:, i, i], ez[:, j, j]
                        zij, zji, eij, eji = z[:, i, j], z[:, j, i], ez[:, i, j], ez[:, j, i]
                        e_diag = np.abs(zi) * ej + np.abs(zj) * ei + ei * ej
                        if pairs_mode == "z":
                            wv = zij * zji
                            ew = np.abs(zij) * eji + np.abs(zji) * eij + eij * eji
                            val = 2.0 * zi.real * zj.real - wv.real - np.abs(wv)
                            err = 2.0 * e_diag + 2.0 * ew
                            scale = 2.0 * np.abs(zi) * np.abs(zj) + 2.0 * np.abs(wv)
                        else:
                            hv = 0.5 * (zij + np.conj(zji))
                            eh = 0.5 * (eij + eji)
                            val = zi.real * zj.real - np.abs(hv) ** 2
                            err = e_diag + eh * (2.0 * np.abs(hv) + eh)
                            scale = np.abs(zi) * np.abs(zj) + np.abs(hv) ** 2
                        conds.append((val, err, scale))
            for val, err, scale in conds:
                bad = np.isfinite(err) & (val < -SAFETY * err)
                rejected[a:a + _CHUNK] |= bad.any(axis=-1)
                g = np.where(np.isfinite(err) & (scale > 0), val / np.where(scale > 0, scale, 1.0), np.inf)
                margin[a:a + _CHUNK] = np.minimum(margin[a:a + _CHUNK], g.min(axis=-1))
    return rejected, margin


def screened_stability(model: str, criterion: str, params: Mapping[str, Any],
                       draws: Mapping[str, np.ndarray],
                       exact_one: Callable[[Mapping[str, Any]], bool]) -> dict[str, Any]:
    """Per-draw stability of ``model`` under ``criterion`` at ``params`` updated with each draw:
    screened rejections (module docstring) and ``exact_one(params) -> stable`` on every other
    draw. Returns ``{"stable", "rejected", "screen_margin"}`` ((N,) arrays), ``"method"`` and ``"cmap"``
    (the measured :class:`CoefficientMap`, or None)."""
    from hil.models import get_model

    names = sorted(draws)
    X = np.column_stack([np.asarray(draws[k], float) for k in names])
    N = X.shape[0]
    m = get_model(model)

    def build(th: Mapping[str, float]) -> Any:
        q = dict(params)
        q.update(th)
        return m.network(q)

    cmap = coefficient_map(build, names, X) if 2 * len(names) + 4 < N else None
    if cmap is not None:
        from hil.models.batch_accept import accept_reject

        # acceptance first (and rejection where a condition is certainly negative at a sample
        # frequency): cheaper per draw than the grid, which runs on the rest only
        accepted, rejected = accept_reject(cmap, X, criterion)
        margin = np.full(N, np.nan)
        rest = np.nonzero(~accepted & ~rejected)[0]
        if rest.size:
            rej_g, margin[rest] = screen(cmap, X[rest], criterion)
            rejected[rest] = rej_g
    else:
        rejected, margin = np.zeros(N, bool), np.full(N, np.nan)
        accepted = np.zeros(N, bool)
    method = "general exact criterion per draw"
    if rejected.any() or accepted.any():
        method = (f"general exact criterion per draw, after a vectorized screen that rejected "
                  f"{int(rejected.sum())} (a necessary frequency condition violated) and accepted "
                  f"{int(accepted.sum())} (a sufficient condition certified) of {N} draws")
    stable = accepted.copy()
    for i in np.nonzero(~rejected & ~accepted)[0]:
        q = dict(params)
        q.update({k: float(X[i, c]) for c, k in enumerate(names)})
        stable[i] = exact_one(q)
    return {"stable": stable, "rejected": rejected, "accepted": accepted, "screen_margin": margin,
            "method": method, "cmap": cmap}
