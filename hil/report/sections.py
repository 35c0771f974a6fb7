"""The report model: what the HTML and the PDF show, as sections of tables, paragraphs and figures.

Both renderers of :mod:`hil.report.render` draw this one model, so a test can walk it: every table
column carries its unit (:class:`Column`; ``"1"`` for a dimensionless number, ``"—"`` for a text
column, ``"per row"`` when a ``unit`` column next to it gives each row's unit), every number in a
key-value table has its unit in that row, and every plot axis label ends with ``[unit]``.

Numbers link to their definitions: :data:`DEFINITIONS` is the ONE mapping from a certificate field
path (``robust.p_stable``) to its anchor in ``docs/CERTIFICATION.md`` (one heading per field); the
renderers turn it into a link (:func:`definition_link`).

Units come from the scene's ``units`` (``cert.scene.units``: linear or rotary, SI) through
:mod:`hil.certify.units`. No heavy imports.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from hil.certify.certificate import Certificate, Series
from hil.certify.numbers import fmt, fmt_p, fmt_range, fmt_signed, fmt_w
from hil.certify.units import parameter_unit, pretty_unit, termination_units

__all__ = [
    "CHARTS",
    "DEFINITIONS",
    "DEFINITIONS_DOC",
    "Block",
    "Column",
    "Estimate",
    "Section",
    "Table",
    "definition_link",
    "failure_estimates",
    "figure_caption",
    "fmt",
    "fmt_p",
    "fmt_range",
    "fmt_w",
    "log10_phi_minus",
    "margin_note",
    "plot_sections",
    "report_sections",
]

#: where the definitions live (relative to the repository root)
DEFINITIONS_DOC = "docs/CERTIFICATION.md"

#: certificate field path -> anchor of its heading in docs/CERTIFICATION.md. The ONE place the
#: report links numbers to definitions: align the anchors here when the document's headings change.
DEFINITIONS: dict[str, str] = {
    "decision": "decision",
    "bench": "bench",
    "policy.required_probability": "policy",
    "policy.confidence": "policy",
    "policy.credible": "policy",
    "measurements": "measurement-outcomes",
    "nominal.network": "nominal-verdict",
    "nominal.criterion": "nominal-verdict",
    "nominal.verdict": "nominal-verdict",
    "nominal.failed_condition": "nominal-verdict",
    "nominal.parameters": "nominal-verdict",
    "nominal.margin": "nominal-margin",
    "nominal.worst_frequency": "nominal-margin",
    "nominal.conditions": "nominal-margin",
    "robust.p_stable": "p-stable",
    "robust.lower": "p-stable",
    "robust.upper": "p-stable",
    "robust.required": "p-stable",
    "robust.p_stable_method": "p-stable-method",
    "robust.n_draws": "independent-draws",
    "robust.sampling": "independent-draws",
    "robust.reliability.beta": "reliability-index-beta",
    "robust.reliability.design_point": "design-point",
    "robust.rare_event": "rare-event-importance-sampling",
    "robust.worst_case_margin": "worst-case-margin",
    "robust.worst_case_parameters": "worst-case-margin",
    "robust.critical_band_rad_s": "critical-band",
    "robust.method": "robust-method",
    "identification.parameters": "identified-parameters",
    "identification.diagnostics": "identified-parameters",
    "design.current": "design-maximum",
    "design.max_value": "design-maximum",
    "design.probability_at_max": "design-maximum",
    "design.nominal_limit": "nominal-headroom",
    "design.nominal_headroom": "nominal-headroom",
    "design.posterior_limit": "posterior-headroom",
    "design.posterior_headroom": "posterior-headroom",
    "witness.terminations": "witness",
    "witness.drive_frequency_rad_s": "witness",
    "witness.band_rad_s": "witness",
    "witness.margin": "witness",
    "witness.closed_loop_poles": "witness",
    "witness.growth_rate_1_s": "witness",
    "witness.time_to_limit_s": "witness",
    "witness.energy_to_limit_J": "witness",
    "energy.min_energy": "energy-evidence",
    "energy.bound": "energy-evidence",
    "energy.first_time": "energy-evidence",
}


def definition_link(path: str | None) -> str | None:
    """``docs/CERTIFICATION.md#<anchor>`` of a field path, or None when it has no entry."""
    if not path or path not in DEFINITIONS:
        return None
    return f"{DEFINITIONS_DOC}#{DEFINITIONS[path]}"


# ---------------------------------------------------------------------------------------------
# model


@dataclass
class Column:
    """A table column: its name, its unit (see the module docstring), a definition link, and
    whether it is numeric (right-aligned) or must never wrap (condition names)."""

    name: str
    unit: str
    field: str | None = None
    num: bool = False
    nowrap: bool = False

    @property
    def header(self) -> str:
        return self.name if self.unit in ("—", "per row") else f"{self.name} [{self.unit}]"

    @property
    def link(self) -> str | None:
        return definition_link(self.field)


@dataclass
class Table:
    columns: list[Column]
    rows: list[list[str]]
    colours: list[list[str | None]] | None = None  # outcome names per cell (None: plain)
    row_fields: list[str | None] | None = None  # definition field per row (key-value tables)
    kv: bool = False
    size: float = 8.0


@dataclass
class Block:
    kind: str  # "para" | "h3" | "table" | "figure" | "gauge" | "chart"
    text: str = ""  # para/h3 text; figure/chart: the caption
    table: Table | None = None
    plot: str = ""  # figure: key into cert.plots; chart: a chart drawn from the record (CHARTS)
    style: str = ""  # para: "muted" | "strong-<OUTCOME>" | ""
    axes: list[str] = field(default_factory=list)  # chart: its axis labels (each ends with [unit])
    field: str | None = None  # figure/chart: the certificate field its caption's definition link names

    @property
    def link(self) -> str | None:
        return definition_link(self.field)


@dataclass
class Section:
    key: str
    title: str
    blocks: list[Block] = field(default_factory=list)


# ---------------------------------------------------------------------------------------------
# formatting (shared with hil.report.render)


def is_number_text(s: str) -> bool:
    """True if a cell's text is (or starts with) a number: then its unit must be stated."""
    return bool(re.match(r"^\s*[\[(]?\s*[−\-+]?(\d|∞|NaN)", s))


def _kv(rows: Sequence[tuple[str, str, str, str | None]]) -> Table:
    """A quantity | value | unit table; rows (label, value, unit, field path)."""
    return Table([Column("quantity", "—"), Column("value", "per row", num=False), Column("unit", "—")],
                 [[a, b, c] for a, b, c, _ in rows], row_fields=[f for *_, f in rows], kv=True, size=9.0)


def _u(unit: str) -> str:
    return unit or "?"


# ---------------------------------------------------------------------------------------------
# plots per section

_PLOT_SECTION = (("frf_", "identification"), ("corner_", "identification"), ("decided", "nominal"),
                 ("bode", "robust"), ("critical_band", "robust"),
                 ("reliability", "robust"), ("headroom", "design"), ("witness", "witness"),
                 ("energy", "energy"))


def plot_sections(cert: Certificate) -> dict[str, list[str]]:
    """Plot keys per section key (a plot whose section is absent goes to ``plots``)."""
    present = {k for k in ("nominal", "robust", "identification", "design", "witness", "energy")
               if getattr(cert, k) is not None}
    out: dict[str, list[str]] = {}
    for key in cert.plots:
        sec = next((s for p, s in _PLOT_SECTION if key.startswith(p)), "plots")
        out.setdefault(sec if sec in present else "plots", []).append(key)
    return out


# ---------------------------------------------------------------------------------------------
# sections


def _status_outcome(status: str) -> str | None:
    s = str(status).strip().lower()
    if s in ("pass", "ok", "holds", "satisfied", "equality", "stable", "true"):
        return "PASS"
    if s in ("fail", "failed", "violated", "potentially_unstable", "unstable", "false"):
        return "FAIL"
    if s in ("marginal", "weak"):
        return "MARGINAL"
    if s in ("error", "not_applicable", "undecided"):
        return "ERROR"
    return None


def robust_status(cert: Certificate) -> tuple[str, str]:
    """(outcome, sentence) of the robust result against the required level."""
    r = cert.robust
    assert r is not None
    if r.lower >= r.required:
        return "PASS", (f"the lower {r.confidence:.0%} bound {fmt_p(r.lower)} clears the required "
                        f"{fmt_p(r.required)}")
    if r.p_stable >= r.required:
        return "MARGINAL", (f"the estimate {fmt_p(r.p_stable)} clears the required {fmt_p(r.required)} "
                            f"but its lower {r.confidence:.0%} bound {fmt_p(r.lower)} does not")
    return "FAIL", f"P(stable) = {fmt_p(r.p_stable)} is below the required {fmt_p(r.required)}"


def margin_note(cert: Certificate) -> str:
    """Page 1's sentence on the margins: the decision uses their sign, never their size (docs/
    CERTIFICATION.md#decision), what "nominal" is, and what a coefficient tolerance asks instead."""
    n, r = cert.nominal, cert.robust
    if n is None or n.margin is None:
        return ""
    parts = [f"nominal {fmt(n.margin)}"]
    wc = None if r is None else r.worst_case_margin
    if wc is not None and r is not None:
        parts.append(f"worst case over the {r.credible:.0%} credible region {fmt(wc)}")
    text = (f"Margins ({', '.join(parts)}): the decision uses only their sign, which is the exact verdict, never "
            "their size.")
    if n.margin >= 0:
        text += (" A small positive margin is still an exact 'stable'; how far the device is from instability is "
                 "what P(stable) and β measure.")
    if wc is not None and wc == n.margin:
        text += " The worst case over the credible region is the nominal point itself."
    return text + (" Nominal: each parameter at its median (the posterior median of an identified parameter, the "
                   "stated value of an uncertain one). A tolerance on the network's coefficients (hil stability "
                   "--rtol R) asks another question: whether the verdict flips under a relative change R.")


def headroom(d: Any) -> str:
    if d.current is None or d.max_value is None or not math.isfinite(d.max_value) or d.max_value == 0:
        return ""
    ratio = d.current / d.max_value
    return f"current is {ratio:.0%} of the largest value" + (" (EXCEEDS it)" if ratio > 1 else "")


def policy_label(key: str) -> str:
    return {"required_probability": "required P(stable)", "confidence": "confidence of the P(stable) interval",
            "credible": "credible region (worst case)"}.get(key, key.replace("_", " "))


def limits_text(lower: float | None, upper: float | None) -> str:
    if lower is not None and upper is not None:
        return f"{fmt(lower)} … {fmt(upper)}"
    if lower is not None:
        return f"≥ {fmt(lower)}"
    if upper is not None:
        return f"≤ {fmt(upper)}"
    return "—"


def measurement_unit(m: Any) -> str:
    """The unit of a measurement value: its own, '1' for a dimensionless number, '—' for text."""
    if m.unit:
        return m.unit
    if isinstance(m.value, bool | str) or m.value is None:
        return "—"
    return "1"


def measurements_table(cert: Certificate) -> Table:
    rows: list[list[str]] = []
    colours: list[list[str | None]] = []
    for m in cert.measurements:
        rows.append([m.name, fmt(m.value), limits_text(m.lower, m.upper), measurement_unit(m), m.outcome,
                     m.description])
        colours.append([None, None, None, None, m.outcome, None])
    return Table([Column("measurement", "—", "measurements"), Column("value", "per row", num=True),
                  Column("limits", "per row", num=True), Column("unit", "—"), Column("outcome", "—"),
                  Column("description", "—")], rows, colours)


def _units(cert: Certificate) -> str | None:
    return cert.scene.units


def _param_rows(params: dict[str, float], cert: Certificate, model: str, field: str
                ) -> list[tuple[str, str, str, str | None]]:
    u = _units(cert)
    return [(k, fmt(v), _u(parameter_unit(k, u, model)), field) for k, v in params.items()]


def report_sections(cert: Certificate) -> list[Section]:
    """The evidence sections present in the record, in reading order (the summary, policy and
    measurements, and the signature are laid out by the renderers themselves)."""
    out: list[Section] = []
    figs = plot_sections(cert)
    u = _units(cert)

    def figures(sec: Section) -> None:
        for k in figs.get(sec.key, []):
            text, fld = figure_caption(cert, k)
            sec.blocks.append(Block("figure", plot=k, text=text, field=fld))

    if cert.nominal is not None:
        n = cert.nominal
        s = Section("nominal", "Nominal verdict")
        weak = " (weak: a condition holds only with equality)" if n.weak else ""
        s.blocks.append(Block("para", "The criterion on the nominal network (each parameter at its median: the "
                                      "posterior median of an identified parameter, the stated value of an uncertain "
                                      f"one; and the scene's gains): {n.verdict}{weak}."))
        s.blocks.append(Block("table", table=_kv([
            ("network", n.network, "—", "nominal.network"), ("criterion", n.criterion, "—", "nominal.criterion"),
            ("verdict", n.verdict + (" (weak)" if n.weak else ""), "—", "nominal.verdict"),
            ("margin (normalized)", fmt(n.margin), "1", "nominal.margin"),
            ("worst frequency", fmt_w(n.worst_frequency), "rad/s", "nominal.worst_frequency"),
            ("failed condition", fmt(n.failed_condition), "—", "nominal.failed_condition")])))
        if n.parameters:
            s.blocks.append(Block("h3", "Nominal parameters"))
            s.blocks.append(Block("table", table=_kv(_param_rows(n.parameters, cert, n.network,
                                                                 "nominal.parameters"))))
        if n.conditions:
            s.blocks.append(Block("h3", "Conditions"))
            s.blocks.append(Block("table", table=Table(
                [Column("condition", "—", "nominal.conditions", nowrap=True), Column("label", "—"),
                 Column("status", "—"), Column("margin", "1", "nominal.margin", num=True),
                 Column("worst frequency", "rad/s", "nominal.worst_frequency", num=True), Column("detail", "—")],
                [[c.name, c.label, c.status, fmt(c.margin), fmt_w(c.worst_frequency), c.detail]
                 for c in n.conditions],
                [[None, None, _status_outcome(c.status), None, None, None] for c in n.conditions])))
        figures(s)
        out.append(s)
    if cert.robust is not None:
        r = cert.robust
        status, sentence = robust_status(cert)
        s = Section("robust", "Robust certification")
        s.blocks.append(Block("para", f"{status}: {sentence}.", style=f"strong-{status}"))
        s.blocks.append(Block("gauge"))
        band = r.critical_band_rad_s
        s.blocks.append(Block("table", table=_kv([
            ("P(stable)", fmt_p(r.p_stable), "1", "robust.p_stable"),
            (f"{r.confidence:.0%} confidence interval (Clopper-Pearson)", f"[{fmt_p(r.lower)}, {fmt_p(r.upper)}]",
             "1", "robust.lower"),
            ("required (the lower bound must clear it)", fmt_p(r.required), "1", "robust.required"),
            ("posterior draws", str(r.n_draws), "1", "robust.n_draws"),
            ("sampling (independent draws)", r.sampling or "—", "—", "robust.sampling"),
            (f"worst-case margin over the {r.credible:.0%} credible region", fmt(r.worst_case_margin), "1",
             "robust.worst_case_margin"),
            ("critical band", "—" if band is None else fmt_range(*band), "rad/s", "robust.critical_band_rad_s"),
            ("method", r.method or "—", "—", "robust.method")])))
        s.blocks.extend(_reliability_blocks(cert))
        if r.worst_case_parameters:
            s.blocks.append(Block("h3", "Worst-case parameters"))
            model = cert.nominal.network if cert.nominal is not None else ""
            s.blocks.append(Block("table", table=_kv(_param_rows(r.worst_case_parameters, cert, model,
                                                                 "robust.worst_case_parameters"))))
        figures(s)
        out.append(s)
    if cert.identification is not None:
        s = Section("identification", "Identification")
        show_truth = any(p.truth is not None for i in cert.identification for p in i.parameters)
        for ident in cert.identification:
            s.blocks.append(Block("h3", f"{ident.model} — " + ("converged" if ident.converged else "NOT converged")))
            s.blocks.append(Block("para", f"record {ident.record}" + (f" · {ident.reason}" if ident.reason else ""),
                                  style="muted"))
            cols = [Column("parameter", "—", "identification.parameters", nowrap=True), Column("unit", "—")]
            cols += [Column(h, "per row", "identification.parameters", num=True)
                     for h in ("mean", "median", "q05", "q95", "std", "LS std", "CRB std")]
            if show_truth:
                cols.append(Column("truth", "per row", num=True))
            rows = []
            for p in ident.parameters:
                pu = _u(pretty_unit(p.unit or parameter_unit(p.name, u)))
                row = [p.name, pu, fmt(p.mean), fmt(p.median), fmt(p.q05), fmt(p.q95), fmt(p.std), fmt(p.ls_std),
                       fmt(p.crb_std)]
                if show_truth:
                    row.append(fmt(p.truth))
                rows.append(row)
            s.blocks.append(Block("table", table=Table(cols, rows)))
            if ident.diagnostics:
                s.blocks.append(Block("h3", "Diagnostics"))
                s.blocks.append(Block("table", table=_kv([(k, fmt(v), _diag_unit(k, v), "identification.diagnostics")
                                                          for k, v in ident.diagnostics.items()])))
        figures(s)
        out.append(s)
    if cert.design is not None:
        d = cert.design
        s = Section("design", "Design guidance")
        du = _u(d.unit or parameter_unit(d.parameter, u))
        drows: list[tuple[str, str, str, str | None]] = [("free parameter", d.parameter, "—", None),
                ("current value", fmt(d.current), du, "design.current"),
                ("largest value meeting the requirement", fmt(d.max_value), du, "design.max_value"),
                ("P(stable) at that value", fmt_p(d.probability_at_max), "1", "design.probability_at_max"),
                ("required", fmt_p(d.required), "1", "robust.required")]
        if headroom(d):
            drows.append(("headroom", headroom(d), "—", "design.max_value"))
        if d.nominal_limit is not None:
            drows.append((f"nominal limit ({d.parameter}_max at the nominal plant)", fmt(d.nominal_limit), du,
                          "design.nominal_limit"))
            drows.append(("nominal headroom (nominal limit / current − 1)", fmt_signed(d.nominal_headroom), "1",
                          "design.nominal_headroom"))
        if d.posterior_limit is not None:
            kind = {"at_least": "≥ ", "at_most": "≤ "}.get(str(d.posterior_limit_kind), "")
            drows.append(("posterior limit (the lower bound crosses the requirement)",
                          kind + fmt(d.posterior_limit), du, "design.posterior_limit"))
            drows.append(("posterior headroom (posterior limit / current − 1)", fmt_signed(d.posterior_headroom),
                          "1", "design.posterior_headroom"))
        s.blocks.append(Block("table", table=_kv(drows)))
        if d.note:
            s.blocks.append(Block("para", d.note))
        figures(s)
        out.append(s)
    if cert.witness is not None:
        out.append(_witness_section(cert, figs))
    if cert.energy is not None:
        s = Section("energy", "Energy evidence")
        s.blocks.append(Block("para", "Port energy E_s(t) = ∫ F·V dt of the energy-injection experiments; negative "
                                      "beyond the noise bound means the network delivered energy."))
        s.blocks.append(Block("table", table=Table(
            [Column("experiment", "—"), Column("port", "—"), Column("record", "—"), Column("E_s < 0", "—"),
             Column("min E_s", "J", "energy.min_energy", num=True),
             Column("noise bound", "J", "energy.bound", num=True),
             Column("first time", "s", "energy.first_time", num=True)],
            [[e.experiment, e.port, e.record, "YES" if e.went_negative else "no", fmt(e.min_energy), fmt(e.bound),
              fmt(e.first_time)] for e in cert.energy],
            [[None, None, None, "FAIL" if e.went_negative else "PASS", None, None, None] for e in cert.energy])))
        figures(s)
        out.append(s)
    if cert.multiport is not None:
        mp = cert.multiport
        s = Section("multiport", "Multi-port network")
        s.blocks.append(Block("table", table=_kv([
            ("ports", str(len(mp.ports)), "1", None), ("DOFs per port", ", ".join(str(p) for p in mp.ports) or "—",
                                                       "1", None),
            ("total DOFs", str(mp.dof_total), "1", None), ("symmetrization", mp.symmetrization or "—", "—", None)])))
        out.append(s)
    if figs.get("plots"):
        s = Section("plots", "Plots")
        figures(s)
        out.append(s)
    if cert.decision == "ERROR":  # evidence missing or broken: the report is short, tables and errors only
        for sec in out:
            sec.blocks = [b for b in sec.blocks if b.kind not in ("figure", "chart", "gauge")]
        out = [sec for sec in out if sec.key != "plots"]
    return out


def _diag_unit(key: str, v: Any) -> str:
    if key.endswith("_s"):
        return "s"
    if isinstance(v, bool | str) or (isinstance(v, list) and v and isinstance(v[0], str)):
        return "—"
    if isinstance(v, int | float | list):
        return "1"  # counts, fractions, τ in steps, R̂
    return "—"


def _witness_section(cert: Certificate, figs: dict[str, list[str]]) -> Section:
    w = cert.witness
    assert w is not None
    u = w.units or cert.scene.units
    s = Section("witness", "Instability witness")
    s.blocks.append(Block("para", "A passive termination under which the network delivers energy at the operator "
                                  "port, what it does to the closed loop, and how soon the bench would reach its "
                                  "safety limits."))
    trows = []
    for port, t in w.terminations.items():
        if isinstance(t, dict) and "params" in t:
            tu = termination_units(t.get("params", {}), u)
            for k, v in t.get("params", {}).items():
                trows.append([f"port {int(port) + 1 if str(port).isdigit() else port}", str(t.get("kind", "—")), k,
                              fmt(v), _u(tu.get(k, ""))])
            if t.get("coupling"):
                trows.append([f"port {port}", str(t.get("kind", "—")), "coupling", fmt(t["coupling"]), "1"])
        else:
            trows.append([str(port), "—", "—", fmt(t), "—"])
    s.blocks.append(Block("h3", "Destabilizing termination"))
    s.blocks.append(Block("table", table=Table([Column("terminated port", "—", "witness.terminations"),
                                                Column("kind", "—"), Column("parameter", "—"),
                                                Column("value", "per row", num=True), Column("unit", "—")], trows)))
    poles = w.closed_loop_poles
    rhp = [p for p in poles if p[0] > 0]
    rows: list[tuple[str, str, str, str | None]] = [
            ("drive frequency (most negative Re Z_in)", fmt_w(w.drive_frequency_rad_s), "rad/s",
             "witness.drive_frequency_rad_s"),
            ("band where Re Z_in < 0", "—" if w.band_rad_s is None else fmt_range(*w.band_rad_s), "rad/s",
             "witness.band_rad_s"),
            ("positive-realness margin of Z_in", fmt(w.margin), "1", "witness.margin")]
    if w.growth_rate_1_s is not None:
        rows.append(("growth rate σ = max Re(pole)", fmt(w.growth_rate_1_s), "1/s", "witness.growth_rate_1_s"))
        if w.growth_rate_1_s > 0:
            rows.append(("e-folding time 1/σ", fmt(1.0 / w.growth_rate_1_s), "s", "witness.growth_rate_1_s"))
        rows.append(("right-half-plane closed-loop poles", ", ".join(_pole(p) for p in rhp) or "none", "1/s",
                     "witness.closed_loop_poles"))
    if w.drive_amplitude is not None:
        rows.append(("simulated drive amplitude", fmt(w.drive_amplitude), "N.m" if u == "rotary" else "N", None))
    for k, v in w.limits.items():
        unit = {"max_velocity": "rad/s" if u == "rotary" else "m/s", "max_position": "rad" if u == "rotary" else "m",
                "max_energy": "J"}.get(k, "—")
        rows.append((f"bench limit {k.replace('_', ' ')}", fmt(v), unit, None))
    if w.limit_exceeded is not None:
        rows.append(("first limit exceeded", w.limit_exceeded.replace("_", " "), "—", "witness.time_to_limit_s"))
        rows.append(("time to exceed it", fmt(w.time_to_limit_s), "s", "witness.time_to_limit_s"))
        rows.append(("port energy E_s at that time", fmt(w.energy_to_limit_J), "J", "witness.energy_to_limit_J"))
    elif w.simulation.get("simulated") and w.limits:
        rows.append(("limits exceeded in the simulated time", f"none in {fmt(w.simulation.get('duration_s'))}", "s",
                     "witness.time_to_limit_s"))
    elif w.simulation and not w.simulation.get("simulated", True):
        rows.append(("simulation", str(w.simulation.get("reason", "not simulated")), "—", None))
    s.blocks.append(Block("h3", "What it does"))
    s.blocks.append(Block("table", table=_kv(rows)))
    if len(poles) > len(rhp):
        s.blocks.append(Block("para", "All closed-loop poles [1/s] (right-half plane first): "
                              + ", ".join(_pole(p) for p in poles), style="muted"))
    for k in figs.get("witness", []):
        text, fld = figure_caption(cert, k)
        s.blocks.append(Block("figure", plot=k, text=text, field=fld))
    return s


# ---------------------------------------------------------------------------------------------
# reliability: P(not stable) by every method, β, the design point


#: charts drawn by the renderers from the record itself (not stored as plots): key -> axis labels
CHARTS: dict[str, list[str]] = {
    "p_failure": ["P(not stable) = 1 − P(stable) [1]", "reliability index β [1]"],
}


@dataclass
class Estimate:
    """One estimate of P(not stable) = 1 − P(stable) for the chart: its value and interval
    (None: not available), the log10 of the value when it underflows double precision, and
    whether the decision used it."""

    label: str
    value: float | None
    lower: float | None = None
    upper: float | None = None
    log10_value: float | None = None
    decides: bool = False
    note: str = ""


def log10_phi_minus(beta: float) -> float:
    """log10 Φ(−β), also where Φ(−β) underflows (β > 37: the asymptotic series of the normal
    tail, log Φ(−β) = −β²/2 − log(β√(2π)) + log(1 − 1/β² + 3/β⁴), relative error < 15/β⁶)."""
    p = 0.5 * math.erfc(beta / math.sqrt(2.0))
    if p > 1e-300:
        return math.log10(p)
    ln = -0.5 * beta * beta - math.log(beta * math.sqrt(2.0 * math.pi)) + math.log1p(-1 / beta ** 2 + 3 / beta ** 4)
    return ln / math.log(10.0)


def failure_estimates(cert: Certificate) -> list[Estimate]:
    """P(not stable) by each method the record holds: sampled (Clopper-Pearson interval on the
    independent draws), FORM Φ(−β), importance sampling (its interval); the one the decision used
    (``robust.p_stable_method``) flagged."""
    r = cert.robust
    if r is None:
        return []
    is_used = r.p_stable_method == "importance_sampling"
    out = [Estimate(f"sampled: {r.n_draws} independent draws, {r.confidence:.0%} Clopper-Pearson",
                    1.0 - r.p_stable, 1.0 - r.upper, 1.0 - r.lower, decides=not is_used)]
    rel = r.reliability
    if rel is not None:
        b = float(rel.beta)
        lg = log10_phi_minus(b) if b > 0 else None
        v = 0.5 * math.erfc(b / math.sqrt(2.0))
        out.append(Estimate(f"FORM: Φ(−β), β = {'≥ ' if rel.censored else ''}{fmt(b)}", v, log10_value=lg,
                            note="first-order approximation (no interval)"))
    ev = r.rare_event
    if ev is not None:
        out.append(Estimate(f"importance sampling: {ev.n} samples, {ev.n_fail} failing, {ev.confidence:.0%} "
                            "normal interval", ev.p_failure, 1.0 - ev.upper, 1.0 - ev.lower, decides=is_used,
                            note="" if ev.reliable else "not reliable (too few failing samples): nothing certified"))
    return out


def _reliability_blocks(cert: Certificate) -> list[Block]:
    """The P(not stable) chart and the design point table of the robust section."""
    r = cert.robust
    assert r is not None
    allow = 1.0 - r.required
    est = failure_estimates(cert)
    used = next((e for e in est if e.decides), est[0])
    text = (f"Every estimate of P(not stable) = 1 − P(stable) on one logarithmic axis against the allowance "
            f"1 − required = {fmt(allow)}: a bar is an interval, a dot an estimate; a value below the axis is drawn "
            f"at its left end with its value printed. The decision uses the upper end of the "
            f"{'importance-sampling' if used is not est[0] else 'sampled'} interval "
            f"(robust.p_stable_method = {r.p_stable_method}).")
    blocks = [Block("chart", plot="p_failure", text=text, field="robust.p_stable_method",
                    axes=list(CHARTS["p_failure"] if r.reliability is not None else CHARTS["p_failure"][:1]))]
    rel = r.reliability
    if rel is None:
        return blocks
    blocks.append(Block("h3", "Design point (FORM)"))
    checked = "" if rel.verified is None else (" Checked by the exact criterion at 0.95·u* and 1.05·u*: "
                                               + ("confirmed." if rel.verified else "NOT confirmed."))
    blocks.append(Block("para", "θ* = μ + L u*: the nearest parameter set where the verdict changes, in posterior-"
                                "standardized coordinates u* and in the parameters' units; α = u*/β are the FORM "
                                "importance factors (Σα² = 1)." + checked))
    model = cert.nominal.network if cert.nominal is not None else ""
    mu = cert.nominal.parameters if cert.nominal is not None else {}
    beta = float(rel.beta) or 1.0
    rows: list[list[str]] = []
    colours: list[list[str | None]] = []
    u = _units(cert)
    for k, (name, th) in enumerate(rel.design_point.items()):
        uk = rel.design_point_u[k] if k < len(rel.design_point_u) else float("nan")
        rows.append([name, _u(parameter_unit(name, u, model)), fmt(mu.get(name)), fmt(th), fmt(uk), fmt(uk / beta)])
        colours.append([None] * 6)
    blocks.append(Block("table", table=Table(
        [Column("parameter", "—", "robust.reliability.design_point", nowrap=True), Column("unit", "—"),
         Column("posterior centre μ", "per row", "robust.reliability.design_point", num=True),
         Column("design point θ*", "per row", "robust.reliability.design_point", num=True),
         Column("u*", "1", "robust.reliability.design_point", num=True),
         Column("importance α = u*/β", "1", "robust.reliability.beta", num=True)], rows, colours)))
    return blocks


#: plot key prefix -> (caption, certificate field whose definition it links)
_CAPTIONS: tuple[tuple[str, str, str], ...] = (
    ("frf_", "Measured H1 with its ≈95 % band from the coherence, the posterior median fit with its 90 % band, phase, "
             "coherence and the normalized residual (fit − H1)/σ (within ±2 for a consistent fit).",
     "identification.parameters"),
    ("corner_", "Posterior draws of the identified parameters: pair densities (contours) and marginals with the 5 %, "
                "50 % and 95 % quantiles (dashed); a parameter whose spread is tiny against its size is drawn as the "
                "offset from the value in its label.", "identification.parameters"),
    ("decided", "The decisive condition of the nominal verdict (the violated one with the most negative margin for a "
                "NO-GO, the one with the smallest margin otherwise): its normalized margin over ω, negative "
                "(violated) region shaded, worst frequency marked; imaginary-axis and infinity conditions as bars of "
                "their residue margins.", "nominal.margin"),
    ("bode", "The immittance entry (1,1) over the posterior draws: median and 90 % band.", "robust.method"),
    ("critical_band", "The coupler condition per draw around its minimum and the critical band, where it is within "
                      "10 % of its minimum.", "robust.critical_band_rad_s"),
    ("reliability", "The design point u* of the reliability index β in a slice of posterior-standardized space "
                    "through u* along its two most important coordinates: the limit state g = 0 (where the verdict "
                    "changes), the sphere ‖u‖ = β touching it at u*, the sphere of the required β (a GO needs it "
                    "inside the stable side) and 99 % of the posterior's 2-D marginal.", "robust.reliability.beta"),
    ("headroom", "P(stable) and its lower confidence bound against the design parameter; the requirement crossing "
                 "(the posterior limit) and the nominal limit are marked, the headroom is limit / current − 1.",
     "design.posterior_headroom"),
    ("witness", "The response of the terminated network to a unit drive at the drive frequency: |V| until it "
                "crosses the bench's first safety limit, and the port energy E_s over that time.",
     "witness.time_to_limit_s"),
    ("energy", "Port energy E_s(t) = ∫ F·V dt of the energy-injection experiment against its noise bound.",
     "energy.min_energy"),
)


def figure_caption(cert: Certificate, key: str) -> tuple[str, str | None]:
    """(caption, field path of its definition) of a stored plot; the plot's title when unknown."""
    for prefix, text, fld in _CAPTIONS:
        if key.startswith(prefix):
            return text, fld
    s = cert.plots.get(key)
    return (s.title if s is not None else key), None


def _pole(p: tuple[float, float]) -> str:
    re_, im = p
    if abs(im) < 1e-12 * max(1.0, abs(re_)):
        return fmt(re_)
    return f"{fmt(re_)} {'+' if im >= 0 else '−'} {fmt(abs(im))}j"


# ---------------------------------------------------------------------------------------------
# units check (used by the tests; also handy for a new section)


def _axis_ok(label: str) -> bool:
    return bool(re.search(r"\[[^\[\]]+\]\s*$", label))


def missing_units(cert: Certificate, sections: list[Section] | None = None) -> list[str]:
    """Every column, key-value number and plot axis without a unit (empty when all have one)."""
    bad: list[str] = []
    for sec in sections if sections is not None else report_sections(cert):
        for b in sec.blocks:
            if b.table is None:
                continue
            t = b.table
            for c in t.columns:
                if not c.unit or c.unit == "?":
                    bad.append(f"{sec.key}: column {c.name!r} has no unit")
            for j, c in enumerate(t.columns):
                if c.unit != "per row":
                    continue
                ucol = next((k for k, cc in enumerate(t.columns) if cc.name == "unit"), None)
                for row in t.rows:
                    if is_number_text(row[j]) and (ucol is None or row[ucol] in ("", "?")):
                        bad.append(f"{sec.key}: {row[0]!r} = {row[j]} has no unit")
    for t in [measurements_table(cert)]:
        for row in t.rows:
            if is_number_text(row[1]) and row[3] in ("", "?", "—"):
                bad.append(f"measurements: {row[0]!r} = {row[1]} has no unit")

    for sec in sections if sections is not None else report_sections(cert):
        for b in sec.blocks:
            if b.kind == "chart":
                for label in b.axes or ["(none)"]:
                    if not _axis_ok(label):
                        bad.append(f"{sec.key}: chart {b.plot} axis {label!r} has no unit")

    def walk(name: str, s: Series) -> None:
        if s.kind == "corner":
            for ln in s.lines:
                if not _axis_ok(ln):
                    bad.append(f"plot {name}: corner axis {ln!r} has no unit")
            return
        for what, label in (("x", s.x_label), ("y", s.y_label)):
            if not _axis_ok(label):
                bad.append(f"plot {name}: {what} axis {label!r} has no unit")
        for i, p in enumerate(s.panels):
            walk(f"{name}/panel {i + 1}", p)

    for name, s in cert.plots.items():
        walk(name, s)
    return bad
