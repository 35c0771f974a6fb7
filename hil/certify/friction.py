"""Friction in a certificate (issue 25; docs/CERTIFICATION.md, "Friction").

* What an identification with friction contributes: its viscous ``B`` feeds the network like any
  identified parameter; dry friction (``F_c``, ``F_s``/``v_s``) and the constant offset ``F_0`` are
  shown (:func:`friction_rows`) but never fed to the network: the linear stability conditions count
  the viscous damping only (conservative, Coulomb friction is passive but not a damping).
* A plant fit that is a misfit (its adequacy tests fail, or a linear 1-DOF fit whose B dry friction
  biases: :func:`linear_friction_screen`) caps the decision at MARGINAL (:func:`adequacy_spec`).
* Energy-injection evidence of a port whose actuator has dry friction is judged on
  ``E_s(t) - D_f(t)``, ``D_f = ∫ F(|v|) |v| dt`` the energy the friction dissipated
  (:func:`energy_with_friction`): the friction's dissipation is not credited to the network.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hil.certify.certificate import Measurement
from hil.certify.stages import Expect, MeasurementSpec, info_spec
from hil.errors import HilError
from hil.scene.spec import FRICTION_NAMES

logger = logging.getLogger(__name__)

#: the identification's adequacy: a misfit caps the decision at MARGINAL (docs/CERTIFICATION.md)
ADEQUACY_DESCRIPTION = ("the plant model's adequacy tests (residual whiteness, input correlation; a linear "
                        "1-DOF fit: B unbiased by dry friction); a misfit caps the decision at MARGINAL")

#: what the friction rows say about the stability conditions
NOT_DAMPING = ("dry friction: passive (dissipates F|v|), NOT counted as damping by the stability conditions, "
               "which use the viscous B only (conservative)")


def adequacy_spec(experiment: str) -> MeasurementSpec:
    """The plant fit's adequacy: adequate passes, a misfit is MARGINAL (never FAIL: the model class
    is wrong, the plant is not shown unstable)."""
    return MeasurementSpec(f"plant model adequacy ({experiment})", expect=Expect({True: "PASS"}, otherwise="MARGINAL"),
                           description=ADEQUACY_DESCRIPTION)


def identify_kwargs(spec: Any, target: str | None = None) -> dict[str, Any]:
    """``identify_record`` keyword arguments of a ``certification.identify`` entry (``target``: its
    experiment's target device, whose channel ``output`` names)."""
    kw: dict[str, Any] = {}
    if spec.model:
        kw["model"] = spec.model
    if spec.friction:
        kw["friction"] = tuple(spec.friction)
    if spec.output is not None and target:
        kw["outputs"] = {spec.output: f"{target}.{spec.output}[0]"}
    return kw


def default_map(names: Sequence[str]) -> dict[str, str]:
    """The identity map of an entry without ``map``: every identified parameter but dry friction."""
    return {n: n for n in names if n not in FRICTION_NAMES}


def friction_rows(experiment: str, res: Any) -> list[Measurement]:
    """INFO rows of an identification with friction: each dry-friction parameter's posterior mean
    with its 90 % credible interval in the description, and the viscous damping the conditions use."""
    summ = res.summary()
    units = dict(zip(res.model.names, res.model.units, strict=True))
    rows: list[Measurement] = []
    for name in ("F_c", "F_s", "v_s", "F_0"):
        if name not in summ:
            continue
        s = summ[name]
        what = {"F_c": "Coulomb friction F_c", "F_s": "Stribeck excess F_s (break-away F_c + F_s)",
                "v_s": "Stribeck velocity v_s", "F_0": "constant force offset F_0"}[name]
        note = NOT_DAMPING if name != "F_0" else ("a constant force (gravity, drive offset): no damping, "
                                                  "not counted by the stability conditions")
        rows.append(info_spec(f"{what} ({experiment})", units.get(name, "")).measure(
            float(s["mean"]), description=f"posterior mean, 90% credible [{s['q05']:.6g}, {s['q95']:.6g}]; {note}"))
    if "B" in summ:
        s = summ["B"]
        spec = info_spec(f"damping counted by the stability conditions ({experiment})", units.get("B", ""))
        rows.append(spec.measure(float(s["mean"]), description=f"viscous B only, posterior mean, 90% credible "
                                                                f"[{s['q05']:.6g}, {s['q95']:.6g}]; dry friction and "
                                                                "offset are not added"))
    return rows


def misfit_reasons(res: Any) -> list[str]:
    """The adequacy report's reasons of a misfit fit (``[]`` when adequate)."""
    if not getattr(res, "misfit", False):
        return []
    rep = getattr(res, "adequacy", None)
    return list(rep.reasons) if rep is not None and rep.reasons else ["flagged by the adequacy tests"]


#: the linear fit's B is "biased by dry friction" when it differs from the friction model's by more than
#: this many combined standard deviations (a 4-sigma false alarm: 6e-5 for a Gaussian estimate)
SCREEN_Z = 4.0


def linear_friction_screen(record: Any, res: Any, spec: Any, units: str = "linear") -> list[str]:
    """For a linear (no ``friction``) 1-DOF ``mbk`` identification: does dry friction bias its damping?
    Both inverse-dynamics models are fitted by IDIM-ML (:func:`hil.identify.inverse_ml.fit_inverse_ml`)
    to the record's effort and position: the linear ``u = M q'' + B q'`` and the one with Coulomb
    friction and an offset. Without friction both estimate the same B; with it the linear B absorbs
    the friction (the EMPS record: 2.1x). Returns the reason when the two B differ by more than
    :data:`SCREEN_Z` combined standard deviations (a misfit for the certificate), else ``[]``. Other
    models (SDEA, m-DOF) have no friction model yet and are not screened."""
    if spec.friction or res.model.name != "mbk" or len(getattr(res, "names", ())) != 3:
        return []
    from hil.identify.inverse_ml import fit_inverse_ml
    from hil.identify.records import sample_rate
    from hil.record.hdf5 import RunRecord

    try:
        rec = RunRecord.open(record)
        targets = [k[: -len(".effort_cmd")] for k in rec.channels if k.endswith(".effort_cmd")]
        if len(targets) != 1 or f"{targets[0]}.position" not in rec.channels:
            return []
        u = np.asarray(rec.channels[f"{targets[0]}.effort_cmd"], float).reshape(-1)
        q = np.asarray(rec.channels[f"{targets[0]}.position"], float).reshape(-1)
        fs = sample_rate(rec.t)
        lin = fit_inverse_ml([(q, u)], fs, (), units=units)
        dry = fit_inverse_ml([(q, u)], fs, ("coulomb", "offset"), units=units)
    except (HilError, ValueError, KeyError, np.linalg.LinAlgError) as exc:
        logger.info("friction screen of %s skipped: %s", record, exc)
        return []

    def b_sd(fit: Any) -> tuple[float, float]:
        i = list(fit.model.names).index("B")
        return float(fit.theta[i]), float(np.sqrt(max(fit.cov_theta[i, i], 0.0)))

    (b0, s0), (b1, s1) = b_sd(lin), b_sd(dry)
    z = abs(b0 - b1) / max(float(np.hypot(s0, s1)), 1e-300)
    if not z > SCREEN_Z:
        return []
    fc = float(dry.theta[list(dry.model.names).index("F_c")])
    return [f"dry friction in the data: the linear fit's B = {b0:.4g} ± {s0:.2g} differs from B = {b1:.4g} ± "
            f"{s1:.2g} of the model with Coulomb friction (F_c = {fc:.4g}) by {z:.1f} sd (IDIM-ML on the "
            "effort and position): the linear fit puts the friction into B; identify with friction: [coulomb, offset]"]


# ---------------------------------------------------------------------------------------------
# energy evidence with dry friction


@dataclass(frozen=True)
class FrictionLevels:
    """Dry friction of one port DOF as its dissipation is computed: ``F_c``, Stribeck excess ``F_s``
    at rest and ``v_s`` (N or N.m; m/s or rad/s), and where the values come from."""

    F_c: float
    F_s: float = 0.0
    v_s: float = 1.0
    source: str = ""

    def dissipation_rate(self, v: np.ndarray) -> np.ndarray:
        """``(F_c + F_s exp(-(v/v_s)^2)) |v|`` (W), the power the friction takes from the motion."""
        a = np.abs(np.asarray(v, float))
        return (self.F_c + self.F_s * np.exp(-((a / self.v_s) ** 2))) * a


def port_friction(scene: Any, actuator: str, idents: Mapping[str, Any]) -> list[FrictionLevels] | None:
    """Dry friction per DOF of the port driven by ``actuator``: from an identification of that
    actuator with friction (``idents``: target -> result; the 95 % quantile of each level, the most
    dissipation the data allow), else from the simulated twin (a mocked bench knows it); None when
    neither says anything."""
    res = idents.get(actuator)
    if res is not None:
        s = res.summary()
        if "F_c" in s:
            return [FrictionLevels(float(s["F_c"]["q95"]), float(s["F_s"]["q95"]) if "F_s" in s else 0.0,
                                   float(s["v_s"]["q95"]) if "v_s" in s else 1.0,
                                   source="identified (95% quantile)")]
    if getattr(scene, "simulation", None) is None:
        return None
    from hil.bench.mechanics import device_mechanics

    groups = {g.name: list(g.devices) for g in getattr(scene, "groups", None) or []}
    try:
        members = [scene.device(m) for m in groups.get(actuator, [actuator])]
    except (KeyError, ValueError):
        return None
    levels: list[FrictionLevels] = []
    for d in members:
        fr = device_mechanics(d).friction
        for _ in range(d.dof):
            levels.append(FrictionLevels(fr.F_c, fr.F_s - fr.F_c, float(fr.stribeck_velocity or 1.0),
                                         source="simulated twin"))
    return levels if any(lv.F_c > 0 or lv.F_s > 0 for lv in levels) else None


def energy_with_friction(t: np.ndarray, V: np.ndarray, energy: np.ndarray, bound: np.ndarray,
                         levels: Sequence[FrictionLevels]) -> dict[str, Any]:
    """The energy test without the friction's dissipation: ``E_s(t) - D_f(t) >= -bound(t)`` with
    ``D_f(t) = ∫_0^t Σ_i F_i(|v_i|) |v_i| dt`` (trapezoid on the samples, like ``E_s``). Returns
    ``went_negative``, ``min_margin`` (min of ``E_s - D_f + bound``), ``dissipated`` (``D_f`` at the end, J),
    ``first_time``."""
    t = np.asarray(t, float).reshape(-1)
    Vm = np.asarray(V, float).reshape(t.size, -1)
    if Vm.shape[1] != len(levels):
        raise ValueError(f"{Vm.shape[1]} port DOF, {len(levels)} friction levels")
    p = np.zeros(t.size)
    for i, lv in enumerate(levels):
        p += lv.dissipation_rate(Vm[:, i])
    d = np.concatenate([[0.0], np.cumsum(0.5 * (p[1:] + p[:-1]) * np.diff(t))]) if t.size else np.zeros(0)
    margin = np.asarray(energy, float) - d + np.asarray(bound, float)
    neg = margin < 0
    return {"went_negative": bool(np.any(neg)), "min_margin": float(np.min(margin)) if margin.size else 0.0,
            "dissipated": float(d[-1]) if d.size else 0.0,
            "first_time": float(t[int(np.argmax(neg))]) if np.any(neg) else None}


def energy_friction_spec(name: str) -> MeasurementSpec:
    """``E_s - D_f`` against the bound: went below it is MARGINAL (the passivity the run seemed to
    show came from the plant's dry friction, not from the network)."""
    return MeasurementSpec(f"E_s(t) − D_friction(t) ≥ -bound ({name})", unit="J",
                           expect=Expect({False: "PASS"}, otherwise="MARGINAL"),
                           description="minimum over the run of E_s − D_f + bound; D_f = ∫ F_friction(|v|)|v| dt")


def friction_energy_evidence(scene: Any, outcomes: Mapping[str, Any], idents: Mapping[str, Any],
                             measurements: list[Measurement]) -> list[str]:
    """Re-read every energy-injection run of a port whose actuator has dry friction without the
    friction's dissipation (:func:`energy_with_friction`); one measurement each. Returns the caps
    (reasons the decision cannot be GO)."""
    caps: list[str] = []
    cfgs = {c["name"]: c for c in scene.experiment_configs()}
    runs = {name: o for name, o in outcomes.items() if name in cfgs and o.record is not None
            and (getattr(o, "results", None) or {}).get("type") == "energy_injection"
            and "went_negative" in o.results}
    if not runs:  # nothing to re-read: no record or experiment code is loaded
        return caps
    from hil.experiments import make_experiment
    from hil.experiments.energy import port_energy
    from hil.experiments.energy_injection import EnergyInjection
    from hil.record.hdf5 import RunRecord

    for name, o in runs.items():
        r = o.results
        exp = make_experiment(cfgs[name], rate_hz=float(scene.rate_hz))
        if not isinstance(exp, EnergyInjection):  # pragma: no cover - the results say energy_injection
            continue
        exp.check(scene)
        levels = port_friction(scene, exp.actuator, idents)
        if levels is None:
            continue
        rec = RunRecord.open(o.record)
        data = {"t": rec.t, **{k: np.asarray(v) for k, v in rec.channels.items()}}
        t, F, V = exp.port_signals(data)
        noise = r.get("noise", {})
        fixed = None if noise.get("source") != "fixed" else float(r.get("final_bound", 0.0))
        res = port_energy(t, F, V, float(noise.get("force_std", 0.0)), float(noise.get("velocity_std", 0.0)),
                          k_sigma=float(noise.get("k_sigma", 4.0)), fixed_bound=fixed,
                          bound_mode=str(noise.get("bound_mode", "final")))
        levels = (levels * V.shape[1])[: V.shape[1]] if len(levels) == 1 else levels
        ev = energy_with_friction(t, V, res.energy, res.bound, levels)
        src = levels[0].source
        measurements.append(energy_friction_spec(name).measure(
            ev["min_margin"], result=ev["went_negative"],
            description=f"min of E_s − D_f + bound; D_f = {ev['dissipated']:.4g} J dissipated by dry friction "
                        f"(F_c = {', '.join(f'{lv.F_c:.4g}' for lv in levels)}, {src})"))
        if ev["went_negative"] and not r["went_negative"]:
            caps.append(f"energy injection ({name}): E_s(t) stayed above its bound only through the dry friction's "
                        f"dissipation (D_f = {ev['dissipated']:.4g} J by t = {t[-1]:.3g} s); without it E_s − D_f "
                        f"went below the bound at t = {ev['first_time']:.3g} s: the network's passivity is not shown")
    return caps
