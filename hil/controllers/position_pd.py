"""Position-position PD coupling (``pd_position_position``) and the dual-master teleoperator
(``dual_master``): efforts N or N.m from position errors m or rad and velocities."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field

from hil.controllers.base import (
    ControllerConfig,
    Measurements,
    _dof_of,
    _field,
    _full,
    _gain_dof,
    _joint,
    _square_gain,
    gain_matrix,
)
from hil.errors import SceneError
from hil.schema import (
    DampMat,
    DofList,
    FieldError,
    Name,
    SceneView,
    StiffMat,
    StrictModel,
    validate,
)


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


class PdPositionPosition(ControllerConfig):
    """Bilateral position-position PD (paper 000 eq. 42-43): master effort
    ``-Kp_m (q_m - q_s) - Kv_m (v_m - v_s)``, slave effort ``-Kp_s (q_s - q_m) - Kv_s (v_s - v_m)``.
    Gains are dof x dof (N/m, N.s/m or N.m/rad, N.m.s/rad); a number means ``k * I``, a flat list
    a diagonal. ``dof`` (optional) must equal the devices' DOF count."""

    type: Literal["pd_position_position"]
    master: Name
    slave: Name
    Kp_m: StiffMat
    Kv_m: DampMat
    Kp_s: StiffMat
    Kv_s: DampMat
    dof: int | None = Field(default=None, ge=1, le=6)

    def normalized(self, scene: SceneView) -> PdPositionPosition:
        n = _dof_of(scene, self.master)
        if n is None:
            return self
        return self.model_copy(update={k: _full(getattr(self, k), n) for k in ("Kp_m", "Kv_m", "Kp_s", "Kv_s")})

    def check_scene(self, scene: SceneView) -> None:
        m = scene.require("controller.master", self.master, "actuator")
        s = scene.require("controller.slave", self.slave, "actuator")
        if m.dof != s.dof:
            raise FieldError("controller.slave", f"master {m.name!r} has {m.dof} DOF, slave {s.name!r} has {s.dof}")
        if self.dof is not None and self.dof != m.dof:
            raise FieldError("controller.dof", f"is {self.dof}, the devices have {m.dof} DOF")
        for key in ("Kp_m", "Kv_m", "Kp_s", "Kv_s"):
            _square_gain(f"controller.{key}", getattr(self, key), m.dof, f"dof x dof of {m.name!r}/{s.name!r}")


class PdGain(StrictModel):
    """A PD gain matrix pair, i.e. the PI velocity controller ``(kp + kv s)/s`` of the papers."""

    kp: StiffMat
    kv: DampMat


class MasterMap(StrictModel):
    """A master device and the slave DOFs it commands (paper 001: master 1 -> x, master 2 -> y, z)."""

    device: Name
    slave_dofs: DofList


class DualMaster(ControllerConfig):
    """Dual-master / single-slave cooperative teleoperation (paper 001 eq. 15-17). ``masters:
    [{device: m1, slave_dofs: [0]}, {device: m2, slave_dofs: [1, 2]}]``: the slave DOFs each
    master's DOFs map to (together, each of the slave's DOFs exactly once). ``C_m`` (master local),
    ``C_4`` (slave -> masters), ``C_s`` (slave local), ``C_1`` (masters -> slave) are ``{kp, kv}``
    pairs of n x n matrices, n the slave DOF count (a number: ``k I``): master effort
    ``C_4 x_s - C_m x_m``, slave effort ``C_1 x_m - C_s x_s`` (x in the slave DOF order)."""

    type: Literal["dual_master"]
    masters: Annotated[list[MasterMap], Field(min_length=1)]
    slave: Name
    C_m: PdGain
    C_4: PdGain
    C_s: PdGain
    C_1: PdGain

    @property
    def n(self) -> int:
        """The slave's DOF count as the masters' maps give it."""
        return sum(len(m.slave_dofs) for m in self.masters)

    def normalized(self, scene: SceneView) -> DualMaster:
        n = _dof_of(scene, self.slave)
        if n is None:
            return self
        gains = {key: getattr(self, key) for key in ("C_m", "C_4", "C_s", "C_1")}
        return self.model_copy(update={key: PdGain(kp=_full(g.kp, n), kv=_full(g.kv, n)) for key, g in gains.items()})

    def check_scene(self, scene: SceneView) -> None:
        s = scene.require("controller.slave", self.slave, "actuator")
        covered: list[int] = []
        for k, mm in enumerate(self.masters):
            d = scene.require(f"controller.masters[{k}].device", mm.device, "actuator")
            if len(mm.slave_dofs) != d.dof:
                raise FieldError(f"controller.masters[{k}].slave_dofs",
                                 f"master {d.name!r} has {d.dof} DOF but maps {len(mm.slave_dofs)} slave DOF")
            bad = [j for j in mm.slave_dofs if j >= s.dof]
            if bad:
                raise FieldError(f"controller.masters[{k}].slave_dofs",
                                 f"slave {s.name!r} has {s.dof} DOF; index {bad[0]} is out of range")
            covered += mm.slave_dofs
        if sorted(covered) != list(range(s.dof)):
            raise FieldError("controller.masters", f"the masters' slave_dofs must cover each of the slave's {s.dof} "
                                                   f"DOF exactly once, got {covered}")
        for key in ("C_m", "C_4", "C_s", "C_1"):
            g = getattr(self, key)
            _square_gain(f"controller.{key}.kp", g.kp, s.dof, "n x n, n = slave DOF")
            _square_gain(f"controller.{key}.kv", g.kv, s.dof, "n x n, n = slave DOF")


def pd_position_position(cfg: PdPositionPosition | Mapping[str, Any], where: str = "controller") -> PositionPD:
    """Paper 000 eq. (42)-(43): ``Kp = [[Kp_m, -Kp_m], [-Kp_s, Kp_s]]`` (same for ``Kv``)."""
    c = validate(PdPositionPosition, cfg, where)
    master, slave = c.master, c.slave
    keys = ("Kp_m", "Kv_m", "Kp_s", "Kv_s")
    d = _gain_dof(c.dof, [getattr(c, k) for k in keys])
    Kp_m, Kv_m, Kp_s, Kv_s = (gain_matrix(getattr(c, k), d, _field(where, k)) for k in keys)
    Kp = np.block([[Kp_m, -Kp_m], [-Kp_s, Kp_s]])
    Kv = np.block([[Kv_m, -Kv_m], [-Kv_s, Kv_s]])
    return PositionPD("pd_position_position", [(master, range(d)), (slave, range(d, 2 * d))], Kp, Kv, where)


def dual_master_controller(cfg: DualMaster | Mapping[str, Any], where: str = "controller") -> PositionPD:
    """Paper 001 eq. (15) with matrix PD gains (module doc) from a :class:`DualMaster` configuration:
    the stack is the masters' DOFs at their slave DOF indices, then the slave's."""
    c = validate(DualMaster, cfg, where)
    n = c.n
    names = [m.device for m in c.masters]
    maps = [list(m.slave_dofs) for m in c.masters]
    slave = c.slave

    def pair(tag: str) -> tuple[np.ndarray, np.ndarray]:
        g = getattr(c, f"C_{tag}")
        f = _field(where, f"C_{tag}")
        return gain_matrix(g.kp, n, f"{f}.kp"), gain_matrix(g.kv, n, f"{f}.kv")

    Kp_m, Kv_m = pair("m")
    Kp_4, Kv_4 = pair("4")
    Kp_s, Kv_s = pair("s")
    Kp_1, Kv_1 = pair("1")
    Kp = np.block([[Kp_m, -Kp_4], [-Kp_1, Kp_s]])
    Kv = np.block([[Kv_m, -Kv_4], [-Kv_1, Kv_s]])
    layout: list[tuple[str, Sequence[int]]] = [(nm, mp) for nm, mp in zip(names, maps, strict=True)]
    layout.append((slave, range(n, 2 * n)))
    return PositionPD("dual_master", layout, Kp, Kv, where)
