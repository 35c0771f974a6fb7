"""Evidence in the reports (issue 18): units on every table column and plot axis, the plotted
stability condition is the decisive one, the witness reports closed-loop poles and the time to
the bench's limits (checked against an independent derivation), labels (Table II gain set, bands
whose ends differ, condition names that do not wrap), and links of numbers to their definitions."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from hil.certify import pipeline as pl
from hil.certify.certificate import Certificate, Series
from hil.certify.figures import decisive_condition, witness_response
from hil.certify.units import parameter_unit, termination_units
from hil.report.sections import DEFINITIONS, fmt, fmt_range, missing_units, report_sections
from hil.scene.spec import builtin_scenes, load_scene
from hil.stability.witness import find_witness, termination_family


def _nominal(name: str):
    sc = load_scene(name)
    cert = sc.certification
    tm = pl.build_network(cert.model, pl.model_params_from_scene(sc))
    return sc, tm, pl._check(tm, pl._criterion(cert.model, cert.criterion))


@pytest.fixture(scope="module")
def bilateral_b():
    return _nominal("bilateral_2dof_B")


# ---------------------------------------------------------------------------------------------
# units


@pytest.mark.parametrize("name", [n for n, _ in builtin_scenes()])
def test_every_model_parameter_of_every_builtin_scene_has_a_unit(name):
    sc = load_scene(name)
    if sc.certification is None:
        pytest.skip("no certification section")
    params = pl.model_params_from_scene(sc)
    flat = {k: v for k, v in params.items() if isinstance(v, int | float)}
    flat.update(params.get("gains", {}))
    flat.update({k: u.value for k, u in sc.certification.uncertain.items()})
    missing = [k for k in flat if not parameter_unit(k, sc.units, sc.certification.model)]
    assert not missing, missing


def test_units_follow_the_scene_domain():
    assert parameter_unit("k_pmyy", "linear") == "N/m" and parameter_unit("k_vmyy", "linear") == "N.s/m"
    assert parameter_unit("k_pm", "rotary") == "N.m/rad" and parameter_unit("mm_yy", "linear") == "kg"
    assert parameter_unit("K_f", "rotary", "sdea") == "N.m/rad" and parameter_unit("M", "rotary", "sdea") == "kg.m²"
    assert termination_units({"k": 1.0, "b": 2.0, "a": 1.0}, "linear") == {"k": "N/m", "b": "N.s/m", "a": "rad/s"}
    assert termination_units({"k": 1.0}, "rotary") == {"k": "N.m/rad"}
    assert parameter_unit("mystery", "linear") == ""  # unknown names are not guessed


def test_unit_walk_finds_a_missing_unit():
    """The walk is not vacuous: an axis without [unit] and a number in a table without a unit are found."""
    from test_report import sdea_go

    cert = sdea_go()
    assert missing_units(cert) == [], missing_units(cert)
    bad = cert.model_copy(deep=True)
    bad.plots["margin"].y_label = "normalized margin"
    bad.nominal.parameters["mystery"] = 1.0
    found = missing_units(bad)
    assert any("plot margin: y axis" in f for f in found), found
    assert any("'mystery'" in f for f in found), found


def test_synthetic_certificates_have_units_everywhere():
    from test_report import error_cert, two_port_nogo

    for c in (two_port_nogo(), error_cert()):
        assert missing_units(c) == [], missing_units(c)


def test_energy_columns_and_termination_parameters_carry_units():
    from test_report import two_port_nogo

    secs = {s.key: s for s in report_sections(two_port_nogo())}
    energy = next(b.table for b in secs["energy"].blocks if b.table is not None)
    headers = [c.header for c in energy.columns]
    assert {"min E_s [J]", "noise bound [J]", "first time [s]"} <= set(headers), headers


# ---------------------------------------------------------------------------------------------
# the decisive condition


def _curve(s: Series) -> tuple[np.ndarray, np.ndarray]:
    (curve,) = s.lines.values()
    return np.array(s.x), np.array([np.nan if v is None else v for v in curve])


def _assert_curve_is_the_margin_function(s: Series, c) -> None:
    """One source (issue 28): the plotted curve is the condition's own p/m_r, whose minimum over ω
    is the margin the table prints; the marked point is the row's (worst frequency, margin) and the
    legend prints them with the table's formatter."""
    x, y = _curve(s)
    scale = max(1.0, abs(c.margin))
    # the margin is the minimum of the function: no plotted value lies below it ...
    assert np.nanmin(y) >= c.margin - 1e-12 * scale, (np.nanmin(y), c.margin)
    # ... and the function reaches it where the table says
    if c.worst_frequency is None:  # constant in ω: the curve is flat at the margin, no point
        assert c.evidence.get("ratio_constant")
        assert np.nanmax(np.abs(y - c.margin)) <= 1e-9 * scale and not s.points
        (label,) = s.lines
        assert f"margin {fmt(c.margin)}, the same at every ω" in label
        return
    ((name, (px, py)),) = s.points.items()
    assert py == c.margin and f"= {fmt(c.margin)} at ω = " in name
    if math.isfinite(c.worst_frequency) and c.worst_frequency > 0:
        assert px == c.worst_frequency and f"at ω = {fmt(c.worst_frequency)} rad/s" in name
        k = int(np.argmin(np.abs(x - px)))
        assert y[k] == pytest.approx(c.margin, rel=1e-9, abs=1e-15)
    else:  # the limit ω → 0 (or ∞), drawn at that edge of the axis, where the curve tends to it
        edge = 0 if c.worst_frequency == 0 else -1
        assert px == x[edge] and ("at ω = 0 rad/s" if edge == 0 else "at ω = inf rad/s") in name
        assert y[edge] == pytest.approx(c.margin, rel=1e-3)


def test_nogo_plots_its_decisive_condition_below_zero(bilateral_b):
    _, tm, r = bilateral_b
    plots: dict[str, Series] = {}
    pl._decided_plot(plots, tm, r)
    s = plots["decided"]
    failed_freq = [c for c in r.conditions if c.name.startswith("E") and c.status == "violated"]
    worst = min(failed_freq, key=lambda c: c.margin)
    (label,) = s.lines
    assert label.startswith(f"{worst.name}:")
    _, y = _curve(s)
    assert np.nanmin(y) < 0 and s.shade_negative
    _assert_curve_is_the_margin_function(s, worst)
    # the decision's own failed condition (an imaginary-axis residue) is shown as its residue margin
    dec = decisive_condition(r)
    assert dec.name == r.failed_condition and s.bars[dec.name] == pytest.approx(dec.margin) and dec.margin < 0
    assert dec.name in s.title and worst.name in s.title


def test_sdea_plot_marks_its_margin_at_omega_zero_as_the_table_prints_it():
    """The default scene's decisive condition reaches its margin as ω → 0 (5.99e-08, a cancelling
    lowest-order coefficient): the plot marks that value at the left edge, never a grid minimum of
    another function (it showed 6.62e-16 at 0.0175 rad/s against the table's 5.994e-08 at 0)."""
    _, tm, r = _nominal("sdea_bench")
    plots: dict[str, Series] = {}
    pl._decided_plot(plots, tm, r)
    dec = decisive_condition(r)
    assert dec.worst_frequency == 0.0 and 0 < dec.margin < 1e-6
    _assert_curve_is_the_margin_function(plots["decided"], dec)


def test_go_plots_the_condition_with_the_smallest_margin():
    _, tm, r = _nominal("bilateral_2dof_A1")
    assert str(r.verdict) == "stable"
    plots: dict[str, Series] = {}
    pl._decided_plot(plots, tm, r)
    freq = [c for c in r.conditions if c.name.startswith("E") and math.isfinite(c.margin)]
    smallest = min(freq, key=lambda c: c.margin)
    (label,) = plots["decided"].lines
    assert label.startswith(f"{smallest.name}:")


# ---------------------------------------------------------------------------------------------
# witness


@pytest.fixture(scope="module")
def witness_b(bilateral_b):
    sc, tm, _ = bilateral_b
    w = find_witness(tm, 0, termination_family(max(tm.port_dofs))[::2], first=True)
    plots: dict[str, Series] = {}
    return sc, w, witness_response(w, plots, sc), plots


def test_witness_closed_loop_poles_are_the_zeros_of_the_port_impedance(witness_b):
    _, w, out, _ = witness_b
    poles = [complex(a, b) for a, b in out["closed_loop_poles"]]
    assert out["growth_rate_1_s"] == pytest.approx(max(p.real for p in poles)) and out["growth_rate_1_s"] > 0
    # independent check: a pole of Y_in = Z_in⁻¹ is a zero of det Z_in(s) (evaluated from the rational
    # entries, relative to the entries' size there)
    for p in poles[:4]:
        Z = np.array([[e(p) for e in row] for row in w.z_in.entries])
        scale = np.prod(np.max(np.abs(Z), axis=1)) or 1.0
        assert abs(np.linalg.det(Z)) / scale < 1e-6, p


def test_witness_time_to_limit_matches_the_growth_rate(witness_b):
    sc, _w, out, plots = witness_b
    assert out["limits"]["max_velocity"] == sc.safety.max_velocity
    assert out["limit_exceeded"] == "max_velocity"
    t_lim = out["time_to_limit_s"]
    s = plots["witness_energy"]
    t = np.array(s.x)
    v = np.array([np.nan if x is None else x for x in s.lines["|V|"]])
    # the response grows as e^(σt): the log-slope of |V| over the last half of the run equals σ
    # within 10 % (the oscillating drive and the slower poles bend the envelope a little)
    half = t > t[-1] / 2
    slope = np.polyfit(t[half], np.log(v[half]), 1)[0]
    assert slope == pytest.approx(out["growth_rate_1_s"], rel=0.10)
    assert v[-1] >= sc.safety.max_velocity > np.nanmax(v[:-2])  # the limit is crossed at the end, not before
    assert t[-1] == pytest.approx(t_lim)
    # the energy then is a finite number of joules, not an overflow
    e = out["energy_to_limit_J"]
    assert math.isfinite(e) and abs(e) < sc.safety.max_energy


def test_witness_section_shows_the_termination_with_units():
    from test_report import two_port_nogo

    cert = two_port_nogo()
    cert.witness.terminations = {"1": {"kind": "spring", "params": {"k": 1.0}, "coupling": 0.0}}
    cert.witness.growth_rate_1_s = 34.4
    cert.witness.closed_loop_poles = [(34.4, 0.0), (-1.0, 2.0)]
    cert.witness.limits = {"max_velocity": 20.0}
    cert.witness.limit_exceeded = "max_velocity"
    cert.witness.time_to_limit_s = 0.26
    cert.witness.energy_to_limit_J = -0.68
    sec = next(s for s in report_sections(cert) if s.key == "witness")
    rows = [r for b in sec.blocks if b.table is not None for r in b.table.rows]
    assert ["port 2", "spring", "k", "1", "N/m"] in rows
    assert ["growth rate σ = max Re(pole)", "34.4", "1/s"] in rows
    assert ["time to exceed it", "0.26", "s"] in rows and ["port energy E_s at that time", "-0.68", "J"] in rows
    assert missing_units(cert) == []


# ---------------------------------------------------------------------------------------------
# labels and links


def test_network_names_the_table2_gain_set():
    for g in ("A1", "A2", "B"):
        _, tm, _ = _nominal(f"bilateral_2dof_{g}")
        assert f"gains {g} (Table II)" in tm.name and "custom" not in tm.name
    from hil.models.teleop import bilateral_2dof

    sc = load_scene("bilateral_2dof_B")
    p = pl.model_params_from_scene(sc)
    p["gains"] = {**p["gains"], "k_pmyy": 501.0}
    assert "gains custom" in bilateral_2dof(p.pop("gains"), p).name


def test_a_band_never_prints_two_equal_ends():
    assert fmt_range(3350.1, 3350.4) == "3350.1 … 3350.4"
    assert fmt_range(40.0, 95.0) == "40 … 95"
    lo, hi = (float(x) for x in fmt_range(3349.9999, 3350.0001).split(" … "))
    assert lo < hi


def test_condition_names_do_not_wrap_in_the_pdf(tmp_path):
    pytest.importorskip("matplotlib")
    from test_report import _pdftext, two_port_nogo

    from hil.report.render import render_pdf

    cert = two_port_nogo()
    cert.nominal.conditions = [cert.nominal.conditions[0].model_copy(update={
        "name": "E{1,2,3,4}", "label": "principal minor {1,2,3,4} of Re Z'(jω) ≥ 0 (Z' rational) " * 2,
        "detail": "negative for ω in [0, inf] rad/s " * 3})]
    text = _pdftext(render_pdf(cert, tmp_path / "r.pdf"))
    assert re.search(r"^\s*E\{1,2,3,4\}\s", text, re.M), "condition name wrapped"


def test_every_linked_field_has_an_anchor_and_the_html_links_it(tmp_path):
    pytest.importorskip("jinja2")
    from test_report import sdea_go

    from hil.report.render import render_html

    cert = sdea_go()
    fields = set()
    for sec in report_sections(cert):
        for b in sec.blocks:
            if b.table is not None:
                fields |= {c.field for c in b.table.columns if c.field}
                fields |= {f for f in (b.table.row_fields or []) if f}
    assert fields and fields <= set(DEFINITIONS), fields - set(DEFINITIONS)
    assert all(re.fullmatch(r"[a-z0-9_-]+", a) for a in DEFINITIONS.values())
    html = render_html(cert, tmp_path / "r.html").read_text(encoding="utf-8")
    assert f'href="docs/CERTIFICATION.md#{DEFINITIONS["robust.p_stable"]}"' in html


def test_schema_round_trip_of_the_new_fields():
    from test_report import two_port_nogo

    c = two_port_nogo()
    c.witness.closed_loop_poles = [(1.0, 0.0)]
    c.plots["p"] = Series(title="t", x=[1.0, 2.0], x_label="x [s]", y_label="y [1]", lines={"a": [1.0, 2.0]},
                          panels=[Series(title="u", x=[1.0, 2.0], x_label="x [s]", y_label="z [J]")],
                          bars={"D[ω=0]": -0.1}, vlines={"w": 1.5}, shade_negative=True)
    again = Certificate.model_validate_json(c.model_dump_json())
    assert again == c


# ---------------------------------------------------------------------------------------------
# identification plots


def test_identification_plots_show_magnitude_phase_coherence_residuals_and_the_corner():
    """A first-order plant H = g/(1 + jω/a) (velocity/torque, rotary): the plotted magnitude and
    phase are those of the complex H1 (20 log10 |H|, unwrapped angle), the coherence band follows
    Bendat & Piersol, the residual is (model − H1)/σ, and every axis carries its unit."""
    from types import SimpleNamespace

    from hil.certify.figures import identification_plots

    f = np.geomspace(1.0, 200.0, 60)
    w = 2 * np.pi * f

    def frf(theta, ww):
        th = np.atleast_2d(theta)
        H = th[:, 0, None] / (1 + 1j * ww[None, :] / th[:, 1, None])
        out = H[:, :, None, None]
        return out[0] if np.ndim(theta) == 1 else out

    H1 = frf(np.array([2.0, 60.0]), w) * (1 + 0.01j)
    coh = np.full((f.size, 1), 0.9)
    sigma = np.full((f.size, 1, 1), 0.01)
    est = SimpleNamespace(f=f, w=w, H=H1, coherence=coh, sigma=sigma, n_avg=8.0, input_names=("torque",),
                          output_names=("velocity",))
    rng = np.random.default_rng(0)
    samples = np.column_stack([2.0 + 0.01 * rng.standard_normal(400), 60.0 + 0.5 * rng.standard_normal(400)])
    model = SimpleNamespace(n_params=2, frf=frf, names=("g", "a"), units=("rad/(N.m.s)", "rad/s"))
    res = SimpleNamespace(frf=est, model=model, posterior=SimpleNamespace(samples=samples), names=("g", "a"))
    plots: dict[str, Series] = {}
    identification_plots(plots, "chirp", res, 0, "rotary")
    s = plots["frf_chirp_0"]
    assert s.y_label == "|H| [dB re 1 (rad/s)/(N.m)]"
    mag = np.array(s.lines["measured H1"])
    assert mag == pytest.approx(20 * np.log10(np.abs(H1[:, 0, 0])), abs=1e-9)
    phase, coherence, resid = s.panels
    assert np.array(phase.lines["measured H1"]) == pytest.approx(np.degrees(np.unwrap(np.angle(H1[:, 0, 0]))),
                                                                 abs=1e-6)
    assert coherence.lines["coherence γ²"] == pytest.approx([0.9] * f.size)
    # confidence band: |H1| (1 ± 2ε), ε = √(1 − γ²)/(|γ| √(2 n_d))
    eps = math.sqrt(0.1) / (math.sqrt(0.9) * math.sqrt(16.0))
    lo, hi = s.bands["measured H1"]
    assert np.array(hi) - mag == pytest.approx(20 * math.log10(1 + 2 * eps), abs=1e-9)
    assert mag - np.array(lo) == pytest.approx(-20 * math.log10(1 - 2 * eps), abs=1e-9)
    Hm = frf(np.median(samples, axis=0), w)[:, 0, 0]
    assert np.array(resid.lines["real part"]) == pytest.approx(((Hm - H1[:, 0, 0]) / 0.01).real, rel=1e-9)
    c = plots["corner_chirp"]
    assert c.kind == "corner" and set(c.lines) == {"g [rad/(N.m.s)]", "a [rad/s]"}
    cert = Certificate.model_validate({"created_utc": "x", "software": {}, "scene": {"name": "s", "sha256": "0"},
                                       "decision": "GO", "reasons": [], "policy": {}, "measurements": [],
                                       "plots": {k: v.model_dump() for k, v in plots.items()}})
    assert missing_units(cert) == []


def test_every_definition_link_points_at_a_heading_of_certification_md() -> None:
    """The report's links (hil.report.sections.DEFINITIONS) land on headings of docs/CERTIFICATION.md
    (GitHub anchors: lower case, spaces to '-'), and every field path of the document's index that
    the report model links is mapped to that path's section."""
    import re
    from pathlib import Path

    from hil.report.sections import DEFINITIONS, DEFINITIONS_DOC

    doc = (Path(__file__).resolve().parents[2] / DEFINITIONS_DOC).read_text(encoding="utf-8")
    anchors = {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-")
               for h in re.findall(r"^#{2,3} (.+)$", doc, flags=re.M)}
    bad = {k: v for k, v in DEFINITIONS.items() if v not in anchors}
    assert not bad, f"links to missing headings: {bad}"
    index = dict(re.findall(r"^\| `([\w.\[\]]+)`[^|]*\| \[#([\w-]+)\]", doc, flags=re.M))
    for path, anchor in index.items():
        if path in DEFINITIONS:
            assert DEFINITIONS[path] == anchor, (path, DEFINITIONS[path], anchor)
