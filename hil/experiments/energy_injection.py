"""``energy_injection``: drive a port with a force profile and measure the energy it absorbs
(a passivity test by experiment). Forces N, energies J."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator, Field
from pydantic_core import PydanticCustomError

from hil.errors import SceneError
from hil.experiments.base import Excitation, ExperimentConfig, _Base, _devices, _get, _sps, _wrench_axes
from hil.experiments.energy import noise_std_from_differences, port_energy
from hil.experiments.signals import schroeder_phases
from hil.schema import (
    Effort,
    FieldError,
    Hz,
    HzOrZero,
    Name,
    Number,
    Positive,
    SceneView,
    Seconds,
    Seed,
    StrictModel,
    near,
    number,
    validate,
)

logger = logging.getLogger(__name__)


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
