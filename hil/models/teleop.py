"""Teleoperation network models from papers 000 (Li, Tavakoli, Huang: multi-DOF multilateral) and
001 (cooperative teleoperation with complementary DOF).

All models are **impedance matrices** F = Z V (forces in N, velocities in m/s, velocities into
the ports), built from the robots' mass-damper-spring impedances Z = (M s² + B s + K)/s and
position-position PD controllers written as PI *velocity* controllers C = (k_p + k_v s)/s
(papers' eqs. 24 and 43). Where a paper does not give the robots' parameters, the defaults below
say what was assumed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from hil.errors import ModelError
from hil.stability.rational import Rational, S, TransferMatrix

__all__ = [
    "BILATERAL_1DOF",
    "DUAL_MASTER_TABLE1",
    "MBK_2DOF",
    "MCET_TABLE1",
    "TWO_DOF_TABLE2",
    "bilateral_1dof",
    "bilateral_2dof",
    "dual_master_3dof",
    "example_Z_000_eq5",
    "mbk_impedance",
    "mcet_trilateral",
    "termination_T1",
    "termination_T2",
]


def _pi(kp: float, kv: float) -> Rational:
    """PD position controller seen as a PI velocity controller: (k_p + k_v s)/s."""
    return (kp + kv * S) / S


def _mbk(m: float, b: float = 0.0, k: float = 0.0) -> Rational:
    """Mass-damper-spring impedance (m s² + b s + k)/s."""
    return (m * S**2 + b * S + k) / S


# ---------------------------------------------------------------------------------------------
# paper 000, section V: dual-user (trilateral) MCET position-position system, eq. (25)

#: Table I of paper 000 (gains) and the simulation masses of section V-B.
MCET_TABLE1: dict[str, float] = {
    "k_pm1": 160.0, "k_vm1": 64.0, "k_pm2": 120.0, "k_vm2": 48.0, "k_ps": 150.0, "k_vs": 85.0,
    "m_m1": 0.7, "m_m2": 0.5, "m_s": 1.5, "alpha": 0.5,
}


def mcet_trilateral(p: Mapping[str, float] | None = None, **kw: float) -> TransferMatrix:
    """Paper 000 eq. (25): the 3-port impedance matrix of the dual-user MCET system under
    position-position control (c1 = c_s, c4mi = -c_mi; other channels zero), robots modelled as
    masses. Ports: master 1 (user 1), master 2 (user 2), slave (environment). ``alpha`` ∈ [0, 1]
    is user 1's authority over the slave.

    Table I: k_vm1 = 64 satisfies the paper's condition (40) k_pm1/k_vm1 = k_pm2/k_vm2
    (absolutely stable); k_vm1 = 80 violates it (potentially unstable).
    """
    q = {**MCET_TABLE1, **(p or {}), **kw}
    a = q["alpha"]
    if not 0.0 <= a <= 1.0:
        raise ModelError("alpha must lie in [0, 1]")
    cm1, cm2, cs = _pi(q["k_pm1"], q["k_vm1"]), _pi(q["k_pm2"], q["k_vm2"]), _pi(q["k_ps"], q["k_vs"])
    zm1, zm2, zs = _mbk(q["m_m1"]), _mbk(q["m_m2"]), _mbk(q["m_s"])
    zero = Rational.const(0.0)
    rows = [
        [cm1 + zm1, -cm1, zero],
        [-cm2, cm2 + zm2, zero],
        [-a * cs, -(1 - a) * cs, cs + zs],
    ]
    return TransferMatrix(rows, "impedance", (1, 1, 1), "mcet_trilateral (000 eq. 25)")


# ---------------------------------------------------------------------------------------------
# an m-DOF mass-damper-spring device as a one-port impedance

MBK_2DOF: dict[str, float] = {"M_00": 1.0, "M_01": 0.2, "M_11": 0.6, "B_00": 8.0, "B_01": -2.0, "B_11": 6.0,
                              "K_00": 6000.0, "K_01": -2500.0, "K_11": 9000.0}


def mbk_impedance(p: Mapping[str, float] | None = None, **kw: float) -> TransferMatrix:
    """Z(s) = (M s² + B s + K)/s of an m-DOF body (F = Z V, one m-DOF port). Parameters ``M_ij``,
    ``B_ij``, ``K_ij`` (i ≤ j, symmetric; the names the identification's ``mbk`` model derives).
    Positive real exactly when M, B, K are symmetric positive semidefinite (Re Z = B, residue K).

    ``dof`` (optional) sets the number of DOF m; without it m is the largest index given here or in
    the 2-DOF defaults (:data:`MBK_2DOF`). Entries missing for i, j < m take those defaults (1-DOF:
    ``dof=1`` with ``M_00``, ``B_00``, ``K_00``); defaults beyond m are ignored."""
    given = {**(p or {}), **kw}
    dof = given.pop("dof", None)
    q = {**MBK_2DOF, **given}
    if dof is None:
        n = 1 + max(int(k[-1]) for k in q if k[:2] in ("M_", "B_", "K_"))
    else:
        n = int(dof)
        if n != dof or not 1 <= n <= 6:
            raise ModelError(f"mbk_impedance: dof must be an integer from 1 to 6, got {dof!r}")
        big = [k for k in given if k[:2] in ("M_", "B_", "K_") and max(int(k[-2]), int(k[-1])) >= n]
        if big:
            raise ModelError(f"mbk_impedance: {big[0]} is outside a {n}-DOF body")
    mats = {}
    for key in ("M", "B", "K"):
        A = np.zeros((n, n))
        for i in range(n):
            for j in range(i, n):
                A[i, j] = A[j, i] = float(q.get(f"{key}_{i}{j}", 0.0))
        mats[key] = A
    rows = [[_mbk(mats["M"][i, j], mats["B"][i, j], mats["K"][i, j]) for j in range(n)] for i in range(n)]
    return TransferMatrix(rows, "impedance", (n,), f"mbk_impedance ({n}-DOF)")


# ---------------------------------------------------------------------------------------------
# 1-DOF bilateral position-position (the m = 1 case of eq. 44)

BILATERAL_1DOF: dict[str, float] = {"k_pm": 2.0, "k_vm": 0.1, "k_ps": 2.0, "k_vs": 0.1,
                                    "m_m": 0.02, "b_m": 0.01, "m_s": 0.02, "b_s": 0.01}


def bilateral_1dof(p: Mapping[str, float] | None = None, **kw: float) -> TransferMatrix:
    """1-DOF bilateral position-position teleoperator (eq. 44 with m = 1):
    [[c_m + z_m, -c_m], [-c_s, c_s + z_s]], c = (k_p + k_v s)/s, z = (m s² + b s)/s."""
    q = {**BILATERAL_1DOF, **(p or {}), **kw}
    cm, cs = _pi(q["k_pm"], q["k_vm"]), _pi(q["k_ps"], q["k_vs"])
    zm, zs = _mbk(q["m_m"], q["b_m"]), _mbk(q["m_s"], q["b_s"])
    return TransferMatrix([[cm + zm, -cm], [-cs, cs + zs]], "impedance", (1, 1), "bilateral_1dof")


# ---------------------------------------------------------------------------------------------
# paper 000, section VI: 2-DOF bilateral position-position system, eq. (44)

#: Table II of paper 000: gain sets A1, A2 (absolutely stable) and B (potentially unstable);
#: master and slave gains are equal in each set. Keys: k_{p|v}{m|s}{yy|zz|yz}.
TWO_DOF_TABLE2: dict[str, dict[str, float]] = {
    "A1": {"k_pyy": 500, "k_vyy": 300, "k_pzz": 500, "k_vzz": 300, "k_pyz": 450, "k_vyz": 250},
    "A2": {"k_pyy": 1000, "k_vyy": 800, "k_pzz": 800, "k_vzz": 600, "k_pyz": 50, "k_vyz": 25},
    "B": {"k_pyy": 500, "k_vyy": 300, "k_pzz": 500, "k_vzz": 250, "k_pyz": 550, "k_vyz": 300},
}

#: Robot parameters for eq. (44) (kg, N.s/m, N/m; coupled, symmetric PSD). Paper 000 does not print
#: the Phantom's M, B, K. These are chosen heavy enough that the Table II gains are also stable as
#: a sampled loop at 1 kHz (k_v (1/M_m + 1/M_s) dt < 1), so the built-in mocked scenes exercise
#: the continuous-time verdicts; the verdicts themselves do not depend on M, B, K (tested).
TWO_DOF_ROBOT: dict[str, float] = {
    "m_yy": 2.0, "m_zz": 1.6, "m_yz": 0.2,
    "b_yy": 0.5, "b_zz": 0.5, "b_yz": 0.05,
    "k_yy": 0.0, "k_zz": 0.0, "k_yz": 0.0,
}


def _gain_matrix(g: Mapping[str, float], prefix: str) -> list[list[Rational]]:
    yy = _pi(g[f"k_p{prefix}yy"], g[f"k_v{prefix}yy"])
    zz = _pi(g[f"k_p{prefix}zz"], g[f"k_v{prefix}zz"])
    yz = _pi(g[f"k_p{prefix}yz"], g[f"k_v{prefix}yz"])
    zy = _pi(g.get(f"k_p{prefix}zy", g[f"k_p{prefix}yz"]), g.get(f"k_v{prefix}zy", g[f"k_v{prefix}yz"]))
    return [[yy, yz], [zy, zz]]


def _robot_matrix(r: Mapping[str, float], prefix: str) -> list[list[Rational]]:
    def z(ax: str) -> Rational:
        return _mbk(r[f"m{prefix}_{ax}"], r[f"b{prefix}_{ax}"], r[f"k{prefix}_{ax}"])

    return [[z("yy"), z("yz")], [z("yz"), z("zz")]]


def _table2_name(gm: Mapping[str, float], gs: Mapping[str, float]) -> str:
    """The Table II set a gain mapping equals on both sides (zy = yz), e.g. "B (Table II)"; else "custom"."""
    for set_name, t in TWO_DOF_TABLE2.items():
        ok = True
        for side, g in (("m", gm), ("s", gs)):
            for k, v in t.items():
                key = k[:3] + side + k[3:]
                alt = key[:-2] + "zy" if key.endswith("yz") else None
                if not math.isclose(float(g.get(key, math.nan)), float(v), rel_tol=1e-12) or (
                        alt is not None and alt in g and not math.isclose(float(g[alt]), float(v), rel_tol=1e-12)):
                    ok = False
        if ok:
            return f"{set_name} (Table II)"
    return "custom"


def bilateral_2dof(gains: str | Mapping[str, float] = "A1", params: Mapping[str, float] | None = None,
                   **kw: float) -> TransferMatrix:
    """Paper 000 eq. (44): [F_h; F_e] = [[C_m + Z_m, -C_m], [-C_s, C_s + Z_s]] [V_h; V_e], a 2-port
    with 2 DOFs (y, z) per port.

    ``gains`` is a Table II set name ("A1", "A2", "B") or a mapping; keys ``k_pyy``... apply to
    both master and slave unless master/slave-specific keys ``k_pmyy`` / ``k_psyy`` are given.
    Robot parameters default to :data:`TWO_DOF_ROBOT` for both master (``mm_yy``...) and slave.
    """
    if isinstance(gains, str) and gains not in TWO_DOF_TABLE2:
        raise ModelError(f"unknown gain set {gains!r} of 000 Table II; known: {', '.join(TWO_DOF_TABLE2)}")
    g = dict(TWO_DOF_TABLE2[gains]) if isinstance(gains, str) else dict(gains)
    g.update({k: v for k, v in kw.items() if k.startswith("k_")})
    # shared keys k_pyy ... (5 chars) apply to both sides; k_pmyy / k_psyy (6 chars) to one side
    gm = {k[:3] + "m" + k[3:]: v for k, v in g.items() if len(k) == 5}
    gs = {k[:3] + "s" + k[3:]: v for k, v in g.items() if len(k) == 5}
    gm.update({k: v for k, v in g.items() if len(k) == 6 and k[3] == "m"})
    gs.update({k: v for k, v in g.items() if len(k) == 6 and k[3] == "s"})
    r0 = {**TWO_DOF_ROBOT, **(params or {}), **{k: v for k, v in kw.items() if not k.startswith("k_")}}
    rob = {}
    for side in ("m", "s"):
        for key in ("m", "b", "k"):
            for ax in ("yy", "zz", "yz"):
                rob[f"{key}{side}_{ax}"] = r0.get(f"{key}{side}_{ax}", r0[f"{key}_{ax}"])
    Cm, Cs = _gain_matrix(gm, "m"), _gain_matrix(gs, "s")
    Zm, Zs = _robot_matrix(rob, "m"), _robot_matrix(rob, "s")
    rows = [[Cm[i][j] + Zm[i][j] for j in range(2)] + [-Cm[i][j] for j in range(2)] for i in range(2)]
    rows += [[-Cs[i][j] for j in range(2)] + [Cs[i][j] + Zs[i][j] for j in range(2)] for i in range(2)]
    name = f"bilateral_2dof (000 eq. 44, gains {gains if isinstance(gains, str) else _table2_name(gm, gs)})"
    return TransferMatrix(rows, "impedance", (2, 2), name)


# ---------------------------------------------------------------------------------------------
# paper 001: dual-master / single-slave 3-DOF system, eq. (17)

#: Table I of paper 001 (simulation gains) and the masses of section VI-A. ``k_pmyz`` is 30
#: (the paper's weakly stable case) or 300 (potentially unstable).
DUAL_MASTER_TABLE1: dict[str, float] = {
    # masters' local controller C_m (block diag: x | yz)
    "k_pmxx": 400, "k_vmxx": 80, "k_pmyy": 300, "k_vmyy": 60, "k_pmzz": 250, "k_vmzz": 50,
    "k_pmyz": 30, "k_vmyz": 10,
    # slave -> masters coupling C_4 (block diag)
    "k_p4xx": 400, "k_v4xx": 80, "k_p4yy": 300, "k_v4yy": 60, "k_p4zz": 250, "k_v4zz": 50,
    "k_p4yz": 30, "k_v4yz": 10,
    # slave local controller C_s (full symmetric)
    "k_psxx": 200, "k_vsxx": 40, "k_psyy": 150, "k_vsyy": 30, "k_pszz": 125, "k_vszz": 25,
    "k_psxy": 0, "k_vsxy": 0, "k_psxz": 15, "k_vsxz": 20, "k_psyz": 15, "k_vsyz": 5,
    # masters -> slave coupling C_1 (full symmetric)
    "k_p1xx": 200, "k_v1xx": 40, "k_p1yy": 150, "k_v1yy": 30, "k_p1zz": 125, "k_v1zz": 25,
    "k_p1xy": 0, "k_v1xy": 0, "k_p1xz": 0, "k_v1xz": 0, "k_p1yz": 15, "k_v1yz": 5,
    # masses (section VI-A)
    "m_mxx": 1.7, "m_myy": 1.9, "m_mzz": 1.3, "m_myz": 0.3,
    "m_sxx": 23, "m_sxy": 5, "m_syy": 5.6, "m_szz": 15, "m_sxz": 0.5, "m_syz": 1.3,
}


def _sym3(q: Mapping[str, float], tag: str, block_x: bool) -> list[list[Rational]]:
    ax = ("x", "y", "z")

    def entry(a: str, b: str) -> Rational:
        key = "".join(sorted(a + b, key=ax.index))
        if block_x and ("x" in key) and key != "xx":
            return Rational.const(0.0)
        return _pi(q[f"k_p{tag}{key}"], q[f"k_v{tag}{key}"])

    return [[entry(a, b) for b in ax] for a in ax]


def dual_master_3dof(p: Mapping[str, float] | None = None, **kw: float) -> TransferMatrix:
    """Paper 001 eq. (17): [F_h; F_e] = [[C_m + Z_m, -C_4], [-C_1, C_s + Z_s]] [V_h; V_e], a two-port
    with 3 DOFs per port (master 1 moves x; master 2 moves y, z; the slave moves x, y, z).

    Robots are masses (Z = M s, eq. 14). C_m and C_4 are block diagonal (x | yz); C_s and C_1 are
    full symmetric. See docs/PAPER_NOTES.md for what Theorem 1 gives on Table I exactly.
    """
    q = {**DUAL_MASTER_TABLE1, **(p or {}), **kw}
    Cm, C4 = _sym3(q, "m", True), _sym3(q, "4", True)
    Cs, C1 = _sym3(q, "s", False), _sym3(q, "1", False)
    Mm = np.array([[q["m_mxx"], 0, 0], [0, q["m_myy"], q["m_myz"]], [0, q["m_myz"], q["m_mzz"]]])
    Ms = np.array([[q["m_sxx"], q["m_sxy"], q["m_sxz"]], [q["m_sxy"], q["m_syy"], q["m_syz"]],
                   [q["m_sxz"], q["m_syz"], q["m_szz"]]])
    rows = [[Cm[i][j] + Mm[i, j] * S for j in range(3)] + [-C4[i][j] for j in range(3)] for i in range(3)]
    rows += [[-C1[i][j] for j in range(3)] + [Cs[i][j] + Ms[i, j] * S for j in range(3)] for i in range(3)]
    return TransferMatrix(rows, "impedance", (3, 3), "dual_master_3dof (001 eq. 17)")


# ---------------------------------------------------------------------------------------------
# terminations


def termination_T1() -> TransferMatrix:
    """Paper 000 eq. (1): a 2-DOF termination whose diagonal entries are passive but which is not."""
    return TransferMatrix([[8 / (S + 3), -5 / (S + 1)], [-5 / (S + 1), 1 / (S + 3)]], "impedance", (2,),
                          "T1 (000 eq. 1)")


def termination_T2() -> TransferMatrix:
    """Paper 001 section VI-A: the passive 3-DOF termination T2 used at the slave port."""
    return TransferMatrix([
        [9 / (S + 1), -2 / (S + 2), -1 / (S + 3)],
        [-2 / (S + 2), 5 / (S + 1), 2 / (S + 1)],
        [-1 / (S + 3), 2 / (S + 1), 4 / (S + 1)],
    ], "impedance", (3,), "T2 (001 sec. VI-A)")


def example_Z_000_eq5() -> TransferMatrix:
    """Paper 000 eq. (5): the 2x2 sub-block Z_x = Z_y used to show per-DOF Llewellyn checks pass."""
    return TransferMatrix([[9 / (S + 3), -1 / (S + 1)], [-1 / (S + 1), 1 / (S + 3)]], "impedance", (1, 1),
                          "Z_x (000 eq. 5)")
