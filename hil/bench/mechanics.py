"""What a simulated bench's actuators add to the plant: friction, viscous damping, encoder.

Each simulated actuator brings its device kind's mechanics (:attr:`hil.mocks.twins.Twin.mechanics`:
a DYNAMIXEL servo's gear friction and 12-bit encoder, an AK-series actuator's friction, nothing for
a drive such as an ODrive), unless the scene's ``devices[].sim.friction`` / ``devices[].sim.encoder``
replace them (docs/guide/friction-twins.md). :func:`plant_mechanics` collects them per body DOF for
:class:`hil.bench.runtime.Bench`; :func:`device_mechanics` is one device's; :func:`friction_truth`
gives the simulated friction of a device as the certificate shows it next to identified values.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from hil.errors import HilError, ModelError, SceneError
from hil.mocks.friction import Friction, Mechanics

logger = logging.getLogger(__name__)


def _kind_default(driver: str) -> Mechanics:
    """The device kind's mechanics (its twin's), or none when it has no twin."""
    from hil.protocols.registry import resolve_twin

    try:
        twin = resolve_twin(driver)
    except HilError:
        return Mechanics()
    m = getattr(twin, "mechanics", None)
    return m if isinstance(m, Mechanics) else Mechanics()


def device_mechanics(cfg: Any, label: str = "", index: int | None = None) -> Mechanics:
    """The mechanics of scene device ``cfg`` (a :class:`hil.scene.spec.Device`): the kind's default
    with the scene's ``sim.friction`` / ``sim.encoder`` blocks replacing their parts. Sensors: none."""
    if cfg.role != "actuator" or getattr(cfg, "sim", None) is None:  # a sensor, or a group of drives
        return Mechanics()
    base = _kind_default(cfg.driver)
    fr, enc = cfg.sim.friction, cfg.sim.encoder
    try:
        friction = base.friction if fr is None else Friction(fr.coulomb, fr.static, fr.stribeck_velocity)
        return Mechanics(friction=friction, viscous=base.viscous if fr is None else float(fr.viscous),
                         encoder_step=base.encoder_step if enc is None else float(enc.step),
                         velocity=base.velocity if enc is None else enc.velocity,
                         source=base.source if fr is None and enc is None else "scene")
    except ModelError as exc:
        where = f"devices[{index}].sim" if index is not None else f"device {cfg.name!r}"
        raise SceneError(f"{label}: {where}: {exc}") from None


def plant_mechanics(scene: Any, body_dofs: dict[str, int], label: str = ""
                    ) -> tuple[dict[str, np.ndarray], dict[str, list[Friction | None]]]:
    """Per body of the plant (``body_dofs``: name -> DOF count): the extra viscous damping on each
    DOF (N.s/m or N.m.s/rad) and the dry friction on each DOF (None: none), from the scene's
    actuators (one actuator per DOF: the scene refuses two)."""
    viscous: dict[str, np.ndarray] = {}
    friction: dict[str, list[Friction | None]] = {}
    for i, cfg in enumerate(scene.devices):
        if cfg.role != "actuator" or cfg.body is None or cfg.body not in body_dofs:
            continue  # a body absent in this variant is reported where the device is attached
        m = device_mechanics(cfg, label, i)
        if not (m.friction.active or m.viscous > 0.0):
            continue
        n = body_dofs[cfg.body]
        dofs = list(cfg.dofs) if cfg.dofs is not None else list(range(n))
        v = viscous.setdefault(cfg.body, np.zeros(n))
        f = friction.setdefault(cfg.body, [None] * n)
        for d in dofs:
            if not 0 <= d < n:
                continue  # checked where the device is attached
            v[d] += m.viscous
            if m.friction.active:
                f[d] = m.friction
    friction = {b: f for b, f in friction.items() if any(x is not None for x in f)}
    viscous = {b: v for b, v in viscous.items() if np.any(v > 0.0)}
    return viscous, friction


def friction_truth(scene: Any, device: str) -> dict[str, float]:
    """The simulated friction of actuator ``device`` under the names identification gives it
    (:mod:`hil.identify.friction`: ``F_c``, ``F_s`` = the Stribeck *excess* static - coulomb, ``v_s``;
    ``F_0`` = 0: the twins have no constant offset), for the certificate's truth column; empty without
    a simulation or for a device without friction."""
    cfg = _device(scene, device)
    if cfg is None:
        return {}
    fr = device_mechanics(cfg).friction
    out = {"F_c": fr.F_c, "F_0": 0.0} if fr.active else {}
    if fr.active and fr.F_s > fr.F_c:
        out.update(F_s=fr.F_s - fr.F_c, v_s=float(fr.stribeck_velocity or 0.0))
    return out


def body_truth(scene: Any, device: str) -> dict[str, float]:
    """``M`` and ``B`` (the body's B plus the actuator's viscous friction) of the 1-DOF simulated body
    actuator ``device`` drives, as the 1-DOF ``mbk`` friction model names them; empty otherwise."""
    cfg = _device(scene, device)
    if cfg is None or cfg.body is None:
        return {}
    body = next((b for b in scene.simulation.bodies if b.name == cfg.body), None)
    if body is None or body.dof != 1:
        return {}
    M = float(np.asarray(body.M, float).reshape(-1)[0])
    B = float(np.asarray(body.B, float).reshape(-1)[0])
    return {"M": M, "B": B + device_mechanics(cfg).viscous}


def _device(scene: Any, device: str) -> Any:
    if getattr(scene, "simulation", None) is None or not device:
        return None
    if scene.group(device) is not None:  # several drives: no single body or friction to show
        return None
    try:
        cfg = scene.device(device)
    except (KeyError, ValueError, SceneError):
        return None
    return cfg if cfg.role == "actuator" else None
