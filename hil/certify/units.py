"""SI units of the quantities a certificate reports, from the scene's ``units`` (linear or rotary).

A scene is either linear (forces in N, positions in m, velocities in m/s) or rotary (torques in
N.m, angles in rad, angular velocities in rad/s); see :class:`hil.scene.spec.Scene`. Every number in a
report table and every plot axis carries its unit; a dimensionless quantity says ``1``
explicitly. This module is the one place that names them:

* :func:`quantity_unit` -- effort, velocity, position, stiffness, damping, mass, ... per domain;
* :func:`parameter_unit` -- a network-model parameter by its name (SDEA Table I, the teleoperator
  gains ``k_p…``/``k_v…`` and robot entries ``m…``/``b…``/``k…``);
* :func:`frf_unit` -- the unit of an FRF ``output/input`` (``(rad/s)/(N.m)``), the reference of
  its dB scale;
* :func:`termination_units` -- the parameters of a witness termination (``k`` [N/m] ...).

Unknown names return ``""`` (the report tests fail on them: a new parameter must be named here).
No heavy imports: :mod:`hil.report.render` uses it on every render.
"""

from __future__ import annotations

import re

__all__ = ["frf_unit", "parameter_unit", "pretty_unit", "quantity_unit", "termination_units", "unit_label"]

_Q: dict[str, dict[str, str]] = {
    "linear": {"effort": "N", "velocity": "m/s", "position": "m", "stiffness": "N/m", "damping": "N.s/m",
               "mass": "kg", "admittance": "m/(N.s)", "impedance": "N.s/m", "hybrid": "1"},
    "rotary": {"effort": "N.m", "velocity": "rad/s", "position": "rad", "stiffness": "N.m/rad",
               "damping": "N.m.s/rad", "mass": "kg.m²", "admittance": "rad/(N.m.s)", "impedance": "N.m.s/rad",
               "hybrid": "1"},
}

#: SDEA under VSIC, paper 002 Table I (rotary; hil.models.sdea)
_SDEA: dict[str, str] = {"M": "kg.m²", "B": "N.m.s/rad", "B_f": "N.m.s/rad", "P_m": "N.m.s/rad",
                         "b22": "N.m.s/rad", "K_f": "N.m/rad", "I_m": "N.m/rad", "k22": "N.m/rad",
                         "P_f": "rad/(N.m.s)", "I_f": "rad/(N.m.s²)", "alpha": "1"}


def quantity_unit(quantity: str, units: str | None) -> str:
    """The SI unit of a physical quantity (effort, velocity, position, stiffness, damping, mass,
    admittance, impedance) in the scene's domain (``linear`` when not recorded)."""
    return _Q["rotary" if units == "rotary" else "linear"].get(quantity, "")


def parameter_unit(name: str, units: str | None, model: str = "") -> str:
    """The unit of a network-model parameter by its name ('' if unknown)."""
    if name in _SDEA and (model.startswith("sdea") or units == "rotary" or name in ("P_f", "I_f", "k22", "b22")):
        return _SDEA[name]
    if name in ("alpha", "dof"):  # a ratio; mbk_impedance's number of DOF (a count)
        return "1"
    m = re.fullmatch(r"([MBK])_\d+", name)  # entries of an identified M, B, K matrix (mbk models)
    if m:
        return quantity_unit({"M": "mass", "B": "damping", "K": "stiffness"}[m.group(1)], units)
    if re.fullmatch(r"k_p.*", name):  # PD position gains: a stiffness
        return quantity_unit("stiffness", units)
    if re.fullmatch(r"k_v.*", name):  # PD velocity gains: a damping
        return quantity_unit("damping", units)
    if re.fullmatch(r"m[a-z0-9]*_[a-z0-9]+|m|m_[a-z0-9]+", name):  # robot masses mm_yy, m_m1, m_s
        return quantity_unit("mass", units)
    if re.fullmatch(r"b[a-z0-9]*_[a-z0-9]+|b", name):
        return quantity_unit("damping", units)
    if re.fullmatch(r"k[a-z0-9]*_[a-z0-9]+|k", name):
        return quantity_unit("stiffness", units)
    if name in _SDEA:
        return _SDEA[name]
    return ""


_SIGNAL = {"torque": "effort", "force": "effort", "effort": "effort", "current": "", "velocity": "velocity",
           "speed": "velocity", "position": "position", "angle": "position"}


def _signal_unit(name: str, units: str | None) -> str:
    base = re.split(r"[._\s]", name.strip().lower())[-1] if name else ""
    for key, q in _SIGNAL.items():
        if key in name.lower() or key == base:
            if key == "current":
                return "A"
            return quantity_unit(q, units)
    return ""


def frf_unit(output: str, input: str, units: str | None) -> str:
    """Unit of the FRF output/input, e.g. ``(rad/s)/(N.m)`` (the dB reference: 0 dB = 1 of it);
    ``1`` when both have the same unit; '' when a signal is not recognized."""
    uo, ui = _signal_unit(output, units), _signal_unit(input, units)
    if not uo or not ui:
        return ""
    if uo == ui:
        return "1"
    wrap = lambda u: f"({u})" if "/" in u or "." in u else u  # noqa: E731
    return f"{wrap(uo)}/{wrap(ui)}"


#: witness termination parameters (hil.stability.witness.Termination): z(s) = k/s, b, m s, (b s + k)/s, g/(s + a)
_TERM = {"k": "stiffness", "b": "damping", "m": "mass", "g": "stiffness"}


def termination_units(params: dict[str, float], units: str | None) -> dict[str, str]:
    """Units of a termination's parameters: k [N/m], b [N.s/m], m [kg], lag gain g [N/m] and
    corner a [rad/s]; a coupling fraction is dimensionless."""
    out = {}
    for k in params:
        out[k] = "rad/s" if k == "a" else ("1" if k == "coupling" else quantity_unit(_TERM.get(k, ""), units))
    return out


def unit_label(name: str, unit: str) -> str:
    """``name [unit]`` (``[1]`` for a dimensionless quantity)."""
    return f"{name} [{unit or '?'}]"


def pretty_unit(unit: str) -> str:
    """A unit as the report prints it: powers as superscripts (``kg.m^2`` -> ``kg.m²``), so a
    model's own spelling and this module's agree."""
    for a, b in (("^-1", "⁻¹"), ("^-2", "⁻²"), ("^2", "²"), ("^3", "³")):
        unit = unit.replace(a, b)
    return unit
