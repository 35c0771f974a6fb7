"""Continuous-time LTI state space, transfer-function realization and EXACT discretization.

Conventions
-----------
* Continuous model ``x' = A x + B u``, ``y = C x + D u`` (time in s; the units of ``x``, ``u``
  and ``y`` are those of the caller, SI throughout the suite).
* Discretization is exact for the chosen hold: with a zero-order hold (ZOH) over ``[k dt, (k+1) dt)``
  ``x[k+1] = Ad x[k] + Bd u[k]`` with ``[[Ad, Bd], [0, I]] = expm([[A, B], [0, 0]] dt)``. The
  sampled states equal the exact solution of the ODE at the sample instants for a
  piecewise-constant input, whatever the stiffness (no stability limit on ``dt``).
* A first-order hold (FOH, input linear between samples) is available for offline simulation:
  ``x[k+1] = Ad x[k] + B0 u[k] + B1 u[k+1]``.

Accuracy of the matrix exponential
----------------------------------
``scipy.linalg.expm`` (Pade 13 with scaling and squaring, Al-Mohy & Higham 2009) chooses few
squarings to avoid over-scaling. For stiff, lightly damped plants (e.g. ``k = 1e6 N/m``,
``m = 1e-3 kg`` at ``dt = 1e-3 s``: a rotation of ~31.6 rad per step) that choice was measured to
give ~3e-13 relative error per step, which accumulates as a phase drift. :func:`expm_accurate`
first balances the block matrix with a diagonal similarity made of powers of two (exact in
floating point, ``scipy.linalg.matrix_balance``), then scales it to a 1-norm <= 2 before calling
``expm`` and squares back; this measured ~5e-15 on the same matrix (see ``tests/mocks/test_lti.py``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg as sla

from hil.errors import ModelError

logger = logging.getLogger(__name__)

ArrayLike = np.ndarray | Sequence[float] | Sequence[Sequence[float]] | float
Hold = Literal["zoh", "foh"]

#: 1-norm target of the scaled block matrix handed to ``scipy.linalg.expm`` (see module doc).
_EXPM_THETA = 2.0


def _as_matrix(value: ArrayLike, rows: int | None, cols: int | None, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    if arr.ndim == 1:
        arr = arr.reshape(-1, 1) if cols == 1 else arr.reshape(1, -1)
    if arr.ndim != 2:
        raise ModelError(f"{name} must be a 2-D matrix, got shape {arr.shape}")
    if arr.size == 0:
        arr = np.zeros((rows or 0, cols or 0))
    if (rows is not None and arr.shape[0] != rows) or (cols is not None and arr.shape[1] != cols):
        raise ModelError(f"{name} has shape {arr.shape}, expected ({rows}, {cols})")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} contains non-finite entries")
    out = np.array(arr, dtype=float, copy=True)
    out.setflags(write=False)
    return out


class StateSpace:
    """Continuous-time LTI system ``x' = A x + B u``, ``y = C x + D u`` (immutable).

    ``A`` is (n, n), ``B`` (n, m), ``C`` (p, n), ``D`` (p, m); ``n`` may be 0 (static gain).
    Discretizations are cached per ``(dt, hold)``; the matrices are read-only so the cache
    cannot go stale.
    """

    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        C: ArrayLike,
        D: ArrayLike,
        *,
        state_names: Sequence[str] | None = None,
        input_names: Sequence[str] | None = None,
        output_names: Sequence[str] | None = None,
    ) -> None:
        A_arr = np.asarray(A, dtype=float)
        n = 0 if A_arr.size == 0 else (A_arr.shape[0] if A_arr.ndim == 2 else 1)
        D_arr = np.asarray(D, dtype=float)
        D_arr = D_arr.reshape(1, 1) if D_arr.ndim == 0 else D_arr
        if D_arr.ndim != 2:
            raise ModelError(f"D must be a 2-D matrix, got shape {D_arr.shape}")
        p, m = D_arr.shape
        self.A = _as_matrix(A_arr, n, n, "A")
        self.B = _as_matrix(B, n, m, "B")
        self.C = _as_matrix(C, p, n, "C")
        self.D = _as_matrix(D_arr, p, m, "D")
        self.state_names = self._names(state_names, n, "x")
        self.input_names = self._names(input_names, m, "u")
        self.output_names = self._names(output_names, p, "y")
        self._cache: dict[tuple[float, str], DiscreteStateSpace] = {}

    @staticmethod
    def _names(names: Sequence[str] | None, count: int, prefix: str) -> tuple[str, ...]:
        if names is None:
            return tuple(f"{prefix}{i}" for i in range(count))
        names = tuple(names)
        if len(names) != count:
            raise ModelError(f"{len(names)} names given for {count} {prefix!r} signals")
        return names

    @property
    def n(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    @property
    def m(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def p(self) -> int:
        """Number of outputs."""
        return self.C.shape[0]

    def __repr__(self) -> str:
        return f"StateSpace(n={self.n}, m={self.m}, p={self.p})"

    def poles(self) -> np.ndarray:
        """Eigenvalues of ``A`` (rad/s)."""
        return np.linalg.eigvals(self.A) if self.n else np.zeros(0, dtype=complex)

    def freqresp(self, w: ArrayLike) -> np.ndarray:
        """Frequency response ``G(jw) = C (jw I - A)^-1 B + D`` at angular frequencies ``w`` (rad/s).

        Returns an array of shape ``(len(w), p, m)``.
        """
        w_arr = np.atleast_1d(np.asarray(w, dtype=float))
        out = np.empty((w_arr.size, self.p, self.m), dtype=complex)
        eye = np.eye(self.n)
        for i, wi in enumerate(w_arr):
            if self.n:
                out[i] = self.C @ np.linalg.solve(1j * wi * eye - self.A, self.B) + self.D
            else:
                out[i] = self.D
        return out

    def dcgain(self) -> np.ndarray:
        """Static gain ``D - C A^-1 B`` (raises ModelError when ``A`` is singular)."""
        if not self.n:
            return np.array(self.D)
        try:
            return self.D - self.C @ np.linalg.solve(self.A, self.B)
        except np.linalg.LinAlgError as exc:
            raise ModelError("dcgain: A is singular (the system has a pole at s = 0)") from exc

    def discretize(self, dt: float, hold: Hold = "zoh") -> DiscreteStateSpace:
        """Exact discretization for a zero-order (``"zoh"``) or first-order (``"foh"``) hold.

        Cached per ``(dt, hold)``.
        """
        if not (dt > 0 and math.isfinite(dt)):
            raise ModelError(f"dt must be a positive finite number of seconds, got {dt!r}")
        key = (float(dt), hold)
        cached = self._cache.get(key)
        if cached is not None:
            return cached
        if hold == "zoh":
            Ad, Bd = zoh_matrices(self.A, self.B, dt)
            B1 = np.zeros_like(Bd)
        elif hold == "foh":
            Ad, Bd, B1 = foh_matrices(self.A, self.B, dt)
        else:
            raise ModelError(f"unknown hold {hold!r}; use 'zoh' or 'foh'")
        disc = DiscreteStateSpace(Ad, Bd, self.C, self.D, float(dt), hold, B1)
        self._cache[key] = disc
        logger.debug("discretized %r with %s at dt=%g s", self, hold, dt)
        return disc


@dataclass(frozen=True)
class DiscreteStateSpace:
    """``x[k+1] = Ad x[k] + Bd u[k] + B1 u[k+1]``, ``y[k] = C x[k] + D u[k]`` (``B1 = 0`` for ZOH)."""

    Ad: np.ndarray
    Bd: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float
    hold: str
    B1: np.ndarray

    def simulate(self, u: ArrayLike, x0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Run the recursion over input samples ``u`` (shape ``(N, m)``).

        Returns ``(x, y)`` with ``x`` of shape ``(N, n)`` (``x[0] = x0``) and ``y`` of shape
        ``(N, p)``. For ZOH, ``u[k]`` is held over ``[k dt, (k+1) dt)``; for FOH the input is
        linear between ``u[k]`` and ``u[k+1]`` (the last sample is held).
        """
        n, m = self.Bd.shape
        u_arr = np.asarray(u, dtype=float)
        u_arr = u_arr.reshape(-1, m) if u_arr.ndim <= 1 else u_arr
        if u_arr.shape[1] != m:
            raise ModelError(f"u has {u_arr.shape[1]} columns, the system has {m} inputs")
        N = u_arr.shape[0]
        x = np.zeros((N, n))
        x[0] = 0.0 if x0 is None else np.asarray(x0, dtype=float).reshape(n)
        for k in range(N - 1):
            x[k + 1] = self.Ad @ x[k] + self.Bd @ u_arr[k] + self.B1 @ u_arr[k + 1]
        y = x @ self.C.T + u_arr @ self.D.T
        return x, y


def expm_accurate(M: np.ndarray) -> np.ndarray:
    """Matrix exponential with exact power-of-two balancing and extra scaling-and-squaring.

    See the module docstring for why this is more accurate than a bare ``scipy.linalg.expm``
    on stiff, lightly damped blocks.
    """
    M = np.asarray(M, dtype=float)
    if M.size == 0:
        return np.zeros_like(M)
    Mb, (scale, _perm) = sla.matrix_balance(M, permute=False, separate=True)
    norm = float(np.linalg.norm(Mb, 1))
    squarings = max(0, math.ceil(math.log2(norm / _EXPM_THETA))) if norm > _EXPM_THETA else 0
    E = sla.expm(Mb / 2.0**squarings)
    for _ in range(squarings):
        E = E @ E
    return scale[:, None] * E / scale[None, :]


def zoh_matrices(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Ad, Bd)`` of the exact ZOH discretization via the augmented exponential."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A * dt
    M[:n, n:] = B * dt
    E = expm_accurate(M)
    return E[:n, :n].copy(), E[:n, n:].copy()


def foh_matrices(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Ad, B0, B1)`` of the exact first-order (input linear over the step) discretization.

    The augmented state ``[x, u, w]`` with ``u' = w / dt``, ``w' = 0`` gives
    ``expm([[A dt, B dt, 0], [0, 0, I], [0, 0, 0]]) = [[Ad, G1, G2], ...]`` and
    ``x[k+1] = Ad x[k] + G1 u[k] + G2 (u[k+1] - u[k])``, so ``B0 = G1 - G2``, ``B1 = G2``.
    """
    n, m = B.shape
    M = np.zeros((n + 2 * m, n + 2 * m))
    M[:n, :n] = A * dt
    M[:n, n : n + m] = B * dt
    M[n : n + m, n + m :] = np.eye(m)
    E = expm_accurate(M)
    Ad = E[:n, :n].copy()
    G1 = E[:n, n : n + m]
    G2 = E[:n, n + m :]
    return Ad, (G1 - G2).copy(), G2.copy()


# ----------------------------------------------------------------------------------------------
# Realizations
# ----------------------------------------------------------------------------------------------

TFEntry = tuple[ArrayLike, ArrayLike] | float | int | None


def _poly(coeffs: ArrayLike, name: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(coeffs, dtype=float))
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} must be a non-empty finite 1-D coefficient list (highest power first)")
    nz = np.flatnonzero(arr)
    return arr[nz[0] :] if nz.size else np.zeros(1)


def _entry(entry: TFEntry) -> tuple[np.ndarray, np.ndarray]:
    if entry is None:
        return np.zeros(1), np.ones(1)
    if isinstance(entry, int | float | np.floating | np.integer):
        return np.array([float(entry)]), np.ones(1)
    try:
        num, den = entry
    except (TypeError, ValueError) as exc:
        raise ModelError(
            f"transfer-matrix entry must be (num, den), a number or None, got {entry!r}"
        ) from exc
    num_p, den_p = _poly(num, "numerator"), _poly(den, "denominator")
    if not np.any(den_p):
        raise ModelError("denominator is identically zero")
    if np.any(num_p) and num_p.size > den_p.size:
        raise ModelError(f"improper transfer function (deg num {num_p.size - 1} > deg den {den_p.size - 1})")
    return num_p / den_p[0], den_p / den_p[0]


def _controllable_canonical(
    nums: np.ndarray, den: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """SIMO controllable canonical form of ``nums[i](s) / den(s)`` (``den`` monic, nums padded to
    ``len(den)``). Same form as ``scipy.signal.tf2ss``, which warns spuriously when every
    numerator has a zero leading coefficient (strictly proper columns)."""
    order = den.size - 1
    a = den[1:]
    A = np.zeros((order, order))
    A[0, :] = -a
    A[1:, :-1] = np.eye(order - 1)
    B = np.zeros((order, 1))
    B[0, 0] = 1.0
    D = nums[:, :1].copy()
    C = nums[:, 1:] - D * a[None, :]
    return A, B, C, D


def tf(num: ArrayLike, den: ArrayLike) -> StateSpace:
    """Controllable-canonical realization of a proper SISO ``num(s)/den(s)`` (highest power first)."""
    return tf_matrix([[(num, den)]])


def tf_matrix(entries: Sequence[Sequence[TFEntry]]) -> StateSpace:
    """State-space realization of a proper transfer matrix ``G(s)`` (p x m).

    ``entries[i][j]`` is ``(num, den)`` (coefficients, highest power first), a number (static
    gain) or ``None`` (zero). Each column is realized in controllable canonical form over the
    product of its *distinct* denominators (equal denominators, up to scaling, are merged),
    and the columns are stacked block-diagonally. The result is controllable; it is minimal
    when no pole is shared between columns (otherwise a few redundant states remain, harmless
    for simulation). E.g. the 3x3 ``T2`` of :func:`hil.mocks.terminations.t2_termination`
    gets 3 + 2 + 2 = 7 states.
    """
    rows = [list(r) for r in entries]
    if not rows or not rows[0]:
        raise ModelError("transfer matrix is empty")
    p, m = len(rows), len(rows[0])
    if any(len(r) != m for r in rows):
        raise ModelError("transfer matrix rows have different lengths")
    parsed = [[_entry(e) for e in r] for r in rows]
    blocks: list[StateSpace] = []
    for j in range(m):
        dens: list[np.ndarray] = []
        for i in range(p):
            num, den = parsed[i][j]
            if not np.any(num) or den.size == 1:
                continue
            if not any(d.size == den.size and np.allclose(d, den, rtol=1e-12, atol=0.0) for d in dens):
                dens.append(den)
        common = np.ones(1)
        for d in dens:
            common = np.polymul(common, d)
        nums = []
        for i in range(p):
            num, den = parsed[i][j]
            if not np.any(num):
                nums.append(np.zeros(common.size))
                continue
            other = np.ones(1)
            used = False
            for d in dens:
                if not used and d.size == den.size and np.allclose(d, den, rtol=1e-12, atol=0.0):
                    used = True
                    continue
                other = np.polymul(other, d)
            full = np.polymul(num, other)
            nums.append(np.concatenate([np.zeros(common.size - full.size), full]))
        if common.size == 1:
            blocks.append(StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((p, 0)),
                                     np.array(nums).reshape(p, 1) / common[0]))
            continue
        blocks.append(StateSpace(*_controllable_canonical(np.array(nums), common)))
    n_tot = sum(b.n for b in blocks)
    A = np.zeros((n_tot, n_tot))
    B = np.zeros((n_tot, m))
    C = np.zeros((p, n_tot))
    D = np.zeros((p, m))
    k = 0
    for j, b in enumerate(blocks):
        A[k : k + b.n, k : k + b.n] = b.A
        B[k : k + b.n, j] = b.B[:, 0]
        C[:, k : k + b.n] = b.C
        D[:, j] = b.D[:, 0]
        k += b.n
    return StateSpace(A, B, C, D)


def gain(K: ArrayLike) -> StateSpace:
    """Static gain ``y = K u`` as a state space with no state."""
    K_arr = np.atleast_2d(np.asarray(K, dtype=float))
    p, m = K_arr.shape
    return StateSpace(np.zeros((0, 0)), np.zeros((0, m)), np.zeros((p, 0)), K_arr)


def append(*systems: StateSpace) -> StateSpace:
    """Block-diagonal union: inputs and outputs concatenated, no interconnection."""
    if not systems:
        raise ModelError("append needs at least one system")
    A = sla.block_diag(*[s.A for s in systems]) if any(s.n for s in systems) else np.zeros((0, 0))
    n = sum(s.n for s in systems)
    m = sum(s.m for s in systems)
    p = sum(s.p for s in systems)
    B = np.zeros((n, m))
    C = np.zeros((p, n))
    D = np.zeros((p, m))
    i = j = k = 0
    for s in systems:
        B[k : k + s.n, j : j + s.m] = s.B
        C[i : i + s.p, k : k + s.n] = s.C
        D[i : i + s.p, j : j + s.m] = s.D
        i, j, k = i + s.p, j + s.m, k + s.n
    return StateSpace(A.reshape(n, n), B, C, D)


def series(first: StateSpace, second: StateSpace) -> StateSpace:
    """``second`` driven by the output of ``first`` (``y = G2 G1 u``); state = ``[x1, x2]``."""
    if first.p != second.m:
        raise ModelError(f"series: first has {first.p} outputs, second has {second.m} inputs")
    n1, n2 = first.n, second.n
    A = np.block([[first.A, np.zeros((n1, n2))], [second.B @ first.C, second.A]])
    B = np.vstack([first.B, second.B @ first.D])
    C = np.hstack([second.D @ first.C, second.C])
    D = second.D @ first.D
    return StateSpace(A, B, C, D)


def feedback(plant: StateSpace, controller: StateSpace | ArrayLike, sign: float = -1.0) -> StateSpace:
    """Closed loop ``u = r + sign * K y`` around ``plant`` (negative feedback by default).

    Inputs are the references ``r`` (plant.m), outputs the plant outputs. Raises ModelError
    when ``I - sign D1 D2`` is singular (an algebraic loop without a solution).
    """
    ctrl = controller if isinstance(controller, StateSpace) else gain(controller)
    if ctrl.m != plant.p or ctrl.p != plant.m:
        raise ModelError("feedback: controller dimensions do not match the plant")
    A1, B1, C1, D1 = plant.A, plant.B, plant.C, plant.D
    A2, B2, C2, D2 = ctrl.A, ctrl.B, ctrl.C, ctrl.D
    E = np.eye(plant.m) - sign * D2 @ D1
    try:
        Einv = np.linalg.inv(E)
    except np.linalg.LinAlgError as exc:
        raise ModelError("feedback: ill-posed algebraic loop (I - D2 D1 singular)") from exc
    if np.linalg.cond(E) > 1e12:
        raise ModelError("feedback: ill-posed algebraic loop (I - D2 D1 nearly singular)")
    # u = Einv (r + sign (C2 x2 + D2 C1 x1))
    Ux1 = Einv @ (sign * D2 @ C1)
    Ux2 = Einv @ (sign * C2)
    Ur = Einv
    y_x1 = C1 + D1 @ Ux1
    y_x2 = D1 @ Ux2
    y_r = D1 @ Ur
    A = np.block([[A1 + B1 @ Ux1, B1 @ Ux2], [B2 @ y_x1, A2 + B2 @ y_x2]])
    B = np.vstack([B1 @ Ur, B2 @ y_r])
    C = np.hstack([y_x1, y_x2])
    return StateSpace(A, B, C, y_r)
