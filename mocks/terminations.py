"""Passive terminations attached to device ports: LTI impedances, wall springs and a human model.

Sign convention (used consistently by :mod:`hil.mocks.physics`)
-----------------------------------------------------------------
A termination sees the port velocity ``v`` (m/s or rad/s, a ``d``-vector) and exerts the force
``-Z(s) v`` ON the device (N or N.m). Equivalently the device exerts ``f = Z(s) v`` on the
termination, and ``v^T f`` is the power flowing INTO the termination. A passive termination
(``Z`` positive real) absorbs non-negative energy from rest: ``int_0^t v^T f dt >= 0``.

* :class:`Impedance` -- any proper LTI ``Z(s)`` (scalar or matrix) as a :class:`StateSpace` with
  input = port velocity, output = force on the termination. Its states are part of the scene.
* :class:`WallSpring` -- ``Z(s) = K/s + B``: springs (+dampers) from the port to a fixed wall whose
  rest position is port displacement 0 (body coordinates). Stamped into the scene's K and B
  matrices (position based, no extra state).
* :class:`Human` -- the arm's passive impedance ``Z_h(s) = m s + b + k/s`` (improper: the arm mass
  moves rigidly with the handle and is added to the scene's mass matrix; ``k`` anchors the hand
  to port displacement 0) plus a state-independent active force ``f_act(t)`` that pushes the
  device in its positive direction: the force on the device is ``f_act - Z_h(s) v``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from hil.errors import ModelError
from hil.lti import ArrayLike, StateSpace, TFEntry, tf_matrix

logger = logging.getLogger(__name__)

#: Active force profile: ``f(t) -> (d,)`` (t in s, N or N.m) or an array of per-tick samples
#: (shape ``(N,)`` for d = 1 or ``(N, d)``); after the last sample the force is zero.
ForceProfile = Callable[[float], ArrayLike] | np.ndarray


def _psd_matrix(value: ArrayLike, dim: int | None, name: str, *, definite: bool = False) -> np.ndarray:
    """Validate a symmetric positive semi-definite (or definite) matrix; scalars/vectors -> diagonal."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = arr * np.eye(dim or 1)
    elif arr.ndim == 1:
        arr = np.diag(arr)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ModelError(f"{name} must be a square matrix, got shape {arr.shape}")
    if dim is not None and arr.shape[0] != dim:
        raise ModelError(f"{name} is {arr.shape[0]}x{arr.shape[0]}, the port has {dim} DOF")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} contains non-finite entries")
    scale = max(float(np.max(np.abs(arr))), np.finfo(float).tiny)
    if not np.allclose(arr, arr.T, rtol=0.0, atol=1e-12 * scale):
        raise ModelError(f"{name} must be symmetric")
    arr = 0.5 * (arr + arr.T)
    if definite:
        try:
            np.linalg.cholesky(arr)
        except np.linalg.LinAlgError as exc:
            raise ModelError(f"{name} must be positive definite") from exc
        return arr
    eig_min = float(np.min(np.linalg.eigvalsh(arr))) if arr.size else 0.0
    if eig_min < -1e-12 * scale:
        raise ModelError(f"{name} must be positive semi-definite (smallest eigenvalue {eig_min:.3g})")
    return arr


@dataclass(frozen=True)
class Impedance:
    """A proper LTI impedance ``Z(s)``: input port velocity (d), output force on the termination (d)."""

    system: StateSpace
    name: str = "impedance"

    def __post_init__(self) -> None:
        if self.system.m != self.system.p:
            raise ModelError(f"impedance {self.name!r} must be square, got {self.system.p}x{self.system.m}")

    @property
    def dim(self) -> int:
        """Port dimension d."""
        return self.system.m

    @classmethod
    def from_tf(cls, entries: Sequence[Sequence[TFEntry]], name: str = "impedance") -> Impedance:
        """From a transfer matrix ``entries[i][j] = (num, den)`` (see :func:`hil.lti.tf_matrix`)."""
        return cls(tf_matrix(entries), name)


@dataclass(frozen=True)
class WallSpring:
    """Springs ``stiffness`` (N/m) and dampers ``damping`` (N.s/m) from the port to a fixed wall.

    Scalars apply to every port DOF; matrices (symmetric PSD) couple them. Rest at port
    displacement 0. Force on the device: ``-(K x + B v)``.
    """

    stiffness: ArrayLike
    damping: ArrayLike = 0.0
    dim: int | None = None
    name: str = "wall"

    def matrices(self, dim: int) -> tuple[np.ndarray, np.ndarray]:
        """Validated ``(K, B)`` for a port of ``dim`` DOF."""
        if self.dim is not None and self.dim != dim:
            raise ModelError(f"wall {self.name!r} has {self.dim} DOF, the port has {dim}")
        return (_psd_matrix(self.stiffness, dim, f"{self.name} stiffness"),
                _psd_matrix(self.damping, dim, f"{self.name} damping"))


@dataclass(frozen=True)
class Human:
    """Human arm: passive mass/damping/stiffness (scalars or d x d PSD) plus an active force.

    ``active`` is a :data:`ForceProfile` or ``None`` (no active force). The hand's anchor (rest of
    ``stiffness``) is port displacement 0.
    """

    mass: ArrayLike = 0.0
    damping: ArrayLike = 0.0
    stiffness: ArrayLike = 0.0
    active: ForceProfile | None = field(default=None, compare=False)
    name: str = "human"

    def matrices(self, dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Validated ``(m, b, k)`` matrices for a port of ``dim`` DOF."""
        return (_psd_matrix(self.mass, dim, f"{self.name} mass"),
                _psd_matrix(self.damping, dim, f"{self.name} damping"),
                _psd_matrix(self.stiffness, dim, f"{self.name} stiffness"))


Termination = Impedance | WallSpring | Human


def profile_value(profile: ForceProfile | None, t: float, k: int, dim: int) -> np.ndarray:
    """Value of a force profile at tick ``k`` (time ``t`` = k dt, s); zeros past an array's end."""
    if profile is None:
        return np.zeros(dim)
    if callable(profile):
        out = np.asarray(profile(t), dtype=float).reshape(-1)
    else:
        arr = np.asarray(profile, dtype=float)
        arr = arr.reshape(-1, 1) if arr.ndim == 1 else arr
        out = arr[k] if k < arr.shape[0] else np.zeros(arr.shape[1])
    if out.size == 1 and dim > 1:
        out = np.full(dim, float(out[0]))
    if out.size != dim:
        raise ModelError(f"active force profile gives {out.size} values, the port has {dim} DOF")
    return out


# ----------------------------------------------------------------------------------------------
# Ready-made terminations
# ----------------------------------------------------------------------------------------------


def t2_termination() -> Impedance:
    """The passive 3x3 termination ``T2(s)`` of the reference paper.

    ``T2(s) = [[9/(s+1), -2/(s+2), -1/(s+3)], [-2/(s+2), 5/(s+1), 2/(s+1)],
    [-1/(s+3), 2/(s+1), 4/(s+1)]]`` (N.s/m per entry, velocity -> force).
    """
    p1, p2, p3 = [1.0, 1.0], [1.0, 2.0], [1.0, 3.0]
    entries = [
        [([9.0], p1), ([-2.0], p2), ([-1.0], p3)],
        [([-2.0], p2), ([5.0], p1), ([2.0], p1)],
        [([-1.0], p3), ([2.0], p1), ([4.0], p1)],
    ]
    return Impedance.from_tf(entries, name="T2")


def spring_array_wall(
    stiffness: ArrayLike = (1e4, 1e4), damping: ArrayLike = (0.0, 0.0), coupling: float = 0.0
) -> WallSpring:
    """A 2x2 array of springs to a stiff wall: diagonal ``stiffness`` (N/m) and ``damping``
    (N.s/m) per axis plus an optional spring ``coupling`` (N/m) between the two axes.

    ``K = diag(k) + coupling * [[1, -1], [-1, 1]]`` (PSD for ``coupling >= 0``).
    """
    k = np.diag(np.asarray(stiffness, dtype=float).reshape(2))
    k = k + coupling * np.array([[1.0, -1.0], [-1.0, 1.0]])
    b = np.diag(np.asarray(damping, dtype=float).reshape(2))
    return WallSpring(k, b, dim=2, name="spring_array_wall")


def passivity_margin(Z: StateSpace, w: ArrayLike) -> float:
    """Smallest eigenvalue of the Hermitian part ``(Z(jw) + Z(jw)^H) / 2`` over the grid ``w``.

    Non-negative on a dense grid (plus stable poles) is the frequency-domain test for positive
    realness of an impedance.
    """
    G = Z.freqresp(w)
    herm = 0.5 * (G + np.conj(np.transpose(G, (0, 2, 1))))
    return float(np.min(np.linalg.eigvalsh(herm)))


def absorbed_energy(Z: StateSpace, v: ArrayLike, dt: float) -> np.ndarray:
    """Energy (J) absorbed by impedance ``Z`` from rest for the port velocity samples ``v``.

    ``v`` (shape ``(N, d)``) is taken piecewise linear between samples (exact first-order-hold
    discretization of ``Z``); the power ``v^T f`` is integrated with the trapezoidal rule.
    Returns the cumulative energy at each sample.
    """
    v_arr = np.asarray(v, dtype=float)
    v_arr = v_arr.reshape(-1, 1) if v_arr.ndim == 1 else v_arr
    _, f = Z.discretize(dt, "foh").simulate(v_arr)
    power = np.sum(v_arr * f, axis=1)
    energy = np.concatenate([[0.0], np.cumsum(0.5 * (power[1:] + power[:-1]) * dt)])
    return energy
