"""Every number a figure prints is the number a table prints (issue 28): one source.

Two small certificates made by the pipeline (no experiments): the SDEA at k22 = 300 with M and B
known to 5 and 10 % (GO: its decisive condition reaches its margin as ω → 0, the design headroom and
the critical band are plotted) and the teleoperator ``bilateral_2dof_B`` (NO-GO: its most negative
frequency condition is constant in ω). Their PDFs are read back as text (pdftotext): the legend of
each figure and the table row it repeats carry the same printed number, made by the same formatter
from the same field. The PDF layout checks: a figure's caption sits on the page of its figure, under
the heading of its own section, and a legend never covers a marked point.
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

from hil.certify.numbers import fmt
from hil.certify.pipeline import certify_scene
from hil.report.drawing import draw_plot, place_legend
from hil.report.render import build_reports
from hil.report.sections import figure_caption, report_sections
from hil.scene.spec import load_scene, scene_from_dict

pytest.importorskip("matplotlib")
pytest.importorskip("jinja2")
from test_report import _tool

SECTION_TITLES = ("Nominal verdict", "Robust certification", "Identification", "Design guidance",
                  "Instability witness", "Energy evidence", "Multi-port network", "Plots", "Evidence and integrity")


def _sdea300() -> dict[str, Any]:
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = []
    c = d["certification"]
    c.pop("identify")
    c["uncertain"] = {"M": {"value": 6.399e-4, "rel_std": 0.05}, "B": {"value": 0.169, "rel_std": 0.1}}
    c["draws"] = 200
    return d


def _b() -> dict[str, Any]:
    d = yaml.safe_load(load_scene("bilateral_2dof_B").source_text)
    d["experiments"] = []
    d["certification"]["draws"] = 20
    return d


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> dict[str, tuple[Any, dict[str, Path], str]]:
    out = {}
    for key, make in (("go", _sdea300), ("nogo", _b)):
        d = tmp_path_factory.mktemp(key)
        cert = certify_scene(scene_from_dict(make(), label=key), d, run_experiments=False)
        files = build_reports(cert, d)
        text = subprocess.run([_tool("pdftotext"), "-layout", str(files["pdf"]), "-"], capture_output=True,
                              text=True, timeout=60, check=True).stdout
        out[key] = (cert, files, text)
    assert out["go"][0].decision == "GO" and out["nogo"][0].decision == "NO-GO"
    return out


def _flat(s: str) -> str:
    return " ".join(s.split())


def _row(text: str, first: str) -> str:
    """The PDF text line of a table row starting with ``first`` (first match)."""
    for line in text.splitlines():
        if line.strip().startswith(first):
            return _flat(line)
    raise AssertionError(f"no row {first!r}")


def test_the_decisive_condition_prints_the_tables_margin(made):
    for key in ("go", "nogo"):
        cert, _, text = made[key]
        s = cert.plots["decided"]
        shown = next(iter(s.lines)).split(":")[0]
        row = next(c for c in cert.nominal.conditions if c.name == shown)
        m = fmt(row.margin)
        # the table row of that condition prints the margin ...
        assert m in _row(text, f"{shown} "), (key, _row(text, f"{shown} "))
        # ... and so does the legend, from the same field by the same formatter
        labels = [*s.lines, *s.points]
        assert any(m in lb for lb in labels), (key, labels)
        assert any(_flat(lb)[:60] in _flat(text) for lb in labels if m in lb), key
        if row.worst_frequency is None:
            assert "the same at every ω" in next(iter(s.lines)) and not s.points
        else:
            ((_, py),) = s.points.values()
            assert py == row.margin
            w = "0" if row.worst_frequency == 0 else fmt(row.worst_frequency)
            assert f"at ω = {w} rad/s" in next(iter(s.points))
            assert _row(text, f"{shown} ").split()[-1] != ""  # the row's worst frequency column
            assert f" {w} " in f" {_row(text, f'{shown} ')} "


def test_headroom_and_critical_band_legends_print_the_design_and_robust_tables(made):
    cert, _, text = made["go"]
    d, r = cert.design, cert.robust
    # the requirement crossing marked in the headroom figure is the design table's posterior limit
    (label, (px, _)), = cert.plots["headroom"].points.items()
    assert px == d.posterior_limit and f"= {fmt(d.posterior_limit)} " in label
    assert f" {fmt(d.posterior_limit)} " in f" {_row(text, 'posterior limit (the lower bound')} "
    assert f"headroom {d.posterior_headroom:+.4g}" in label
    assert f" {d.posterior_headroom:+.4g} " in f" {_row(text, 'posterior headroom (posterior limit')} "
    # the nominal limit line: the design table's nominal limit and headroom
    (vname, vx), = [(k, v) for k, v in cert.plots["headroom"].vlines.items() if k.startswith("nominal limit")]
    assert vx == d.nominal_limit and f"headroom {d.nominal_headroom:+.4g}" in vname
    assert f" {fmt(d.nominal_limit)} " in f" {_row(text, 'nominal limit (k22_max at the nominal')} "
    # the critical band's marked edges are the robust table's band
    pts = cert.plots["critical_band"].points
    lo, hi = r.critical_band_rad_s
    assert pts["critical band, low edge (over the draws)"][0] == lo
    assert pts["critical band, high edge (over the draws)"][0] == hi
    assert f" {fmt(lo)} … {fmt(hi)} " in f" {_row(text, 'critical band ')} "
    # the curve is drawn at the nominal point, the nominal table's parameters
    assert "nominal (posterior median)" in cert.plots["critical_band"].lines


def test_uncertain_parameters_are_nominal_at_their_stated_value(made):
    """"nominal" is each parameter's median: an uncertain parameter's stated value exactly (its
    log-normal median), not the mean of its draws (2.026 where the scene says 2.0)."""
    cert = made["nogo"][0]
    sc = load_scene("bilateral_2dof_B")
    for k, u in sc.certification.uncertain.items():
        assert cert.nominal.parameters[k] == u.value, k
    cert_go, _, _ = made["go"]
    assert cert_go.nominal.parameters["M"] == 6.399e-4 and cert_go.nominal.parameters["B"] == 0.169
    assert "posterior medians" in cert.reasons[0] and "passive operator and environment" in cert.reasons[0]


def _pages(pdf: Path) -> list[str]:
    text = subprocess.run([_tool("pdftotext"), "-layout", str(pdf), "-"], capture_output=True, text=True,
                          timeout=60, check=True).stdout
    return [p for p in text.split("\f") if p.strip()]


@pytest.mark.parametrize("key", ["go", "nogo"])
def test_figures_sit_under_their_own_heading_with_their_caption(made, key):
    cert, files, _ = made[key]
    pages = _pages(files["pdf"])
    # reading order: (page, line) of each section heading and each figure's title
    heads: list[tuple[int, int, str]] = []
    for i, p in enumerate(pages):
        for j, line in enumerate(p.splitlines()):
            if line.strip() in SECTION_TITLES:
                heads.append((i, j, line.strip()))
    for sec in report_sections(cert):
        for b in sec.blocks:
            if b.kind != "figure":
                continue
            cap, _ = figure_caption(cert, b.plot)
            cap_words = _flat(cap)[:50]
            hits = [(i, j) for i, p in enumerate(pages) for j, line in enumerate(p.splitlines())
                    if _flat(line).startswith(cap_words[:30])]
            assert hits, f"{key}: caption of {b.plot} not found"
            i, j = hits[0]
            # the caption's page also shows the figure (its title, first words)
            title_words = _flat(cert.plots[b.plot].title.split("\n")[0])[:25]
            assert title_words in _flat(pages[i]), f"{key}: {b.plot} caption on page {i + 1} without its figure"
            # the last heading before the caption is the figure's own section
            before = [h for h in heads if (h[0], h[1]) < (i, j)]
            assert before and before[-1][2] == sec.title, (key, b.plot, before[-1] if before else None, sec.title)


def test_a_legend_never_covers_a_marked_point():
    """The placement moves the legend off the marked points (and, when every inside place covers
    one, makes room above the data); checked in display coordinates on a plot built to crowd them."""
    import numpy as np
    from matplotlib.figure import Figure

    from hil.certify.certificate import Series
    from hil.report.drawing import _legend_cover

    x = np.linspace(0.0, 1.0, 50)
    # a point in each corner and one in the middle: no inside location is free
    pts = {f"p{k} =": (px, py) for k, (px, py) in enumerate([(0.02, 0.98), (0.98, 0.98), (0.02, 0.02),
                                                             (0.98, 0.02), (0.5, 0.5), (0.5, 0.98),
                                                             (0.02, 0.5), (0.98, 0.5), (0.5, 0.02)])}
    s = Series(title="crowded", x=x.tolist(), x_label="x [1]", y_label="y [1]",
               lines={"a long legend entry for the line": x.tolist()}, points=pts)
    fig = Figure(figsize=(6.8, 3.6))
    draw_plot(fig, s)
    ax = fig.axes[0]
    leg = ax.get_legend()
    assert leg is not None
    assert _legend_cover(ax, leg, fig._get_renderer())[0] == 0
    # and the check is not vacuous: the same legend forced into the corner covers a point
    leg.set_loc("upper right")
    ax.set_ylim(-0.05, 1.05)
    assert _legend_cover(ax, leg, fig._get_renderer())[0] > 0
    assert place_legend(ax) is not None


@pytest.mark.parametrize("key", ["go", "nogo"])
def test_no_legend_of_a_certificate_covers_a_marked_point(made, key):
    from matplotlib.figure import Figure

    from hil.report.drawing import _legend_cover, _plot_height

    cert, _, _ = made[key]
    for name, s in cert.plots.items():
        if s.kind == "corner":
            continue
        fig = Figure(figsize=(6.8, _plot_height(s)))
        draw_plot(fig, s)
        for ax in fig.axes:
            leg = ax.get_legend()
            if leg is not None:
                assert _legend_cover(ax, leg, fig._get_renderer())[0] == 0, (key, name)


def test_page_one_says_the_decision_uses_the_margins_sign_never_their_size(made):
    for key in ("go", "nogo"):
        cert, files, _ = made[key]
        page1 = _flat(_pages(files["pdf"])[0])
        assert "the decision uses only their sign, which is the exact verdict, never their size" in page1
        assert f"nominal {fmt(cert.nominal.margin)}" in page1
        assert f"{fmt(cert.robust.worst_case_margin)}" in page1
        assert "Nominal: each parameter at its median" in page1
        html = files["html"].read_text(encoding="utf-8")
        assert "never their size" in html
