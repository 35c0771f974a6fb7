"""Grey-box frequency-response models with physical parameter vectors.

Conventions
-----------
* Frequencies ``w`` are angular, in rad/s, and ``s = j w``.
* ``model.frf(theta, w)`` takes ``theta`` of shape ``(..., p)`` (any batch of parameter vectors, in
  physical units, in the order of ``model.names``) and returns a complex array of shape
  ``(..., n_freq, n_outputs, n_inputs)``: entry ``[..., k, o, i]`` is the transfer function from
  input ``i`` to measured output ``o`` at ``w[k]``.
* Every parameter has bounds. Strictly positive parameters (``Parameter.log``) are fitted and
  sampled in log space: the "z-space" vector is ``z = log(theta)`` for those, ``z = theta`` for the
  others (``to_z`` / ``from_z``). The default prior is uniform in z inside the bounds, i.e.
  log-uniform for positive physical parameters.
* Optional nuisance parameters appended after the physical ones: one sensor gain per measured
  output (``gain_<output>``, dimensionless, log-uniform on [0.2, 5]) multiplying that output, and
  one pure delay ``delay`` [s] multiplying every entry by ``exp(-s T)``.

Sampled (digitally controlled) benches: with ``zoh_fs`` [Hz] set, ``frf`` is the EXACT frequency
response of the plant as a sampled-data system: the input is held constant over each period
``T = 1/zoh_fs`` (zero-order hold: a drive applying the last effort command until the next one)
and the outputs are sampled at the start of each period, before the new command (the runner's
read -> command -> advance tick). With the state space ``x' = A x + B u, y = C x``::

    x_{k+1} = Phi x_k + Gamma u_k,  Phi = e^{A T},  Gamma = A^{-1} (Phi - I) B,  y_k = C x_k
    H_d(w) = C (e^{j w T} I - Phi)^{-1} Gamma
           = sum_i (C v_i)(w_i^T B) (e^{l_i T} - 1) / l_i / (e^{j w T} - e^{l_i T})

(modal form: eigenvalues ``l_i``, right/left eigenvectors ``v_i``/``w_i`` of ``A``; evaluated batched,
one eigen-decomposition per parameter vector). It differs from ``H(jw)`` by the hold's half-sample
delay and sinc droop and by aliasing -- 9 degrees of phase at f = fs/20 already, far more than the
noise of a good record. Continuous-time models (``zoh_fs=None``) suit data simulated or measured
without a hold (e.g. an anti-aliased analog test).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.identify.errors import ModelSpecError

logger = logging.getLogger(__name__)

__all__ = [
    "SDEA_NOMINAL",
    "GreyBoxModel",
    "MbkModel",
    "Parameter",
    "SdeaFreeOutput",
    "SdeaLockedOutput",
    "make_model",
]

#: Nominal SDEA values (paper Table I): K_f [N.m/rad], B_f [N.m.s/rad], M [kg.m^2], B [N.m.s/rad].
SDEA_NOMINAL: dict[str, float] = {"K_f": 362.0, "B_f": 0.05, "M": 6.399e-4, "B": 0.169}


@dataclass(frozen=True)
class Parameter:
    """One model parameter: name, unit, bounds (physical units), nominal value, log flag."""

    name: str
    unit: str
    lower: float
    upper: float
    nominal: float
    log: bool = True
    description: str = ""

    def __post_init__(self) -> None:
        if not self.lower < self.upper:
            raise ModelSpecError(f"parameter {self.name}: lower bound must be < upper bound")
        if self.log and self.lower <= 0:
            raise ModelSpecError(f"parameter {self.name}: log parameters need a positive lower bound")
        if not self.lower <= self.nominal <= self.upper:
            raise ModelSpecError(f"parameter {self.name}: nominal {self.nominal} outside bounds")


class GreyBoxModel:
    """Base class: parameter bookkeeping, z-space transforms and the gain/delay nuisance factors.

    Subclasses set ``name``, ``input_names``, ``output_names`` and implement
    :meth:`_core_frf` (the physical model without nuisance factors).
    """

    name: str = "model"

    def __init__(
        self,
        core: Sequence[Parameter],
        input_names: Sequence[str],
        output_names: Sequence[str],
        *,
        gain: bool = False,
        delay: bool = False,
        max_delay: float = 0.02,
        zoh_fs: float | None = None,
    ) -> None:
        if zoh_fs is not None and not (np.isfinite(zoh_fs) and zoh_fs > 0):
            raise ModelSpecError(f"zoh_fs must be a positive sample rate [Hz], got {zoh_fs!r}")
        self.zoh_fs = None if zoh_fs is None else float(zoh_fs)
        params = list(core)
        self.n_core = len(params)
        self.input_names = tuple(input_names)
        self.output_names = tuple(output_names)
        self.has_gain = bool(gain)
        self.has_delay = bool(delay)
        if gain:
            params += [
                Parameter(f"gain_{o}", "1", 0.2, 5.0, 1.0, True, f"sensor gain of {o}") for o in self.output_names
            ]
        if delay:
            params.append(Parameter("delay", "s", 0.0, max_delay, 0.0, False, "pure delay exp(-sT)"))
        self.parameters: tuple[Parameter, ...] = tuple(params)
        names = [p.name for p in params]
        if len(set(names)) != len(names):
            raise ModelSpecError(f"duplicate parameter names in {names}")

    # ------------------------------------------------------------------ bookkeeping
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def units(self) -> tuple[str, ...]:
        return tuple(p.unit for p in self.parameters)

    @property
    def n_params(self) -> int:
        return len(self.parameters)

    @property
    def log_mask(self) -> NDArray[np.bool_]:
        return np.array([p.log for p in self.parameters], dtype=bool)

    @property
    def lower(self) -> NDArray[np.float64]:
        return np.array([p.lower for p in self.parameters], dtype=float)

    @property
    def upper(self) -> NDArray[np.float64]:
        return np.array([p.upper for p in self.parameters], dtype=float)

    @property
    def nominal(self) -> NDArray[np.float64]:
        return np.array([p.nominal for p in self.parameters], dtype=float)

    def z_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Bounds in z-space (log for positive parameters)."""
        return self.to_z(self.lower), self.to_z(self.upper)

    def to_z(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Physical parameters -> z-space (``log`` of the positive ones)."""
        th = np.asarray(theta, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.log_mask, np.log(np.where(self.log_mask, th, 1.0)), th)

    def from_z(self, z: ArrayLike) -> NDArray[np.float64]:
        """z-space -> physical parameters."""
        zz = np.asarray(z, dtype=float)
        return np.where(self.log_mask, np.exp(np.where(self.log_mask, zz, 0.0)), zz)

    def vector(self, values: dict[str, float]) -> NDArray[np.float64]:
        """Parameter vector from a ``{name: value}`` dict; missing names take their nominal value."""
        unknown = set(values) - set(self.names)
        if unknown:
            raise ModelSpecError(f"unknown parameters {sorted(unknown)} for {self.name}; known {self.names}")
        return np.array([values.get(p.name, p.nominal) for p in self.parameters], dtype=float)

    def describe(self) -> str:
        lines = [f"{self.name}: inputs {self.input_names} -> outputs {self.output_names}"]
        lines += [
            f"  {p.name} [{p.unit}] in [{p.lower:g}, {p.upper:g}], nominal {p.nominal:g}" for p in self.parameters
        ]
        return "\n".join(lines)

    # ------------------------------------------------------------------ responses
    def _core_frf(self, theta: NDArray[np.float64], s: NDArray[np.complex128]) -> NDArray[np.complex128]:
        """Physical FRF for ``theta`` (..., n_core) -> (..., n_freq, n_out, n_in). Subclasses implement."""
        raise NotImplementedError

    def state_space(
        self, theta: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Continuous-time ``(A, B, C)`` of the physical model (no nuisance factors) for ``theta``
        (..., p or n_core): shapes (..., n, n), (..., n, n_in), (..., n_out, n). Strictly proper
        (no feedthrough) for every built-in model."""
        th = np.asarray(theta, dtype=float)
        return self._state_space(th[..., : self.n_core])

    def _state_space(
        self, theta: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        raise NotImplementedError(f"{self.name} has no state-space form (zoh_fs unavailable)")

    def _zoh_frf(self, theta: NDArray[np.float64], w: NDArray[np.float64]) -> NDArray[np.complex128]:
        """Exact ZOH-sampled FRF (module docstring) in modal form, batched over ``theta``."""
        assert self.zoh_fs is not None
        T = 1.0 / self.zoh_fs
        A, Bm, C = self._state_space(theta)
        lam, V = np.linalg.eig(A)  # (..., n), (..., n, n)
        W = np.linalg.inv(V)
        CV = C @ V  # (..., no, n)
        WB = W @ Bm  # (..., n, ni)
        R = CV[..., :, :, None].swapaxes(-3, -2) * WB[..., :, None, :]  # (..., n, no, ni): (C v_i)(w_i^T B)
        lt = lam * T
        small = np.abs(lt) < 1e-8
        g = np.where(small, T * (1 + lt / 2), np.expm1(np.where(small, 1.0, lt)) / np.where(small, 1.0, lam))
        mu = np.exp(lt)  # (..., n)
        z = np.exp(1j * w * T)  # (nf,)
        coef = g[..., None, :] / (z[:, None] - mu[..., None, :])  # (..., nf, n)
        no, ni = R.shape[-2:]
        # sum over the modes as one batched matrix product (BLAS): 7-10x less CPU than einsum's
        # generic loop for a posterior's walkers (same sums, last-bit differences only)
        return (coef @ R.reshape(*R.shape[:-2], no * ni)).reshape(*coef.shape[:-1], no, ni)

    def frf(self, theta: ArrayLike, w: ArrayLike) -> NDArray[np.complex128]:
        """Frequency response at angular frequencies ``w`` [rad/s] for a batch of parameter vectors.

        ``theta``: (..., p) physical units. Returns (..., n_freq, n_outputs, n_inputs) complex.
        With ``zoh_fs`` set: the exact response of the zero-order-hold sampled plant (module doc).
        """
        th = np.asarray(theta, dtype=float)
        if th.shape[-1] != self.n_params:
            raise ModelSpecError(f"{self.name}: expected {self.n_params} parameters, got shape {th.shape}")
        ww = np.asarray(w, dtype=float)
        s = 1j * ww
        if self.zoh_fs is not None:
            H = self._zoh_frf(th[..., : self.n_core], ww)
        else:
            H = self._core_frf(th[..., : self.n_core], s)
        k = self.n_core
        if self.has_gain:
            g = th[..., k : k + len(self.output_names)]
            H = H * g[..., None, :, None]
            k += len(self.output_names)
        if self.has_delay:
            T = th[..., k]
            H = H * np.exp(-s * T[..., None])[..., None, None]
        return H

    #: True when :meth:`to_sampling` is not the identity
    has_sampling_transform: bool = False

    def to_sampling(self, z: ArrayLike) -> NDArray[np.float64]:
        """z-space -> the coordinates the MCMC moves in (default: z itself). A model overrides this
        pair when the data pin down a nonlinear combination of z far better than the rest: the
        posterior is then a thin curved ridge in z, which ensemble samplers cross slowly, but a
        flat one in coordinates where that combination is a coordinate."""
        return np.asarray(z, dtype=float)

    def from_sampling(self, u: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Inverse of :meth:`to_sampling` and ``log |det dz/du|`` (NaN z outside its domain)."""
        uu = np.asarray(u, dtype=float)
        return uu, np.zeros(uu.shape[:-1])

    def derived(self, samples: ArrayLike) -> dict[str, tuple[NDArray[np.float64], str]]:
        """Physically meaningful functions of the parameters, per sample: ``{name: (values, unit)}``
        (e.g. the entries of M, B, K of an MBK model whose parameters are Cholesky factors)."""
        return {}

    def initial_guess(self, est: Any) -> NDArray[np.float64] | None:
        """A data-derived starting point for the fit (physical units), or None to use ``nominal``."""
        return None

    def identifiability_hint(self, names: set[str]) -> str | None:
        """A model-specific explanation/fix when ``names`` span a Fisher null direction (or None)."""
        if self.has_gain and any(n.startswith("gain_") for n in names):
            return (
                "a sensor gain multiplies the whole response and trades off against the physical scale "
                "parameters: calibrate the sensor (fix the gain) or measure a second channel with a known gain"
            )
        if "delay" in names:
            return "the delay is not resolved in this band: extend the band upwards or fix the delay"
        return None


def _split(theta: NDArray[np.float64], n: int) -> list[NDArray[np.float64]]:
    """Split the last axis into ``n`` arrays with a trailing frequency axis for broadcasting."""
    return [theta[..., i][..., None] for i in range(n)]


_SDEA_PARAMETERS = {  # name -> (unit, description); rotary SDEA of paper 002
    "K_f": ("N.m/rad", "series spring stiffness"),
    "B_f": ("N.m.s/rad", "series (parallel-to-spring) damping"),
    "M": ("kg.m^2", "actuator inertia"),
    "B": ("N.m.s/rad", "actuator viscous damping"),
    "m_h": ("kg.m^2", "output-side (handle) inertia"),
}


def _sdea_parameters(names: Sequence[str], nominal: dict[str, float], span: float) -> list[Parameter]:
    """Log-scaled SDEA parameters with bounds ``nominal / span .. nominal * span``."""
    return [Parameter(n, _SDEA_PARAMETERS[n][0], nominal[n] / span, nominal[n] * span, nominal[n], True,
                      _SDEA_PARAMETERS[n][1]) for n in names]


def _select_channels(model: str, channels: Sequence[str], allowed: tuple[str, ...]) -> tuple[str, ...]:
    """The measured outputs as a tuple; a clear error unless a non-empty subset of ``allowed``."""
    chans = tuple(channels)
    if not chans or any(c not in allowed for c in chans):
        raise ModelSpecError(f"{model}: channels must be a non-empty subset of {allowed}")
    return chans


class SdeaLockedOutput(GreyBoxModel):
    r"""1-DOF series damped elastic actuator with its end-effector locked (fixed).

    Motor side: inertia ``M`` [kg.m^2], viscous damping ``B`` [N.m.s/rad], motor torque ``tau``
    [N.m], motor angle ``x`` [rad]. The series spring ``K_f`` [N.m/rad] in parallel with the damper
    ``B_f`` [N.m.s/rad] connects the motor to the end-effector, which is fixed (``x_e = 0``).

    Equations: ``M x'' = tau - B x' - (K_f x + B_f x')`` and the spring force ``F = K_f x + B_f x'``.
    With ``D(s) = M s^2 + (B + B_f) s + K_f``::

        v / tau = s / D(s)                   (motor velocity, rad/s per N.m)
        F / tau = (B_f s + K_f) / D(s)       (spring torque, N.m per N.m)

    With the motor velocity alone, ``B`` and ``B_f`` appear only as the sum ``B + B_f``: they are not
    separately identifiable. The spring-force channel carries ``B_f`` in its zero and separates them.

    Parameters: ``K_f, B_f, M, B`` (+ optional gain/delay nuisance). ``channels`` selects the measured
    outputs among ``("velocity", "force")``.
    """

    name = "sdea_locked"
    CHANNELS = ("velocity", "force")

    def __init__(
        self,
        channels: Sequence[str] = ("velocity", "force"),
        *,
        nominal: dict[str, float] | None = None,
        gain: bool = False,
        delay: bool = False,
        span: float = 100.0,
        zoh_fs: float | None = None,
    ) -> None:
        chans = _select_channels(self.name, channels, self.CHANNELS)
        nom = {**SDEA_NOMINAL, **(nominal or {})}
        core = _sdea_parameters(("K_f", "B_f", "M", "B"), nom, span)
        self.channels = chans
        super().__init__(core, ("torque",), chans, gain=gain, delay=delay, zoh_fs=zoh_fs)

    has_sampling_transform = True

    def to_sampling(self, z: ArrayLike) -> NDArray[np.float64]:
        """MCMC coordinates ``(log K_f, log B_f, log M, log(B + B_f))``: the motor velocity fixes
        ``K_f``, ``M`` and ``B + B_f`` (often to float precision), the spring force ``B_f`` alone;
        in these coordinates the velocity constraint is flat instead of a curve in (log B, log B_f)."""
        u = np.array(z, dtype=float, copy=True)
        u[..., 3] = np.logaddexp(u[..., 3], u[..., 1])
        return u

    def from_sampling(self, u: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        z = np.array(u, dtype=float, copy=True)
        d = z[..., 1] - z[..., 3]  # log(B_f / (B + B_f)) < 0
        with np.errstate(invalid="ignore", divide="ignore"):
            l1 = np.log1p(-np.exp(np.minimum(d, 0.0)))
        ok = d < 0
        z[..., 3] = np.where(ok, z[..., 3] + l1, np.nan)
        return z, np.where(ok, -l1, np.nan)  # log |dz3/du3| = log((B + B_f)/B)

    def _state_space(
        self, theta: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        # state (x, v): M v' = tau - (B + B_f) v - K_f x;  v;  F = K_f x + B_f v
        K, Bf, M, B = (theta[..., i] for i in range(4))
        A = np.zeros((*K.shape, 2, 2))
        A[..., 0, 1] = 1.0
        A[..., 1, 0] = -K / M
        A[..., 1, 1] = -(B + Bf) / M
        Bm = np.zeros((*K.shape, 2, 1))
        Bm[..., 1, 0] = 1.0 / M
        C = np.zeros((*K.shape, len(self.channels), 2))
        for j, c in enumerate(self.channels):
            if c == "velocity":
                C[..., j, 1] = 1.0
            else:
                C[..., j, 0] = K
                C[..., j, 1] = Bf
        return A, Bm, C

    def _core_frf(self, theta: NDArray[np.float64], s: NDArray[np.complex128]) -> NDArray[np.complex128]:
        K, Bf, M, B = _split(theta, 4)
        w = s.imag
        # D(jw) = (K - M w^2) + j (B + B_f) w, evaluated in real arithmetic (this is the MCMC hot path).
        re = K - M * w**2
        im = (B + Bf) * w
        den = re**2 + im**2
        out = np.empty((*den.shape, len(self.channels), 1), dtype=complex)
        for j, c in enumerate(self.channels):
            if c == "velocity":  # j w / D
                out[..., j, 0].real = w * im / den
                out[..., j, 0].imag = w * re / den
            else:  # (K + j B_f w) / D
                bw = Bf * w
                out[..., j, 0].real = (K * re + bw * im) / den
                out[..., j, 0].imag = (bw * re - K * im) / den
        return out

    def identifiability_hint(self, names: set[str]) -> str | None:
        if {"B", "B_f"} <= names and "force" not in self.channels:
            return (
                "B and B_f are not separable from motor velocity alone (only B + B_f enters v/tau): "
                "also measure the spring force, or run the free-output experiment"
            )
        if self.channels == ("force",) and {"K_f", "M"} <= names:
            return (
                "the spring-force response F/tau has unit static gain and depends only on ratios to K_f: "
                "the absolute scale of K_f, M, B is not observable; also measure the motor velocity"
            )
        return super().identifiability_hint(names)


class SdeaFreeOutput(GreyBoxModel):
    r"""1-DOF SDEA with a free end-effector of mass ``m_h`` [kg.m^2] (known, or identified).

    Motor angle ``x1``, end-effector angle ``x2``, spring/damper impedance ``Z(s) = B_f s + K_f``,
    ``D1(s) = M s^2 + B s``, ``D2(s) = m_h s^2``::

        (D1 + Z) X1 - Z X2 = tau,     -Z X1 + (D2 + Z) X2 = 0
        Delta(s) = D1 D2 + Z (D1 + D2)
        v  / tau = s (D2 + Z) / Delta     (motor velocity)
        F  / tau = D2 Z / Delta           (spring torque F = Z (X1 - X2))
        ve / tau = s Z / Delta            (end-effector velocity)

    Here ``B_f`` also enters the numerator of ``v/tau`` (the antiresonance of the end-effector), so
    ``B`` and ``B_f`` separate even with the motor velocity alone. ``m_h=None`` identifies ``m_h``.
    """

    name = "sdea_free"
    CHANNELS = ("velocity", "force", "output_velocity")

    def __init__(
        self,
        channels: Sequence[str] = ("velocity",),
        *,
        m_h: float | None = 2e-3,
        nominal: dict[str, float] | None = None,
        gain: bool = False,
        delay: bool = False,
        span: float = 100.0,
        zoh_fs: float | None = None,
    ) -> None:
        chans = _select_channels(self.name, channels, self.CHANNELS)
        nom = {**SDEA_NOMINAL, "m_h": m_h if m_h is not None else 2e-3, **(nominal or {})}
        names = ("K_f", "B_f", "M", "B") + (("m_h",) if m_h is None else ())
        core = _sdea_parameters(names, nom, span)
        self.channels = chans
        self.m_h_fixed = m_h
        super().__init__(core, ("torque",), chans, gain=gain, delay=delay, zoh_fs=zoh_fs)

    def _state_space(
        self, theta: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        # state (d = x1 - x2, v1, v2): the spring deflection instead of both angles removes the
        # rigid-body integrator, which no output observes
        K, Bf, M, B = (theta[..., i] for i in range(4))
        m_h = theta[..., 4] if self.m_h_fixed is None else np.full(K.shape, float(self.m_h_fixed))
        A = np.zeros((*K.shape, 3, 3))
        A[..., 0, 1], A[..., 0, 2] = 1.0, -1.0
        A[..., 1, 0], A[..., 1, 1], A[..., 1, 2] = -K / M, -(B + Bf) / M, Bf / M
        A[..., 2, 0], A[..., 2, 1], A[..., 2, 2] = K / m_h, Bf / m_h, -Bf / m_h
        Bm = np.zeros((*K.shape, 3, 1))
        Bm[..., 1, 0] = 1.0 / M
        C = np.zeros((*K.shape, len(self.channels), 3))
        for j, c in enumerate(self.channels):
            if c == "velocity":
                C[..., j, 1] = 1.0
            elif c == "output_velocity":
                C[..., j, 2] = 1.0
            else:  # F = K d + B_f (v1 - v2)
                C[..., j, 0], C[..., j, 1], C[..., j, 2] = K, Bf, -Bf
        return A, Bm, C

    def _core_frf(self, theta: NDArray[np.float64], s: NDArray[np.complex128]) -> NDArray[np.complex128]:
        K, Bf, M, B = _split(theta, 4)
        m_h = theta[..., 4][..., None] if self.m_h_fixed is None else self.m_h_fixed
        Z = Bf * s + K
        D1 = M * s**2 + B * s
        D2 = m_h * s**2
        Delta = D1 * D2 + Z * (D1 + D2)
        cols = {
            "velocity": lambda: s * (D2 + Z) / Delta,
            "force": lambda: D2 * Z / Delta,
            "output_velocity": lambda: s * Z / Delta,
        }
        out = np.stack([np.broadcast_to(cols[c](), Delta.shape) for c in self.channels], axis=-1)
        return out[..., None]


class MbkModel(GreyBoxModel):
    r"""m-DOF mass-damper-spring device ``M q'' + B q' + K q = f`` with full symmetric matrices.

    Receptance ``X(s) = (M s^2 + B s + K)^{-1} F(s)``; mobility (velocity output) ``V = s X``.
    Each of ``M, B, K`` is parametrized by its lower Cholesky factor ``L`` (``M = L L^T``) with
    positive diagonal fitted in log space, so the matrices stay symmetric positive definite
    (semidefinite only as a limit) while cross-coupling (off-diagonal) terms are free.
    Parameter names ``LM_ij``, ``LB_ij``, ``LK_ij`` (``i >= j``), row-major over the lower triangle.
    Units: the factor of a matrix in unit ``u`` has unit ``sqrt(u)`` (``kg``, ``N.s/m``, ``N/m`` for
    translational DOFs).

    ``inputs``/``outputs`` select the actuated and measured DOF indices (default: all).
    """

    name = "mbk"

    def __init__(
        self,
        n_dof: int = 2,
        *,
        M: ArrayLike | None = None,
        B: ArrayLike | None = None,
        K: ArrayLike | None = None,
        output: str = "velocity",
        inputs: Sequence[int] | None = None,
        outputs: Sequence[int] | None = None,
        gain: bool = False,
        delay: bool = False,
        span: float = 30.0,
        zoh_fs: float | None = None,
        units: str = "linear",
    ) -> None:
        n = int(n_dof)
        if units not in ("linear", "rotary"):
            raise ModelSpecError("units must be 'linear' or 'rotary'")
        self.units_kind = units
        if n < 1:
            raise ModelSpecError("n_dof must be >= 1")
        if output not in ("velocity", "position"):
            raise ModelSpecError("output must be 'velocity' or 'position'")
        self.n_dof = n
        self.output = output
        self.in_idx = tuple(range(n)) if inputs is None else tuple(int(i) for i in inputs)
        self.out_idx = tuple(range(n)) if outputs is None else tuple(int(i) for i in outputs)
        mats = {
            "M": np.eye(n) if M is None else np.asarray(M, float),
            "B": np.eye(n) if B is None else np.asarray(B, float),
            "K": 100.0 * np.eye(n) if K is None else np.asarray(K, float),
        }
        self.tril = np.tril_indices(n)
        core: list[Parameter] = []
        linear = {"M": "kg", "B": "N.s/m", "K": "N/m"}
        rotary = {"M": "kg.m^2", "B": "N.m.s/rad", "K": "N.m/rad"}
        self.matrix_units = linear if units == "linear" else rotary
        unit = {k: f"sqrt({u})" for k, u in self.matrix_units.items()}
        for key in ("M", "B", "K"):
            try:
                L = np.linalg.cholesky(mats[key])
            except np.linalg.LinAlgError as exc:
                raise ModelSpecError(f"nominal {key} must be symmetric positive definite") from exc
            scale = float(np.max(np.abs(np.diag(L))))
            for i, j in zip(*self.tril, strict=True):
                v = float(L[i, j])
                if i == j:
                    core.append(Parameter(f"L{key}_{i}{j}", unit[key], v / span, v * span, v, True))
                else:
                    core.append(Parameter(f"L{key}_{i}{j}", unit[key], -span * scale, span * scale, v, False))
        self.n_tri = len(self.tril[0])
        ins = [f"force_{i}" for i in self.in_idx]
        outs = [f"{output}_{o}" for o in self.out_idx]
        super().__init__(core, ins, outs, gain=gain, delay=delay, zoh_fs=zoh_fs)

    def matrices(self, theta: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(M, B, K) of shape (..., n, n) for parameter vectors ``theta`` (..., p)."""
        th = np.asarray(theta, float)
        out = []
        for k in range(3):
            vals = th[..., k * self.n_tri : (k + 1) * self.n_tri]
            L = np.zeros((*th.shape[:-1], self.n_dof, self.n_dof))
            L[..., self.tril[0], self.tril[1]] = vals
            out.append(L @ np.swapaxes(L, -1, -2))
        return out[0], out[1], out[2]

    def theta_from_matrices(self, M: ArrayLike, B: ArrayLike, K: ArrayLike, **nuisance: float) -> NDArray[np.float64]:
        """Parameter vector (Cholesky entries, then nuisance) for given SPD matrices."""
        vals = [np.linalg.cholesky(np.asarray(A, float))[self.tril] for A in (M, B, K)]
        core = np.concatenate(vals)
        extra = [nuisance.get(p.name, p.nominal) for p in self.parameters[self.n_core :]]
        return np.concatenate([core, np.asarray(extra, float)])

    def derived(self, samples: ArrayLike) -> dict[str, tuple[NDArray[np.float64], str]]:
        """Entries ``M_ij``, ``B_ij``, ``K_ij`` (i <= j) of the symmetric matrices, per sample."""
        mats = self.matrices(np.asarray(samples, float)[..., : self.n_core])
        out: dict[str, tuple[NDArray[np.float64], str]] = {}
        for key, A in zip(("M", "B", "K"), mats, strict=True):
            for i in range(self.n_dof):
                for j in range(i, self.n_dof):
                    out[f"{key}_{i}{j}"] = (A[..., i, j], self.matrix_units[key])
        return out

    def initial_guess(self, est: Any) -> NDArray[np.float64] | None:
        """Equation-error (Levy) estimate: ``(M s^2 + B s + K) X(s) = F(s)`` is linear in the entries of
        M, B, K; every measured FRF column gives ``n_dof`` complex equations per bin. Solved by linear
        least squares, symmetrized and projected onto positive definite matrices. Needs every DOF
        measured (else None)."""
        if sorted(self.out_idx) != list(range(self.n_dof)):
            return None
        n = self.n_dof
        H = np.asarray(est.H)
        s = 1j * np.asarray(est.w, float)
        iu = [(i, j) for i in range(n) for j in range(i, n)]
        rows, rhs = [], []
        order = [self.out_idx.index(o) for o in range(n)]
        for k in range(s.size):
            for c, dof_in in enumerate(self.in_idx):
                h = H[k, order, c]
                if not np.all(np.isfinite(h)):
                    continue
                x = h / s[k] if self.output == "velocity" else h  # displacement per unit force
                for r in range(n):
                    row = np.zeros(3 * len(iu), complex)
                    for m, (i, j) in enumerate(iu):
                        # d/d(A_ij) of (A x)_r for a symmetric A: A_ij multiplies x_j in row i and x_i in row j
                        val = (x[j] if r == i else 0.0) + (x[i] if (r == j and i != j) else 0.0)
                        for blk, pw in enumerate((s[k] ** 2, s[k], 1.0)):
                            row[blk * len(iu) + m] = pw * val
                    rows.append(row)
                    rhs.append(1.0 if r == dof_in else 0.0)
        if len(rows) < 3 * len(iu):
            return None
        Amat = np.asarray(rows)
        b = np.asarray(rhs, complex)
        Ar = np.concatenate([Amat.real, Amat.imag])
        br = np.concatenate([b.real, b.imag])
        scale = np.maximum(np.linalg.norm(Ar, axis=0), 1e-300)
        sol, *_ = np.linalg.lstsq(Ar / scale, br, rcond=None)
        sol = sol / scale
        mats = []
        for blk in range(3):
            A = np.zeros((n, n))
            for m, (i, j) in enumerate(iu):
                A[i, j] = A[j, i] = sol[blk * len(iu) + m]
            ev, vec = np.linalg.eigh(A)
            floor = max(1e-6 * float(np.max(np.abs(ev))), 1e-300)
            mats.append((vec * np.maximum(ev, floor)) @ vec.T)
        th = self.theta_from_matrices(*mats)
        lo, hi = self.lower, self.upper
        if not np.all(np.isfinite(th)):
            return None
        return np.clip(th, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))

    def _state_space(
        self, theta: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        Mm, Bm, Km = self.matrices(theta)
        n = self.n_dof
        Mi = np.linalg.inv(Mm)
        A = np.zeros((*Mm.shape[:-2], 2 * n, 2 * n))
        A[..., :n, n:] = np.eye(n)
        A[..., n:, :n] = -Mi @ Km
        A[..., n:, n:] = -Mi @ Bm
        Bin = np.zeros((*Mm.shape[:-2], 2 * n, len(self.in_idx)))
        Bin[..., n:, :] = Mi[..., :, list(self.in_idx)]
        C = np.zeros((*Mm.shape[:-2], len(self.out_idx), 2 * n))
        off = n if self.output == "velocity" else 0
        for r, o in enumerate(self.out_idx):
            C[..., r, off + o] = 1.0
        return A, Bin, C

    def _core_frf(self, theta: NDArray[np.float64], s: NDArray[np.complex128]) -> NDArray[np.complex128]:
        Mm, Bm, Km = self.matrices(theta)
        s3 = s[:, None, None]
        A = Mm[..., None, :, :] * s3**2 + Bm[..., None, :, :] * s3 + Km[..., None, :, :]
        if self.n_dof == 2:  # closed-form 2x2 inverse: ~5x faster than np.linalg.inv on the MCMC hot path
            a, b, c, d = A[..., 0, 0], A[..., 0, 1], A[..., 1, 0], A[..., 1, 1]
            det = a * d - b * c
            H = np.asarray(np.stack([np.stack([d, -b], -1), np.stack([-c, a], -1)], -2) / det[..., None, None],
                           complex)
        else:
            H = np.linalg.inv(A)
        if self.output == "velocity":
            H = H * s3
        return H[..., list(self.out_idx), :][..., list(self.in_idx)]


def make_model(name: str, channels: Sequence[str] | None = None, **options: object) -> GreyBoxModel:
    """Build a model by name: ``sdea_locked``, ``sdea_free`` or ``mbk`` (``channels`` for SDEA models)."""
    key = name.lower().replace("-", "_")
    if key in ("sdea_locked", "sdea"):
        return SdeaLockedOutput(channels or ("velocity", "force"), **options)  # type: ignore[arg-type]
    if key == "sdea_free":
        return SdeaFreeOutput(channels or ("velocity",), **options)  # type: ignore[arg-type]
    if key == "mbk":
        if channels:
            options.setdefault("output", channels[0])
        return MbkModel(**options)  # type: ignore[arg-type]
    raise ModelSpecError(f"unknown model {name!r}; known: sdea_locked, sdea_free, mbk")
