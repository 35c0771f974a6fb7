"""Experiment planning (``hil plan SCENE``): predicted posterior sd and safety of each identification
experiment BEFORE running it, and a proposal (amplitude, band, duration) for a requested precision.

For each open-loop (``controller: none``) chirp or multisine experiment of a scene with a
``simulation`` section (the nominal model):

* **Model**: what identification would fit to its record (:mod:`hil.identify.records`): the
  locked/free SDEA (``sdea_locked`` with velocity and spring force, ``sdea_free`` with ``m_h``
  identified) from ``simulation.sdea``, or the ``mbk`` model of the target's body, at the nominal
  values, sampled behind a zero-order hold at ``rate_hz`` (the runner's tick).
* **Excitation**: the exact samples the runner plays (:func:`hil.experiments.make_experiment`):
  one period of ``n`` samples per input, its DFT ``U_k`` on the lines ``f_k = k / period``.
* **Noise** per output: the scene's white sensor noise (``sensor_noise.velocity_std`` /
  ``force_std``) averaged over the ``K`` analysed periods (the first is skipped as the start-up
  transient when there are several, as identification does) plus the float32 rounding of the
  recorded outputs and of the applied command, identical in every period and therefore not averaged
  (``q = mean(spacing^2)/12`` of the predicted signals, :func:`hil.identify.frf.rounding_variance`).
  Per FRF component (real or imaginary part) at line ``k``::

      sigma_k,o,i^2 = n (s_o^2 / K + q_o + sum_j |H_oj|^2 q_j) / (2 |U_i,k|^2)

  (a bin driven by more than one input of one experiment cannot separate them: not used).
* **Prediction**: the Cramér-Rao bound of that design at the nominal parameters,
  ``sd = sqrt(diag F^-1)`` (delta method to physical units; :func:`hil.identify.fisher.crb`):
  the posterior sd an efficient identification reaches, ``rel_sd = sd / |nominal|``. The
  excitation adequacy of the band (:mod:`hil.identify.excitation`, information fraction >= 0.5)
  says whether identification would accept it.
* **Safety**: the nominal plant simulated from rest (exact ZOH discretization) under the whole
  command sequence: peak ``|effort|``, ``|velocity|`` and the position range of the actuated DOFs
  against ``safety.max_effort``, ``max_velocity`` and ``position_limits`` (``ratio`` = peak /
  limit; allowed when every ratio <= 1). Port energy is not predicted.

Proposal (``precision={param: rel_sd}``): the amplitude is scaled to the largest that keeps every
peak within ``SAFETY_MARGIN`` (0.8) of its limit (the plant is linear: peaks scale with it); if the
band does not pin every parameter it is widened towards the model's reference band (a decade around
its natural frequencies), within the runner's limit ``f1 <= rate/10`` and ``f0 >= 1/period``; then
the number of periods is raised until every requested sd is met (noise-limited variance falls as
``1/K``; the rounding floor does not, so the prediction is recomputed at each step), up to
``MAX_DURATION`` s. Infeasible requests are reported with the best sd reached.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, cast

import numpy as np

from hil.errors import HilError, SceneError

logger = logging.getLogger(__name__)

__all__ = ["ExperimentPrediction", "PlanError", "plan_scene", "predict_experiment"]

#: fraction of each safety limit a proposed amplitude may reach
SAFETY_MARGIN = 0.8
#: longest experiment a proposal may ask for [s]
MAX_DURATION = 600.0


class _PeriodicExperiment(Protocol):
    """What planning reads of a chirp/multisine (:class:`hil.experiments.periodic._PeriodicEffort` subclasses set
    these when built): one period of ``n_period`` samples per selected DOF in ``wave`` (n_sel, n_period),
    laid out in ``n_blocks`` blocks of ``n_block`` samples."""

    name: str
    rate_hz: float
    duration: float
    period: float
    periods: int
    n_period: int
    n_block: int
    n_blocks: int
    sel: list[int]
    wave: Any
    f0: float
    f1: float

    def check(self, scene: Any) -> None: ...


class PlanError(HilError):
    """The scene cannot be planned (no nominal model, no identification experiment, bad request)."""


@dataclass
class ExperimentPrediction:
    """Prediction for one experiment (module docstring). ``config``: the experiment as planned (or
    proposed); ``sd``/``rel_sd``: per parameter; ``safety``: per limit ``{peak, limit, ratio}``."""

    name: str
    model: str
    config: dict[str, Any]
    names: tuple[str, ...]
    nominal: dict[str, float]
    sd: dict[str, float]
    rel_sd: dict[str, float]
    information_fraction: dict[str, float]
    not_pinned: list[str]
    safety: dict[str, dict[str, float]]
    noise: dict[str, float]
    n_averages: int
    band: tuple[float, float]
    requested: dict[str, float] = field(default_factory=dict)
    proposal_notes: list[str] = field(default_factory=list)
    ok_precision: bool | None = None

    @property
    def allowed(self) -> bool:
        return all(v["ratio"] <= 1.0 for v in self.safety.values())

    def to_dict(self) -> dict[str, Any]:
        return {"experiment": self.name, "model": self.model, "config": self.config,
                "band_hz": list(self.band), "n_averages": self.n_averages, "noise_std": self.noise,
                "parameters": {n: {"nominal": self.nominal[n], "sd": self.sd[n], "rel_sd": self.rel_sd[n],
                                   "information_fraction": self.information_fraction[n],
                                   **({"requested_rel_sd": self.requested[n]} if n in self.requested else {})}
                               for n in self.names},
                "not_pinned": self.not_pinned, "safety": self.safety, "allowed": self.allowed,
                "precision_met": self.ok_precision, "notes": self.proposal_notes}


# ------------------------------------------------------------------------------------------ model


def _nominal_model(scene: Any, exp: Any) -> tuple[Any, dict[str, float]]:
    """(model, noise std per output) that identification would use for ``exp``'s record."""
    from hil.identify.models import GreyBoxModel, MbkModel, SdeaFreeOutput, SdeaLockedOutput

    sim = scene.simulation
    if sim is None:
        raise PlanError(f"scene {scene.name}: no simulation section, so no nominal model to plan with")
    noise = sim.sensor_noise
    rate = float(scene.rate_hz)
    sdea = sim.sdea
    if sdea is not None and exp.target == sdea.name:
        variant = exp.variant or ("locked" if sdea.m_out is None else "free")
        has_force = bool(scene.force_sensors)
        chans = ("velocity", "force") if has_force else ("velocity",)
        nom = {"K_f": sdea.K_f, "B_f": sdea.B_f, "M": sdea.M, "B": sdea.B}
        mdl: GreyBoxModel
        if variant == "locked":
            mdl = SdeaLockedOutput(chans, nominal=nom, zoh_fs=rate)
        else:
            if sdea.m_out is None:
                raise PlanError(f"experiment {exp.name}: free-output variant but simulation.sdea.m_out is null")
            mdl = SdeaFreeOutput(chans, m_h=None, nominal={**nom, "m_h": sdea.m_out}, zoh_fs=rate)
        out = {"velocity": noise.velocity_std, "force": noise.force_std}
        # a force sensor slower than the loop holds its samples: only the fraction r/rate of the
        # ticks carries new noise (hil.identify.sensor_hold), so its noise counts rate/r times
        out["force"] *= math.sqrt(max(1.0, rate / _sensor_rate(scene, rate)))
        return mdl, {c: float(out[c]) for c in chans}
    dev = scene.device(exp.target)
    body = next((b for b in sim.bodies if b.name == dev.body), None)
    if body is None:
        raise PlanError(f"experiment {exp.name}: no simulated body {dev.body!r} for target {exp.target!r}")
    n = body.dof

    def mat(v: Any) -> np.ndarray:
        a = np.asarray(v, float)
        return a * np.eye(n) if a.ndim == 0 else (np.diag(a) if a.ndim == 1 else a)

    sel = list(exp.dofs) if exp.dofs is not None else list(range(n))
    mdl_mbk = MbkModel(n, M=mat(body.M), B=mat(body.B), K=mat(body.K), inputs=sel, outputs=list(range(n)),
                   zoh_fs=rate, units=scene.units if scene.units in ("linear", "rotary") else "linear")
    return mdl_mbk, {o: float(noise.velocity_std) for o in mdl_mbk.output_names}


def _dofs_motion(mdl: Any, theta: np.ndarray, u: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """(position, velocity) of the actuated DOFs, (n, n_in) each, simulated from rest under the held
    command ``u`` (n, n_in) (exact ZOH discretization of the model's state space)."""
    A, B, _ = mdl.state_space(theta)
    X = _simulate(A, B, np.eye(A.shape[0]), u, fs)
    name = mdl.name
    if name == "sdea_locked":
        return X[:, [0]], X[:, [1]]
    if name == "sdea_free":
        v = X[:, [1]]
        return np.cumsum(v, axis=0) / fs, v
    n = mdl.n_dof
    idx = list(mdl.in_idx)
    return X[:, :n][:, idx], X[:, n:][:, idx]


# ------------------------------------------------------------------------------------- prediction


def _command(exp: Any) -> np.ndarray:
    """The effort the runner plays, (n_ticks, n_sel): the per-DOF periodic table laid out in blocks
    (vectorized :meth:`hil.experiments.periodic._PeriodicEffort._sample`)."""
    n = round(exp.duration * exp.rate_hz)
    wave = np.asarray(exp.wave, float)
    one = np.tile(wave, (1, exp.n_block // exp.n_period))  # (n_sel, n_block)
    if exp.n_blocks == 1:
        u = one.T
    else:
        u = np.zeros((exp.n_blocks * exp.n_block, len(exp.sel)))
        for b in range(exp.n_blocks):
            u[b * exp.n_block:(b + 1) * exp.n_block, b] = one[b]
    out = np.zeros((n, len(exp.sel)))
    m = min(n, u.shape[0])
    out[:m] = u[:m]
    return out


def _simulate(A: np.ndarray, B: np.ndarray, C: np.ndarray, u: np.ndarray, fs: float) -> np.ndarray:
    """Outputs ``C x_k`` (n, n_out) of ``x' = A x + B u`` from rest, ``u`` held over each tick (exact ZOH
    discretization), sampled before the tick's command (the runner's read -> command order)."""
    from scipy.signal import cont2discrete, lfilter, ss2tf

    Phi, Gam, Cd, Dd, _ = cont2discrete((A, B, C, np.zeros((C.shape[0], B.shape[1]))), 1.0 / fs, method="zoh")
    y = np.zeros((u.shape[0], C.shape[0]))
    for i in range(B.shape[1]):
        if not np.any(u[:, i]):
            continue
        num, den = ss2tf(Phi, Gam, Cd, Dd, input=i)
        for o in range(C.shape[0]):
            y[:, o] += lfilter(num[o], den, u[:, i])
    return y


def _design(exp: Any) -> tuple[list[tuple[np.ndarray, list[int]]], int, float]:
    """[(U (n_in, n_lines) DFT of one period per input, which model inputs it drives)], averages K, skip."""
    waves = np.asarray(exp.wave, float)
    n_sel = len(exp.sel)
    K = max(exp.periods - 1, 1) if exp.periods > 1 else 1
    if exp.n_blocks == 1:  # all inputs at once
        return [(np.fft.rfft(waves, axis=1), list(range(n_sel)))], K, (exp.period if exp.periods > 1 else 0.0)
    blocks = []
    for b in range(n_sel):
        U = np.zeros((n_sel, exp.n_period // 2 + 1), complex)
        U[b] = np.fft.rfft(waves[b])
        blocks.append((U, [b]))
    return blocks, K, (exp.period if exp.periods > 1 else 0.0)


def predict_experiment(scene: Any, exp_cfg: Any, *, requested: Mapping[str, float] | None = None
                       ) -> ExperimentPrediction:
    """Predicted sd, excitation adequacy and safety of one experiment entry (module docstring)."""
    from hil.experiments import make_experiment
    from hil.identify.excitation import plan_adequacy
    from hil.identify.fisher import crb, fisher_information
    from hil.identify.frf import rounding_variance

    cfg = exp_cfg.model_dump() if hasattr(exp_cfg, "model_dump") else dict(exp_cfg)
    cfg = {k: v for k, v in cfg.items() if v is not None}
    built = make_experiment(cfg, rate_hz=scene.rate_hz)
    if not hasattr(built, "n_period"):
        raise PlanError(f"experiment {built.name}: type {cfg.get('type')!r} is not a periodic chirp or multisine")
    exp = cast(_PeriodicExperiment, built)
    exp.check(scene)
    spec = type("E", (), {"target": cfg["target"], "variant": cfg.get("variant"), "dofs": cfg.get("dofs"),
                          "name": exp.name})()
    mdl, noise = _nominal_model(scene, spec)
    th = mdl.nominal
    fs = float(scene.rate_hz)
    n = exp.n_period
    f_all = np.fft.rfftfreq(n, 1.0 / fs)
    lo = max(float(exp.f0), 1.0 / exp.period)
    band = (lo, float(exp.f1))
    sel = (f_all >= band[0] - 1e-9) & (f_all <= band[1] + 1e-9) & (f_all > 0)
    f = f_all[sel]
    H = mdl.frf(th, 2 * np.pi * f)  # (nf, no, ni)
    blocks, K, _ = _design(exp)
    u = _command(exp)
    pos, vel = _dofs_motion(mdl, th, u, fs)
    # predicted outputs for the rounding floor: the time response of each output (velocity, force)
    A, Bm, C = mdl.state_space(th)
    Y = _simulate(A, Bm, C, u, fs)
    q_y = np.array([rounding_variance(Y[:, o], "float32") for o in range(C.shape[0])])
    # a drive that reports velocity in whole encoder counts per second quantizes it far above float32;
    # the rounding repeats with the signal in every period (not averaged), like the float32 floor
    steps = _velocity_steps(scene, cfg["target"])
    for o, name in enumerate(mdl.output_names):
        if name.startswith("velocity") and steps:
            q_y[o] = max(q_y[o], rounding_variance(Y[:, o], steps[min(_dof_index(name), len(steps) - 1)]))
    q_u = np.array([rounding_variance(u[:, i], "float32") for i in range(u.shape[1])])
    s2 = np.array([noise[o] ** 2 for o in mdl.output_names])
    floor = n * (s2[None, :] / K + q_y[None, :] + (np.abs(H) ** 2 @ q_u)[..., None][..., 0])  # (nf, no)
    sigma = np.full(H.shape, np.inf)
    for U, inputs in blocks:
        P = np.abs(U[:, sel].T) ** 2  # (nf, n_in)
        driven = 1e-12 * max(float(P.max()), 1e-300) <= P
        one = driven.sum(axis=1) == 1
        for i in inputs:
            ok = one & driven[:, i]
            sigma[ok, :, i] = np.sqrt(floor[ok] / (2.0 * P[ok, i][:, None]))
    F = fisher_information(mdl, th, 2 * np.pi * f, sigma)
    _, sd = crb(mdl, th, F)
    names = mdl.names
    rel = {nm: float(sd[i] / abs(th[i])) if th[i] != 0 else float("inf") for i, nm in enumerate(names)}
    usable = np.any(np.isfinite(sigma), axis=(1, 2))
    adequacy = plan_adequacy(mdl, th, f[usable], sigma[usable], fs, fs / n)
    s = scene.safety
    lim_pos = s.position_limits
    safety = {"effort": {"peak": float(np.max(np.abs(u))), "limit": float(s.max_effort)},
              "velocity": {"peak": float(np.max(np.abs(vel))), "limit": float(s.max_velocity)}}
    if lim_pos is not None:
        half = [(float(np.max(pos)), float(lim_pos[1])), (float(np.min(pos)), float(lim_pos[0]))]
        worst = max(half, key=lambda pl: pl[0] / pl[1] if pl[1] != 0 else math.inf)
        safety["position"] = {"peak": worst[0], "limit": worst[1]}
    for v in safety.values():
        v["ratio"] = v["peak"] / v["limit"] if v["limit"] not in (0.0, math.inf) else 0.0
    req = dict(requested or {})
    return ExperimentPrediction(
        name=exp.name, model=mdl.name, config={k: v for k, v in cfg.items()},
        names=names, nominal={nm: float(th[i]) for i, nm in enumerate(names)},
        sd={nm: float(sd[i]) for i, nm in enumerate(names)}, rel_sd=rel,
        information_fraction={nm: float(adequacy.information_fraction[i]) for i, nm in enumerate(names)},
        not_pinned=list(adequacy.not_pinned), safety=safety, noise=noise, n_averages=K, band=band,
        requested=req, ok_precision=(all(rel[k] <= v for k, v in req.items()) if req else None))


# --------------------------------------------------------------------------------------- proposal


def _propose(scene: Any, exp_cfg: Any, requested: Mapping[str, float]) -> ExperimentPrediction:
    from hil.experiments.base import BAND_LIMIT_FRACTION
    from hil.identify.excitation import reference_band

    cfg = exp_cfg.model_dump() if hasattr(exp_cfg, "model_dump") else dict(exp_cfg)
    cfg = {k: v for k, v in cfg.items() if v is not None}
    notes: list[str] = []
    periods0 = int(cfg.get("periods") or 1)
    periodic = bool(cfg.get("periodic", cfg.get("type") == "multisine"))
    first = predict_experiment(scene, cfg, requested=requested)
    if first.ok_precision and not first.not_pinned and first.allowed:
        first.proposal_notes = ["the experiment as planned meets the requested precision"]
        return first
    if not periodic or periods0 < 2:  # averaging needs periods: make it periodic with the same sweep length
        cfg.update(periodic=True, periods=max(periods0, 2), duration=float(cfg["duration"]) * max(periods0, 2)
                   / max(periods0, 1))
        notes.append("periodic sweep (identical periods, one skipped as the transient) so that averaging "
                     "reduces the noise")
    period = float(cfg["duration"]) / int(cfg["periods"])
    pred = predict_experiment(scene, cfg)
    # 1. band: widen towards the reference band when the excitation does not pin every parameter
    if pred.not_pinned:
        mdl, _ = _nominal_model(scene, type("E", (), {"target": cfg["target"], "variant": cfg.get("variant"),
                                                      "dofs": cfg.get("dofs"), "name": pred.name})())
        ref = reference_band(mdl, mdl.nominal, float(scene.rate_hz))
        f0 = max(min(float(cfg["f0"]), ref[0]), 1.0 / period)
        f1 = min(max(float(cfg["f1"]), ref[1]), BAND_LIMIT_FRACTION * float(scene.rate_hz))
        if (f0, f1) != (float(cfg["f0"]), float(cfg["f1"])):
            notes.append(f"band {cfg['f0']:g}-{cfg['f1']:g} Hz -> {f0:.4g}-{f1:.4g} Hz (it did not pin "
                         f"{', '.join(pred.not_pinned)})")
            cfg.update(f0=f0, f1=f1)
            pred = predict_experiment(scene, cfg)
    # 2. amplitude: the largest within SAFETY_MARGIN of every limit (linear plant: peaks scale with it)
    worst = max(v["ratio"] for v in pred.safety.values())
    if worst > 0:
        a = float(cfg["amplitude"]) * SAFETY_MARGIN / worst
        if abs(a / float(cfg["amplitude"]) - 1) > 1e-3:
            notes.append(f"amplitude {cfg['amplitude']:g} -> {a:.4g} ({SAFETY_MARGIN:.0%} of the tightest limit)")
            cfg["amplitude"] = a
            pred = predict_experiment(scene, cfg)
    # 3. periods: variance ~ 1/K for the noise part; recompute (the rounding floor does not average)
    def need(p: ExperimentPrediction) -> float:
        return max(p.rel_sd[k] / v for k, v in requested.items())

    max_periods = max(int(MAX_DURATION / period), 2)
    while need(pred) > 1.0 and int(cfg["periods"]) < max_periods:
        K = pred.n_averages
        K_new = max(math.ceil(K * need(pred) ** 2 * 1.02), K + 1)
        P = min(K_new + 1, max_periods)
        cfg.update(periods=P, duration=P * period)
        new = predict_experiment(scene, cfg)
        if need(new) > 0.98 * need(pred) and max_periods > P:  # floor-limited: more periods do not help
            pred = new
            break
        pred = new
    if int(cfg["periods"]) != periods0:
        notes.append(f"{cfg['periods']} periods of {period:g} s (duration {cfg['duration']:.4g} s)")
    pred = predict_experiment(scene, cfg, requested=requested)
    if not pred.ok_precision:
        notes.append(f"requested precision not reached within {MAX_DURATION:g} s and the safety limits (best: "
                     + ", ".join(f"{k} {pred.rel_sd[k]:.3g}" for k in requested) + ")")
    pred.proposal_notes = notes
    return pred


def plan_scene(scene: Any, *, experiments: Sequence[str] | None = None,
               precision: Mapping[str, float] | None = None) -> list[ExperimentPrediction]:
    """Predictions for the scene's open-loop chirp/multisine experiments (``experiments``: names to
    keep); with ``precision`` ``{param: relative sd}`` a proposal for every experiment whose model has
    those parameters (unknown names raise :class:`PlanError`)."""
    cand = [e for e in scene.experiments if getattr(e, "type", None) in ("chirp", "multisine")
            and getattr(e, "controller", "scene") == "none"]
    if experiments:
        names = [e.name or e.type for e in cand]
        missing = [x for x in experiments if x not in names]
        if missing:
            raise PlanError(f"no open-loop chirp/multisine experiment {missing[0]!r} in scene {scene.name} "
                            f"(have {', '.join(names) or 'none'})")
        cand = [e for e in cand if (e.name or e.type) in experiments]
    if not cand:
        raise PlanError(f"scene {scene.name}: no open-loop (controller: none) chirp or multisine experiment to plan")
    out = []
    req = dict(precision or {})
    for v in req.values():
        if not (math.isfinite(v) and v > 0):
            raise PlanError(f"--precision: a relative sd must be a positive number, got {v!r}")
    known: set[str] = set()
    for e in cand:
        try:
            pred = predict_experiment(scene, e)
        except SceneError:
            raise
        known |= set(pred.names)
        mine = {k: v for k, v in req.items() if k in pred.names}
        out.append(_propose(scene, e, mine) if mine else pred)
    unknown = sorted(set(req) - known)
    if unknown:
        raise PlanError(f"--precision {unknown[0]}: no planned experiment identifies it (parameters: "
                        f"{', '.join(sorted(known))})")
    return out


def _dof_index(output: str) -> int:
    """DOF of a velocity output name (``velocity`` -> 0, ``velocity_1`` -> 1)."""
    tail = output.rsplit("_", 1)[-1]
    return int(tail) if tail.isdigit() else 0


def _velocity_steps(scene: Any, target: str) -> list[float]:
    """Velocity quantization step [rad/s] per DOF of the target actuator (a device or a group), where its
    driver reports velocity in whole encoder counts per second: CiA 402 (0x606C in counts/s,
    ``2 pi / (counts_per_rev * gear_ratio)`` rad/s per count, :mod:`hil.protocols.cia402`). Empty when
    no such driver (float32 feedback only) or when counts_per_rev is left to be read from the drive."""
    devs = [d for d in scene.devices if d.name == target]
    if not devs:
        group = next((g for g in getattr(scene, "groups", None) or [] if g.name == target), None)
        members = list(getattr(group, "devices", []) or [])
        devs = [d for m in members for d in scene.devices if d.name == m]
    steps: list[float] = []
    for d in devs:
        p = dict(d.params or {})
        if d.driver != "cia402" or not p.get("counts_per_rev"):
            return []
        steps += [2 * math.pi / (float(p["counts_per_rev"]) * abs(float(p.get("gear_ratio", 1.0))))] * int(d.dof or 1)
    return steps


def _sensor_rate(scene: Any, rate: float) -> float:
    """Sample rate [Hz] of the scene's first force sensor (the loop rate unless its driver streams
    slower, e.g. a Bota serial sensor at 51200/sinc Hz)."""
    from hil.protocols.link_budget import bota_rate_hz

    for d in scene.devices:
        if d.role == "force_sensor" and d.driver.startswith("bota"):
            return min(rate, float(bota_rate_hz(d.params)))
    return rate
