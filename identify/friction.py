"""Friction in the identification plant models: viscous + Coulomb (+ Stribeck) + a constant offset.

One actuated joint (the 1-DOF ``mbk`` model with friction; per joint of the multi-DOF models) obeys

    M q'' = u - F_0 - F_f(q'),     F_f(v) = B v + (F_c + F_s exp(-(v/v_s)^2)) sgn(v)   (moving)

with ``u`` the actuator force (effort command) [N] or torque [N.m], held constant over each sample
period ``T`` (the bench's zero-order hold), ``q`` the position [m] or angle [rad]. Parameters
(:data:`PARAMETERS`; linear units, rotary in brackets):

* ``M`` mass [kg] (inertia [kg.m^2]);
* ``B`` viscous damping [N.s/m] ([N.m.s/rad]) -- the only damping the linear stability conditions
  may count (Coulomb friction is passive but not a damping);
* ``F_c`` Coulomb friction level [N] ([N.m]), term ``coulomb``;
* ``F_s`` Stribeck excess at rest [N] ([N.m]) and ``v_s`` its velocity scale [m/s] ([rad/s]), term
  ``stribeck`` (implies ``coulomb``): the break-away force is ``F_c + F_s``;
* ``F_0`` constant offset [N] ([N.m]), term ``offset``: a force the actuator spends whatever the
  motion (gravity on an inclined axis, a drive's current offset). Sign convention of the inverse
  model ``u = M q'' + B q' + F_c sgn(q') + F_0`` (the EMPS benchmark's ``OF1``).

At rest (``q' = 0``) friction holds the joint while ``|u - F_0| <= F_c + F_s`` (stiction) and
breaks away in the direction of ``u - F_0`` otherwise (Karnopp's model; Armstrong-Helouvry,
Dupont, Canudas de Wit, *Automatica* 30 (1994) 1083).

Simulation (:func:`simulate`), exact for viscous + Coulomb + offset: between velocity reversals the
joint is linear with a constant Coulomb force, so over one period ``v(t) = v_inf + (v0 - v_inf)
e^{-t/tau}``, ``tau = M/B``, ``v_inf = (u - F_0 - F_c s)/B``, and the position is its integral. A step
in which ``v`` reaches zero is split at the crossing time ``t* = tau ln((v0 - v_inf)/(-v_inf))``: the
joint then sticks for the rest of the period or continues in the other direction. Runs without
reversals are computed with :func:`scipy.signal.lfilter` (the exact one-step recursion
``v_{k+1} = a v_k + (1 - a)/B (u_k - F_0 - F_c s)``, ``a = e^{-T/tau}``), so a 25 000-sample record
costs well under a millisecond per reversal. With ``stribeck`` the Stribeck excess
``F_s exp(-(v/v_s)^2)`` is held over each period at its value at the period's start (explicit;
the Coulomb part, stiction and crossings stay exact), in a time-stepping kernel vectorized over
parameter vectors.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import lfilter

from hil.identify.errors import ModelSpecError
from hil.identify.inverse_models import (
    FRICTION_TERMS,
    PARAMETERS,
    Equation,
    InverseDynamicsModel,
    Joint,
    friction_names,
    model_parameter,
    normalize_friction,
)
from hil.identify.models import Parameter

if TYPE_CHECKING:
    from hil.identify.idim import Motion

logger = logging.getLogger(__name__)

__all__ = [
    "FRICTION_TERMS",
    "PARAMETERS",
    "FrictionModel",
    "friction_force",
    "normalize_friction",
    "simulate",
]

def parameter_names(terms: Sequence[str]) -> tuple[str, ...]:
    """Parameter names of a 1-DOF model with friction ``terms`` (in vector order)."""
    return ("M", "B", *friction_names(terms))


class FrictionModel(InverseDynamicsModel):
    """``n_dof`` mass-damper(-spring) joints with viscous + optional Coulomb/Stribeck friction and an
    offset on every joint (module docstring; :mod:`hil.identify.inverse_models`).

    One DOF: parameters ``M``, ``B``, ``F_c``, ``F_s``, ``v_s``, ``F_0`` (:func:`parameter_names`), a free
    joint as in the EMPS benchmark (no spring). ``n_dof > 1``: the symmetric ``M``, ``B``, ``K`` of the
    linear ``mbk`` model, by their entries ``M_ij``, ``B_ij``, ``K_ij`` (``i <= j``; the names of
    :meth:`hil.identify.models.MbkModel.derived`; diagonal ``M``, ``B`` positive, the rest of any sign)
    and per joint ``i`` the friction ``F_c_i``, ``F_s_i``, ``v_s_i``, ``F_0_i``; equation ``i`` balances
    the force ``force_i`` held on joint ``i``:

        u_i = sum_j (M_ij q_j'' + B_ij q_j' + K_ij q_j) + F_c_i sgn(q_i') + F_0_i
              [+ F_s_i e^{-(q_i'/v_s_i)^2} sgn(q_i')]

    Input ``force`` (``force_i``) [N or N.m]; output ``position`` (``position_i``) [m or rad] (the
    encoder) or ``velocity``. Nonlinear: no frequency response (``frf`` is the viscous part's, for
    reporting only); one DOF is simulated in the time domain (:meth:`simulate`). ``nominal`` {name:
    value} sets nominal values (data derived: the IDIM-LS start) and the bounds
    (:func:`hil.identify.inverse_models.model_parameter`); ``scale`` {name: magnitude} the ranges of the
    entries of any sign (default ``span`` times the largest diagonal entry of the same matrix).
    """

    name = "mbk"

    def __init__(
        self,
        friction: Sequence[str] = ("coulomb",),
        *,
        n_dof: int = 1,
        nominal: dict[str, float] | None = None,
        scale: dict[str, float] | None = None,
        units: str = "linear",
        output: str = "position",
        span: float = 30.0,
        force_scale: float | None = None,
        zoh_fs: float = 1000.0,
    ) -> None:
        if units not in ("linear", "rotary"):
            raise ModelSpecError("units must be 'linear' or 'rotary'")
        if output not in ("position", "velocity"):
            raise ModelSpecError("output must be 'position' or 'velocity'")
        n = int(n_dof)
        if n < 1:
            raise ModelSpecError("n_dof must be >= 1")
        self.n_dof = n
        self.terms = normalize_friction(friction)
        self.units_kind = units
        self.output = output
        col = 0 if units == "linear" else 1
        nom = {"M": 1.0, "B": 1.0, "F_c": 1.0, "F_s": 0.5, "v_s": 0.01, "F_0": 0.0, **(nominal or {})}
        fric = [k for k in nom if k.split("_")[0] == "F" and k[:3] in ("F_c", "F_0")]
        fscale = float(force_scale) if force_scale else max([abs(nom[k]) * 10 for k in fric] + [1.0])
        core: list[Parameter] = []
        ins: tuple[str, ...]
        outs: tuple[str, ...]
        if n == 1:
            self.coordinates, self.equations, self.joints = ("position",), (Equation("force", "input"),), (Joint(0, 0),)
            for k in ("M", "B"):
                core.append(model_parameter(k, "positive", PARAMETERS[k][col], PARAMETERS[k][2], nom[k], span=span,
                                            scale=1.0))
            ins, outs = ("force",), (output,)
        else:
            self.coordinates = tuple(f"position_{i}" for i in range(n))
            self.equations = tuple(Equation(f"force_{i}", "input") for i in range(n))
            self.joints = tuple(Joint(i, i, f"_{i}") for i in range(n))
            self.pairs = [(i, j) for i in range(n) for j in range(i, n)]
            for k in ("M", "B", "K"):
                unit, desc = PARAMETERS[k][col], PARAMETERS[k][2]
                diag = [abs(nom.get(f"{k}_{i}{i}", 1.0 if k != "K" else 0.0)) for i in range(n)]
                for i, j in self.pairs:
                    nm = f"{k}_{i}{j}"
                    v = nom.get(nm, (1.0 if k != "K" else 0.0) if i == j else 0.0)
                    if i == j and k != "K":
                        core.append(model_parameter(nm, "positive", unit, f"{desc} {i}{j}", v, span=span, scale=1.0))
                    else:
                        sc = (scale or {}).get(nm, span * max([*diag, 1.0]))
                        core.append(model_parameter(nm, "free", unit, f"{desc} {i}{j}", v, span=span, scale=sc))
            ins = tuple(f"force_{i}" for i in range(n))
            outs = tuple(f"{output}_{i}" for i in range(n))
        core += self.friction_parameters(nom, span=span, force_scale=fscale)
        super().__init__(core, ins, outs, zoh_fs=zoh_fs)

    def stick_joints(self) -> tuple[Joint, ...]:
        """One DOF with dry friction (``coulomb``; the spring-free joint of the module docstring): its
        joint, whose equation is ``u = f`` while it sticks (:func:`hil.identify.idim.stuck_periods`)."""
        return self.joints if self.n_dof == 1 and "stribeck" in self.terms else ()

    def structural_columns(self, m: Motion) -> list[tuple[int, int, NDArray]]:
        """``M`` with the acceleration, ``B`` the velocity, ``K`` the position: entry ``A_ij`` (``i <= j``)
        enters equation ``i`` with coordinate ``j`` and equation ``j`` with coordinate ``i``."""
        if self.n_dof == 1:
            return [(0, 0, m.a(0, "input")), (1, 0, m.v(0, "input"))]
        idx = {nm: i for i, nm in enumerate(self.names)}
        get = {"M": m.a, "B": m.v, "K": m.q}
        out: list[tuple[int, int, NDArray]] = []
        for k in ("M", "B", "K"):
            for i, j in self.pairs:
                out.append((idx[f"{k}_{i}{j}"], i, get[k](j, "input")))
                if i != j:
                    out.append((idx[f"{k}_{i}{j}"], j, get[k](i, "input")))
        return out

    def matrices(self, theta: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(M, B, K) (..., n, n) of parameter vectors (one DOF: K = 0)."""
        th = np.asarray(theta, float)
        n = self.n_dof
        out = []
        idx = {nm: i for i, nm in enumerate(self.names)}
        for k in ("M", "B", "K"):
            A = np.zeros((*th.shape[:-1], n, n))
            if n == 1:
                if k != "K":
                    A[..., 0, 0] = th[..., idx[k]]
            else:
                for i, j in self.pairs:
                    A[..., i, j] = A[..., j, i] = th[..., idx[f"{k}_{i}{j}"]]
            out.append(A)
        return out[0], out[1], out[2]

    def split(self, theta: ArrayLike) -> dict[str, NDArray[np.float64]]:
        """``{name: (...,) array}`` of a parameter batch of a 1-DOF model (missing terms: zeros)."""
        th = np.asarray(theta, float)
        out = {n: np.zeros(th.shape[:-1]) for n in PARAMETERS}
        out["v_s"] = np.ones(th.shape[:-1])
        for i, n in enumerate(self.names):
            out[n] = th[..., i]
        return out

    def _state_space(self, theta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                                  NDArray[np.float64]]:
        """The viscous (linear) part: state (q, v)."""
        Mm, Bm_, Km = self.matrices(theta)
        n = self.n_dof
        Mi = np.linalg.inv(Mm)
        A = np.zeros((*Mm.shape[:-2], 2 * n, 2 * n))
        A[..., :n, n:] = np.eye(n)
        A[..., n:, :n] = -Mi @ Km
        A[..., n:, n:] = -Mi @ Bm_
        Bin = np.zeros((*Mm.shape[:-2], 2 * n, n))
        Bin[..., n:, :] = Mi
        C = np.zeros((*Mm.shape[:-2], n, 2 * n))
        off = 0 if self.output == "position" else n
        for i in range(n):
            C[..., i, off + i] = 1.0
        return A, Bin, C

    def _core_frf(self, theta: NDArray[np.float64], s: NDArray[np.complex128]) -> NDArray[np.complex128]:
        Mm, Bm_, Km = self.matrices(theta)
        s3 = s[:, None, None]
        H = np.linalg.inv(Mm[..., None, :, :] * s3**2 + Bm_[..., None, :, :] * s3 + Km[..., None, :, :])
        if self.output == "velocity":
            H = H * s3
        return np.asarray(H, complex)

    def simulate(self, theta: ArrayLike, u: ArrayLike, *, x0: float = 0.0, v0: float = 0.0) -> NDArray[np.float64]:
        """Model output (..., n) for input samples ``u`` (n,) held over each period ``1/zoh_fs``,
        from position ``x0`` and velocity ``v0``: :func:`simulate` on the batch ``theta`` (..., p). One DOF."""
        if self.n_dof != 1:
            raise ModelSpecError("the friction simulator is for one joint (n_dof = 1)")
        th = np.asarray(theta, float)
        p = self.split(th.reshape(-1, th.shape[-1]))
        x, v = simulate(p["M"], p["B"], p["F_c"], p["F_0"], np.asarray(u, float), 1.0 / float(self.zoh_fs or 1.0),
                        F_s=p["F_s"], v_s=p["v_s"], x0=x0, v0=v0)
        y = x if self.output == "position" else v
        return y.reshape(*th.shape[:-1], -1)


def friction_force(v: ArrayLike, B: float, F_c: float = 0.0, F_s: float = 0.0, v_s: float = 1.0) -> NDArray:
    """Friction force of a MOVING joint at velocity ``v``: ``B v + (F_c + F_s exp(-(v/v_s)^2)) sgn(v)``."""
    vv = np.asarray(v, float)
    return B * vv + (F_c + F_s * np.exp(-((vv / v_s) ** 2))) * np.sign(vv)


def simulate(
    M: ArrayLike, B: ArrayLike, F_c: ArrayLike, F_0: ArrayLike, u: ArrayLike, T: float, *,
    F_s: ArrayLike | None = None, v_s: ArrayLike | None = None, x0: float = 0.0, v0: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Positions and velocities (B, n) at the sample instants ``k T`` (before input ``u_k`` acts) of
    the friction model (module docstring) for a batch of parameters (each (B,) or scalar); ``u``
    (n,) held over each period ``T`` [s]. Exact for viscous + Coulomb + offset (segment kernel);
    with a nonzero ``F_s`` the time-stepping kernel (Stribeck excess held over each period)."""
    uu = np.asarray(u, float)
    arrs = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, float)) for a in
                                 (M, B, F_c, F_0, 0.0 if F_s is None else F_s, 1.0 if v_s is None else v_s)))
    Mb, Bb, Fcb, F0b, Fsb, vsb = (np.array(a, float) for a in arrs)
    if np.any(~(Mb > 0)) or np.any(~(Bb > 0)) or np.any(Fcb < 0) or np.any(Fsb < 0) or np.any(~(vsb > 0)):
        raise ModelSpecError("friction model needs M > 0, B > 0, F_c >= 0, F_s >= 0, v_s > 0")
    if np.any(Fsb > 0):
        return _simulate_steps(Mb, Bb, Fcb, F0b, Fsb, vsb, uu, float(T), x0, v0)
    X = np.empty((Mb.size, uu.size))
    V = np.empty((Mb.size, uu.size))
    for i in range(Mb.size):
        X[i], V[i] = _simulate_segments(float(Mb[i]), float(Bb[i]), float(Fcb[i]), float(F0b[i]), uu, float(T),
                                        float(x0), float(v0))
    return X, V


#: samples filtered per call of the segment kernel (a run without reversal longer than this continues)
_CHUNK = 2048


def _simulate_segments(M: float, B: float, Fc: float, F0: float, u: NDArray[np.float64], T: float, x0: float,
                       v0: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact simulation of one parameter vector, run by run between reversals (module docstring)."""
    n = u.size
    tau = M / B
    a = float(np.exp(-T / tau))
    bv = (1.0 - a) / B
    cv = tau * (1.0 - a)  # position gained per unit starting velocity over one period
    cg = (T - cv) / B  # ... per unit net force
    f = u - F0
    V = np.empty(n + 1)
    S = np.zeros(n)  # direction of the Coulomb force per step (0: stuck, or special step)
    special = np.zeros(n, dtype=bool)
    dx_special = np.zeros(n)
    V[0] = v = float(v0)
    k = 0
    while k < n:
        if v == 0.0:  # at rest: stuck while |u - F_0| <= F_c
            idx = np.flatnonzero(np.abs(f[k:]) > Fc)
            j = n if idx.size == 0 else k + int(idx[0])
            V[k + 1 : j + 1] = 0.0
            special[k:j] = True
            k = j
            if k >= n:
                break
            s = 1.0 if f[k] > 0 else -1.0
        else:
            s = 1.0 if v > 0 else -1.0
        g = f[k : k + _CHUNK] - Fc * s
        y = lfilter([bv], [1.0, -a], g, zi=np.array([a * v]))[0]
        bad = np.flatnonzero(s * y < 0.0)
        m = y.size if bad.size == 0 else int(bad[0])
        V[k + 1 : k + m + 1] = y[:m]
        S[k : k + m] = s
        k += m
        if bad.size == 0:
            v = float(y[-1])
            continue
        # the velocity reaches zero inside step k: split it at the crossing
        v = float(V[k])
        fk = float(f[k])
        vinf = (fk - Fc * s) / B
        ts = tau * float(np.log((v - vinf) / (-vinf)))
        xs = vinf * ts + (v - vinf) * tau * (1.0 - np.exp(-ts / tau))
        r = T - ts
        if abs(fk) > Fc:  # breaks away the other way for the rest of the period
            vinf2 = (fk + Fc * s) / B
            e2 = float(np.exp(-r / tau))
            v = vinf2 * (1.0 - e2)
            xs += vinf2 * r - vinf2 * tau * (1.0 - e2)
        else:
            v = 0.0
        V[k + 1] = v
        special[k] = True
        dx_special[k] = xs
        k += 1
    dx = np.where(special, dx_special, cv * V[:n] + cg * (f - Fc * S))
    X = x0 + np.concatenate([[0.0], np.cumsum(dx[:-1])])
    return X, V[:n]


def _simulate_steps(M: NDArray, B: NDArray, Fc: NDArray, F0: NDArray, Fs: NDArray, vs: NDArray,
                    u: NDArray[np.float64], T: float, x0: float, v0: float
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Time-stepping kernel, vectorized over the batch: exact per period for the viscous and
    Coulomb parts and stiction (break-away at ``F_c + F_s``), Stribeck excess held over the period."""
    nb, n = M.size, u.size
    tau = M / B
    a = np.exp(-T / tau)
    X = np.empty((n, nb))
    V = np.empty((n, nb))
    v = np.full(nb, float(v0))
    x = np.full(nb, float(x0))
    brk = Fc + Fs
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(n):
            X[k], V[k] = x, v
            f = u[k] - F0
            s = np.sign(v)
            rest = s == 0
            s = np.where(rest, np.where(np.abs(f) > brk, np.sign(f), 0.0), s)
            level = Fc + Fs * np.exp(-((v / vs) ** 2))
            vinf = np.where(s == 0, 0.0, (f - level * s) / B)
            vn = vinf + (v - vinf) * a
            xn = x + vinf * T + (v - vinf) * tau * (1 - a)
            cross = s * vn < 0
            if np.any(cross):
                ts = np.where(cross, tau * np.log((v - vinf) / (-vinf)), 0.0)
                xs = x + vinf * ts + (v - vinf) * tau * (1 - np.exp(-ts / tau))
                s2 = np.where(np.abs(f) > brk, -s, 0.0)
                vinf2 = np.where(s2 == 0, 0.0, (f - brk * s2) / B)
                r = T - ts
                e2 = np.exp(-r / tau)
                vn = np.where(cross, vinf2 * (1 - e2), vn)
                xn = np.where(cross, xs + vinf2 * r - vinf2 * tau * (1 - e2), xn)
            v, x = vn, xn
    return X.T.copy(), V.T.copy()


def describe_terms(terms: Sequence[str]) -> str:
    """``"viscous + coulomb + offset"`` (or ``"linear (viscous only)"``)."""
    return "viscous + " + " + ".join(terms) if terms else "linear (viscous only)"
