"""Experiments the runner plays on the bench (``docs/RUNNER_SPEC.md``): chirp, multisine, energy
injection, static hold.

Each experiment type has one pydantic schema here (:class:`ChirpExperiment`,
:class:`MultisineExperiment`, :class:`EnergyInjectionExperiment`, :class:`StaticHoldExperiment`) and
one implementation, registered in :data:`EXPERIMENT_TYPES` (``register_experiment``); :mod:`hil.scene.spec`
composes the scene's ``experiments`` list from that registry. Each experiment is built from one
validated entry by :func:`make_experiment` and then

* ``check(scene)`` -- before anything moves: band below Nyquist/5 (``f1 <= rate_hz / 10``; the
  zero-order hold costs ``ω T/2`` of phase, 18° at that limit), amplitude within
  ``safety.max_effort``, ``duration > 0``, target device and DOFs exist. Raises
  :class:`hil.errors.SceneError` naming the field (``experiments[<name>].<field>: ...``). It also
  resolves scene-dependent details (port devices, force-sensor axes and sign, noise levels);
* ``excitation(k, t, meas) -> Excitation`` -- once per tick ``k`` (``t = k / rate_hz``): efforts
  added to the controller output (held over the tick) and active forces of simulated humans;
* ``finish(data, meta) -> dict`` -- analysis of the recorded channels (``"t"``,
  ``"<device>.position"``, ``"<device>.velocity"``, ``"<sensor>.wrench"``, ...; arrays with time on
  axis 0), stored in the run record.

Signals are computed from the tick index ``k`` (not from accumulated time), so periodic
excitations are *exactly* periodic in samples: ``u[k + N_p] == u[k]`` bit for bit.

Units SI: efforts N or N.m, positions m or rad, frequencies Hz, times s, energies J.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from types import ModuleType
from typing import Annotated, Any, Generic, Literal, Protocol, TypeVar

import numpy as np
from pydantic import BeforeValidator, Field, model_validator
from pydantic_core import PydanticCustomError

from hil.errors import SceneError
from hil.plugins import load_group
from hil.schema import (
    DampNonneg,
    DofList,
    Effort,
    EffortNonneg,
    FieldError,
    Hz,
    HzOrZero,
    Name,
    Number,
    Positive,
    SceneView,
    Seconds,
    SecondsOrZero,
    Seed,
    StiffPos,
    StrictModel,
    near,
    number,
    register_tagged,
    validate,
)


def _sps() -> ModuleType:  # scipy.signal takes seconds to import: only some profiles need it
    from scipy import signal

    return signal

logger = logging.getLogger(__name__)

__all__ = [
    "EXPERIMENT_TYPES",
    "Chirp",
    "ChirpExperiment",
    "EnergyInjection",
    "EnergyInjectionExperiment",
    "EnergyResult",
    "Excitation",
    "Experiment",
    "ExperimentConfig",
    "ExperimentType",
    "ForceProfileCfg",
    "Multisine",
    "MultisineExperiment",
    "ServoCfg",
    "StaticHold",
    "StaticHoldExperiment",
    "chirp_signal",
    "experiment_schemas",
    "force_profile",
    "make_experiment",
    "multisine_lines",
    "port_energy",
    "raised_cosine_fade",
    "register_experiment",
    "schroeder_phases",
]

#: Highest excitation frequency as a fraction of the sampling rate (Nyquist/5).
BAND_LIMIT_FRACTION = 0.1


@dataclass
class Excitation:
    """One tick of excitation: ``effort`` per actuator (added to the controller output, N or
    N.m, shape (dof,)) and ``human`` active force per network port (simulated operator)."""

    effort: dict[str, np.ndarray] = field(default_factory=dict)
    human: dict[str, np.ndarray] = field(default_factory=dict)


class Experiment(Protocol):
    """What the runner plays: built from one validated scene entry (module doc)."""

    name: str
    duration: float

    def check(self, scene: Any) -> None: ...
    def excitation(self, k: int, t: float, meas: Mapping[str, Any]) -> Excitation: ...
    def finish(self, data: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict[str, Any]: ...


# ---------------------------------------------------------------------------------------------
# schemas: one pydantic model per experiment type, validated once (by hil.scene.spec or make_experiment)


class ExperimentConfig(StrictModel):
    """Fields every experiment has. ``controller``: ``scene`` runs the scene's controller during
    the experiment, ``none`` runs it open loop (identification). ``name`` defaults to the type
    (``<type>_<n>`` when several of one type are unnamed; filled in by :class:`hil.scene.spec.Scene`)."""

    type: str
    name: Name | None = None
    controller: Literal["scene", "none"] = "scene"

    def check_scene(self, scene: SceneView, path: str) -> None:
        """Refuse broken references to ``scene`` (pure; ``path``: ``experiments[i]``). The checks
        that need the control rate run when the experiment is built (:meth:`Experiment.check`)."""


def _check_target(cfg: _PeriodicConfig | StaticHoldExperiment, scene: SceneView, path: str) -> None:
    d = scene.require(f"{path}.target", cfg.target, "actuator")
    if cfg.dofs is not None and max(cfg.dofs) >= d.dof:
        raise FieldError(f"{path}.dofs", f"device {d.name!r} has {d.dof} DOF")
    sim = scene.simulation
    if cfg.variant == "free" and sim is not None and (sim.sdea is None or sim.sdea.m_out is None):
        raise FieldError(f"{path}.variant", "variant 'free' needs simulation.sdea.m_out (the output inertia)")


def _band_ok(f0: float, f1: float) -> None:
    if not f0 < f1:
        raise PydanticCustomError("band", "f1 ({f1} Hz) must exceed f0 ({f0} Hz)", {"f0": f0, "f1": f1, "key": "f1"})


class ServoCfg(StrictModel):
    """The experiment's own position servo for ``excite: motion``: ``kp`` (N/m or N.m/rad, > 0)
    and ``kv`` (N.s/m or N.m.s/rad, >= 0); its effort is added to the controller's."""

    kp: StiffPos
    kv: DampNonneg = 0.0


class _PeriodicConfig(ExperimentConfig):
    """Fields of the periodic effort signals (chirp, multisine) on one actuator."""

    f0: Hz
    f1: Hz
    duration: Seconds
    amplitude: EffortNonneg
    target: Name
    dofs: DofList | None = None
    excite: Literal["effort", "motion"] = "effort"
    servo: ServoCfg | None = None
    periods: int = Field(default=1, ge=1)
    variant: Literal["locked", "free"] | None = None

    def check_scene(self, scene: SceneView, path: str) -> None:
        _check_target(self, scene, path)

    @model_validator(mode="after")
    def _band_and_servo(self) -> _PeriodicConfig:
        _band_ok(self.f0, self.f1)
        if self.excite == "motion" and self.servo is None:
            raise PydanticCustomError("servo", "excite: motion needs servo (kp in N/m, kv in N.s/m)", {"key": "servo"})
        return self


class ChirpExperiment(_PeriodicConfig):
    """Swept sine from ``f0`` to ``f1`` (Hz) of ``amplitude`` (N or N.m; m or rad with ``excite:
    motion``) on ``target``'s ``dofs`` (see :class:`Chirp`)."""

    type: Literal["chirp"]
    sweep: Literal["log", "linear"] = "log"
    fade: SecondsOrZero = 0.0
    periodic: bool = False
    simultaneous: bool = False


class MultisineExperiment(_PeriodicConfig):
    """Sum of ``n_lines`` sines per DOF between ``f0`` and ``f1`` (Hz), peak ``amplitude`` (N or
    N.m) on ``target``'s ``dofs`` (see :class:`Multisine`)."""

    type: Literal["multisine"]
    n_lines: int = Field(default=64, ge=1)
    simultaneous: bool = True
    spacing: Literal["linear", "log"] = "linear"
    seed: Seed | None = None


def _auto_or_joules(value: Any) -> Any:
    if value == "auto":
        return value
    x = number(value, "J (or 'auto')")
    if x < 0:
        raise PydanticCustomError("number", "expected 'auto' or a number >= 0 in J, got {got}", {"got": x})
    return x


class ForceProfileCfg(StrictModel):
    """An active force profile (see :func:`force_profile`): ``kind`` sine | multisine | square |
    step | noise, ``amplitude`` (N or N.m), ``freq`` (Hz; the noise cutoff), ``phase`` (rad),
    ``freqs`` (Hz, the lines of ``multisine``), ``direction`` (weights per port DOF, default ones),
    ``seed`` (noise)."""

    kind: Literal["sine", "multisine", "square", "step", "noise"] = "sine"
    amplitude: Effort
    freq: HzOrZero = 1.0
    phase: Annotated[float, BeforeValidator(lambda v: number(v, "rad"))] = 0.0
    freqs: Annotated[list[Hz], Field(min_length=1)] | None = None
    direction: list[Number] | None = None
    seed: Seed | None = None


class EnergyInjectionExperiment(ExperimentConfig):
    """Active force at a network ``port`` for ``duration`` s while ``E_s = ∫ F^T V dt`` at the port
    is tracked (see :class:`EnergyInjection`)."""

    type: Literal["energy_injection"]
    port: Name
    duration: Seconds
    profile: ForceProfileCfg
    noise_bound: Annotated[Literal["auto"] | float, BeforeValidator(_auto_or_joules)] = "auto"
    via: Literal["human", "actuator"] | None = None
    force_sign: Literal[1, -1] | None = None
    k_sigma: Positive = 4.0
    bound_mode: Literal["final", "running"] = "final"

    def check_scene(self, scene: SceneView, path: str) -> None:
        pnames = sorted(p.name for p in scene.network.ports)
        if self.port not in pnames:
            raise FieldError(f"{path}.port", f"unknown port {self.port!r}{near(self.port, pnames)}")
        port = scene.port(self.port)
        d = self.profile.direction
        if d is not None and len(d) != port.dofs:
            raise FieldError(f"{path}.profile.direction", f"port {port.name!r} has {port.dofs} DOF, direction has "
                                                          f"{len(d)}")


class StaticHoldExperiment(ExperimentConfig):
    """Constant ``effort`` (N or N.m; one value, or one per DOF) on ``target``'s ``dofs`` for
    ``duration`` s; statistics after ``settle`` s; ``variant``: plant configuration of a simulated
    SDEA (``locked`` | ``free`` output; recorded) (see :class:`StaticHold`)."""

    type: Literal["static_hold"]
    target: Name
    dofs: DofList | None = None
    effort: Effort | Annotated[list[Effort], Field(min_length=1)]
    duration: Seconds
    settle: SecondsOrZero = 0.0
    variant: Literal["locked", "free"] | None = None

    def check_scene(self, scene: SceneView, path: str) -> None:
        _check_target(self, scene, path)

    @model_validator(mode="after")
    def _settle(self) -> StaticHoldExperiment:
        if self.settle >= self.duration:
            raise PydanticCustomError("settle", "settle ({s} s) must be shorter than duration ({d} s)",
                                      {"s": self.settle, "d": self.duration, "key": "settle"})
        return self


# ---------------------------------------------------------------------------------------------
# scene access (works on the pydantic Scene of hil.scene.spec and on plain mappings)


def _get(obj: Any, key: str, default: Any = None) -> Any:
    if obj is None:
        return default
    if isinstance(obj, Mapping):
        return obj.get(key, default)
    return getattr(obj, key, default)


def _devices(scene: Any) -> dict[str, Any]:
    """Devices by name, plus device groups (as the scene's group actuator) when the scene has them."""
    out = {str(_get(d, "name")): d for d in (_get(scene, "devices") or [])}
    for g in _get(scene, "groups") or []:
        name = str(_get(g, "name"))
        out[name] = scene.device(name) if hasattr(scene, "device") else g
    return out


def _wrench_axes(dev: Any) -> list[int]:
    axes = _get(dev, "axes")
    return [int(a) for a in axes] if axes is not None else list(range(int(_get(dev, "dof", 1))))


# ---------------------------------------------------------------------------------------------
# signal building blocks


def raised_cosine_fade(n: int, n_fade: int) -> np.ndarray:
    """Window of ``n`` samples rising as ``(1 - cos(π i / n_fade))/2`` over the first ``n_fade``
    samples, 1 in the middle, mirrored at the end. ``n_fade = 0`` gives ones."""
    w = np.ones(n)
    if n_fade <= 0:
        return w
    n_fade = min(n_fade, n // 2)
    ramp = 0.5 * (1.0 - np.cos(np.pi * np.arange(n_fade) / n_fade))
    w[:n_fade] = ramp
    w[n - n_fade:] = ramp[::-1]
    return w


def chirp_signal(n: int, fs: float, f0: float, f1: float, sweep: str = "log") -> tuple[np.ndarray, np.ndarray]:
    """One sweep of ``n`` samples at ``fs`` Hz from ``f0`` to ``f1`` Hz, unit amplitude.

    Phase ``φ(τ)`` (``τ = i/fs``, sweep length ``P = n/fs``): linear
    ``2π (f0 τ + (f1 - f0) τ²/(2P))``, instantaneous frequency ``f0 + (f1 - f0) τ/P``; log
    ``2π f0 P (r^{τ/P} - 1)/ln r`` with ``r = f1/f0``, instantaneous frequency ``f0 r^{τ/P}``.
    Returns ``(sin φ, f_inst)``.
    """
    tau = np.arange(n) / fs
    P = n / fs
    if sweep == "linear":
        phase = 2 * np.pi * (f0 * tau + (f1 - f0) * tau**2 / (2 * P))
        finst = f0 + (f1 - f0) * tau / P
    elif sweep == "log":
        r = f1 / f0
        phase = 2 * np.pi * f0 * P * (np.power(r, tau / P) - 1.0) / math.log(r)
        finst = f0 * np.power(r, tau / P)
    else:
        raise SceneError(f"sweep: 'log' or 'linear', got {sweep!r}")
    return np.sin(phase), finst


def schroeder_phases(n_lines: int) -> np.ndarray:
    """Schroeder's low-crest-factor phases for ``n_lines`` equal-amplitude, equally spaced lines:
    ``φ_l = -π l (l - 1)/L``, ``l = 1..L`` (Schroeder 1970)."""
    ell = np.arange(1, n_lines + 1)
    return -np.pi * ell * (ell - 1) / n_lines


def multisine_lines(kmin: int, kmax: int, n_total: int, spacing: str = "linear") -> np.ndarray:
    """``n_total`` distinct harmonic indices spread over ``[kmin, kmax]`` (linear or log).
    Raises ValueError when they cannot be distinct."""
    if kmax < kmin or kmax - kmin + 1 < n_total:
        raise ValueError(f"only {max(kmax - kmin + 1, 0)} harmonics available, {n_total} needed")
    if spacing == "linear":
        idx = np.round(np.linspace(kmin, kmax, n_total)).astype(int)
    elif spacing == "log":
        idx = np.round(np.geomspace(max(kmin, 1), kmax, n_total)).astype(int)
    else:
        raise ValueError(f"spacing must be 'linear' or 'log', got {spacing!r}")
    if np.unique(idx).size != n_total:
        raise ValueError(f"{n_total} {spacing} lines collide on the harmonic grid [{kmin}, {kmax}]")
    return idx


def crest_factor(x: np.ndarray) -> float:
    """Peak over RMS."""
    x = np.asarray(x, dtype=float)
    return float(np.max(np.abs(x)) / np.sqrt(np.mean(x**2)))


# ---------------------------------------------------------------------------------------------
# energy


@dataclass(frozen=True)
class EnergyResult:
    """``E_s(t) = ∫_0^t F^T V dt`` (J) at the sample times, the noise ``bound(t)`` (J, >= 0), and
    whether/when/how much ``E_s`` went below ``-bound``."""

    t: np.ndarray
    energy: np.ndarray
    bound: np.ndarray
    went_negative: bool
    first_time: float | None
    min_energy: float
    min_margin: float  # min over t of E_s(t) + bound(t) (negative iff went_negative)

    def summary(self) -> dict[str, Any]:
        """JSON-friendly scalars."""
        i = int(np.argmin(self.energy)) if self.energy.size else 0
        return {"went_negative": bool(self.went_negative), "first_time": self.first_time,
                "min_energy": float(self.min_energy), "time_of_min": float(self.t[i]) if self.t.size else None,
                "bound_at_min": float(self.bound[i]) if self.bound.size else 0.0,
                "final_energy": float(self.energy[-1]) if self.energy.size else 0.0,
                "final_bound": float(self.bound[-1]) if self.bound.size else 0.0,
                "min_margin": float(self.min_margin)}


def port_energy(t: Any, force: Any, velocity: Any, noise_force_std: float = 0.0, noise_velocity_std: float = 0.0,
                *, k_sigma: float = 4.0, fixed_bound: float | None = None,
                bound_mode: str = "final") -> EnergyResult:
    """Energy flowing into a port, ``E_s(t) = ∫ F^T V dt`` (paper 000 eq. 6, 001 eq. 30), by the
    trapezoidal rule on the samples (``force``, ``velocity``: (N,) or (N, d); F applied TO the
    device, V into the port, so E_s > 0 is energy absorbed by the device).

    Noise bound. With white, independent measurement noise ``n_F`` (std σ_F per DOF) and ``n_V``
    (σ_V), the measured power is ``F^T V + n_F^T V + F^T n_V + n_F^T n_V``; its error has zero mean and
    the accumulated error ``Σ w_j dt e_j`` (trapezoid weights ``w_j``) has variance
    ``dt² Σ w_j² (σ_F² |V_j|² + σ_V² |F_j|² + d σ_F² σ_V²)`` (terms independent across samples).
    The variance is evaluated with ``|V_j|² ≈ |V_meas,j|² - d σ_V²`` and ``|F_j|² ≈ |F_meas,j|² - d σ_F²``
    (unbiased: the measured magnitudes include the noise); its running sum ``σ²(t)`` is kept
    non-decreasing and at least its noise-only part.

    ``bound_mode="final"`` (default): a constant ``bound = k_sigma σ(t_end)``. The accumulated
    error is a sum of independent symmetric terms, so by Lévy's (reflection) inequality its minimum
    over the whole record is below ``-k σ(t_end)`` with probability at most ``2 Φ(-k)`` (6e-5 for
    ``k_sigma = 4``): a rigorous false-alarm bound for "E_s ever went negative". ``"running"``:
    ``bound(t) = k_sigma σ(t)``, tighter early in the record but the crossing of a ``√t``-shaped
    curve is more likely than ``2 Φ(-k)`` (it grows like ``k φ(k) ln N`` for N samples).
    ``fixed_bound`` (J) replaces both by a constant.
    A round-off floor of ``1e-12 ∫|F^T V| dt`` is always added.
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    F = np.asarray(force, dtype=float)
    V = np.asarray(velocity, dtype=float)
    F = F.reshape(t.size, -1)
    V = V.reshape(t.size, -1)
    if F.shape != V.shape:
        raise ValueError(f"force {F.shape} and velocity {V.shape} must have the same shape")
    n, d = F.shape
    if n == 0:
        z = np.zeros(0)
        return EnergyResult(t, z, z, False, None, 0.0, 0.0)
    p = np.sum(F * V, axis=1)
    dt = np.diff(t)
    energy = np.concatenate([[0.0], np.cumsum(0.5 * (p[1:] + p[:-1]) * dt)])
    absint = np.concatenate([[0.0], np.cumsum(0.5 * (np.abs(p[1:]) + np.abs(p[:-1])) * dt)])
    if fixed_bound is not None:
        bound = np.full(n, float(fixed_bound))
    else:
        sf2, sv2 = noise_force_std**2, noise_velocity_std**2
        # |V|², |F|² of the true signals estimated from the measured ones: E|V_meas|² = |V|² + d σ_V²,
        # so the running sum below is an unbiased estimate of the variance; it is kept
        # non-decreasing and never below the noise-only part Σ w² d σ_F² σ_V²
        v2 = np.sum(V**2, axis=1) - d * sv2
        f2 = np.sum(F**2, axis=1) - d * sf2
        var_p = sf2 * v2 + sv2 * f2 + d * sf2 * sv2
        # sample j enters E(t_k) with weight dt_{j-1}/2 + dt_j/2 (interior) and dt/2 at both ends;
        # use the interior weight ((dt_prev + dt_next)/2)² for every sample up to k: an upper
        # bound on the variance (end weights are half as large)
        dts = np.concatenate([[dt[0] if dt.size else 0.0], dt])
        dts_next = np.concatenate([dt, [dt[-1] if dt.size else 0.0]])
        w2 = (0.5 * (dts + dts_next)) ** 2
        floor = np.cumsum(w2 * d * sf2 * sv2)
        var_e = np.maximum.accumulate(np.maximum(np.cumsum(w2 * var_p), floor))
        if bound_mode == "final":
            bound = np.full(n, k_sigma * math.sqrt(var_e[-1]))
        elif bound_mode == "running":
            bound = k_sigma * np.sqrt(var_e)
        else:
            raise ValueError(f"bound_mode must be 'final' or 'running', got {bound_mode!r}")
    bound = bound + 1e-12 * absint
    margin = energy + bound
    neg = margin < 0
    first = float(t[int(np.argmax(neg))]) if np.any(neg) else None
    return EnergyResult(t, energy, bound, bool(np.any(neg)), first, float(np.min(energy)), float(np.min(margin)))


def noise_std_from_differences(x: np.ndarray) -> float:
    """White-noise std estimate from first differences: ``std(Δx)/√2`` (the smooth signal's own
    increment over one sample is negligible at the control rate; conservative otherwise)."""
    x = np.asarray(x, dtype=float)
    if x.shape[0] < 3:
        return 0.0
    dx = np.diff(x, axis=0)
    return float(np.sqrt(np.mean(dx**2) / 2.0))


# ---------------------------------------------------------------------------------------------
# base class


C = TypeVar("C", bound=ExperimentConfig)


class _Base(Generic[C]):
    """Common handling of a validated configuration ``cfg`` (one schema of this module)."""

    kind = "experiment"
    duration: float

    def __init__(self, cfg: C, rate_hz: float) -> None:
        if not (isinstance(rate_hz, int | float) and rate_hz > 0 and math.isfinite(rate_hz)):
            raise SceneError(f"rate_hz: must be positive, got {rate_hz!r}")
        self.cfg = cfg
        self.rate_hz = float(rate_hz)
        self.dt = 1.0 / self.rate_hz
        self.name = str(cfg.name or self.kind)
        self.where = f"experiments[{self.name}]"

    def f(self, key: str) -> str:
        """Field path for messages."""
        return f"{self.where}.{key}"

    def _check_target(self, scene: Any, target: str, dofs: Sequence[int] | None) -> tuple[Any, list[int]]:
        devs = _devices(scene)
        if target not in devs:
            raise SceneError(f"{self.f('target')}: no device {target!r} in the scene (have {sorted(devs)})")
        dev = devs[target]
        if _get(dev, "role", "actuator") != "actuator":
            raise SceneError(f"{self.f('target')}: device {target!r} is not an actuator")
        n = int(_get(dev, "dof", 1))
        sel = list(range(n)) if dofs is None else [int(i) for i in dofs]
        if not sel or any(i < 0 or i >= n for i in sel) or len(set(sel)) != len(sel):
            raise SceneError(f"{self.f('dofs')}: {sel} not distinct DOF indices of {target!r} ({n} DOF)")
        return dev, sel

    def _check_band(self, f0: float, f1: float) -> None:
        lim = BAND_LIMIT_FRACTION * self.rate_hz
        if f1 > lim:
            raise SceneError(f"{self.f('f1')}: {f1} Hz exceeds Nyquist/5 = {lim:g} Hz at rate_hz {self.rate_hz:g} "
                             "(zero-order hold phase lag ωT/2 > 18°); lower f1 or raise rate_hz")

    def _check_effort(self, scene: Any, peak: float, field_name: str) -> None:
        max_effort = _get(_get(scene, "safety"), "max_effort")
        if max_effort is not None and peak > float(max_effort):
            raise SceneError(f"{self.f(field_name)}: peak effort {peak:g} exceeds safety.max_effort "
                             f"{float(max_effort):g}")


# ---------------------------------------------------------------------------------------------
# periodic effort signals on one actuator (chirp, multisine)


P = TypeVar("P", bound=_PeriodicConfig)


class _PeriodicEffort(_Base[P]):
    """Shared machinery: per-DOF periodic sample arrays played on ``target``, sequentially (one
    DOF after the other, each for ``block`` samples) or simultaneously."""

    wave: np.ndarray
    wave_rate: np.ndarray
    simultaneous: bool

    def __init__(self, cfg: P, rate_hz: float, *, periodic: bool) -> None:
        super().__init__(cfg, rate_hz)
        self.f0, self.f1 = cfg.f0, cfg.f1
        self.amplitude = cfg.amplitude
        self.variant = cfg.variant
        self._setup_periods(cfg.duration, periodic, cfg.periods)
        self.excite = cfg.excite
        self.kp = cfg.servo.kp if cfg.servo is not None else 0.0
        self.kv = cfg.servo.kv if cfg.servo is not None else 0.0
        self._x_start: np.ndarray | None = None
        self.target = cfg.target
        self.dofs_cfg = cfg.dofs
        self.sel = [0] if cfg.dofs is None else list(cfg.dofs)
        self.target_dof = max(self.sel) + 1
        self.checked = False

    def _setup_periods(self, duration: float, periodic: bool, periods: int) -> None:
        self.periods = periods if periodic else 1
        n_block = round(duration * self.rate_hz)
        self.n_period = max(1, n_block // self.periods)
        if self.n_period * self.periods != n_block:
            logger.info("%s: duration %.6g s rounded to %d periods of %d samples", self.name, duration,
                        self.periods, self.n_period)
        self.n_block = self.n_period * self.periods
        self.period = self.n_period / self.rate_hz

    def _layout(self, n_dofs: int, simultaneous: bool) -> None:
        self.simultaneous = simultaneous
        self.n_blocks = 1 if simultaneous or n_dofs == 1 else n_dofs
        self.duration = self.n_blocks * self.n_block / self.rate_hz

    def _value(self, k: int) -> np.ndarray:
        """Effort per selected DOF at tick k (zeros after the end)."""
        return self._sample(self.wave, k)

    def _value_rate(self, k: int) -> np.ndarray:
        """Time derivative of the excitation per selected DOF at tick k (units/s)."""
        return self._sample(self.wave_rate, k)

    def _sample(self, table: np.ndarray, k: int) -> np.ndarray:
        """Row of a per-DOF periodic table at tick k, laid out in blocks; zeros outside."""
        out = np.zeros(len(self.sel))
        block, i = divmod(k, self.n_block)
        if k < 0 or block >= self.n_blocks:
            return out
        j = i % self.n_period
        if self.n_blocks == 1:
            out[:] = table[:, j]
        else:
            out[block] = table[block, j]
        return out

    def segments(self) -> list[dict[str, Any]]:
        """Time windows of the blocks: which DOFs are excited when (s)."""
        if self.n_blocks == 1:
            return [{"dofs": list(self.sel), "t_start": 0.0, "t_end": self.duration}]
        T = self.n_block / self.rate_hz
        return [{"dofs": [d], "t_start": b * T, "t_end": (b + 1) * T} for b, d in enumerate(self.sel)]

    def excitation(self, k: int, t: float, meas: Mapping[str, Any]) -> Excitation:
        u = self._value(k)
        if self.excite == "motion":
            s = meas.get(self.target) if meas is not None else None
            if s is None:
                return Excitation()
            pos = np.asarray(s.position, dtype=float).reshape(-1)[self.sel]
            vel = np.asarray(s.velocity, dtype=float).reshape(-1)[self.sel]
            if self._x_start is None or k == 0:
                self._x_start = pos.copy()
            rd = self._value_rate(k)
            u = self.kp * (self._x_start + u - pos) + self.kv * (rd - vel)
        eff = np.zeros(self.target_dof)
        eff[self.sel] = u
        return Excitation(effort={self.target: eff})

    def _finish_rate(self) -> None:
        """Derivative of the periodic waves (for motion references), central differences."""
        w = self.wave
        self.wave_rate = (np.roll(w, -1, axis=1) - np.roll(w, 1, axis=1)) * (0.5 * self.rate_hz)
        if self.periods == 1:  # not periodic: one-sided at the ends
            self.wave_rate[:, 0] = (w[:, 1] - w[:, 0]) * self.rate_hz if w.shape[1] > 1 else 0.0
            self.wave_rate[:, -1] = (w[:, -1] - w[:, -2]) * self.rate_hz if w.shape[1] > 1 else 0.0

    def _check_common(self, scene: Any) -> None:
        self._check_band(self.f0, self.f1)
        dev, sel = self._check_target(scene, self.target, self.dofs_cfg)
        if sel != self.sel:
            raise SceneError(f"{self.f('dofs')}: resolved {sel}, built for {self.sel}")
        if int(_get(dev, "dof", 1)) != self.target_dof:
            self.target_dof = int(_get(dev, "dof", 1))
        peak = float(np.max(np.abs(self.wave))) if self.wave.size else 0.0
        if self.excite == "motion":
            stalled = self.kp * peak + self.kv * float(np.max(np.abs(self.wave_rate)))
            self._check_effort(scene, stalled, "amplitude")
            lims = _get(_get(scene, "safety"), "position_limits")
            if lims is not None and peak > 0.5 * (float(lims[1]) - float(lims[0])):
                raise SceneError(f"{self.f('amplitude')}: motion amplitude {peak:g} exceeds half the position range")
        else:
            self._check_effort(scene, peak, "amplitude")
        self.checked = True

    def check(self, scene: Any) -> None:
        """Validate against the scene (module doc). When ``dofs`` is omitted, all of the
        target's DOFs are excited: the signals are rebuilt for the scene's DOF count."""
        devs = _devices(scene)
        dev = devs.get(self.target)
        if self.dofs_cfg is None and dev is not None and int(_get(dev, "dof", 1)) != len(self.sel):
            self.sel = list(range(int(_get(dev, "dof", 1))))
            self.target_dof = len(self.sel)
            self._build()
        self._check_common(scene)

    def _build(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError


class Chirp(_PeriodicEffort[ChirpExperiment]):
    """Swept sine on ``target``'s ``dofs``.

    Fields: ``f0``, ``f1`` (Hz), ``duration`` (s, per DOF block), ``amplitude`` (N or N.m; m or rad
    with ``excite: motion``), ``sweep`` (log | linear), ``fade`` (s, raised cosine in and out),
    ``periodic`` + ``periods`` (``periods`` identical sweeps of ``duration/periods`` s, rounded to
    whole samples), ``simultaneous`` (all DOFs at once with the same sweep; default false: one DOF
    after the other, each for ``duration``), ``excite`` (effort | motion: a position reference
    ``x(0) + r(t)`` tracked by the experiment's own servo ``servo: {kp, kv}`` added to the
    controller effort), ``variant`` (locked | free; recorded, the scene decides the physics).

    Fade and periodicity: the fade is applied to *every period* (each period starts and ends at
    zero), so all periods are identical sample for sample and a Welch segment of exactly one
    period (rectangular window, no overlap) after the first (transient) period gives an unbiased
    H1 estimate. Without fade a periodic sweep jumps back from its end phase to 0 at each period
    boundary (broadband but periodic; harmless for H1).
    """

    kind = "chirp"

    def __init__(self, cfg: ChirpExperiment, rate_hz: float) -> None:
        super().__init__(cfg, rate_hz, periodic=cfg.periodic)
        self.fade = cfg.fade
        self.sweep = cfg.sweep
        self.periodic = cfg.periodic
        if 2 * round(self.fade * self.rate_hz) > self.n_period:
            raise SceneError(f"{self.f('fade')}: {self.fade} s in and out exceeds the period {self.period:g} s")
        self._build()
        if self.periodic and self.f0 < 1.0 / self.period:
            logger.warning("%s: f0 = %g Hz is below the frequency resolution 1/period = %g Hz", self.name, self.f0,
                           1.0 / self.period)

    def _build(self) -> None:
        x, self.f_inst = chirp_signal(self.n_period, self.rate_hz, self.f0, self.f1, self.sweep)
        win = raised_cosine_fade(self.n_period, round(self.fade * self.rate_hz))
        one = self.amplitude * win * x
        self.wave = np.tile(one, (len(self.sel), 1))
        self._layout(len(self.sel), self.cfg.simultaneous)
        self._finish_rate()

    def finish(self, data: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict:
        """Identification hints: band, period (Welch segment), ``skip`` (one period of transient),
        blocks per DOF, and the RMS of the recorded excitation per DOF."""
        res: dict[str, Any] = {
            "type": "chirp", "band": [self.f0, self.f1], "sweep": self.sweep, "fs": self.rate_hz,
            "period": self.period, "periods": self.periods, "nperseg": self.n_period,
            "skip": self.period if self.periods > 1 else 0.0, "fade": self.fade, "target": self.target,
            "dofs": list(self.sel), "simultaneous": self.simultaneous, "excite": self.excite,
            "variant": self.variant, "segments": self.segments(), "periodic": self.periodic,
        }
        exc = data.get(f"{self.target}.excitation")
        n = int(np.shape(exc)[0]) if exc is not None and np.ndim(exc) else 0
        if n:
            sq: np.ndarray | None = None
            for _, blk in _row_blocks(exc, n):  # in blocks: the channel may be an h5py dataset of a long run
                part = np.sum(blk ** 2, axis=0)
                sq = part if sq is None else sq + part
            assert sq is not None
            res["excitation_rms"] = [float(np.sqrt(sq[i] / n)) for i in self.sel if i < sq.size]
        return res


class Multisine(_PeriodicEffort[MultisineExperiment]):
    """Periodic multisine with Schroeder phases, for MIMO identification in one experiment.

    Fields: ``f0``, ``f1`` (Hz), ``n_lines`` (lines per DOF), ``duration`` (s), ``periods``,
    ``amplitude`` (peak per DOF, N or N.m), ``target``, ``dofs``, ``simultaneous`` (default true:
    all DOFs at once on *zippered* lines -- DOF j gets every n-th line of one grid, so every line
    carries exactly one input and the MIMO FRF separates line by line; false: one DOF after the
    other on the same lines), ``spacing`` (linear | log), ``seed`` (recorded; phases are
    deterministic), ``variant``, ``excite``/``servo`` as for :class:`Chirp`.

    Lines are harmonics ``h / P`` of the period ``P = duration/periods`` in ``[f0, f1]``; each
    DOF's lines get Schroeder phases (low crest factor for equally spaced lines) and the sum is
    scaled so that its peak over a period equals ``amplitude``.
    """

    kind = "multisine"

    def __init__(self, cfg: MultisineExperiment, rate_hz: float) -> None:
        super().__init__(cfg, rate_hz, periodic=True)
        self.n_lines = cfg.n_lines
        self.spacing = cfg.spacing
        self.seed = cfg.seed
        self._build()

    def _build(self) -> None:
        simultaneous = self.cfg.simultaneous
        n_in = len(self.sel) if simultaneous else 1
        df = 1.0 / self.period
        kmin, kmax = math.ceil(self.f0 / df - 1e-9), math.floor(self.f1 / df + 1e-9)
        try:
            grid = multisine_lines(kmin, kmax, self.n_lines * n_in, self.spacing)
        except ValueError as exc:
            raise SceneError(f"{self.f('n_lines')}: {self.n_lines} lines x {n_in} DOF on the {df:g} Hz grid of "
                             f"[{self.f0}, {self.f1}] Hz: {exc}; lengthen the period or reduce n_lines") from exc
        if kmax >= self.n_period / 2:
            raise SceneError(f"{self.f('f1')}: above Nyquist")
        self.lines = [grid[j::n_in] for j in range(n_in)]  # harmonic indices per input (zipper)
        ph = schroeder_phases(self.n_lines)
        i = np.arange(self.n_period)
        waves = []
        for h in self.lines:
            x = np.sum(np.cos(2 * np.pi * np.outer(h, i) / self.n_period + ph[: h.size, None]), axis=0)
            peak = float(np.max(np.abs(x)))
            waves.append(self.amplitude * x / peak if peak > 0 else x)
        self.wave = np.array(waves if simultaneous else waves * len(self.sel))
        self._layout(len(self.sel), simultaneous)
        self._finish_rate()

    def line_frequencies(self) -> list[list[float]]:
        """Excited frequencies (Hz) per input (per DOF when simultaneous)."""
        return [list(np.asarray(h, dtype=float) / self.period) for h in self.lines]

    def finish(self, data: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict:
        return {"type": "multisine", "band": [self.f0, self.f1], "fs": self.rate_hz, "period": self.period,
                "periods": self.periods, "nperseg": self.n_period, "skip": self.period if self.periods > 1 else 0.0,
                "target": self.target, "dofs": list(self.sel), "simultaneous": self.simultaneous,
                "lines_hz": self.line_frequencies(), "crest_factor": [crest_factor(w) for w in self.wave],
                "segments": self.segments(), "variant": self.variant, "seed": self.seed, "excite": self.excite}


# ---------------------------------------------------------------------------------------------
# energy injection


def force_profile(profile: ForceProfileCfg | Mapping[str, Any], n: int, fs: float, dim: int,
                  where: str = "profile") -> np.ndarray:
    """Active force samples ``(n, dim)`` (N or N.m) of a profile (:class:`ForceProfileCfg`, or a
    mapping validated against it):

    * ``sine``: ``amplitude sin(2π freq t + phase)``;
    * ``multisine``: sum over ``freqs`` (Hz, list) of ``amplitude/len(freqs) sin(2π f t + φ_i)``
      with Schroeder phases;
    * ``square``: ``amplitude sign(sin(2π freq t + phase))``;
    * ``step``: ``amplitude`` from t = 0;
    * ``noise``: smoothed random: seeded white Gaussian through a 2nd-order Butterworth low-pass at
      ``freq`` Hz (forward-backward, zero phase), rescaled to std ``amplitude``.

    ``direction`` (per port DOF weights, default ones) multiplies the scalar profile.
    """
    cfg = validate(ForceProfileCfg, profile, where)
    kind, amp, freq, phase = cfg.kind, cfg.amplitude, cfg.freq, cfg.phase
    t = np.arange(n) / fs
    if kind == "sine":
        x = amp * np.sin(2 * np.pi * freq * t + phase)
    elif kind == "multisine":
        freqs = np.atleast_1d(np.asarray(cfg.freqs if cfg.freqs is not None else [freq], dtype=float))
        ph = schroeder_phases(freqs.size)
        x = amp / freqs.size * np.sum(np.sin(2 * np.pi * np.outer(freqs, t) + ph[:, None] + phase), axis=0)
    elif kind == "square":
        x = amp * np.sign(np.sin(2 * np.pi * freq * t + phase))
    elif kind == "step":
        x = np.full(n, amp)
    elif kind == "noise":
        if not 0 < freq < fs / 2:
            raise SceneError(f"{where}.freq: noise cutoff must lie in (0, {fs / 2:g}) Hz, got {freq}")
        rng = np.random.default_rng(int(cfg.seed or 0))
        w = rng.standard_normal(n + 2000)
        b, a = _sps().butter(2, freq / (fs / 2))
        y = _sps().filtfilt(b, a, w)[1000:1000 + n]
        x = amp * y / (np.std(y) or 1.0)
    else:  # pragma: no cover - the schema's Literal admits no other kind
        raise SceneError(f"{where}.kind: one of sine, multisine, square, step, noise; got {kind!r}")
    direction = cfg.direction
    dvec = np.ones(dim) if direction is None else np.asarray(direction, dtype=float).reshape(-1)
    if dvec.size != dim:
        raise SceneError(f"{where}.direction: {dvec.size} weights for a {dim}-DOF port")
    return x[:, None] * dvec[None, :]


class EnergyInjection(_Base[EnergyInjectionExperiment]):
    """Drive a network ``port`` with an active force profile and track ``E_s(t) = ∫ F_h^T V_h dt``
    at the port (paper 000 eq. 6, 001 eq. 30).

    Fields: ``port``, ``duration`` (s), ``profile`` (see :func:`force_profile`), ``noise_bound``
    (``auto``: from the scene's sensor noise, or estimated from the data by first differences on a
    real bench; or a number in J), ``via`` (``human``: the simulated operator's active force,
    ``Excitation.human[port]``; ``actuator``: effort on the port's actuator, which then plays the
    operator's active force: F_h = excitation + force_sign x sensor (if any). Default: human when
    the scene is simulated and a human holds the port's body, else actuator), ``force_sign`` (sensor
    reading; default from the scene: +1 when the simulated sensor reports the hand's force
    (``sim.measure: human``, the bench's ``auto`` with a human), else -1: the sensor reads the
    force the device exerts on what it touches), ``k_sigma`` (default 4), ``bound_mode`` (final |
    running, see :func:`port_energy`).

    ``finish`` reports whether ``E_s`` went below ``-bound`` (the port generated energy beyond
    what noise explains: an active, potentially unstable teleoperator), when first, and by how much.
    """

    kind = "energy_injection"

    def __init__(self, cfg: EnergyInjectionExperiment, rate_hz: float) -> None:
        super().__init__(cfg, rate_hz)
        self.port = cfg.port
        self.duration = cfg.duration
        self.profile_cfg = cfg.profile
        #: the profile as recorded in the results (``freqs`` only when given: ``multisine`` lines)
        self.profile = cfg.profile.model_dump(exclude={"freqs"} if cfg.profile.freqs is None else None)
        self.via: str | None = cfg.via
        self.noise_bound: str | float = cfg.noise_bound
        self.k_sigma = cfg.k_sigma
        self.bound_mode = cfg.bound_mode
        self._force_sign_cfg: float | None = None if cfg.force_sign is None else float(cfg.force_sign)
        self.force_sign: float | None = self._force_sign_cfg
        self._via_cfg = self.via
        self.n = round(self.duration * self.rate_hz)
        # defaults until check() resolves the port against the scene
        self.actuator = self.port
        self.sensor: str | None = None
        direction = cfg.profile.direction
        self.dofs = 1 if direction is None else len(direction)
        self.axes: list[int] | None = None
        self.noise = (0.0, 0.0)
        self.simulated = False
        self._samples = force_profile(self.profile_cfg, self.n, self.rate_hz, self.dofs, self.f("profile"))

    def check(self, scene: Any) -> None:
        ports = {str(_get(p, "name")): p for p in (_get(_get(scene, "network"), "ports") or [])}
        if self.port not in ports:
            raise SceneError(f"{self.f('port')}: no network port {self.port!r} (have {sorted(ports)})")
        p = ports[self.port]
        devs = _devices(scene)
        self.actuator = str(_get(p, "actuator"))
        self.sensor = _get(p, "force_sensor")
        self.dofs = int(_get(p, "dofs", 1))
        if self.actuator not in devs:
            raise SceneError(f"{self.f('port')}: port actuator {self.actuator!r} is not a device")
        sim = _get(scene, "simulation")
        self.simulated = sim is not None
        humans = []
        if sim is not None:
            h = _get(sim, "human")
            humans = [] if h is None else (list(h) if isinstance(h, list | tuple) else [h])
        act_body = _get(devs[self.actuator], "body", self.actuator)
        has_human = any(str(_get(h, "port")) == str(act_body) for h in humans)
        self.via = self._via_cfg
        if self.via is None:
            self.via = "human" if (self.simulated and has_human) else "actuator"
        if self.via == "human" and not (self.simulated and has_human):
            raise SceneError(f"{self.f('via')}: 'human' needs a simulated human holding body {act_body!r}")
        if self.sensor is not None and self.sensor not in devs:
            raise SceneError(f"{self.f('port')}: force sensor {self.sensor!r} of port {self.port!r} is not a device")
        if self.sensor is None and self.via == "human":
            raise SceneError(f"{self.f('port')}: port {self.port!r} needs a force_sensor to measure F_h")
        sdev = devs.get(self.sensor) if self.sensor is not None else None
        self.axes = _wrench_axes(sdev)[: self.dofs] if sdev is not None else None
        self.force_sign = self._force_sign_cfg
        if self.force_sign is None:
            measure = str(_get(_get(sdev, "sim"), "measure", "auto") or "auto")
            if measure == "auto":
                measure = "human" if (self.simulated and has_human) else "body"
            self.force_sign = 1.0 if measure == "human" else -1.0
        if self.noise_bound == "auto" and sim is not None:
            sn = _get(sim, "sensor_noise")
            self.noise = (float(_get(sn, "force_std", 0.0) or 0.0), float(_get(sn, "velocity_std", 0.0) or 0.0))
        self._samples = force_profile(self.profile_cfg, self.n, self.rate_hz, self.dofs, self.f("profile"))
        peak = float(np.max(np.abs(self._samples))) if self._samples.size else 0.0
        if self.via == "actuator":
            self._check_effort(scene, peak, "profile.amplitude")
        logger.info("%s: port %s via %s, F_h = %+g x %s%s", self.name, self.port, self.via, self.force_sign,
                    self.sensor, self.axes)

    def excitation(self, k: int, t: float, meas: Mapping[str, Any]) -> Excitation:
        f = self._samples[k] if 0 <= k < self.n else np.zeros(self.dofs)
        if self.via == "human":
            return Excitation(human={self.port: f.copy()})
        return Excitation(effort={self.actuator: f.copy()})

    def port_signals(self, data: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(t, F_h, V_h)`` at the port from the recorded channels.

        ``via: human``: ``F_h = force_sign x wrench[axes]`` (the hand's force on the device).
        ``via: actuator``: the actuator plays the operator's active force, so the force applied to
        the device from outside its controller is the recorded excitation ``<actuator>.excitation``
        plus, when the port has a force sensor, ``force_sign x wrench`` (e.g. a passive dummy hand).
        """
        try:
            t = np.asarray(data["t"], dtype=float)
            v = np.asarray(data[f"{self.actuator}.velocity"], dtype=float)
            w = None if self.sensor is None else np.asarray(data[f"{self.sensor}.wrench"], dtype=float)
            u = np.asarray(data[f"{self.actuator}.excitation"], dtype=float) if self.via == "actuator" else None
        except KeyError as exc:
            raise SceneError(f"{self.where}: record lacks channel {exc.args[0]!r}") from exc
        v = v.reshape(t.size, -1)[:, : self.dofs]
        F = np.zeros_like(v)
        if w is not None:
            w = w.reshape(t.size, -1)
            if w.shape[1] > self.dofs and self.axes is not None:
                w = w[:, self.axes]
            F = F + (self.force_sign if self.force_sign is not None else -1.0) * w[:, : self.dofs]
        if u is not None:
            F = F + u.reshape(t.size, -1)[:, : self.dofs]
        return t, F, v

    def finish(self, data: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict:
        t, F, V = self.port_signals(data)
        sf, sv = self.noise
        how = "scene"
        if self.noise_bound == "auto" and not self.simulated:
            sf, sv = noise_std_from_differences(F), noise_std_from_differences(V)
            how = "first differences"
        fixed = None if self.noise_bound == "auto" else float(self.noise_bound)
        res = port_energy(t, F, V, sf, sv, k_sigma=self.k_sigma, fixed_bound=fixed, bound_mode=self.bound_mode)
        out = {"type": "energy_injection", "port": self.port, "via": self.via, "force_sign": self.force_sign,
               "noise": {"force_std": sf, "velocity_std": sv, "source": how if fixed is None else "fixed",
                         "k_sigma": self.k_sigma, "bound_mode": self.bound_mode},
               "profile": self.profile, **res.summary()}
        if res.went_negative:
            logger.warning("%s: E_s at port %s went to %.4g J (bound %.3g J) at t = %.3f s: energy generated",
                           self.name, self.port, res.min_energy, out["bound_at_min"], res.first_time)
        return out


# ---------------------------------------------------------------------------------------------
# static hold


class StaticHold(_Base[StaticHoldExperiment]):
    """Step ``effort`` (N or N.m; scalar or per DOF) on ``target``'s ``dofs``, hold for
    ``duration`` s; after ``settle`` s report the static stiffness ``K = ΔF/Δx`` per DOF (ΔF the
    effort step, Δx the mean position after settling minus the position at the start, i.e. what
    the device + its controller + its environment oppose to a constant force)."""

    kind = "static_hold"

    def __init__(self, cfg: StaticHoldExperiment, rate_hz: float) -> None:
        super().__init__(cfg, rate_hz)
        self.target = cfg.target
        self.duration = cfg.duration
        self.settle = cfg.settle
        self.effort_cfg = np.atleast_1d(np.asarray(cfg.effort, dtype=float))
        self.dofs_cfg = cfg.dofs
        self.sel = [0] if cfg.dofs is None else list(cfg.dofs)
        self.target_dof = max(self.sel) + 1
        self.variant = cfg.variant
        self._resolve_effort()

    def _resolve_effort(self) -> None:
        e = self.effort_cfg
        if e.size == 1:
            e = np.full(len(self.sel), float(e[0]))
        if e.size != len(self.sel):
            raise SceneError(f"{self.f('effort')}: {e.size} values for {len(self.sel)} DOF")
        self.effort = e

    def check(self, scene: Any) -> None:
        dev, sel = self._check_target(scene, self.target, self.dofs_cfg)
        self.sel = sel
        self.target_dof = int(_get(dev, "dof", 1))
        self._resolve_effort()
        self._check_effort(scene, float(np.max(np.abs(self.effort))), "effort")

    def excitation(self, k: int, t: float, meas: Mapping[str, Any]) -> Excitation:
        e = np.zeros(self.target_dof)
        if 0 <= k < round(self.duration * self.rate_hz):
            e[self.sel] = self.effort
        return Excitation(effort={self.target: e})

    def finish(self, data: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict:
        """Stiffness from the settled window, in one pass over blocks of rows (bounded memory: the
        channels may be h5py datasets of the record); mean, std and drift (least-squares slope)
        from merged per-block moments (Chan et al.), equal to the two-pass values to rounding."""
        try:
            t_all = data["t"]
            x_all = data[f"{self.target}.position"]
        except KeyError as exc:
            raise SceneError(f"{self.where}: record lacks channel {exc.args[0]!r}") from exc
        n_all = int(np.shape(t_all)[0])
        if n_all < 2:
            raise SceneError(f"{self.where}: no samples after settle = {self.settle} s")
        x0 = np.asarray(x_all[0], dtype=float).reshape(-1)[self.sel]
        mom = _Moments()
        for i, tb in _row_blocks(t_all, n_all):
            xb = np.asarray(x_all[i:i + tb.shape[0]], dtype=float).reshape(tb.shape[0], -1)[:, self.sel]
            win = tb >= self.settle
            if np.any(win):
                mom.add(tb[win], xb[win])
        if mom.n == 0:
            raise SceneError(f"{self.where}: no samples after settle = {self.settle} s")
        xm = mom.mean_x
        dx = xm - x0
        with np.errstate(divide="ignore", invalid="ignore"):
            K = np.where(np.abs(dx) > 0, self.effort / dx, np.inf)
        res: dict[str, Any] = {"type": "static_hold", "target": self.target, "dofs": list(self.sel),
                               "effort": self.effort.tolist(), "x0": x0.tolist(), "x_mean": xm.tolist(),
                               "dx": dx.tolist(), "x_std": np.sqrt(np.maximum(mom.m2_x, 0.0) / mom.n).tolist(),
                               "stiffness": [float(k) for k in K], "settle": self.settle, "variant": self.variant,
                               "n_samples": int(mom.n)}
        # drift over the averaging window: a still-moving position means settle was too short
        if mom.n > 2 and mom.m2_t > 0:
            res["drift_per_s"] = np.atleast_1d(mom.c_tx / mom.m2_t).tolist()
        return res


_BLOCK_ROWS = 65536


def _row_blocks(ds: Any, n: int) -> Iterator[tuple[int, np.ndarray]]:
    """``(start, rows)`` blocks of the first ``n`` rows of an array or h5py dataset, as float arrays
    (``rows`` is (m,) for 1-D data, (m, k) otherwise)."""
    for i in range(0, n, _BLOCK_ROWS):
        blk = np.asarray(ds[i:min(n, i + _BLOCK_ROWS)], dtype=float)
        yield i, blk if blk.ndim == 1 else blk.reshape(blk.shape[0], -1)


class _Moments:
    """Count, means, centred sums of squares of ``t`` and ``x`` (per column) and their centred cross
    sum, merged block by block (Chan, Golub & LeVeque's pairwise update)."""

    def __init__(self) -> None:
        self.n = 0
        self.mean_t = 0.0
        self.m2_t = 0.0
        self.mean_x: np.ndarray = np.zeros(0)
        self.m2_x: np.ndarray = np.zeros(0)
        self.c_tx: np.ndarray = np.zeros(0)

    def add(self, t: np.ndarray, x: np.ndarray) -> None:
        nb = t.shape[0]
        mt, mx = float(np.mean(t)), np.mean(x, axis=0)
        dt_, dx_ = t - mt, x - mx
        m2t, m2x, ctx = float(dt_ @ dt_), np.sum(dx_ ** 2, axis=0), dt_ @ dx_
        if self.n == 0:
            self.n, self.mean_t, self.m2_t, self.mean_x, self.m2_x, self.c_tx = nb, mt, m2t, mx, m2x, ctx
            return
        na, n = self.n, self.n + nb
        d_t, d_x = mt - self.mean_t, mx - self.mean_x
        f = na * nb / n
        self.m2_t += m2t + d_t * d_t * f
        self.m2_x = self.m2_x + m2x + d_x * d_x * f
        self.c_tx = self.c_tx + ctx + d_t * d_x * f
        self.mean_t += d_t * nb / n
        self.mean_x = self.mean_x + d_x * nb / n
        self.n = n


# ---------------------------------------------------------------------------------------------
# registry and factory


@dataclass(frozen=True)
class ExperimentType:
    """One experiment type: its scene ``type`` name, its schema and its implementation (built as
    ``impl(validated_config, rate_hz)``)."""

    name: str
    schema: type[ExperimentConfig]
    impl: Callable[[Any, float], Experiment]


#: experiment type name -> (schema, implementation); :mod:`hil.scene.spec` builds its ``experiments``
#: union from it (register before importing :mod:`hil.scene.spec`)
EXPERIMENT_TYPES: dict[str, ExperimentType] = {}


def register_experiment(name: str, schema: type[ExperimentConfig], impl: Callable[[Any, float], Experiment]) -> None:
    """Add an experiment type: ``schema`` is a :class:`ExperimentConfig` whose ``type`` field is
    ``Literal[name]``; ``impl(cfg, rate_hz)`` builds the :class:`Experiment` from a validated ``cfg``."""
    register_tagged(EXPERIMENT_TYPES, name, schema, ExperimentType(name, schema, impl), "experiment type")


def experiment_schemas() -> tuple[type[ExperimentConfig], ...]:
    """The schemas of every registered experiment type (registration order), after those of the
    ``hil_certify.experiments`` entry points (:mod:`hil.plugins`, read once)."""
    load_group("experiments", ExperimentType, lambda t: register_experiment(t.name, t.schema, t.impl))
    return tuple(t.schema for t in EXPERIMENT_TYPES.values())


register_experiment("chirp", ChirpExperiment, Chirp)
register_experiment("multisine", MultisineExperiment, Multisine)
register_experiment("energy_injection", EnergyInjectionExperiment, EnergyInjection)
register_experiment("static_hold", StaticHoldExperiment, StaticHold)


def make_experiment(cfg: ExperimentConfig | Mapping[str, Any], *, rate_hz: float) -> Experiment:
    """Build one experiment at the control rate from its validated configuration (a scene's
    ``experiments`` entry, e.g. :meth:`hil.scene.spec.Scene.experiment_models`), or from a mapping,
    which is validated here against the schema of its ``type``."""
    if isinstance(cfg, ExperimentConfig):
        etype = cfg.type
        if etype not in EXPERIMENT_TYPES:
            raise SceneError(f"experiments[{cfg.name or '?'}].type: unknown experiment {etype!r}; "
                             f"one of {sorted(EXPERIMENT_TYPES)}")
        model = cfg
    else:
        raw = {k: v for k, v in dict(cfg).items() if v is not None}
        etype = str(raw.get("type", ""))
        if etype not in EXPERIMENT_TYPES:
            raise SceneError(f"experiments[{raw.get('name') or '?'}].type: unknown experiment {etype!r}; "
                             f"one of {sorted(EXPERIMENT_TYPES)}")
        model = validate(EXPERIMENT_TYPES[etype].schema, raw, f"experiments[{raw.get('name') or etype}]")
    exp = EXPERIMENT_TYPES[etype].impl(model, rate_hz)
    logger.debug("experiment %s (%s), %.3f s", exp.name, etype, exp.duration)
    return exp
