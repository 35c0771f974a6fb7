"""How each built-in network model reads its fixed parameters from a scene: the controller's gains
and, on a simulated bench, the plant's masses and damping (the model's ``from_scene``, see
:class:`hil.models.BuiltinModel`). Each function takes the scene and its controller configuration
(a dict, ``scene.controller_config()``) and returns the parameters, or nothing when the scene's
controller is not the one the model describes (then only ``certification.parameters`` apply).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from hil.schema import as_matrix

logger = logging.getLogger(__name__)

__all__ = ["bilateral_1dof_params", "bilateral_2dof_params", "dual_master_3dof_params", "mcet_params", "sdea_params"]

_YZ = (((0, 0), "yy"), ((1, 1), "zz"), ((0, 1), "yz"))


def _as_matrix(value: Any, n: int) -> np.ndarray:
    return np.asarray(as_matrix(value, n), float)


def _bodies(scene: Any) -> dict[str, Any]:
    return {b.name: b for b in scene.simulation.bodies} if scene.simulation is not None else {}


def sdea_params(scene: Any, c: dict[str, Any]) -> dict[str, Any]:
    """VSIC gains (P_m, I_m, P_f, I_f, alpha, k22, b22) and the simulated SDEA's M, B, K_f, B_f."""
    p: dict[str, Any] = {}
    if c.get("type") != "vsic":
        return p
    for k in ("P_m", "I_m", "P_f", "I_f", "alpha", "k22", "b22"):
        if c.get(k) is not None:
            p[k] = float(c[k])
    sd = scene.simulation.sdea if scene.simulation is not None else None
    if sd is not None:
        p.update({"M": float(sd.M), "B": float(sd.B), "K_f": float(sd.K_f), "B_f": float(sd.B_f)})
    return p


def bilateral_2dof_params(scene: Any, c: dict[str, Any]) -> dict[str, Any]:
    """The position-position gain table (``gains``: k_p/k_v, m/s, yy/zz/yz/zy) and the simulated
    bodies' M, B, K entries (mm_yy, bs_yz, ...)."""
    p: dict[str, Any] = {}
    if c.get("type") != "pd_position_position":
        return p
    km, kvm = np.asarray(c["Kp_m"], float), np.asarray(c["Kv_m"], float)
    ks, kvs = np.asarray(c["Kp_s"], float), np.asarray(c["Kv_s"], float)
    gains = {}
    for tag, K, V in (("m", km, kvm), ("s", ks, kvs)):
        for (i, j), ax in (((0, 0), "yy"), ((1, 1), "zz"), ((0, 1), "yz"), ((1, 0), "zy")):
            gains[f"k_p{tag}{ax}"] = float(K[i, j])
            gains[f"k_v{tag}{ax}"] = float(V[i, j])
    p["gains"] = gains
    bodies = _bodies(scene)
    if scene.simulation is not None:
        for side, body in (("m", c["master"]), ("s", c["slave"])):
            b = bodies.get(scene.device(body).body or body)
            if b is None:
                continue
            for key, mat in (("m", b.M), ("b", b.B), ("k", b.K)):
                A = _as_matrix(mat, 2)
                for (i, j), ax in _YZ:
                    p[f"{key}{side}_{ax}"] = float(A[i, j])
    return p


def bilateral_1dof_params(scene: Any, c: dict[str, Any]) -> dict[str, Any]:
    """The 1-DOF position-position gains k_pm, k_vm, k_ps, k_vs."""
    p: dict[str, Any] = {}
    if c.get("type") != "pd_position_position":
        return p
    for tag in ("m", "s"):
        p[f"k_p{tag}"] = float(np.asarray(c[f"Kp_{tag}"], float).reshape(-1)[0])
        p[f"k_v{tag}"] = float(np.asarray(c[f"Kv_{tag}"], float).reshape(-1)[0])
    return p


def dual_master_3dof_params(scene: Any, c: dict[str, Any]) -> dict[str, Any]:
    """The four 3x3 controllers C_m, C_4, C_s, C_1 (upper triangles), restricted to the entries
    paper 001's Table I names."""
    if c.get("type") != "dual_master":
        return {}
    from hil.models.teleop import DUAL_MASTER_TABLE1

    p: dict[str, Any] = {}
    ax = ("x", "y", "z")
    for tag, key in (("m", "C_m"), ("4", "C_4"), ("s", "C_s"), ("1", "C_1")):
        kp, kv = np.asarray(c[key]["kp"], float), np.asarray(c[key]["kv"], float)
        for i in range(3):
            for j in range(i, 3):
                p[f"k_p{tag}{ax[i]}{ax[j]}"] = float(kp[i, j])
                p[f"k_v{tag}{ax[i]}{ax[j]}"] = float(kv[i, j])
    return {k: v for k, v in p.items() if k in DUAL_MASTER_TABLE1}


def mcet_params(scene: Any, c: dict[str, Any]) -> dict[str, Any]:
    """The MCET gains and alpha, and the simulated masses of the two masters and the slave."""
    p: dict[str, Any] = {}
    if c.get("type") != "mcet":
        return p
    for k in ("k_pm1", "k_vm1", "k_pm2", "k_vm2", "k_ps", "k_vs", "alpha"):
        p[k] = float(c[k])
    bodies = _bodies(scene)
    if scene.simulation is not None:
        for key, dev in (("m_m1", c["masters"][0]), ("m_m2", c["masters"][1]), ("m_s", c["slave"])):
            b = bodies.get(scene.device(dev).body or dev)
            if b is not None:
                p[key] = float(_as_matrix(b.M, 1)[0, 0])
    return p
