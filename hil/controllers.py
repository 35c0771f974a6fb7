"""Discrete-time controllers the runner composes (``docs/RUNNER_SPEC.md``).

Every controller maps the latest measurements to actuator efforts once per control period::

    u = controller.update(t, dt, meas)      # {actuator device name: effort (dof,) in N or N.m}
    controller.reset()                      # back to the initial (rest) state

The effort is applied by the bench over the next period (zero-order hold), so a continuous-time
law ``C(s)`` is realized with an unavoidable half-sample average delay ``e^{-sT/2}`` (T = dt);
the tests compare the closed loop with the papers' continuous network models at frequencies
where ``ωT/2`` is small, and attribute the residual to that delay.

Units and signs
---------------
SI throughout: positions m or rad, velocities m/s or rad/s, efforts N or N.m (``units`` =
``linear`` or ``rotary`` only changes the names in messages). As in ``protocols/base.py`` a
positive effort accelerates a joint in its positive direction. Gains: ``Kp`` in N/m (N.m/rad),
``Kv`` in N.s/m (N.m.s/rad); scalars mean ``k * I``, vectors ``diag(k)``, nested lists matrices.

Position-position controllers (papers 000, 001)
-----------------------------------------------
The papers write a PD position controller as a PI *velocity* controller ``C = (k_p + k_v s)/s``
acting on velocities; with positions measured from the rest configuration (``x = v/s``) this is
``C v = k_p x + k_v v``. All three teleoperation laws are therefore one linear map on the stacked
coordinates ``q`` (positions of all devices) and ``v`` (velocities)::

    u = -(Kp q + Kv v)          (PositionPD)

with block gain matrices chosen so that the closed-loop network matrix is exactly the paper's
``Z_robots(s) + C(s)``, ``C(s) = (Kp + Kv s)/s``. A positive position error of a device w.r.t. its
partner produces a restoring (negative) effort on it.

* ``pd_position_position`` (000 eq. 42-43): ``q = [x_m; x_s]``,
  ``F_m = -Kp_m (x_m - x_s) - Kv_m (v_m - v_s)``, ``F_s = -Kp_s (x_s - x_m) - Kv_s (v_s - v_m)``.
* ``mcet`` (000 eq. 21-25, dual-user four-channel, position-position case ``c1 = c_s``,
  ``c4mi = -c_mi``, ``c2 = c3 = c5 = c6 = 0``). Eq. (22)-(23) give the control forces
  ``f_cm1 = -c_m1 v_h1 - c_4m1 v_h2 = -c_m1 (v_h1 - v_h2)``, ``f_cm2 = -c_m2 (v_h2 - v_h1)``,
  ``f_cs = -c_s v_e + c_1 (α v_h1 + (1-α) v_h2) = -c_s (v_e - α v_h1 - (1-α) v_h2)``; with
  ``c = (k_p + k_v s)/s`` on velocities these are PD laws on positions:
  ``F_m1 = -k_pm1 (x_1 - x_2) - k_vm1 (v_1 - v_2)``, ``F_m2 = -k_pm2 (x_2 - x_1) - k_vm2 (v_2 - v_1)``,
  ``F_s = -k_ps (x_s - α x_1 - (1-α) x_2) - k_vs (v_s - α v_1 - (1-α) v_2)``.
  Substituting into the robots ``Z_i v_i = F_i + f_ci`` reproduces eq. (25) row by row
  (``F_h1 = (c_m1 + Z_m1) v_h1 - c_m1 v_h2`` etc.). Note that in this special case the masters are
  coupled to each other, not to the slave; the slave follows the authority-weighted masters.
* ``dual_master`` (001 eq. 15): ``F_cm = -C_m V_h + C_4 V_e``, ``F_cs = -C_s V_e + C_1 V_h`` with
  ``V_h`` the masters' velocities stacked in the slave's DOF order (master 1 -> x, master 2 ->
  y, z by default: ``masters: [{name: m1, dofs: [0]}, {name: m2, dofs: [1, 2]}]``) and every
  ``C = (Kp + Kv s)/s`` a matrix; i.e. ``Kp = [[Kp_m, -Kp_4], [-Kp_1, Kp_s]]``.

SDEA velocity-sourced impedance control (paper 002)
---------------------------------------------------
See :class:`VSIC` for the block diagram and its equivalence with eq. (12).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from hil.errors import SceneError
from hil.protocols.base import JointSample, WrenchSample

logger = logging.getLogger(__name__)

__all__ = [
    "VSIC",
    "Controller",
    "Measurements",
    "NullController",
    "PositionPD",
    "dual_master_controller",
    "make_controller",
    "mcet_controller",
    "pd_position_position",
    "vsic_controller",
]

DeviceSample = JointSample | WrenchSample
Measurements = Mapping[str, DeviceSample]


@runtime_checkable
class Controller(Protocol):
    """What the runner calls once per control period."""

    def reset(self) -> None:
        """Back to the initial state (integrators, virtual environment at rest)."""

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        """Efforts (N or N.m) per actuator device for the period starting at ``t`` (s)."""


# ---------------------------------------------------------------------------------------------
# helpers


def _field(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def gain_matrix(value: Any, dof: int | None, field: str) -> np.ndarray:
    """A ``dof x dof`` gain matrix from a scalar (``k I``), a vector (``diag``) or a matrix.

    Raises :class:`SceneError` naming ``field`` for wrong shapes or non-finite entries. With
    ``dof=None`` a scalar gives a 1x1 matrix.
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{field}: not a number or matrix ({value!r})") from exc
    if arr.ndim == 0:
        arr = float(arr) * np.eye(dof or 1)
    elif arr.ndim == 1:
        arr = np.diag(arr)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise SceneError(f"{field}: must be a scalar, a vector or a square matrix, got shape {arr.shape}")
    if dof is not None and arr.shape[0] != dof:
        raise SceneError(f"{field}: is {arr.shape[0]}x{arr.shape[1]}, expected {dof}x{dof}")
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{field}: non-finite entries")
    return arr


def _infer_dof(cfg: Mapping[str, Any], keys: Sequence[str]) -> int:
    """DOF from ``cfg['dof']`` or from the first non-scalar gain among ``keys`` (default 1)."""
    if "dof" in cfg:
        return int(cfg["dof"])
    for k in keys:
        if k in cfg:
            arr = np.asarray(cfg[k], dtype=float)
            if arr.ndim >= 1:
                return int(arr.shape[0])
    return 1


def _check_keys(cfg: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(cfg) - allowed - {"type"})
    if unknown:
        raise SceneError(f"{where}: unknown field(s) {', '.join(unknown)}; allowed: {', '.join(sorted(allowed))}")


def _require(cfg: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in cfg or cfg[key] is None:
        raise SceneError(f"{_field(where, key)}: required")
    return cfg[key]


def _joint(meas: Measurements, name: str, field: str) -> JointSample:
    try:
        s = meas[name]
    except KeyError as exc:
        raise SceneError(f"{field}: no measurement from device {name!r} (have {sorted(meas)})") from exc
    if not isinstance(s, JointSample):
        raise SceneError(f"{field}: device {name!r} is not an actuator (got {type(s).__name__})")
    return s


# ---------------------------------------------------------------------------------------------
# none


class NullController:
    """``type: none``: zero effort on every actuator present in the measurements."""

    name = "none"

    def reset(self) -> None:
        """Nothing to reset."""

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        return {k: np.zeros(np.asarray(s.position).size) for k, s in meas.items() if isinstance(s, JointSample)}


# ---------------------------------------------------------------------------------------------
# position-position PD family


class PositionPD:
    """``u = -(Kp q + Kv v)`` on coordinates stacked from several devices.

    ``layout``: ``[(device, stack indices), ...]``: device ``i``'s DOF ``j`` sits at
    ``q[idx_i[j]]`` and receives ``u[idx_i[j]]``. ``Kp`` (N/m or N.m/rad) and ``Kv`` (N.s/m or
    N.m.s/rad) are ``n x n``. Stateless (a static map of the sampled positions/velocities); the
    continuous equivalent is ``C(s) = (Kp + Kv s)/s`` acting on velocities (module doc).
    """

    def __init__(self, name: str, layout: Sequence[tuple[str, Sequence[int]]], Kp: np.ndarray, Kv: np.ndarray,
                 where: str = "controller") -> None:
        self.name = name
        self.layout = [(dev, np.asarray(idx, dtype=int)) for dev, idx in layout]
        self.n = int(sum(idx.size for _, idx in self.layout))
        covered = np.sort(np.concatenate([idx for _, idx in self.layout])) if self.layout else np.zeros(0)
        if not np.array_equal(covered, np.arange(self.n)):
            raise SceneError(f"{where}: device DOF maps must cover stack indices 0..{self.n - 1} exactly once "
                             f"(got {[idx.tolist() for _, idx in self.layout]})")
        self.Kp = gain_matrix(Kp, self.n, f"{where}: Kp (stacked)")
        self.Kv = gain_matrix(Kv, self.n, f"{where}: Kv (stacked)")
        self.where = where

    def reset(self) -> None:
        """Stateless: nothing to reset."""

    def stack(self, meas: Measurements) -> tuple[np.ndarray, np.ndarray]:
        """Stacked positions and velocities from the devices' :class:`JointSample`s."""
        q = np.zeros(self.n)
        v = np.zeros(self.n)
        for dev, idx in self.layout:
            s = _joint(meas, dev, self.where)
            pos = np.asarray(s.position, dtype=float).reshape(-1)
            vel = np.asarray(s.velocity, dtype=float).reshape(-1)
            if pos.size != idx.size or vel.size != idx.size:
                raise SceneError(f"{self.where}: device {dev!r} reports {pos.size} DOF, the controller "
                                 f"expects {idx.size}")
            q[idx] = pos
            v[idx] = vel
        return q, v

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        q, v = self.stack(meas)
        u = -(self.Kp @ q + self.Kv @ v)
        return {dev: u[idx].copy() for dev, idx in self.layout}


def pd_position_position(cfg: Mapping[str, Any], where: str = "controller") -> PositionPD:
    """Paper 000 eq. (42)-(43): ``Kp = [[Kp_m, -Kp_m], [-Kp_s, Kp_s]]`` (same for ``Kv``)."""
    keys = ["Kp_m", "Kv_m", "Kp_s", "Kv_s"]
    _check_keys(cfg, {"master", "slave", "dof", *keys}, where)
    master, slave = str(_require(cfg, "master", where)), str(_require(cfg, "slave", where))
    d = _infer_dof(cfg, keys)
    Kp_m, Kv_m, Kp_s, Kv_s = (gain_matrix(_require(cfg, k, where), d, _field(where, k)) for k in keys)
    Kp = np.block([[Kp_m, -Kp_m], [-Kp_s, Kp_s]])
    Kv = np.block([[Kv_m, -Kv_m], [-Kv_s, Kv_s]])
    return PositionPD("pd_position_position", [(master, range(d)), (slave, range(d, 2 * d))], Kp, Kv, where)


class FourChannelMCET:
    """Dual-user MCET four-channel law of paper 000, eq. (22)-(23), in the time domain.

    With the position controllers ``c = (k_p + k_v s)/s`` acting on velocities (PD on positions,
    written ``c[q]`` = k_p q + k_v v) and static force gains::

        f_cm1 = -c_m1[q_1] - c_4m1[q_2] + c_6m1 f_h1 - c_2m1 f_e / 2
        f_cm2 = -c_m2[q_2] - c_4m2[q_1] + c_6m2 f_h2 - c_2m2 f_e / 2
        f_cs  = -c_s[q_e] + c_1[α q_1 + (1-α) q_2] - c_5 f_e + c_3 (α f_h1 + (1-α) f_h2)

    (v_h1d = v_h2, v_h2d = v_h1, v_ed = α v_h1 + (1-α) v_h2, f_hid = f_e/2, f_ed = α f_h1 + (1-α) f_h2).
    ``f_hi``: force of user i on master i (positive along its velocity); ``f_e``: force of the
    environment on the slave. The position part is a :class:`PositionPD` on the stacked
    coordinates; the force part needs force sensors (``force_sensors``) when any force gain is
    non-zero. Position-position control is the special case c_4mi = -c_mi, c_1 = c_s, force gains 0
    (eq. 25).
    """

    def __init__(self, pd: PositionPD, force_gain: np.ndarray, sensors: Sequence[str | None],
                 signs: Sequence[float], axes: Sequence[Sequence[int] | None], d: int) -> None:
        self.name = "mcet"
        self.pd = pd
        self.G = force_gain  # (3d, 3d): u_force = G @ [f_h1; f_h2; f_e]
        self.sensors, self.signs, self.axes, self.d = list(sensors), list(signs), list(axes), d
        self.uses_force = bool(np.any(self.G))

    def reset(self) -> None:
        self.pd.reset()

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        out = self.pd.update(t, dt, meas)
        if not self.uses_force:
            return out
        f = np.zeros(3 * self.d)
        for k, (sensor, sign, axes) in enumerate(zip(self.sensors, self.signs, self.axes, strict=True)):
            if sensor is None:
                continue
            w = np.asarray(meas[sensor].wrench, dtype=float).reshape(-1)
            w = w[list(axes)] if axes is not None else w[: self.d]
            f[k * self.d:(k + 1) * self.d] = sign * w
        uf = self.G @ f
        for dev, idx in self.pd.layout:
            out[dev] = out[dev] + uf[idx]
        return out


def mcet_controller(cfg: Mapping[str, Any], where: str = "controller") -> FourChannelMCET:
    """Paper 000 eq. (21)-(25): the dual-user MCET four-channel controller (:class:`FourChannelMCET`).

    Fields: ``masters: [m1, m2]``, ``slave``, ``alpha`` ∈ [0, 1] (user 1's authority),
    ``k_pm1, k_vm1, k_pm2, k_vm2, k_ps, k_vs`` (local PD gains); optional channels
    ``k_p4m1, k_v4m1, k_p4m2, k_v4m2`` (default -k_pm1, -k_vm1, ...: position-position),
    ``k_p1, k_v1`` (default k_ps, k_vs), force gains ``c2m1, c2m2, c3, c5, c6m1, c6m2`` (default 0),
    ``force_sensors: {master1, master2, slave}`` (device names; required with force gains),
    ``force_axes`` (same keys, wrench components), ``slave_force_sign`` (default -1: the slave
    sensor reports the force the slave exerts on the environment, f_e is its negative), ``dof``.
    """
    keys = ["k_pm1", "k_vm1", "k_pm2", "k_vm2", "k_ps", "k_vs"]
    opt = ["k_p4m1", "k_v4m1", "k_p4m2", "k_v4m2", "k_p1", "k_v1"]
    forces = ["c2m1", "c2m2", "c3", "c5", "c6m1", "c6m2"]
    _check_keys(cfg, {"masters", "slave", "alpha", "dof", "force_sensors", "force_axes", "slave_force_sign",
                      *keys, *opt, *forces}, where)
    masters = _require(cfg, "masters", where)
    if isinstance(masters, str) or len(masters) != 2:
        raise SceneError(f"{_field(where, 'masters')}: exactly two master device names required")
    m1, m2 = (str(m) for m in masters)
    slave = str(_require(cfg, "slave", where))
    a = float(cfg.get("alpha", 0.5))
    if not 0.0 <= a <= 1.0:
        raise SceneError(f"{_field(where, 'alpha')}: must lie in [0, 1], got {a}")
    d = _infer_dof(cfg, keys)
    kp1, kv1, kp2, kv2, kps, kvs = (gain_matrix(_require(cfg, k, where), d, _field(where, k)) for k in keys)

    def opt_gain(key: str, default: np.ndarray) -> np.ndarray:
        return default if cfg.get(key) is None else gain_matrix(cfg[key], d, _field(where, key))

    kp4m1, kv4m1 = opt_gain("k_p4m1", -kp1), opt_gain("k_v4m1", -kv1)
    kp4m2, kv4m2 = opt_gain("k_p4m2", -kp2), opt_gain("k_v4m2", -kv2)
    kpc1, kvc1 = opt_gain("k_p1", kps), opt_gain("k_v1", kvs)
    Z = np.zeros((d, d))

    def block(cm1: np.ndarray, c4m1: np.ndarray, cm2: np.ndarray, c4m2: np.ndarray, c1: np.ndarray,
              cs: np.ndarray) -> np.ndarray:
        # u = -(K q): row i of K holds the channels acting on master i / the slave
        return np.block([[cm1, c4m1, Z], [c4m2, cm2, Z], [-a * c1, -(1 - a) * c1, cs]])

    layout = [(m1, range(d)), (m2, range(d, 2 * d)), (slave, range(2 * d, 3 * d))]
    pd = PositionPD("mcet", layout, block(kp1, kp4m1, kp2, kp4m2, kpc1, kps),
                    block(kv1, kv4m1, kv2, kv4m2, kvc1, kvs), where)
    g = {k: float(cfg.get(k) or 0.0) for k in forces}
    I_ = np.eye(d)
    G = np.block([[g["c6m1"] * I_, Z, -0.5 * g["c2m1"] * I_],
                  [Z, g["c6m2"] * I_, -0.5 * g["c2m2"] * I_],
                  [a * g["c3"] * I_, (1 - a) * g["c3"] * I_, -g["c5"] * I_]])
    fs = cfg.get("force_sensors") or {}
    fa = cfg.get("force_axes") or {}
    sensors = [fs.get("master1"), fs.get("master2"), fs.get("slave")]
    needs = [bool(g["c6m1"] or g["c3"]), bool(g["c6m2"] or g["c3"]), bool(g["c2m1"] or g["c2m2"] or g["c5"])]
    for name, s_, need in zip(("master1", "master2", "slave"), sensors, needs, strict=True):
        if need and not s_:
            raise SceneError(f"{_field(where, 'force_sensors')}: the force gains need a {name!r} force sensor")
    signs = [1.0, 1.0, float(cfg.get("slave_force_sign", -1.0))]
    axes = [fa.get("master1"), fa.get("master2"), fa.get("slave")]
    return FourChannelMCET(pd, G, sensors, signs, axes, d)


def _pair(cfg: Mapping[str, Any], tag: str, n: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Gains of ``C_<tag>``: ``C_<tag>: {kp, kv}`` or flat ``Kp_<tag>``/``Kv_<tag>``."""
    nested = cfg.get(f"C_{tag}")
    if nested is not None:
        f = _field(where, f"C_{tag}")
        if not isinstance(nested, Mapping):
            raise SceneError(f"{f}: must be a mapping {{kp: ..., kv: ...}}")
        low = {str(k).lower(): v for k, v in nested.items()}
        return (gain_matrix(_require(low, "kp", f), n, f"{f}.kp"), gain_matrix(_require(low, "kv", f), n, f"{f}.kv"))
    return (gain_matrix(_require(cfg, f"Kp_{tag}", where), n, _field(where, f"Kp_{tag}")),
            gain_matrix(_require(cfg, f"Kv_{tag}", where), n, _field(where, f"Kv_{tag}")))


def dual_master_controller(cfg: Mapping[str, Any], where: str = "controller") -> PositionPD:
    """Paper 001 eq. (15) with matrix PD gains (module doc).

    ``masters``: ``[{device: m1, slave_dofs: [0]}, {device: m2, slave_dofs: [1, 2]}]`` (as in
    :mod:`hil.scene`; ``{name, dofs}`` is accepted too) (slave DOF indices each
    master's DOFs map to; together they must cover the slave's DOFs exactly once), or names with
    ``master_dofs: [[0], [1, 2]]``. Gains ``C_m, C_4, C_s, C_1`` as ``{kp, kv}`` mappings or flat
    ``Kp_m, Kv_m, Kp_4, ...``, all ``n x n`` with ``n`` the slave's DOF count (default 3).
    """
    tags = ("m", "4", "s", "1")
    allowed = {"masters", "master_dofs", "slave", "dof", *(f"C_{t}" for t in tags),
               *(f"K{x}_{t}" for t in tags for x in "pv")}
    _check_keys(cfg, allowed, where)
    masters = _require(cfg, "masters", where)
    names: list[str] = []
    maps: list[list[int]] = []
    if isinstance(masters, str) or not isinstance(masters, Sequence):
        raise SceneError(f"{_field(where, 'masters')}: a list of master devices required")
    for i, m in enumerate(masters):
        if isinstance(m, Mapping):
            fm = _field(where, f"masters[{i}]")
            name_key = "device" if "device" in m else "name"  # hil.scene: {device, slave_dofs}
            dofs_key = "slave_dofs" if "slave_dofs" in m else "dofs"
            names.append(str(_require(m, name_key, fm)))
            maps.append([int(j) for j in _require(m, dofs_key, fm)])
        else:
            names.append(str(m))
    if not maps:
        md = cfg.get("master_dofs", [[0], [1, 2]] if len(names) == 2 else None)
        if md is None or len(md) != len(names):
            raise SceneError(f"{_field(where, 'master_dofs')}: one DOF list per master required")
        maps = [[int(j) for j in row] for row in md]
    n = int(cfg.get("dof", sum(len(m) for m in maps)))
    slave = str(_require(cfg, "slave", where))
    Kp_m, Kv_m = _pair(cfg, "m", n, where)
    Kp_4, Kv_4 = _pair(cfg, "4", n, where)
    Kp_s, Kv_s = _pair(cfg, "s", n, where)
    Kp_1, Kv_1 = _pair(cfg, "1", n, where)
    Kp = np.block([[Kp_m, -Kp_4], [-Kp_1, Kp_s]])
    Kv = np.block([[Kv_m, -Kv_4], [-Kv_1, Kv_s]])
    layout = [(nm, mp) for nm, mp in zip(names, maps, strict=True)] + [(slave, range(n, 2 * n))]
    return PositionPD("dual_master", layout, Kp, Kv, where)


# ---------------------------------------------------------------------------------------------
# SDEA: velocity-sourced impedance control with a virtual coupler


class _Trapezoid:
    """Linear ODE ``x' = A x + B u``, ``y = C x + D u`` integrated with the trapezoidal rule
    (Tustin: A-stable, maps a passive continuous impedance to a passive discrete one)."""

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> None:
        self.A, self.B, self.C, self.D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (A, B, C, D))
        self.n = self.A.shape[0] if self.A.size else 0
        self.x = np.zeros(self.n)
        self.u_prev: np.ndarray | None = None
        self._dt = -1.0

    def reset(self) -> None:
        self.x = np.zeros(self.n)
        self.u_prev = None

    def step(self, u: np.ndarray, dt: float) -> np.ndarray:
        if self.n == 0:
            return self.D @ u
        if self.u_prev is None:
            # start at the equilibrium for the first input (no kick from the initial offset)
            try:
                self.x = -np.linalg.solve(self.A, self.B @ u)
            except np.linalg.LinAlgError:
                self.x = np.zeros(self.n)
            self.u_prev = u.copy()
        if dt != self._dt:
            eye = np.eye(self.n)
            self._lhs = np.linalg.inv(eye - 0.5 * dt * self.A)
            self._rhs = eye + 0.5 * dt * self.A
            self._dt = dt
        self.x = self._lhs @ (self._rhs @ self.x + 0.5 * dt * (self.B @ (u + self.u_prev)))
        self.u_prev = u.copy()
        return self.C @ self.x + self.D @ u


class _TrapezoidPI:
    """``y = P e + I ∫ e dt`` with the integral by the trapezoidal rule (Tustin ``T/2 (z+1)/(z-1)``)."""

    def __init__(self, P: float, I: float) -> None:
        self.P, self.I = float(P), float(I)
        self.reset()

    def reset(self) -> None:
        self.z = 0.0
        self.e_prev: float | None = None

    def step(self, e: float, dt: float) -> float:
        prev = e if self.e_prev is None else self.e_prev
        # first sample: (e + e)/2 * dt would integrate an error from before the start; use 0
        self.z += 0.0 if self.e_prev is None else 0.5 * dt * (e + prev)
        self.e_prev = e
        return self.P * e + self.I * self.z


def virtual_environment(k22: float, b22: float, k: float = 0.0, b: float = 0.0,
                        m: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """State space of virtual coupler (``k22``, ``b22``) + virtual environment (mass ``m``, damper
    ``b``, spring ``k`` to its rest at 0) driven by the output position/velocity ``u = [x_o, v_o]``;
    output the coupler force on the output ``F_ref = k22 (x_ve - x_o) + b22 (v_ve - v_o)``.

    ``m > 0``: states ``[x_ve, v_ve]``, ``m a_ve = -F_ref - k x_ve - b v_ve``. ``m = 0`` and
    ``b + b22 > 0``: state ``x_ve``, ``(b + b22) v_ve = k22 x_o + b22 v_o - (k + k22) x_ve``.
    Otherwise static: ``F_ref = -k k22/(k + k22) x_o`` (zero when both are zero).
    """
    if m > 0:
        A = np.array([[0.0, 1.0], [-(k + k22) / m, -(b + b22) / m]])
        B = np.array([[0.0, 0.0], [k22 / m, b22 / m]])
        C = np.array([[k22, b22]])
        D = np.array([[-k22, -b22]])
        return A, B, C, D
    bt = b + b22
    if bt > 0:
        # v_ve = (k22 x_o + b22 v_o - (k + k22) x_ve)/bt
        A = np.array([[-(k + k22) / bt]])
        B = np.array([[k22 / bt, b22 / bt]])
        C = np.array([[k22 + b22 * A[0, 0]]])
        D = np.array([[-k22 + b22 * B[0, 0], -b22 + b22 * B[0, 1]]])
        return A, B, C, D
    kt = k + k22
    keq = k * k22 / kt if kt > 0 else 0.0
    return np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), np.array([[-keq, 0.0]])


class VSIC:
    """Velocity-sourced impedance control of a series damped elastic actuator (paper 002).

    Block diagram implemented (one DOF; rotary units N.m, rad, rad/s by default)::

        x_o, v_o (output) ─► [virtual coupler k22, b22 + virtual environment] ─► F_ref (+ F_d(t))
        F_ref - F ─► C_f = P_f + I_f/s ─► v_ref
        v_ref - v_m ─► C_m = P_m + I_m/s ─► τ_fb
        τ = τ_fb + (1 - α) F                          (feed-forward of the interaction force)

    with ``F`` the measured series-spring force ``F = K_f (x_m - x_o) + B_f (v_m - v_o)`` (force
    sensor, or the actuator's effort channel), ``v_m`` the motor velocity. The motor obeys
    ``M s v_m = τ - B v_m - F``, so ``(M s + B + C_m) v_m = C_m C_f F_ref - (C_m C_f + α) F``: the
    feed-forward turns the "+1" (spring reaction) of ``(C_m C_f + 1)`` into ``α``. Eliminating
    ``v_m`` with ``F = (K_f + B_f s)/s (v_m - v_o)`` and multiplying by ``s³`` gives eq. (12a)::

        F = h11 (-v_o) + h12 F_ref,   a(s) = s²(Ms² + (B+P_m)s + I_m) + (K_f + B_f s)((P_m s + I_m)(P_f s + I_f) + α s²)
        h11 = s (K_f + B_f s)(M s² + (B + P_m) s + I_m)/a(s),   h12 = (K_f + B_f s)(P_m s + I_m)(P_f s + I_f)/a(s)

    and the virtual coupler ``F_ref = (k22/s + b22)(v_ve - v_o)`` is eq. (12b) (``v_ve = v_o + h22
    F_ref``, ``h22 = s/(b22 s + k22)``) with the virtual environment terminating port 2
    (``F_ref = -Z_env v_ve``). A disturbance torque ``d`` added to ``τ`` (e.g. an effort
    excitation) reaches the locked-output force as ``F/d = s² (K_f + B_f s)/a(s)``.

    Discretization at the control period T: both PI integrals and the coupler/environment ODE use
    the trapezoidal rule (Tustin; A-stable, passivity-preserving for the virtual environment);
    ``τ`` is computed from the samples at ``t_k`` and held over ``[t_k, t_k + T)``.
    """

    name = "vsic"

    def __init__(self, actuator: str, *, P_m: float, I_m: float, P_f: float, I_f: float, alpha: float = 1.0,
                 k22: float, b22: float, environment: Mapping[str, Any] | None = None,
                 force_sensor: str | None = None, force_axis: int = 0, force_sign: float = 1.0,
                 output: str | None = None, force_reference: Callable[[float], float] | None = None,
                 where: str = "controller") -> None:
        self.actuator = actuator
        self.force_sensor = force_sensor
        self.force_axis = int(force_axis)
        self.force_sign = float(force_sign)
        self.output = output
        self.alpha = float(alpha)
        self.where = where
        for key, val in {"P_m": P_m, "I_m": I_m, "P_f": P_f, "I_f": I_f, "k22": k22, "b22": b22}.items():
            if not math.isfinite(float(val)) or float(val) < 0:
                raise SceneError(f"{_field(where, key)}: must be finite and non-negative, got {val!r}")
        if not 0.0 <= self.alpha <= 1.0:
            raise SceneError(f"{_field(where, 'alpha')}: must lie in [0, 1], got {alpha}")
        if k22 == 0 and b22 == 0:
            raise SceneError(f"{_field(where, 'k22')}: the virtual coupler needs k22 > 0 or b22 > 0")
        env = dict(environment or {"type": "none"})
        etype = str(env.pop("type", "spring"))
        allowed = {"none": set(), "spring": {"k", "b"}, "spring_damper": {"k", "b"},
                   "mass_spring_damper": {"m", "k", "b"}}
        if etype not in allowed:
            raise SceneError(f"{_field(where, 'environment.type')}: one of {sorted(allowed)}, got {etype!r}")
        bad = set(env) - allowed[etype]
        if bad:
            raise SceneError(f"{_field(where, 'environment')}: unknown field(s) {sorted(bad)} for {etype}")
        ev = {k: float(v) for k, v in env.items()}
        if any(v < 0 or not math.isfinite(v) for v in ev.values()):
            raise SceneError(f"{_field(where, 'environment')}: parameters must be finite and non-negative")
        self.environment = {"type": etype, **ev}
        self.k22, self.b22 = float(k22), float(b22)
        self._env_free = etype == "none"
        self._env = _Trapezoid(*virtual_environment(self.k22, self.b22, ev.get("k", 0.0), ev.get("b", 0.0),
                                                    ev.get("m", 0.0)))
        self._pf = _TrapezoidPI(P_f, I_f)
        self._pm = _TrapezoidPI(P_m, I_m)
        self.params = {"P_m": float(P_m), "I_m": float(I_m), "P_f": float(P_f), "I_f": float(I_f),
                       "alpha": self.alpha, "k22": self.k22, "b22": self.b22}
        self.force_reference = force_reference
        self.last: dict[str, float] = {}

    def reset(self) -> None:
        """Integrators and the virtual environment back to rest."""
        self._env.reset()
        self._pf.reset()
        self._pm.reset()
        self.last = {}

    def spring_force(self, meas: Measurements) -> float:
        """Measured series-spring force F (N or N.m): ``force_sign * wrench[force_axis]`` of the
        force sensor, or the actuator's effort channel when no sensor is configured."""
        if self.force_sensor is not None:
            s = meas.get(self.force_sensor)
            if not isinstance(s, WrenchSample):
                raise SceneError(f"{_field(self.where, 'force_sensor')}: no wrench from {self.force_sensor!r}")
            w = np.asarray(s.wrench, dtype=float).reshape(-1)
            if w.size <= self.force_axis and w.size != 1:
                raise SceneError(f"{_field(self.where, 'force_axis')}: {self.force_axis} out of range for the "
                                 f"{w.size}-component wrench of {self.force_sensor!r}")
            return self.force_sign * float(w[self.force_axis if w.size > self.force_axis else 0])
        j = _joint(meas, self.actuator, _field(self.where, "actuator"))
        if j.effort is None:
            raise SceneError(f"{_field(self.where, 'force_sensor')}: required: actuator {self.actuator!r} "
                             "reports no effort channel")
        return self.force_sign * float(np.asarray(j.effort, dtype=float).reshape(-1)[0])

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        jm = _joint(meas, self.actuator, _field(self.where, "actuator"))
        v_m = float(np.asarray(jm.velocity, dtype=float).reshape(-1)[0])
        F = self.spring_force(meas)
        if self.output is not None:
            jo = _joint(meas, self.output, _field(self.where, "output"))
            x_o = float(np.asarray(jo.position, dtype=float).reshape(-1)[0])
            v_o = float(np.asarray(jo.velocity, dtype=float).reshape(-1)[0])
        else:
            x_o = v_o = 0.0  # locked output (or no output encoder): v_h = 0
        F_ref = 0.0 if self._env_free else float(self._env.step(np.array([x_o, v_o]), dt)[0])
        if self.force_reference is not None:
            F_ref += float(self.force_reference(t))
        v_ref = self._pf.step(F_ref - F, dt)
        tau = self._pm.step(v_ref - v_m, dt) + (1.0 - self.alpha) * F
        self.last = {"F": F, "F_ref": F_ref, "v_ref": v_ref, "tau": tau}
        return {self.actuator: np.array([tau])}


def vsic_controller(cfg: Mapping[str, Any], where: str = "controller") -> VSIC:
    """``type: vsic`` from the scene: ``actuator``, ``force_sensor`` (optional), ``force_axis``,
    ``force_sign``, ``output`` (optional end-effector encoder device), ``P_m, I_m, P_f, I_f``,
    ``alpha`` (default 1), ``k22``, ``b22``, ``environment: {type: none|spring|spring_damper|
    mass_spring_damper, k, b, m}``."""
    keys = {"actuator", "force_sensor", "force_axis", "force_sign", "output", "P_m", "I_m", "P_f", "I_f",
            "alpha", "k22", "b22", "environment"}
    _check_keys(cfg, keys, where)
    gains = {k: float(_require(cfg, k, where)) for k in ("P_m", "I_m", "P_f", "I_f", "k22", "b22")}
    env = cfg.get("environment")
    if env is not None and not isinstance(env, Mapping):
        raise SceneError(f"{_field(where, 'environment')}: must be a mapping")
    return VSIC(str(_require(cfg, "actuator", where)), alpha=float(cfg.get("alpha", 1.0)), environment=env,
                force_sensor=cfg.get("force_sensor"), force_axis=int(cfg.get("force_axis", 0)),
                force_sign=float(cfg.get("force_sign", 1.0)), output=cfg.get("output"), where=where, **gains)


# ---------------------------------------------------------------------------------------------
# factory

_BUILDERS: dict[str, Callable[[Mapping[str, Any], str], Controller]] = {
    "pd_position_position": pd_position_position,
    "mcet": mcet_controller,
    "dual_master": dual_master_controller,
    "vsic": vsic_controller,
}


def make_controller(cfg: Mapping[str, Any] | None, *, units: str = "linear", scene: Any = None) -> Controller:
    """Build the scene's ``controller`` mapping (``type``: none | pd_position_position | mcet |
    dual_master | vsic). ``units`` (``linear`` | ``rotary``) is validated and logged; the laws
    are unit-agnostic. Raises :class:`SceneError` naming the offending field.

    ``scene`` (optional, a :class:`hil.scene.Scene` or mapping): used to resolve the VSIC force
    sensor's wrench component (``devices[].axes``) when ``force_axis`` is not given. Without it the
    VSIC reads wrench component 0 (or the only component)."""
    if units not in ("linear", "rotary"):
        raise SceneError(f"units: must be 'linear' or 'rotary', got {units!r}")
    if cfg is None:
        return NullController()
    if hasattr(cfg, "model_dump"):  # a pydantic model from hil.scene
        cfg = cfg.model_dump()
    ctype = str(cfg.get("type", "none"))
    if ctype == "none":
        _check_keys(cfg, set(), "controller")
        return NullController()
    try:
        builder = _BUILDERS[ctype]
    except KeyError as exc:
        raise SceneError(f"controller.type: unknown controller {ctype!r}; one of "
                         f"{['none', *_BUILDERS]}") from exc
    clean = {k: v for k, v in cfg.items() if v is not None or k == "type"}
    if ctype == "vsic" and "force_axis" not in clean and clean.get("force_sensor") and scene is not None:
        for dev in (scene.get("devices") if isinstance(scene, Mapping) else getattr(scene, "devices", None)) or []:
            get = dev.get if isinstance(dev, Mapping) else (lambda k, d=None, _o=dev: getattr(_o, k, d))
            if get("name") == clean["force_sensor"] and get("axes") is not None:
                clean["force_axis"] = int(next(iter(get("axes"))))
    ctrl = builder(clean, "controller")
    logger.info("controller %s (%s units)", ctype, units)
    return ctrl
