"""The scene's cross-references, checked after the per-field validation (:func:`cross_check`): device
and port names, link budgets, the simulation's shapes, the certification's models, parameters and
identification mappings. Pure: nothing in the scene changes; the first broken reference is a
:class:`hil.schema.FieldError` ``(path, message)``. Called by :func:`hil.scene.spec.scene_from_dict`."""

from __future__ import annotations

import difflib
import logging
import math
import re
from collections.abc import Sequence
from typing import Any

from hil.scene.spec import (
    FRICTION_PARAMETERS,
    IDENTIFICATION_MODELS,
    NAMED_TERMINATION_DOF,
    CertificationCfg,
    HumanCfg,
    IdentifyCfg,
    ImpedanceTermination,
    NamedTermination,
    Scene,
    Simulation,
    WallTermination,
    is_friction_name,
)
from hil.schema import FieldError
from hil.schema import matrix_shape as _shape
from hil.schema import near as _near

__all__ = ["cross_check"]

logger = logging.getLogger(__name__)

def cross_check(sc: Scene) -> None:
    """Raise :class:`hil.schema.FieldError` ``(path, message)`` for the first broken reference or
    shape. Pure: nothing in ``sc`` changes (the final values are set by ``Scene._final_values``)."""
    names = [d.name for d in sc.devices]
    seen: set[str] = set()
    for i, d in enumerate(sc.devices):
        if d.name in seen:
            raise FieldError(f"devices[{i}].name", f"duplicate device name {d.name!r}")
        seen.add(d.name)
    dev = {d.name: d for d in sc.devices}
    grouped: set[str] = set()
    for i, g in enumerate(sc.groups):
        if g.name in dev:
            raise FieldError(f"groups[{i}].name", f"group name {g.name!r} is already a device name")
        for k, m in enumerate(g.devices):
            if m not in dev:
                raise FieldError(f"groups[{i}].devices[{k}]", f"unknown device {m!r}{_near(m, names)}")
            if dev[m].role != "actuator":
                raise FieldError(f"groups[{i}].devices[{k}]", f"device {m!r} is a {dev[m].role}; groups hold actuators")
            if m in grouped:
                raise FieldError(f"groups[{i}].devices[{k}]", f"device {m!r} is already in another group")
            grouped.add(m)
        dev[g.name] = sc.device(g.name)
    need = sc.require

    # network
    pnames: set[str] = set()
    for i, p in enumerate(sc.network.ports):
        if p.name in pnames:
            raise FieldError(f"network.ports[{i}].name", f"duplicate port name {p.name!r}")
        pnames.add(p.name)
        a = need(f"network.ports[{i}].actuator", p.actuator, "actuator")
        if a.dof != p.dofs:
            raise FieldError(f"network.ports[{i}].dofs", f"port has {p.dofs} DOF but actuator {a.name!r} has {a.dof}")
        if p.force_sensor is not None:
            s = need(f"network.ports[{i}].force_sensor", p.force_sensor, "force_sensor")
            if s.dof != p.dofs:
                raise FieldError(f"network.ports[{i}].force_sensor",
                                 f"sensor {s.name!r} measures {s.dof} DOF, the port has {p.dofs}")
    # the controller and the experiments check their own references (pure)
    sc.controller.check_scene(sc)
    exp_names: dict[str, int] = {}
    for i, e in enumerate(sc.experiment_models()):
        assert e.name is not None  # filled by experiment_models
        if e.name in exp_names:
            raise FieldError(f"experiments[{i}].name", f"duplicate experiment name {e.name!r} (also "
                                                       f"experiments[{exp_names[e.name]}])")
        exp_names[e.name] = i
    for i, e in enumerate(sc.experiments):
        e.check_scene(sc, f"experiments[{i}]")
    for i, d in enumerate(sc.devices):
        if d.role == "actuator" and d.axes is not None:
            raise FieldError(f"devices[{i}].axes", "axes applies to force sensors only")
        if d.driver == "cia402" and (sc.units == "linear" or d.dof != 1 or d.role != "actuator"):
            # hil.protocols.cia402: one rotary axis (rad, N.m) per drive node
            raise FieldError(f"devices[{i}].driver",
                             "a cia402 drive is one rotary actuator axis: role actuator, dof 1, units rotary")
    if sc.simulation is not None:
        _check_simulation(sc, sc.simulation)
    if sc.certification is not None:
        _check_certification(sc, sc.certification)
    _check_link_budgets(sc)


def _check_link_budgets(sc: Scene) -> None:
    """Refuse a scene whose buses cannot carry the traffic it asks for: serial lines at baud/10
    bytes/s, CAN at the bit rate with worst-case stuffed frames (formulas and per-driver traffic:
    :mod:`hil.protocols.link_budget`)."""
    from hil.protocols.link_budget import over_budget

    for use in over_budget(sc.devices, sc.rate_hz):
        i = next(k for k, d in enumerate(sc.devices) if d.name == use.devices[0])
        raise FieldError(f"devices[{i}].params", f"link budget exceeded: {use.message()}")


def _check_simulation(sc: Scene, sim: Simulation) -> None:
    bodies: dict[str, int] = {}
    for i, b in enumerate(sim.bodies):
        if b.name in bodies:
            raise FieldError(f"simulation.bodies[{i}].name", f"duplicate body name {b.name!r}")
        s = _shape(b.M)
        if s is not None and s[0] != s[1]:
            raise FieldError(f"simulation.bodies[{i}].M", f"mass matrix must be square, got {s[0]}x{s[1]}")
        for key in ("B", "K"):
            t = _shape(getattr(b, key))
            if t is not None and t != (b.dof, b.dof):
                raise FieldError(f"simulation.bodies[{i}].{key}",
                                 f"expected a {b.dof}x{b.dof} matrix, got {t[0]}x{t[1]}")
        bodies[b.name] = b.dof
    if sim.sdea is not None:
        for nm in (sim.sdea.name, f"{sim.sdea.name}_out"):
            if nm in bodies:
                raise FieldError("simulation.sdea.name", f"body name {nm!r} is already used")
    all_bodies = sim.body_dofs()
    if not all_bodies:
        raise FieldError("simulation", "a simulation needs at least one body (bodies or sdea)")
    known = sorted(all_bodies)

    def body(path: str, name: str, dofs: list[int] | None) -> int:
        if name not in all_bodies:
            raise FieldError(path, f"unknown body {name!r}{_near(name, known)}")
        n = all_bodies[name]
        if dofs is not None:
            bad = [j for j in dofs if j >= n]
            if bad:
                raise FieldError(path, f"body {name!r} has {n} DOF; DOF index {bad[0]} is out of range")
            return len(dofs)
        return n

    def square(path: str, value: Any, n: int) -> None:
        t = _shape(value)
        if t is not None and t != (n, n):
            raise FieldError(path, f"expected a {n}x{n} matrix (the port has {n} DOF), got {t[0]}x{t[1]}")

    for i, sp in enumerate(sim.springs):
        na = body(f"simulation.springs[{i}].a", sp.a, sp.a_dofs)
        if sp.b is not None:
            nb = body(f"simulation.springs[{i}].b", sp.b, sp.b_dofs)
            if nb != na:
                raise FieldError(f"simulation.springs[{i}].b", f"ports have {na} and {nb} DOF")
        square(f"simulation.springs[{i}].stiffness", sp.stiffness, na)
        square(f"simulation.springs[{i}].damping", sp.damping, na)
    for i, term in enumerate(sim.terminations):
        n = body(f"simulation.terminations[{i}].port", term.port, term.dofs)
        if isinstance(term, ImpedanceTermination) and len(term.tf) != n:
            raise FieldError(f"simulation.terminations[{i}].tf", f"expected a {n}x{n} transfer matrix (port DOF), "
                                                             f"got {len(term.tf)}x{len(term.tf)}")
        if isinstance(term, WallTermination):
            square(f"simulation.terminations[{i}].stiffness", term.stiffness, n)
            square(f"simulation.terminations[{i}].damping", term.damping, n)
        if isinstance(term, NamedTermination) and NAMED_TERMINATION_DOF[term.name] != n:
            raise FieldError(f"simulation.terminations[{i}].name",
                             f"{term.name} has {NAMED_TERMINATION_DOF[term.name]} ports, the port has {n} DOF")
    hnames: set[str] = set()
    for i, h in enumerate(sim.humans):
        path = "simulation.human" if isinstance(sim.human, HumanCfg) else f"simulation.human[{i}]"
        n = body(f"{path}.port", h.port, h.dofs)
        for key in ("mass", "damping", "stiffness"):
            square(f"{path}.{key}", getattr(h, key), n)
        nm = h.name or ("human" if len(sim.humans) == 1 else f"human_{h.port}")
        if nm in hnames or nm in all_bodies:
            raise FieldError(f"{path}.name", f"name {nm!r} is already used")
        hnames.add(nm)
    for i, d in enumerate(sc.devices):
        if d.body is None:
            raise FieldError(f"devices[{i}].body", "required when the scene has a simulation (the simulated body "
                                               "the device is attached to)")
        n = body(f"devices[{i}].body", d.body, d.dofs)
        if n != d.dof:
            raise FieldError(f"devices[{i}].dof",
                             f"device has {d.dof} DOF but is attached to {n} DOF of body {d.body!r}")
        sel = d.dofs if d.dofs is not None else list(range(all_bodies[d.body]))
        if d.role == "actuator":
            for j, other in enumerate(sc.devices[:i]):
                if other.role == "actuator" and other.body == d.body:
                    osel = other.dofs if other.dofs is not None else list(range(all_bodies[d.body]))
                    if set(osel) & set(sel):
                        raise FieldError(f"devices[{i}].dofs", f"DOF already driven by actuator {sc.devices[j].name!r}")


def _hint(name: str, known: Sequence[str], limit: int = 16) -> str:
    """`` (did you mean 'x'?)`` or ``; known: a, b, ...`` (at most ``limit`` names)."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.5)
    if close:
        return f" (did you mean {close[0]!r}?)"
    shown = list(known)[:limit]
    more = f", ... ({len(known) - limit} more)" if len(known) > limit else ""
    return f"; known: {', '.join(shown) if shown else '(none)'}{more}"


_MBK_ENTRY = re.compile(r"^([MBK])_(\d)(\d)$")


def _network_parameters(model: str) -> tuple[list[str], Any]:
    """The parameters the network model ``model`` accepts: ``(names for messages, predicate)``.

    Most built-in models take exactly the keys of their defaults. ``mbk_impedance`` takes the
    upper-triangle entries ``M_ij``, ``B_ij``, ``K_ij`` (i <= j) of any size and ``dof``; ``bilateral_2dof``
    takes ``gains`` (a Table II set or a mapping), gains ``k_{p|v}[m|s]{yy|zz|yz|zy}`` and robot
    entries ``{m|b|k}[m|s]_{yy|zz|yz}`` (shared, master or slave)."""
    from hil.models import get_model

    m = get_model(model)
    if model == "mbk_impedance":
        names = sorted(m.defaults)

        def ok(k: str) -> bool:
            if k == "dof":  # the body's size (hil.models.teleop.mbk_impedance): 1-DOF needs it
                return True
            hit = _MBK_ENTRY.match(k)
            return hit is not None and int(hit.group(2)) <= int(hit.group(3))

        return names, ok
    if model == "bilateral_2dof":
        known = {"gains"}
        for side in ("", "m", "s"):
            known |= {f"k_{pv}{side}{ax}" for pv in "pv" for ax in ("yy", "zz", "yz", "zy")}
            known |= {f"{key}{side}_{ax}" for key in "mbk" for ax in ("yy", "zz", "yz")}
        names = sorted(known)
        return names, known.__contains__
    names = sorted(m.defaults)
    return names, set(names).__contains__


def _identification_names(sc: Scene, path: str, spec: IdentifyCfg, exp: Any) -> tuple[str, list[str], list[str]]:
    """``(model, sampled parameter names, every name a map may use)`` of what identifying ``spec``
    from experiment ``exp`` yields; the model is inferred as :func:`hil.identify.records.plan_from_record`
    does (an SDEA variant, else a 1-DOF target with a force sensor, else an m-DOF MBK body)."""
    n = len(exp.dofs) if exp.dofs is not None else sc.device(exp.target).dof
    variant = getattr(exp, "variant", None)
    key = None if spec.model is None else spec.model.lower().replace("-", "_")
    if key == "sdea":
        key = "sdea_locked"
    if key is not None and key not in IDENTIFICATION_MODELS:
        raise FieldError(f"{path}.model", f"unknown identification model {spec.model!r}"
                                      f"{_hint(spec.model or '', IDENTIFICATION_MODELS)}")
    sdea = ["K_f", "B_f", "M", "B"]

    def mbk(k: int) -> tuple[list[str], list[str]]:
        sampled = [f"L{m}_{i}{j}" for m in "MBK" for i in range(k) for j in range(i + 1)]
        derived = [f"{m}_{i}{j}" for m in "MBK" for i in range(k) for j in range(i, k)]
        return sampled, sampled + derived

    if key is None:
        if variant in ("locked", "free"):
            key = f"sdea_{variant}"
        elif n == 1:
            tdev = sc.device(exp.target)
            by_port = any(p.actuator == exp.target and p.force_sensor for p in sc.network.ports)
            same_body = [s for s in sc.force_sensors if s.body is not None and s.body == tdev.body]
            if by_port or len(same_body) == 1:
                key = "sdea_locked"
            elif sc.force_sensors:  # decided from the record's channels: either model
                if spec.friction:
                    fr = _friction_names(spec.friction)
                    return "sdea_locked or mbk", [*sdea, *fr], [*sdea, *fr]  # M, B: in both models
                ms, ma = mbk(1)
                return "sdea_locked or mbk", sdea + ms, sdea + ma
            else:
                key = "mbk"
        else:
            key = "mbk"
    if spec.output is not None and (key != "mbk" or n != 1):
        raise FieldError(f"{path}.output", f"output chooses the measured output of the 1-DOF mbk model; experiment "
                                        f"{spec.experiment!r} gives {key} on {n} DOF")
    fric = _friction_names(spec.friction)
    if fric and key == "mbk":
        # hil.identify's friction models (hil.identify.inverse_models): 1 DOF M, B, F_c, ...; n DOF the
        # entries M_ij, B_ij, K_ij (i <= j) and per joint F_c_i, ...
        if n == 1:
            names = ["M", "B", *fric]
        else:
            names = [f"{m}_{i}{j}" for m in "MBK" for i in range(n) for j in range(i, n)]
            names += [f"{p}_{i}" for i in range(n) for p in fric]
        return key, names, names
    if key.startswith("sdea"):
        if n != 1:
            raise FieldError(f"{path}.model", f"{key} identifies a 1-DOF SDEA; experiment {spec.experiment!r} "
                                          f"excites {n} DOF")
        if key == "sdea_locked" and not sc.force_sensors:
            # the locked-output velocity alone carries B + B_f only: identification would refuse
            # after the runs (hil.identify's identifiability check)
            raise FieldError(f"{path}.model", "sdea_locked needs the spring force: with only the motor velocity, "
                                          "B and B_f are inseparable; add a force sensor on the target's body "
                                          "or network port, or identify sdea_free from a free-output chirp")
        names = sdea + (["m_h"] if key == "sdea_free" else []) + fric  # friction on the motor
        return key, names, names
    sampled, available = mbk(n)
    return key, sampled, available


def _friction_names(terms: Sequence[str]) -> list[str]:
    """The parameters the friction ``terms`` add to one joint, in a fixed order (``[]`` for none)."""
    want = {p for t in terms for p in FRICTION_PARAMETERS[t]}
    return [p for p in ("F_c", "F_s", "v_s", "F_0") if p in want]


def _check_certification(sc: Scene, cert: CertificationCfg) -> None:
    """Every name and range of the ``certification`` section, before anything runs: the network
    model and its parameters, the criterion for that network, the identify entries (experiment,
    identification model, map on both sides), the uncertain parameters, the design range."""
    from hil.models import get_model, model_names

    try:
        get_model(cert.model)
    except KeyError:
        raise FieldError("certification.model", f"unknown model {cert.model!r}{_hint(cert.model, model_names())}"
                         ) from None
    names, accepts = _network_parameters(cert.model)

    def need_param(path: str, k: str) -> None:
        if not accepts(k):
            raise FieldError(path, f"model {cert.model} has no parameter {k!r}{_hint(k, names)}")

    for k, v in cert.parameters.items():
        need_param(f"certification.parameters.{k}", k)
        if cert.model == "bilateral_2dof" and k == "gains":
            from hil.models.teleop import TWO_DOF_TABLE2

            if isinstance(v, str) and v not in TWO_DOF_TABLE2:
                raise FieldError(f"certification.parameters.{k}", f"unknown gain set {v!r}"
                                                              f"{_hint(v, sorted(TWO_DOF_TABLE2))}")
            if isinstance(v, dict):
                for gk, gv in v.items():
                    need_param(f"certification.parameters.gains.{gk}", str(gk))
                    _param_number(f"certification.parameters.gains.{gk}", gv)
            elif not isinstance(v, str):
                raise FieldError(f"certification.parameters.{k}",
                                 f"expected a gain set name ({', '.join(TWO_DOF_TABLE2)}) or a mapping of gains, "
                                 f"got {v!r}")
            continue
        _param_number(f"certification.parameters.{k}", v)
    for k in cert.uncertain:
        need_param(f"certification.uncertain.{k}", k)
    # identify entries
    exps = {c["name"]: (i, sc.experiments[i]) for i, c in enumerate(sc.experiment_configs())}
    identified: dict[str, str] = {}
    for i, spec in enumerate(cert.identify):
        path = f"certification.identify[{i}]"
        if spec.experiment not in exps:
            raise FieldError(f"{path}.experiment", f"no experiment {spec.experiment!r} in the scene"
                                               f"{_hint(spec.experiment, sorted(exps))}")
        j, exp = exps[spec.experiment]
        if exp.type not in ("chirp", "multisine"):
            raise FieldError(f"{path}.experiment",
                             f"experiment {spec.experiment!r} (experiments[{j}]) is a {exp.type}; "
                             "identification needs a chirp or a multisine")
        model, sampled, available = _identification_names(sc, path, spec, exp)
        # dry friction is shown on the certificate, never fed to the network (it is not a damping)
        mapping = spec.map or {n: n for n in sampled if not is_friction_name(n)}
        for src, dst in mapping.items():
            where = f"{path}.map.{src}" if spec.map else f"{path}.map"
            if src not in available:
                raise FieldError(where, f"identification model {model} has no parameter {src!r}{_hint(src, available)}")
            if is_friction_name(src):
                raise FieldError(where, f"{src} is dry friction: it is identified and shown, but the stability "
                                        "conditions count only the viscous B as damping (docs/CERTIFICATION.md, "
                                        "Friction); remove it from the map")
            if not accepts(dst):
                what = (f"maps {src!r} to {dst!r}, which" if spec.map
                        else f"is empty: every identified parameter keeps its name, but {dst!r}")
                raise FieldError(where, f"{what} is not a parameter of model {cert.model}{_hint(dst, names)}")
            if dst in identified:
                raise FieldError(where, f"parameter {dst!r} is already identified by {identified[dst]}")
            if dst in cert.uncertain:
                raise FieldError(where, f"parameter {dst!r} is also in certification.uncertain: identify it or "
                                    "give its uncertainty, not both")
            identified[dst] = path
    # design
    d = cert.design
    if d is not None:
        need_param("certification.design.parameter", d.parameter)
        if cert.model != "sdea" or d.parameter not in ("k22", "b22"):
            raise FieldError("certification.design.parameter", "the design search is implemented for the SDEA "
                                                           "coupler (model sdea, parameter k22 or b22)")
        if d.range[0] < 0:
            raise FieldError("certification.design.range", f"{d.parameter} must be >= 0, got [{d.range[0]:g}, "
                                                       f"{d.range[1]:g}]")
        if d.parameter in identified or d.parameter in cert.uncertain:
            raise FieldError("certification.design.parameter", f"{d.parameter!r} is identified or uncertain; a design "
                                                           "parameter is chosen, not measured")
        if not identified and not cert.uncertain:
            raise FieldError("certification.design", "the design search runs over the posterior: it needs identify "
                                                 "or uncertain entries")
    _check_network_builds(sc, cert)


def _param_number(path: str, v: Any) -> None:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        raise FieldError(path, f"expected a finite number, got {v!r}")


def _check_network_builds(sc: Scene, cert: CertificationCfg) -> None:
    """Build the nominal network once (fixed parameters from the controller and simulation,
    ``parameters``, the uncertain values; identified ones at the model defaults) and check that
    the criterion applies to its shape."""
    from hil.errors import HilError
    from hil.models import build_network, model_params_from_scene

    q = model_params_from_scene(sc)
    q.update({k: u.value for k, u in cert.uncertain.items()})
    try:
        tm = build_network(cert.model, q)
    except (HilError, ValueError, TypeError, KeyError, ArithmeticError) as exc:
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise FieldError("certification", f"the network model {cert.model} cannot be built from this scene: {msg}"
                         ) from None
    if cert.criterion == "llewellyn" and not (tm.n == 2 and tm.n_ports == 2):
        raise FieldError("certification.criterion", f"llewellyn applies to 1-DOF two-ports; model {cert.model} is a "
                                                f"{tm.n_ports}-port with {tm.n} DOF (use absolute_stability or "
                                                "passivity)")


