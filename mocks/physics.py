"""Coupled multi-port physics: mass-damper-spring bodies, couplings, terminations, SDEA plants.

Everything in a :class:`Scene` (bodies, springs/dampers between bodies or to ground, passive
terminations, humans) is assembled into ONE continuous-time state space and discretized once
(exactly, ZOH, :mod:`hil.lti`), so dampers and terminations with direct feedthrough never
form an algebraic loop and stiff couplings cannot destabilize the integration.

Units and signs
---------------
* Generalized coordinates per body DOF: m (linear) or rad (rotary); velocities m/s or rad/s;
  efforts N or N.m; stiffness N/m or N.m/rad; damping N.s/m or N.m.s/rad; mass kg or kg.m^2.
  A :class:`Scene` only records which family (``units``); the algebra is the same.
* A positive actuator effort accelerates the DOF in its positive direction.
* Each body obeys ``M a + B v + K q = effort + (forces of attached elements)``; its own ``B`` and
  ``K`` act relative to ground (position 0).
* Every element (spring, termination, human) sees its port displacement ``G q`` (``G`` maps the
  generalized coordinates to the port: ``P_a - P_b`` for a two-body spring, ``P_a`` to ground)
  and the element force ``f_e`` is the force the device exerts ON the element; the element
  exerts ``-G^T f_e`` on the generalized coordinates. For a termination ``f_e = Z(s) G v``.
* ``<body>.force`` (what a force sensor on that body measures, returned by
  ``SimulatedJoints.measured_force``) is the force the body exerts on everything attached to it:
  ``sum_e (G_e^T f_e)`` restricted to the body's DOFs. For an SDEA motor body this is the
  series spring-damper force ``F = K_f (x_m - x_e) + B_f (v_m - v_e)``; for a handle held by a
  human it is the force the handle exerts on the hand (minus the force the hand applies).

State vector: ``x = [q (all body DOFs in insertion order), v (same order), termination states]``.
Inputs: ``<body>.effort`` for every body, then ``<human>.active`` for every human.
Outputs: ``<body>.position``, ``<body>.velocity``, ``<body>.force`` per body, then
``<element>.force`` and ``<element>.displacement`` (port displacement ``G q``) per element.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg as sla

from hil.errors import ModelError
from hil.lti import ArrayLike, StateSpace
from hil.mocks.terminations import ForceProfile, Human, Impedance, Termination, WallSpring, _psd_matrix

logger = logging.getLogger(__name__)

Units = Literal["linear", "rotary"]
#: A body port: a body name (all its DOFs), ``(name, [dof indices])`` or ``(name, S)`` with a
#: selection matrix ``S`` of shape ``(d, body.dof)``.
Port = str | tuple[str, Sequence[int] | np.ndarray]


def validate_mbk(
    M: ArrayLike, B: ArrayLike | None, K: ArrayLike | None, name: str = "body"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate mass (symmetric positive definite), damping and stiffness (symmetric PSD).

    Scalars and vectors are turned into (diagonal) matrices. Raises :class:`ModelError` with
    the offending matrix named.
    """
    M_arr = np.asarray(M, dtype=float)
    dof = 1 if M_arr.ndim == 0 else M_arr.shape[0]
    Mv = _psd_matrix(M_arr, dof, f"{name}: mass matrix M", definite=True)
    Bv = _psd_matrix(0.0 if B is None else B, dof, f"{name}: damping matrix B")
    Kv = _psd_matrix(0.0 if K is None else K, dof, f"{name}: stiffness matrix K")
    return Mv, Bv, Kv


@dataclass(frozen=True)
class Body:
    """An m-DOF mass-damper-spring body ``M a + B v + K q = f`` (see module doc for units)."""

    name: str
    M: np.ndarray
    B: np.ndarray
    K: np.ndarray
    offset: int  # index of its first DOF in the scene's generalized coordinates

    @property
    def dof(self) -> int:
        return self.M.shape[0]


@dataclass
class _Element:
    name: str
    kind: str  # "spring" | "impedance" | "human"
    G: np.ndarray  # (d, N)
    K: np.ndarray | None = None
    B: np.ndarray | None = None
    mass: np.ndarray | None = None
    Z: StateSpace | None = None
    active: ForceProfile | None = None
    bodies: tuple[str, ...] = ()


@dataclass(frozen=True)
class JointMap:
    """Where one body's handle reads and writes in a :class:`Plant` (slices into u and y)."""

    body: str
    dof: int
    effort: slice
    position: slice
    velocity: slice
    force: slice
    q: slice  # slice of the state vector holding the body's positions
    v: slice  # ... and velocities


@dataclass(frozen=True)
class Plant:
    """A continuous-time scene model ready for simulation.

    ``system`` has named inputs/outputs; ``inputs``/``outputs`` map group names to slices;
    ``joints`` maps body names to their :class:`JointMap`; ``profiles`` maps exogenous input
    groups (``<human>.active``) to their force profiles.
    """

    system: StateSpace
    inputs: dict[str, slice]
    outputs: dict[str, slice]
    joints: dict[str, JointMap]
    profiles: dict[str, ForceProfile | None] = field(default_factory=dict)
    units: Units = "linear"
    n_dof: int = 0

    def state(self, q: ArrayLike | None = None, v: ArrayLike | None = None) -> np.ndarray:
        """A state vector with generalized positions ``q`` and velocities ``v`` (termination
        states zero)."""
        x = np.zeros(self.system.n)
        if q is not None:
            x[: self.n_dof] = np.asarray(q, dtype=float).reshape(self.n_dof)
        if v is not None:
            x[self.n_dof : 2 * self.n_dof] = np.asarray(v, dtype=float).reshape(self.n_dof)
        return x

    def output_matrices(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """``(C, D)`` rows of output group ``name``."""
        try:
            sl = self.outputs[name]
        except KeyError as exc:
            raise ModelError(f"no output {name!r}; have {sorted(self.outputs)}") from exc
        return self.system.C[sl], self.system.D[sl]


class Scene:
    """Builder of a coupled multi-port plant. Add bodies, then elements, then :meth:`build`."""

    def __init__(self, units: Units = "linear") -> None:
        if units not in ("linear", "rotary"):
            raise ModelError(f"units must be 'linear' or 'rotary', got {units!r}")
        self.units: Units = units
        self.bodies: dict[str, Body] = {}
        self._elements: list[_Element] = []
        self._n = 0

    # -- construction ------------------------------------------------------------------------

    def add_body(self, name: str, M: ArrayLike, B: ArrayLike | None = None,
                 K: ArrayLike | None = None) -> Body:
        """Add an m-DOF body with mass ``M`` (SPD), damping ``B`` and stiffness ``K`` to ground
        (symmetric PSD, cross-coupling allowed)."""
        self._check_name(name)
        Mv, Bv, Kv = validate_mbk(M, B, K, name)
        body = Body(name, Mv, Bv, Kv, self._n)
        self.bodies[name] = body
        self._n += body.dof
        if self._elements:
            # generalized coordinate count changed: widen existing port maps
            for e in self._elements:
                e.G = np.hstack([e.G, np.zeros((e.G.shape[0], body.dof))])
        return body

    def add_spring(self, a: Port, b: Port | None = None, stiffness: ArrayLike = 0.0,
                   damping: ArrayLike = 0.0, name: str | None = None) -> str:
        """Spring (+ parallel damper) between ports ``a`` and ``b`` (``None`` = ground at 0).

        The element force is ``K (x_a - x_b) + B (v_a - v_b)`` (force ``a`` exerts on the
        spring; ``a`` receives its negative, ``b`` receives it). Returns the element name.
        """
        Ga, ba = self._port(a)
        bodies: tuple[str, ...] = (ba,)
        if b is not None:
            Gb, bb = self._port(b)
            if Gb.shape[0] != Ga.shape[0]:
                raise ModelError(f"spring ports have {Ga.shape[0]} and {Gb.shape[0]} DOF")
            G = Ga - Gb
            bodies = (ba, bb)
        else:
            G = Ga
        d = G.shape[0]
        name = name or f"spring{len(self._elements)}"
        self._check_name(name)
        K = _psd_matrix(stiffness, d, f"{name}: stiffness")
        B = _psd_matrix(damping, d, f"{name}: damping")
        self._elements.append(_Element(name, "spring", G, K=K, B=B, bodies=bodies))
        return name

    def add_termination(self, port: Port, termination: Termination | StateSpace,
                        name: str | None = None) -> str:
        """Attach a passive termination to ``port`` (see :mod:`hil.mocks.terminations` for the
        sign convention). Returns the element name."""
        if isinstance(termination, StateSpace):
            termination = Impedance(termination)
        G, body = self._port(port)
        d = G.shape[0]
        name = name or getattr(termination, "name", None) or f"term{len(self._elements)}"
        self._check_name(name)
        if isinstance(termination, WallSpring):
            K, B = termination.matrices(d)
            self._elements.append(_Element(name, "spring", G, K=K, B=B, bodies=(body,)))
        elif isinstance(termination, Impedance):
            if termination.dim != d:
                raise ModelError(f"termination {name!r} has {termination.dim} ports, port has {d} DOF")
            self._elements.append(_Element(name, "impedance", G, Z=termination.system, bodies=(body,)))
        elif isinstance(termination, Human):
            m, b, k = termination.matrices(d)
            self._elements.append(_Element(name, "human", G, K=k, B=b, mass=m,
                                           active=termination.active, bodies=(body,)))
        else:
            raise ModelError(f"unsupported termination type {type(termination).__name__}")
        return name

    def add_human(self, port: Port, human: Human, name: str | None = None) -> str:
        """Attach a :class:`Human` (passive arm + active force input ``<name>.active``)."""
        return self.add_termination(port, human, name or human.name)

    def add_sdea(self, name: str, M: float, B: float, K_f: float, B_f: float,
                 m_out: float | None = None, b_out: float = 0.0) -> tuple[str, str | None, str]:
        """Add a 1-DOF series damped elastic actuator.

        Motor body ``name`` (inertia ``M``, viscous damping ``B`` to ground, driven by the motor
        effort) connected through the series spring ``K_f`` in parallel with damper ``B_f`` to
        the end-effector body ``<name>_out`` (mass ``m_out``, damping ``b_out`` to ground; free
        output), or to ground when ``m_out is None`` (locked output, ``x_e = 0``).
        The spring element ``<name>_spring`` has force ``F = K_f (x_m - x_e) + B_f (v_m - v_e)``
        (what the SDEA force sensor measures; also ``<name>.force``). Returns
        ``(motor body, output body or None, spring element)``.
        """
        self.add_body(name, M, B)
        out = None
        if m_out is not None:
            out = f"{name}_out"
            self.add_body(out, m_out, b_out)
        spring = self.add_spring(name, out, K_f, B_f, name=f"{name}_spring")
        return name, out, spring

    def _check_name(self, name: str) -> None:
        if not name or name in self.bodies or any(e.name == name for e in self._elements):
            raise ModelError(f"name {name!r} is empty or already used in the scene")

    def _port(self, port: Port) -> tuple[np.ndarray, str]:
        if isinstance(port, str):
            body_name, sel = port, None
        else:
            body_name, sel = port
        body = self.bodies.get(body_name)
        if body is None:
            raise ModelError(f"unknown body {body_name!r}; add it before attaching elements")
        if sel is None:
            S = np.eye(body.dof)
        else:
            sel_arr = np.asarray(sel)
            if sel_arr.ndim == 2:
                S = sel_arr.astype(float)
                if S.shape[1] != body.dof:
                    raise ModelError(f"selection matrix for {body_name!r} must have {body.dof} columns")
            else:
                idx = sel_arr.astype(int).reshape(-1)
                if np.any(idx < 0) or np.any(idx >= body.dof):
                    raise ModelError(f"DOF index out of range for body {body_name!r} ({body.dof} DOF)")
                S = np.eye(body.dof)[idx]
        G = np.zeros((S.shape[0], self._n))
        G[:, body.offset : body.offset + body.dof] = S
        return G, body_name

    # -- assembly ----------------------------------------------------------------------------

    def build(self) -> Plant:
        """Assemble the coupled continuous-time state space (see module doc for the layout)."""
        if not self.bodies:
            raise ModelError("scene has no body")
        N = self._n
        bodies = list(self.bodies.values())
        Mt = sla.block_diag(*[b.M for b in bodies])
        Bt = sla.block_diag(*[b.B for b in bodies])
        Kt = sla.block_diag(*[b.K for b in bodies])
        imps = [e for e in self._elements if e.kind == "impedance"]
        humans = [e for e in self._elements if e.kind == "human"]
        for e in self._elements:
            G = e.G
            if e.K is not None:
                Kt = Kt + G.T @ e.K @ G
            if e.B is not None:
                Bt = Bt + G.T @ e.B @ G
            if e.mass is not None:
                Mt = Mt + G.T @ e.mass @ G
            if e.Z is not None:
                Bt = Bt + G.T @ e.Z.D @ G
        nz = sum(e.Z.n for e in imps if e.Z is not None)
        n = 2 * N + nz
        # inputs: efforts for every body DOF (identity), then human active forces
        m_h = sum(e.G.shape[0] for e in humans)
        m = N + m_h
        Fu = np.zeros((N, m))  # generalized force per unit input
        Fu[:, :N] = np.eye(N)
        inputs: dict[str, slice] = {f"{b.name}.effort": slice(b.offset, b.offset + b.dof) for b in bodies}
        profiles: dict[str, ForceProfile | None] = {}
        col = N
        for e in humans:
            d = e.G.shape[0]
            Fu[:, col : col + d] = e.G.T
            inputs[f"{e.name}.active"] = slice(col, col + d)
            profiles[f"{e.name}.active"] = e.active
            col += d
        # generalized force from termination states: -G^T Cz z
        Fz = np.zeros((N, nz))
        Az = np.zeros((nz, nz))
        Bz = np.zeros((nz, N))
        zoff: dict[str, int] = {}
        k = 0
        for e in imps:
            Z = e.Z
            assert Z is not None
            zoff[e.name] = k
            Fz[:, k : k + Z.n] = -e.G.T @ Z.C
            Az[k : k + Z.n, k : k + Z.n] = Z.A
            Bz[k : k + Z.n] = Z.B @ e.G
            k += Z.n
        try:
            cho = sla.cho_factor(Mt)
        except np.linalg.LinAlgError as exc:  # pragma: no cover - bodies are validated SPD
            raise ModelError("assembled mass matrix is not positive definite") from exc
        A = np.zeros((n, n))
        Bm = np.zeros((n, m))
        A[:N, N : 2 * N] = np.eye(N)
        A[N : 2 * N, :N] = -sla.cho_solve(cho, Kt)
        A[N : 2 * N, N : 2 * N] = -sla.cho_solve(cho, Bt)
        if nz:
            A[N : 2 * N, 2 * N :] = sla.cho_solve(cho, Fz)
            A[2 * N :, N : 2 * N] = Bz
            A[2 * N :, 2 * N :] = Az
        Bm[N : 2 * N] = sla.cho_solve(cho, Fu)
        # rows of x and u giving q, v, a (acceleration)
        Sq = np.hstack([np.eye(N), np.zeros((N, n - N))])
        Sv = np.hstack([np.zeros((N, N)), np.eye(N), np.zeros((N, nz))])
        Ca, Da = A[N : 2 * N], Bm[N : 2 * N]
        # element forces (force the device exerts on the element) as C x + D u
        elem_rows: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]] = []
        for e in self._elements:
            G = e.G
            d = G.shape[0]
            Ce = np.zeros((d, n))
            De = np.zeros((d, m))
            if e.kind in ("spring", "human"):
                assert e.K is not None and e.B is not None
                Ce += e.K @ G @ Sq + e.B @ G @ Sv
            if e.kind == "human":
                assert e.mass is not None
                Ce += e.mass @ G @ Ca
                De += e.mass @ G @ Da
                sl = inputs[f"{e.name}.active"]
                De[:, sl] -= np.eye(d)
            if e.kind == "impedance":
                Z = e.Z
                assert Z is not None
                Ce[:, 2 * N + zoff[e.name] : 2 * N + zoff[e.name] + Z.n] = Z.C
                Ce += Z.D @ G @ Sv
            elem_rows.append((e.name, Ce, De, G))
        C_blocks: list[np.ndarray] = []
        D_blocks: list[np.ndarray] = []
        outputs: dict[str, slice] = {}
        row = 0

        def emit(key: str, Cb: np.ndarray, Db: np.ndarray) -> None:
            nonlocal row
            outputs[key] = slice(row, row + Cb.shape[0])
            C_blocks.append(Cb)
            D_blocks.append(Db)
            row += Cb.shape[0]

        joints: dict[str, JointMap] = {}
        for b in bodies:
            idx = slice(b.offset, b.offset + b.dof)
            emit(f"{b.name}.position", Sq[idx], np.zeros((b.dof, m)))
            emit(f"{b.name}.velocity", Sv[idx], np.zeros((b.dof, m)))
            Cf = np.zeros((b.dof, n))
            Df = np.zeros((b.dof, m))
            for _, Ce, De, G in elem_rows:
                Cf += (G.T @ Ce)[idx]
                Df += (G.T @ De)[idx]
            emit(f"{b.name}.force", Cf, Df)
            joints[b.name] = JointMap(
                body=b.name, dof=b.dof, effort=inputs[f"{b.name}.effort"],
                position=outputs[f"{b.name}.position"], velocity=outputs[f"{b.name}.velocity"],
                force=outputs[f"{b.name}.force"], q=idx, v=slice(N + b.offset, N + b.offset + b.dof),
            )
        for name, Ce, De, G in elem_rows:
            emit(f"{name}.force", Ce, De)
            emit(f"{name}.displacement", G @ Sq, np.zeros((G.shape[0], m)))
        C = np.vstack(C_blocks)
        D = np.vstack(D_blocks)
        state_names = ([f"{b.name}.q{i}" for b in bodies for i in range(b.dof)]
                       + [f"{b.name}.v{i}" for b in bodies for i in range(b.dof)]
                       + [f"{e.name}.z{i}" for e in imps if e.Z is not None for i in range(e.Z.n)])
        input_names = [f"{key}[{i}]" for key, sl in inputs.items() for i in range(sl.stop - sl.start)]
        output_names = [f"{key}[{i}]" for key, sl in outputs.items() for i in range(sl.stop - sl.start)]
        system = StateSpace(A, Bm, C, D, state_names=state_names, input_names=input_names,
                            output_names=output_names)
        logger.debug("built scene: %d bodies, %d elements, %d states", len(bodies), len(self._elements), n)
        return Plant(system, inputs, outputs, joints, profiles, self.units, N)


# ----------------------------------------------------------------------------------------------
# Convenience plants
# ----------------------------------------------------------------------------------------------


def mbk_plant(M: ArrayLike, B: ArrayLike | None = None, K: ArrayLike | None = None,
              name: str = "body", units: Units = "linear") -> Plant:
    """A single m-DOF body ``M a + B v + K q = effort`` as a plant (handle ``name``)."""
    scene = Scene(units)
    scene.add_body(name, M, B, K)
    return scene.build()


def sdea_plant(M: float, B: float, K_f: float, B_f: float, m_out: float | None = None,
               b_out: float = 0.0, name: str = "sdea", units: Units = "rotary") -> Plant:
    """A 1-DOF SDEA plant (see :meth:`Scene.add_sdea`); ``m_out=None`` locks the output.

    Rotary by default: M in kg.m^2, B in N.m.s/rad, K_f in N.m/rad, B_f in N.m.s/rad, effort
    in N.m. Handle ``name`` drives the motor; its ``measured_force`` is the spring force F.
    Outputs include ``<name>.position`` (motor), ``<name>_out.position`` (end effector, when
    free) and ``<name>_spring.force`` (F).
    """
    scene = Scene(units)
    scene.add_sdea(name, M, B, K_f, B_f, m_out, b_out)
    return scene.build()
