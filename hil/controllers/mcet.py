"""The four-channel MCET controller of the trilateral teleoperator (paper 000): position and force
channels between masters and the slave."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import BeforeValidator, Field

from hil.controllers.base import ControllerConfig, Measurements, _field, _gain_dof, _square_gain, gain_matrix
from hil.controllers.position_pd import PositionPD
from hil.errors import SceneError
from hil.protocols.base import WrenchSample
from hil.schema import (
    DampMat,
    FieldError,
    Fraction,
    Name,
    SceneView,
    StiffMat,
    StrictModel,
    WrenchAxes,
    number,
    validate,
)


class McetForceSensors(StrictModel):
    """Force sensors of the MCET force channels (device names): ``master1`` and ``master2`` read
    the users' forces on the masters, ``slave`` the force between slave and environment."""

    master1: Name | None = None
    master2: Name | None = None
    slave: Name | None = None


class McetForceAxes(StrictModel):
    """Wrench components (indices into Fx..Tz) each MCET force sensor contributes, per DOF."""

    master1: WrenchAxes | None = None
    master2: WrenchAxes | None = None
    slave: WrenchAxes | None = None


class Mcet(ControllerConfig):
    """Dual-user MCET four-channel controller (paper 000 eq. 21-25): ``masters: [m1, m2]``,
    ``slave``, ``alpha`` in [0, 1] (user 1's authority), local PD gains ``k_pm1, k_vm1, k_pm2,
    k_vm2, k_ps, k_vs``; optional coordinating channels ``k_p4m1, k_v4m1, k_p4m2, k_v4m2``
    (default -k_pm1, ...: position-position) and ``k_p1, k_v1`` (default k_ps, k_vs); force gains
    ``c2m1, c2m2, c3, c5, c6m1, c6m2`` (default 0: position-position, eq. 25) with
    ``force_sensors: {master1, master2, slave}`` (required for the channels those gains use),
    ``force_axes`` (same keys: the wrench components of each sensor), ``slave_force_sign``
    (default -1: the slave sensor reports the force the slave exerts on the environment), ``dof``
    (optional; the three devices' common DOF count). Gains are numbers (``k I``) or dof x dof."""

    type: Literal["mcet"]
    masters: Annotated[list[Name], Field(min_length=2, max_length=2)]
    slave: Name
    alpha: Fraction
    k_pm1: StiffMat
    k_vm1: DampMat
    k_pm2: StiffMat
    k_vm2: DampMat
    k_ps: StiffMat
    k_vs: DampMat
    k_p4m1: StiffMat | None = None
    k_v4m1: DampMat | None = None
    k_p4m2: StiffMat | None = None
    k_v4m2: DampMat | None = None
    k_p1: StiffMat | None = None
    k_v1: DampMat | None = None
    c2m1: Annotated[float, BeforeValidator(number)] = 0.0
    c2m2: Annotated[float, BeforeValidator(number)] = 0.0
    c3: Annotated[float, BeforeValidator(number)] = 0.0
    c5: Annotated[float, BeforeValidator(number)] = 0.0
    c6m1: Annotated[float, BeforeValidator(number)] = 0.0
    c6m2: Annotated[float, BeforeValidator(number)] = 0.0
    force_sensors: McetForceSensors = Field(default_factory=McetForceSensors)
    force_axes: McetForceAxes = Field(default_factory=McetForceAxes)
    slave_force_sign: Literal[1, -1] = -1
    dof: int | None = Field(default=None, ge=1, le=6)

    GAINS: ClassVar[tuple[str, ...]] = ("k_pm1", "k_vm1", "k_pm2", "k_vm2", "k_ps", "k_vs")
    CHANNELS: ClassVar[tuple[str, ...]] = ("k_p4m1", "k_v4m1", "k_p4m2", "k_v4m2", "k_p1", "k_v1")

    def check_scene(self, scene: SceneView) -> None:
        devs = [scene.require(f"controller.masters[{k}]", m, "actuator") for k, m in enumerate(self.masters)]
        devs.append(scene.require("controller.slave", self.slave, "actuator"))
        d = self.dof if self.dof is not None else devs[0].dof
        for path, dev in zip(("controller.masters[0]", "controller.masters[1]", "controller.slave"), devs,
                             strict=True):
            if dev.dof != d:
                raise FieldError(path, f"mcet needs robots of equal DOF ({d}); {dev.name!r} has {dev.dof} DOF")
        for key in (*self.GAINS, *self.CHANNELS):
            g = getattr(self, key)
            if g is not None:
                _square_gain(f"controller.{key}", g, d, "dof x dof of the robots")
        for role in ("master1", "master2", "slave"):
            sensor = getattr(self.force_sensors, role)
            if sensor is not None:
                sdev = scene.require(f"controller.force_sensors.{role}", sensor, "force_sensor")
                axes = getattr(self.force_axes, role)
                if axes is not None and len(axes) != d:
                    raise FieldError(f"controller.force_axes.{role}", f"lists {len(axes)} wrench components for "
                                                                      f"{d} DOF")
                if axes is None and sdev.dof < d:
                    raise FieldError(f"controller.force_sensors.{role}", f"sensor {sensor!r} measures {sdev.dof} "
                                                                         f"DOF, the robots have {d}")


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
            sample = meas[sensor]
            if not isinstance(sample, WrenchSample):
                raise SceneError(f"MCET: no wrench from force sensor {sensor!r}")
            w = np.asarray(sample.wrench, dtype=float).reshape(-1)
            w = w[list(axes)] if axes is not None else w[: self.d]
            f[k * self.d:(k + 1) * self.d] = sign * w
        uf = self.G @ f
        for dev, idx in self.pd.layout:
            out[dev] = out[dev] + uf[idx]
        return out


def mcet_controller(cfg: Mcet | Mapping[str, Any], where: str = "controller") -> FourChannelMCET:
    """Paper 000 eq. (21)-(25): the dual-user MCET four-channel controller (:class:`FourChannelMCET`)
    from a :class:`Mcet` configuration (fields there)."""
    c = validate(Mcet, cfg, where)
    m1, m2 = c.masters
    slave = c.slave
    a = c.alpha
    d = _gain_dof(c.dof, [getattr(c, k) for k in Mcet.GAINS])
    kp1, kv1, kp2, kv2, kps, kvs = (gain_matrix(getattr(c, k), d, _field(where, k)) for k in Mcet.GAINS)

    def opt_gain(key: str, default: np.ndarray) -> np.ndarray:
        v = getattr(c, key)
        return default if v is None else gain_matrix(v, d, _field(where, key))

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
    g = {k: float(getattr(c, k)) for k in ("c2m1", "c2m2", "c3", "c5", "c6m1", "c6m2")}
    I_ = np.eye(d)
    G = np.block([[g["c6m1"] * I_, Z, -0.5 * g["c2m1"] * I_],
                  [Z, g["c6m2"] * I_, -0.5 * g["c2m2"] * I_],
                  [a * g["c3"] * I_, (1 - a) * g["c3"] * I_, -g["c5"] * I_]])
    fs, fa = c.force_sensors, c.force_axes
    sensors = [fs.master1, fs.master2, fs.slave]
    needs = [bool(g["c6m1"] or g["c3"]), bool(g["c6m2"] or g["c3"]), bool(g["c2m1"] or g["c2m2"] or g["c5"])]
    for name, s_, need in zip(("master1", "master2", "slave"), sensors, needs, strict=True):
        if need and not s_:
            raise SceneError(f"{_field(where, 'force_sensors')}: the force gains need a {name!r} force sensor")
    signs = [1.0, 1.0, float(c.slave_force_sign)]
    axes: list[Sequence[int] | None] = [fa.master1, fa.master2, fa.slave]
    return FourChannelMCET(pd, G, sensors, signs, axes, d)
