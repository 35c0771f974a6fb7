"""Run records (a :class:`hil.identify.source.RecordSource`: native or imported) -> identification problems.

:func:`plan_from_record` reads what a record says about itself and returns an
:class:`IdentificationPlan`: the model, which signals are its inputs and outputs, the experiment
windows, the Welch segment and the analysis band. Every inferred item can be overridden (the
``overrides`` mapping; the CLI flags of ``hil identify``), and ``plan.notes`` lists how each was
decided, so a user can see (``--json``: ``record.mapping``) what was identified from what.

Inference, in order of precedence (override > record meta/results > scene > channel names):

* experiment: ``meta["experiment"]`` (the runner stores the experiment's config there; imported
  records may carry it in their sidecar ``meta``) and the experiment's results
  (``/results/<name>``: ``period``, ``skip``, ``band``, ``segments``, ``dofs``, ``target``);
* target actuator: the experiment's ``target`` (a device or a device group), else the actuator
  whose ``<device>.effort_cmd`` carries the most power;
* model: ``sdea_<variant>`` when the experiment names an SDEA ``variant`` (``locked`` | ``free``),
  else ``sdea_locked`` for a 1-DOF target with a force sensor, else ``mbk`` with one DOF per
  excited DOF of the target (units from the scene/meta: ``linear`` or ``rotary``);
* input: the motor effort command ``<target>.effort_cmd[i]`` (exact: the command, not the drive's
  estimate of its torque; what the drive applies differs only by its float32 rounding, which the
  likelihood carries as an input error);
* outputs: the target's ``velocity[i]``; for SDEA models also the spring force, the wrench
  component ``devices[].axes[0]`` of the force sensor on the target's body (scene), or of the
  network port of the target, or of the only wrench channel when it has one axis;
* windows: one per excitation segment (``results.segments``; sequential chirps on several DOFs
  give one experiment per DOF), each dropping ``skip`` seconds (one period of start-up transient);
* Welch segment ``nperseg``/``period`` and ``band`` from the results (the chirp's ``[f0, f1]``,
  the multisine's lines); a record without experiment meta (imported from CSV/.mat) gets the band
  its input actually excites: 99.8 % of the measured input power
  (:func:`hil.identify.excitation.excited_band`), capped at 0.45 fs -- not the whole 0.45 fs, whose
  unexcited bins would read as "coherence at the noise-only level";
* sampling: ``zoh`` (the runner's tick: outputs sampled, then a command held for one period; see
  :mod:`hil.identify.models`); ``continuous`` on request.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.identify.errors import ModelSpecError

logger = logging.getLogger(__name__)

__all__ = ["IdentificationPlan", "nominal_rate", "plan_from_record", "sample_rate", "scene_of_record"]

#: experiment types that identification understands
_EXCITATIONS = ("chirp", "multisine")


@dataclass
class IdentificationPlan:
    """What to identify from a record: ``model`` name and options, ``inputs``/``outputs`` (model
    channel -> signal name, a leading ``-`` negates), ``windows`` ([t0, t1) per experiment, s), and
    keyword arguments for :func:`hil.identify.api.identify_experiments`."""

    model: str
    model_options: dict[str, Any]
    channels: tuple[str, ...] | None
    inputs: list[str]
    outputs: dict[str, str]
    windows: list[tuple[float, float]]
    kwargs: dict[str, Any] = field(default_factory=dict)
    experiment: str | None = None
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "model_options": self.model_options,
            "channels": list(self.channels) if self.channels else None,
            "inputs": self.inputs,
            "outputs": self.outputs,
            "windows_s": [list(w) for w in self.windows],
            "experiment": self.experiment,
            "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.kwargs.items()},
            "notes": self.notes,
        }


def scene_of_record(rec: Any) -> Any:
    """The validated scene of a record source (:attr:`hil.identify.source.RecordSource.scene`: parsed
    by the side that owns the scene schema), or None (imported records have none)."""
    return getattr(rec, "scene", None)


def _experiment(rec: Any, name: str | None) -> tuple[str | None, dict[str, Any], dict[str, Any]]:
    """(name, config, results) of the identification experiment of a record."""
    meta = dict(getattr(rec, "meta", {}) or {})
    cfg = meta.get("experiment")
    cfg = dict(cfg) if isinstance(cfg, Mapping) else {}
    results = dict(getattr(rec, "results", {}) or {})
    if name is not None:
        hit = [k for k in results if k == name or k.split("_", 1)[-1] == name]
        if not hit and cfg.get("name") != name:
            raise ModelSpecError(f"no experiment {name!r} in the record (results: {sorted(results)})")
        res = dict(results[hit[0]]) if hit else {}
        return (hit[0] if hit else name), cfg, res
    exc = [k for k, v in results.items() if isinstance(v, Mapping) and v.get("type") in _EXCITATIONS]
    if len(exc) > 1:
        raise ModelSpecError(f"the record holds several excitation experiments {exc}: choose one with --experiment")
    if exc:
        return exc[0], cfg, dict(results[exc[0]])
    return cfg.get("name"), cfg, {}


def _vector_names(signals: Mapping[str, Any], channel: str) -> list[str]:
    """Signal names of a record channel: ``channel`` itself (scalar) or ``channel[0]``, ``channel[1]``..."""
    if channel in signals:
        return [channel]
    out = []
    i = 0
    while f"{channel}[{i}]" in signals:
        out.append(f"{channel}[{i}]")
        i += 1
    return out


def _pick_target(signals: Mapping[str, Any], notes: list[str]) -> str:
    cands = sorted({k.split(".effort_cmd")[0] for k in signals if ".effort_cmd" in k})
    if not cands:
        raise ModelSpecError("the record has no <device>.effort_cmd channel: name the input with --input")
    power = {}
    for c in cands:
        cols = [np.asarray(signals[n], float) for n in _vector_names(signals, f"{c}.effort_cmd")]
        power[c] = (float(sum(np.nanmean(x**2) for x in cols)), len(cols))
    # the excited actuator; among equals (a group and its members) the one with more DOFs
    best = max(cands, key=lambda c: (round(power[c][0], 12), power[c][1]))
    notes.append(f"target {best!r}: the actuator whose effort command carries the most power")
    return best


def _force_signal(scene: Any, signals: Mapping[str, Any], target: str, notes: list[str]) -> str | None:
    """``<sensor>.wrench[axis]`` measuring the target's DOF, or None."""
    if scene is not None:
        try:
            tdev = scene.device(target)
        except KeyError:
            tdev = None
        sensors = list(scene.force_sensors)
        chosen = None
        for p in getattr(scene.network, "ports", []) or []:
            if p.actuator == target and p.force_sensor:
                chosen = next((s for s in sensors if s.name == p.force_sensor), None)
                if chosen is not None:
                    notes.append(f"force: sensor {chosen.name!r} of network port {p.name!r}")
                    break
        if chosen is None and tdev is not None:
            same = [s for s in sensors if s.body is not None and s.body == tdev.body]
            if len(same) == 1:
                chosen = same[0]
                notes.append(f"force: sensor {chosen.name!r} on the target's body {tdev.body!r}")
        if chosen is not None:
            axis = chosen.wrench_axes[0]
            names = _vector_names(signals, f"{chosen.name}.wrench")
            if axis < len(names):
                notes.append(f"force axis {axis} from devices[{chosen.name}].axes")
                return names[axis]
    wrenches = sorted({k.split(".wrench")[0] for k in signals if ".wrench" in k})
    if len(wrenches) == 1:
        names = _vector_names(signals, f"{wrenches[0]}.wrench")
        if len(names) == 1:
            notes.append(f"force: the only wrench channel {names[0]!r}")
            return names[0]
        if names:
            raise ModelSpecError(
                f"cannot tell which axis of {wrenches[0]}.wrench ({len(names)} axes) is the spring force without "
                f"the scene: pass --output force={wrenches[0]}.wrench[i]"
            )
    return None


def plan_from_record(
    rec: Any, signals: Mapping[str, Any], overrides: Mapping[str, Any] | None = None
) -> IdentificationPlan:
    """Infer the identification of a record (:class:`hil.identify.source.RecordSource`; module docstring).

    ``signals``: the record's 1-D signals (:meth:`~hil.identify.source.RecordSource.to_identify_dict`). ``overrides``:
    ``model``, ``channels``, ``inputs`` (list of signal names), ``outputs`` (model channel -> signal),
    ``target``, ``experiment``, ``period``, ``skip``, ``band``, ``nperseg``, ``sampling``
    (``zoh``/``continuous``), ``model_options`` and any keyword of ``identify_experiments``.
    """
    ov = {k: v for k, v in dict(overrides or {}).items() if v is not None}
    notes: list[str] = []
    meta = dict(getattr(rec, "meta", {}) or {})
    exp_name, cfg, res = _experiment(rec, ov.pop("experiment", None))
    scene = scene_of_record(rec)
    t = np.asarray(rec.t, float)
    fs = sample_rate(t) if t.size > 1 and t[-1] > t[0] else nominal_rate(float(getattr(rec, "rate_hz", 1.0)))
    if exp_name:
        notes.append(f"experiment {exp_name!r} ({res.get('type') or cfg.get('type') or 'type unknown'})")
    closed_loop = cfg.get("controller") not in (None, "none")
    if closed_loop and scene is not None and getattr(scene.controller, "type", "none") != "none":
        notes.append("WARNING: the experiment ran in closed loop (controller: scene): H1 from the effort command "
                     "is biased by the feedback; identify from an open-loop (controller: none) run")
        logger.warning("record %s: closed-loop experiment, the identified plant may be biased", rec.path)

    # -- target and DOFs
    target = ov.pop("target", None) or res.get("target") or cfg.get("target")
    if target is None and "inputs" not in ov:
        target = _pick_target(signals, notes)
    dofs = ov.pop("dofs", None) or res.get("dofs") or cfg.get("dofs")
    if target is not None and dofs is None:
        dofs = list(range(len(_vector_names(signals, f"{target}.effort_cmd")) or 1))
    dofs = [int(d) for d in (dofs or [0])]

    # -- model
    variant = res.get("variant") or cfg.get("variant")
    model = ov.pop("model", None)
    force = None
    if model is None:
        if variant in ("locked", "free"):
            model = f"sdea_{variant}"
            notes.append(f"model {model}: the experiment's SDEA variant {variant!r}")
        else:
            force = _force_signal(scene, signals, target, notes) if (target and len(dofs) == 1) else None
            model = "sdea_locked" if force is not None else "mbk"
            notes.append(f"model {model}: " + ("1-DOF actuator with a force sensor" if force else
                                                f"{len(dofs)}-DOF mass-damper-spring device"))
    key = model.lower().replace("-", "_")
    units = (getattr(scene, "units", None) if scene is not None else None) or meta.get("units") or "linear"
    model_options = dict(ov.pop("model_options", None) or {})
    inputs = ov.pop("inputs", None)
    outputs = ov.pop("outputs", None)
    channels = ov.pop("channels", None)
    if inputs is None:
        if target is None:
            raise ModelSpecError("no input: name it with --input or the target with --target")
        names = _vector_names(signals, f"{target}.effort_cmd")
        if not names:
            raise ModelSpecError(f"the record has no channel {target}.effort_cmd")
        inputs = [names[d] for d in dofs]
    if key.startswith("sdea"):
        if outputs is None:
            if target is None:
                raise ModelSpecError("no outputs: name them with --output velocity=SIG --output force=SIG")
            vel = _vector_names(signals, f"{target}.velocity")
            outputs = {"velocity": vel[dofs[0]]} if vel else {}
            force = force or _force_signal(scene, signals, target, notes)
            if force is not None:
                outputs["force"] = force
            if not outputs:
                raise ModelSpecError(f"no {target}.velocity and no force channel in the record")
        if channels is None:
            channels = tuple(outputs)
        if key == "sdea_free":
            model_options.setdefault("m_h", None)  # the output inertia is identified too
    elif key == "mbk":
        n = len(inputs)
        model_options.setdefault("n_dof", n)
        model_options.setdefault("units", units if units in ("linear", "rotary") else "linear")
        if outputs is None:
            vel = _vector_names(signals, f"{target}.velocity") if target else []
            pos = _vector_names(signals, f"{target}.position") if target else []
            if vel:
                outputs = {f"velocity_{i}": vel[d] for i, d in enumerate(dofs)}
            elif pos:  # an encoder: the model's output is the position (mbk output="position")
                outputs = {f"position_{i}": pos[d] for i, d in enumerate(dofs)}
                notes.append("outputs: the target's position (no velocity channel in the record)")
            else:
                raise ModelSpecError("no velocity or position outputs: name them with --output velocity_0=SIG "
                                     "or --output position_0=SIG")
        kinds = {k.split("_")[0] for k in outputs}
        if kinds == {"position"}:
            model_options.setdefault("output", "position")
            outputs = {(k if "_" in k else f"{k}_0"): v for k, v in outputs.items()}
        elif kinds == {"velocity"}:
            outputs = {(k if "_" in k else f"{k}_0"): v for k, v in outputs.items()}
        else:
            raise ModelSpecError(f"mbk outputs are all velocity_i or all position_i, got {sorted(outputs)}")
    else:
        raise ModelSpecError(f"unknown model {model!r}; known: sdea_locked, sdea_free, mbk")

    # -- windows, segment, band
    t0, t1 = float(t[0]) if t.size else 0.0, float(t[-1]) + 0.5 / fs if t.size else 0.0
    segs = res.get("segments") or []
    windows = [(float(s["t_start"]), float(s["t_end"])) for s in segs] if segs else [(t0, t1)]
    if len(windows) > 1:
        notes.append(f"{len(windows)} excitation segments (one DOF after the other): one experiment each")
    kw: dict[str, Any] = {}
    period = ov.pop("period", None)
    if period is None:
        period = res.get("period")
        if period is None and cfg.get("duration") and (cfg.get("periodic") or cfg.get("type") == "multisine"):
            period = float(cfg["duration"]) / max(int(cfg.get("periods") or 1), 1)
    skip = ov.pop("skip", None)
    if skip is None:
        skip = res.get("skip")
        if skip is None and period is not None and int(cfg.get("periods") or 1) > 1:
            skip = period
        elif skip is None and period is not None and not cfg and t1 - t0 >= 2.0 * float(period):
            # an imported record with --period: its first period holds the start-up transient (a
            # record started from rest is not yet periodic), dropped as for the suite's own records
            skip = float(period)
            notes.append(f"the first period ({float(period):g} s) is dropped as start-up transient (--skip 0 "
                         "keeps it)")
    band = ov.pop("band", None)
    if band is None:
        band = res.get("band") or ([cfg["f0"], cfg["f1"]] if "f0" in cfg and "f1" in cfg else None)
        if band is not None and period:
            band = [max(float(band[0]), 1.0 / float(period)), float(band[1])]
    if band is None:  # no experiment meta (an imported record): the band the input actually excites
        band = _measured_band(t, signals, inputs, windows, fs, notes)
        if band is not None and period:
            band = [max(float(band[0]), 1.0 / float(period)), float(band[1])]
    nperseg = ov.pop("nperseg", None) or (None if period is not None else res.get("nperseg"))
    for k, v in (("period", period), ("skip", skip), ("band", band), ("nperseg", nperseg)):
        if v is not None:
            kw[k] = tuple(float(x) for x in v) if k == "band" else (int(v) if k == "nperseg" else float(v))
    sampling = ov.pop("sampling", "zoh")
    if sampling not in ("zoh", "continuous"):
        raise ModelSpecError(f"sampling must be 'zoh' or 'continuous', got {sampling!r}")
    if sampling == "zoh":
        model_options.setdefault("zoh_fs", fs)
        notes.append(f"zero-order-hold sampled model at {fs:g} Hz (command held over each tick)")
    kw.update(ov)
    return IdentificationPlan(
        model=key,
        model_options=model_options,
        channels=tuple(channels) if channels else None,
        inputs=list(inputs),
        outputs=dict(outputs),
        windows=windows,
        kwargs=kw,
        experiment=exp_name,
        notes=notes,
    )


def _measured_band(t: np.ndarray, signals: Mapping[str, Any], inputs: Sequence[str],
                   windows: Sequence[tuple[float, float]], fs: float, notes: list[str]) -> list[float] | None:
    """The band holding 99.8 % of the input power over the experiment windows
    (:func:`hil.identify.excitation.excited_band`), capped at 0.45 fs; None if no input has power."""
    from hil.identify.excitation import excited_band

    lo, hi = np.inf, 0.0
    for w in windows:
        m = window_mask(t, w)
        if np.count_nonzero(m) < 8:
            continue
        try:
            u = np.column_stack([signal(signals, n)[m] for n in inputs])
            b = excited_band(u, fs)
        except ValueError:  # an idle window (one DOF after the other)
            continue
        lo, hi = min(lo, b[0]), max(hi, b[1])
    if not np.isfinite(lo) or hi <= lo:
        return None
    hi = min(hi, 0.45 * fs)
    notes.append(f"band {lo:.4g}-{hi:.4g} Hz: 99.8 % of the measured input power (no experiment meta)")
    return [float(lo), float(hi)]


def nominal_rate(fs: float) -> float:
    """A sample rate measured from decimal timestamps (``1 / median(dt)`` of an imported CSV:
    1999.99999999978 Hz) snapped to its short decimal form (2000 Hz) when within 1e-9: the same
    run then gives the same zero-order-hold model, native or imported."""
    short = float(f"{fs:.6g}")
    return short if abs(short / fs - 1.0) < 1e-9 else fs


def sample_rate(t: Any) -> float:
    """THE sample rate [Hz] of a time column, used everywhere a rate is derived from samples (the
    band edges, the DFT grid, the zero-order-hold model): ``1 / median(diff t)`` snapped to its short
    decimal form (:func:`nominal_rate`). Two rates of one record (a rounded one for the band, the
    raw one for the DFT) once dropped the lowest bin of a band computed at 1000.0 Hz from a DFT at
    999.9999999999991 Hz. The mean step ``(t[-1] - t[0]) / (n - 1)`` is used: timestamps stored with
    rounding jitter (the EMPS record: steps of 0.99998..1.00002 ms) have a median step off by the
    jitter, their mean step is the clock's (gaps are a data check of their own)."""
    tt = np.asarray(t, float)
    if tt.size < 2 or not tt[-1] > tt[0]:
        raise ModelSpecError("a record needs at least 2 increasing samples to have a sample rate")
    return nominal_rate((tt.size - 1) / float(tt[-1] - tt[0]))


def signal(signals: Mapping[str, Any], name: str) -> np.ndarray:
    """A signal by name; a leading ``-`` negates it (a sensor mounted the other way round)."""
    neg = name.startswith("-")
    key = name[1:] if neg else name
    if key not in signals:
        raise ModelSpecError(f"signal {key!r} is not in the record (have {sorted(signals)})")
    x = np.asarray(signals[key], float)
    return -x if neg else x


def window_mask(t: np.ndarray, window: Sequence[float]) -> np.ndarray:
    """Samples with ``t0 <= t < t1``."""
    return (t >= window[0] - 1e-9) & (t < window[1] - 1e-9)
