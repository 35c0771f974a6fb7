"""Theorem 1 of paper 000: the symmetrization of an m-DOF n-port (preconditions A and B, the
symmetrized matrix Z' formed exactly up to a diagonal similarity) and the flagged numerical sweep
for blocks whose Z' is not rational."""

from __future__ import annotations

import itertools
import logging
import math

import numpy as np
from flint import fmpq, fmpq_poly
from numpy.polynomial import polynomial as P

from hil.stability.forms import QEntries, _lbl
from hil.stability.jpoly import trim_back
from hil.stability.rational import _RF, Rational, TransferMatrix
from hil.stability.results import Condition, ConditionStatus
from hil.stability.tolerances import Tolerances

logger = logging.getLogger(__name__)


# -- Theorem 1 of paper 000 ------------------------------------------------------------------


def _poly_sqrt(c: np.ndarray, rtol: float = 1e-9) -> tuple[np.ndarray, float] | None:
    """If c(s) = κ·r(s)² with r monic-led real polynomial, return (r, κ); else None."""
    c = trim_back(np.asarray(c, float))
    n = c.size - 1
    if n % 2:
        return None
    k = 0
    while c[k] == 0:
        k += 1
    if k % 2:
        return None
    kappa = c[-1]
    cn = c / kappa  # monic
    m = n // 2
    r = np.zeros(m + 1)
    r[m] = 1.0
    # match coefficients from the top: (r²)_{m+i} determines r_{i}
    for i in range(m - 1, -1, -1):
        deg = m + i
        # coefficient of s^deg in r² = 2 r_i r_m + (sum of pairs not involving r_i)
        acc = 0.0
        for a in range(m + 1):
            b = deg - a
            if 0 <= b <= m and a != i and b != i:
                acc += r[a] * r[b]
        r[i] = (cn[deg] - acc) / 2.0
    sq = P.polymul(r, r)
    mag: np.ndarray = P.polymul(np.abs(r), np.abs(r))
    if np.all(np.abs(sq - np.pad(cn, (0, sq.size - cn.size))) <= rtol * np.maximum(mag, 1e-300) + 1e-300):
        return r, float(kappa)
    return None


def _rational_sqrt(a: Rational, b: Rational) -> Rational | None:
    """√(a·b) as a real rational function when a·b is the square of one (up to a positive constant)."""
    num = P.polymul(a.num, b.num)
    den = P.polymul(a.den, b.den)
    rn, rd = _poly_sqrt(num), _poly_sqrt(den)
    if rn is None or rd is None:
        return None
    kap = rn[1] / rd[1]
    if kap <= 0:
        return None
    return Rational(math.sqrt(kap) * rn[0], rd[0])


def _components(nz: np.ndarray) -> list[list[int]]:
    n = nz.shape[0]
    seen = [False] * n
    comps = []
    for s in range(n):
        if seen[s]:
            continue
        stack, comp = [s], []
        seen[s] = True
        while stack:
            v = stack.pop()
            comp.append(v)
            for u in range(n):
                if nz[v, u] and not seen[u]:
                    seen[u] = True
                    stack.append(u)
        comps.append(sorted(comp))
    return comps


def _symmetrize(tm: TransferMatrix, comp: list[int], W: dict[tuple[int, int], Rational]) -> list[list[Rational]] | None:
    """Rational Z' on a component with signs chosen so that cycle products match Z's."""
    rng = np.random.default_rng(12345)
    s0 = complex(0.37 + rng.random(), 1.1 + rng.random())
    parent: dict[int, int | None] = {comp[0]: None}
    sign: dict[tuple[int, int], float] = {}
    # BFS spanning tree with + signs
    q = [comp[0]]
    while q:
        v = q.pop(0)
        for u in comp:
            if u not in parent and (min(u, v), max(u, v)) in W:
                parent[u] = v
                sign[(min(u, v), max(u, v))] = 1.0
                q.append(u)
    # non-tree edges: sign from the triangle/cycle product through the tree root paths
    def path(v: int) -> list[int]:
        out = [v]
        while (p := parent[out[-1]]) is not None:
            out.append(p)
        return out

    for (i, j), _w in W.items():
        if (i, j) in sign or i not in parent:
            continue
        pi, pj = path(i), path(j)
        # cycle: i -> ... -> root -> ... -> j -> i (through the spanning tree)
        nodes = pi + pj[::-1][1:]
        zprod = complex(1.0)
        wprod = complex(1.0)
        seq = [*nodes, i]
        for a, b in itertools.pairwise(seq):
            zprod *= complex(tm[a, b](s0))
            key = (min(a, b), max(a, b))
            ws = sign.get(key, 1.0) if key != (i, j) else 1.0
            wprod *= ws * complex(W[key](s0))
        ratio = zprod / wprod if wprod != 0 else 0
        if abs(abs(ratio) - 1) > 1e-6 or abs(ratio.imag) > 1e-6:
            return None
        sign[(i, j)] = 1.0 if ratio.real > 0 else -1.0
    k = len(comp)
    out = [[Rational.const(0.0)] * k for _ in range(k)]
    for a, i in enumerate(comp):
        for b, j in enumerate(comp):
            if i == j:
                out[a][b] = tm[i, i]
            else:
                key = (min(i, j), max(i, j))
                if key in W:
                    out[a][b] = W[key] * sign[key]
    return out


def _rf_equal(a: _RF, b: _RF) -> bool:
    """Exact equality of rational functions (both reduced with monic denominators)."""
    return bool(a.n == b.n and a.d == b.d)


def _poly_square_root(p: fmpq_poly) -> tuple[fmpq, fmpq_poly] | None:
    """(κ, r) with p = κ·r² exactly (squarefree decomposition over Q), or None."""
    c, facs = p.factor_squarefree()
    r = fmpq_poly([1])
    for f, e in facs:
        if e % 2:
            return None
        r *= f ** (int(e) // 2)
    return fmpq(c), r


def _exact_sqrt(P_: _RF) -> tuple[fmpq, _RF] | None:
    """(κ, ρ) with P = κ·ρ² exactly, κ > 0 rational and ρ a rational function over Q, or None
    (then √P, the entry z'_ij = √(z_ij z_ji) of Theorem 1, is not a real rational function up
    to a constant and the block is swept)."""
    a, b = _poly_square_root(P_.n), _poly_square_root(P_.d)
    if a is None or b is None:
        return None
    kap = a[0] / b[0]
    if kap <= 0:
        return None
    # normalize ρ by λ ≈ √κ (exact when κ is a rational square): κ/λ² ≈ 1, so the diagonal
    # similarity of _exact_symmetrize stays near the identity and the margins near those of Z'
    num, den = int(kap.p), int(kap.q)
    lam = fmpq(math.isqrt(num * den * 4**64), den * 2**64)
    return kap / (lam * lam), _RF(a[1], b[1]) * _RF(fmpq_poly([lam]), fmpq_poly([1]), reduced=True)


def _sqrt_of_pair(zij: _RF, zji: _RF) -> tuple[fmpq, _RF] | None:
    """(κ, ρ) with z_ij z_ji = κ ρ² (:func:`_exact_sqrt`); a symmetric pair z_ij = z_ji needs no
    factorization: κ = 1, ρ = z_ij."""
    if _rf_equal(zij, zji):
        return fmpq(1), zij
    return _exact_sqrt(zij * zji)


def _fmpq_sqrt(q: fmpq) -> fmpq | None:
    """The exact rational square root of q ≥ 0, or None when q is not a rational square."""
    num, den = int(q.p), int(q.q)
    if num < 0:
        return None
    rn, rd = math.isqrt(num), math.isqrt(den)
    return fmpq(rn, rd) if rn * rn == num and rd * rd == den else None


def _exact_symmetrize(RF: list[list[_RF]], comp: list[int],
                      roots: dict[tuple[int, int], tuple[fmpq, _RF]]) -> tuple[QEntries | None, str]:
    """Theorem 1's symmetrized block Z' (z'_ij = γ_ij √(z_ij z_ji) = γ_ij √κ_ij ρ_ij), exactly.

    √κ_ij need not be rational, so Z' is formed up to a diagonal similarity S = T⁻¹ Z' T,
    T = diag(√q_i) with q_root = 1 and q_j = q_i κ_ij along a spanning tree: S_ij = γ_ij
    √(κ_ij q_j/q_i) ρ_ij is rational on tree edges and is required to be on the other edges. A real
    diagonal similarity keeps Re S = T⁻¹ Re Z' T and so every principal minor of Re Z'(jω). Signs
    γ: +1 on tree edges; on the others the cycle product of S (= that of Z') must equal Z's exactly
    up to sign. Then every principal minor of S must equal Z's (exactly, over Q(s)).

    Returns (S as exact entries, "") or (None, reason): ``"irrational"`` when S is not rational
    (the caller sweeps), else why no Z' reproduces Z's principal minors (not applicable)."""
    from hil.stability.rational import _rf_det

    k = len(comp)
    loc = {g: a for a, g in enumerate(comp)}
    adj = {g: [h for h in comp if h != g and (min(g, h), max(g, h)) in roots] for g in comp}
    q: dict[int, fmpq] = {comp[0]: fmpq(1)}
    parent: dict[int, int | None] = {comp[0]: None}
    order = [comp[0]]
    for v in order:
        for u in adj[v]:
            if u not in q:
                q[u] = q[v] * roots[(min(u, v), max(u, v))][0]
                parent[u] = v
                order.append(u)
    S: list[list[_RF]] = [[RF[comp[a]][comp[a]] if a == b else _RF(fmpq_poly([]), fmpq_poly([1]), reduced=True)
                           for b in range(k)] for a in range(k)]

    def set_edge(i: int, j: int, sign: int) -> bool:
        kap, rho = roots[(min(i, j), max(i, j))]
        t = _fmpq_sqrt(kap * q[j] / q[i])
        if t is None:
            return False
        S[loc[i]][loc[j]] = rho * _RF(fmpq_poly([sign * t]), fmpq_poly([1]), reduced=True)
        S[loc[j]][loc[i]] = rho * _RF(fmpq_poly([sign * kap / t]), fmpq_poly([1]), reduced=True)
        return True

    tree = {(min(u, p), max(u, p)) for u, p in parent.items() if p is not None}
    for i, j in tree:
        set_edge(i, j, 1)  # rational by construction of q

    def path(v: int) -> list[int]:
        out = [v]
        while parent[out[-1]] is not None:
            out.append(parent[out[-1]])  # type: ignore[arg-type]
        return out

    for i, j in sorted(set(roots) - tree):
        if not set_edge(i, j, 1):
            return None, "irrational"
        pi, pj = path(i), path(j)
        seq = [*pi, *pj[::-1][1:], i]
        zp = sp = _RF(fmpq_poly([1]), fmpq_poly([1]), reduced=True)
        for a, b in itertools.pairwise(seq):
            zp = zp * RF[a][b]
            sp = sp * S[loc[a]][loc[b]]
        if _rf_equal(zp, sp):
            continue
        if _rf_equal(zp, -sp):
            set_edge(i, j, -1)
            continue
        return None, (f"no sign choice of √(z{i + 1}{j + 1} z{j + 1}{i + 1}) reproduces Z's cycle products "
                      "(a longer cycle condition fails)")
    # With every fundamental cycle balanced, the ratios z_ij/S_ij (whose two directions multiply to
    # 1) are potential differences φ_i/φ_j on the coupling graph, so Z = Φ S Φ⁻¹ on the edges and
    # all principal minors agree. Only an entry with z_ij ≠ 0 but z_ji = 0 (no edge, S_ij = 0) can
    # still make them differ (through a longer cycle): then they are compared exactly.
    one_way = any(RF[comp[a]][comp[b]].is_zero != RF[comp[b]][comp[a]].is_zero
                  for a in range(k) for b in range(a + 1, k))
    for r in range(2, k + 1 if one_way else 2):
        for idx in itertools.combinations(range(k), r):
            mz = _rf_det([[RF[comp[a]][comp[b]] for b in idx] for a in idx])
            ms = _rf_det([[S[a][b] for b in idx] for a in idx])
            if not _rf_equal(mz, ms):
                return None, (f"principal minor {_lbl([comp[a] for a in idx])} of Z' differs from Z's "
                              "(no sign choice of √(z_ij z_ji) reproduces it)")
    nums: list[list[fmpq_poly | None]] = [[None if S[a][b].is_zero else S[a][b].n for b in range(k)]
                                          for a in range(k)]
    dens = [[S[a][b].d for b in range(k)] for a in range(k)]
    return (nums, dens), ""


def _sweep_block(tm: TransferMatrix, comp: list[int], tol: Tolerances) -> list[Condition]:
    """Numerical fallback for a Theorem-1 block of size ≥ 3 whose Z' is not rational.

    Re Z'(jω) is formed pointwise (principal square roots with cycle-consistent signs) on a
    dense logarithmic grid spanning the poles/zeros, and each principal minor is minimized with
    local refinement. Flagged ``method: sweep`` in the evidence: this is not an exact decision.
    """
    mags = [abs(p) for p in tm.poles() if abs(p) > 0] + [1.0]
    lo, hi = min(mags) * 1e-4, max(mags) * 1e4
    w = np.geomspace(lo, hi, 20001)
    G = tm.freq(w)[:, comp][:, :, comp]
    k = len(comp)
    R = np.zeros((w.size, k, k))
    for a in range(k):
        R[:, a, a] = G[:, a, a].real
    # pointwise symmetrization via a star from node 0 plus cycle consistency
    for a in range(k):
        for b in range(a + 1, k):
            c = G[:, a, b] * G[:, b, a]
            root = np.sqrt(c)
            if a > 0:
                ref = G[:, 0, a] * G[:, a, b] * G[:, b, 0]
                w0a = np.sqrt(G[:, 0, a] * G[:, a, 0])
                w0b = np.sqrt(G[:, 0, b] * G[:, b, 0])
                prod = w0a * root * w0b
                flip = (np.abs(prod) > 0) & ((ref / np.where(prod == 0, 1, prod)).real < 0)
                root = np.where(flip, -root, root)
            R[:, a, b] = R[:, b, a] = root.real
    conds = []
    for r in range(1, k + 1):
        for idx in itertools.combinations(range(k), r):
            sub = R[:, idx][:, :, idx]
            mn = np.linalg.det(sub) if r > 1 else sub[:, 0, 0]
            scale = np.abs(np.linalg.det(np.abs(sub))) + np.prod(np.abs(np.diagonal(sub, axis1=1, axis2=2)), axis=1)
            rho = mn / np.maximum(scale, 1e-300)
            i0 = int(np.argmin(rho))
            v = float(rho[i0])
            status: ConditionStatus = "violated" if v < -1e-6 else ("marginal" if v <= 1e-6 else "satisfied")
            glob = tuple(comp[i] for i in idx)
            conds.append(Condition(f"E{_lbl(glob)}", f"principal minor {_lbl(glob)} of Re Z'(jω) ≥ 0", status, v,
                                   float(w[i0]), "decided on a dense frequency grid (Z' is not rational)",
                                   {"method": "sweep", "grid_points": int(w.size)}))
    return conds
