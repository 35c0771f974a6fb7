"""Reliability figures of the report (issue 18, numbers of issue 11): the design point in
posterior-standardized coordinates with the limit state traced by the verdict (checked against
the closed form of a linear limit state), P(not stable) by every method on one axis (Φ(−β) in the
far tail against scipy's log survival function), the chart's units and definition links in the
PDF, and the corner plot as vector text in the PDF."""

from __future__ import annotations

import math
import re
import subprocess
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from test_report import _tool, sdea_go

from hil.certify.certificate import Certificate, Series
from hil.certify.figures import design_point_axes, design_point_plot
from hil.report.drawing import _corner_offset
from hil.report.render import render_pdf
from hil.report.sections import (
    CHARTS,
    Block,
    Section,
    failure_estimates,
    log10_phi_minus,
    missing_units,
    report_sections,
)

# a linear limit state in u: stable iff a·u < b; β = b/‖a‖, u* = β a/‖a‖ (closed form)
A = np.array([0.3, 2.0, -1.0])
B = 5.0
BETA = B / np.linalg.norm(A)
U_STAR = BETA * A / np.linalg.norm(A)


def _rel(u_star=U_STAR, beta=BETA):
    return SimpleNamespace(design_point_u=list(u_star), beta=float(beta), censored=False, required_beta=1.645)


def _curve(s: Series, name_start: str) -> np.ndarray:
    ys = next(v for k, v in s.lines.items() if k.startswith(name_start))
    return np.array([np.nan if v is None else v for v in ys])


def _plot_cert(plots: dict[str, Series]) -> Certificate:
    return Certificate.model_validate({"created_utc": "x", "software": {}, "scene": {"name": "s", "sha256": "0"},
                                       "decision": "GO", "reasons": [], "policy": {}, "measurements": [],
                                       "plots": {k: v.model_dump() for k, v in plots.items()}})


@pytest.mark.parametrize("fast", [True, False])
def test_design_point_plot_traces_a_linear_limit_state(fast):
    calls = []

    def stable(U):
        calls.append(len(U))
        return U @ A < B

    plots: dict[str, Series] = {}
    design_point_plot(plots, stable, _rel(), ["B", "K_f", "M"], model="sdea", fast=fast)
    s = plots["reliability"]
    i, j = design_point_axes(U_STAR)
    assert (i, j) == (1, 2)  # |u*| largest along K_f (2.0), then M (|−1.0|)
    x = np.array(s.x)
    yb = _curve(s, "limit state")
    # the slice holds u_0 = u*_0: the boundary is u_i = (b − a_j x − a_0 u*_0)/a_i
    exact = (B - A[j] * x - A[0] * U_STAR[0]) / A[i]
    ok = np.isfinite(yb)
    assert ok.sum() > 0.8 * x.size
    top = max(1.3 * BETA, BETA + 3.0)
    # fast: 40 grid steps then 24 bisections of the search height top; otherwise 4 + 4 on 7 columns,
    # linearly interpolated (exact for a line): the bracket width bounds the error
    tol = top / 40 / 2 ** 24 * 1.01 if fast else top / 4 / 2 ** 4 * 1.01
    assert np.max(np.abs(yb[ok] - exact[ok])) <= tol
    # the section of the sphere ‖u‖ = β passes through u* (where it touches the limit state)
    k = int(np.argmin(np.abs(x - U_STAR[j])))
    assert x[k] == pytest.approx(U_STAR[j], abs=1e-12)
    assert _curve(s, "‖u‖ = β =")[k] == pytest.approx(U_STAR[i], abs=1e-9)
    assert s.points[f"design point u* (β = {BETA:.4g})"] == pytest.approx((U_STAR[j], U_STAR[i]))
    assert "other coordinates at their u* values" in s.title  # u*_0 ≠ 0: a slice, not through u = 0
    if not fast:
        assert sum(calls) <= 8 * 4 + 8 * 4  # 8 columns (7 + the design point's), grid then bisection
    assert missing_units(_plot_cert(plots)) == []


def test_design_point_plot_is_skipped_without_a_design_point():
    plots: dict[str, Series] = {}
    design_point_plot(plots, lambda U: U[:, 0] < 1, SimpleNamespace(design_point_u=[1.0, 0.0], beta=1.0,
                                                                       censored=True, required_beta=1.6), ["a", "b"])
    design_point_plot(plots, lambda U: U[:, 0] < 1, _rel([1.0], 1.0), ["a"])  # one parameter: no plane
    assert plots == {}


@pytest.mark.parametrize("beta", [0.5, 3.0, 10.0, 37.0, 38.5, 45.0, 70.06, 500.0])
def test_log10_phi_minus_matches_scipy_in_the_far_tail(beta):
    from scipy.stats import norm

    # scipy's logsf is accurate in the tail; our asymptotic series has relative error < 15/β⁶ in
    # ln Φ(−β) beyond β = 37, far below 1e-6 in log10 there
    assert log10_phi_minus(beta) == pytest.approx(norm.logsf(beta) / math.log(10.0), abs=1e-6, rel=1e-9)


def _with_reliability(method: str = "monte_carlo") -> Certificate:
    c = sdea_go()
    data = c.model_dump()
    data["robust"]["reliability"] = {"beta": 2.5, "phi_beta": 0.9937903346742238, "required_beta": 1.6448536,
                                     "design_point": {"M": 0.0034, "B": 0.8, "K_f": 1200.0, "B_f": 1.9},
                                     "design_point_u": [2.0, -1.2, 0.0, 0.9], "verified": True}
    data["robust"]["rare_event"] = {"method": "importance sampling", "n": 20000, "n_fail": 812,
                                    "p_failure": 0.0061, "std_error": 0.0003, "p_stable": 0.9939,
                                    "lower": 0.99331, "upper": 0.99449, "confidence": 0.95, "ess": 700.0,
                                    "reliable": True}
    data["robust"]["p_stable_method"] = method
    return Certificate.model_validate(data)


def test_failure_estimates_are_one_minus_each_p_stable():
    from scipy.stats import norm

    c = _with_reliability("importance_sampling")
    r = c.robust
    sampled, form, ims = failure_estimates(c)
    assert (sampled.value, sampled.lower, sampled.upper) == pytest.approx((1 - r.p_stable, 1 - r.upper,
                                                                           1 - r.lower))
    assert form.value == pytest.approx(norm.sf(2.5), rel=1e-12) and form.lower is None
    assert (ims.value, ims.lower, ims.upper) == pytest.approx((0.0061, 1 - 0.99449, 1 - 0.99331))
    assert [e.decides for e in (sampled, form, ims)] == [False, False, True]
    assert [e.decides for e in failure_estimates(_with_reliability())] == [True, False, False]


def test_reliability_chart_and_design_point_table_in_the_pdf(tmp_path):
    c = _with_reliability()
    secs = report_sections(c)
    robust = next(s for s in secs if s.key == "robust")
    chart = next(b for b in robust.blocks if b.kind == "chart")
    assert chart.axes == CHARTS["p_failure"] and chart.link == "docs/CERTIFICATION.md#p-stable-method"
    table = next(b.table for b in robust.blocks if b.table is not None and b.table.columns[0].name == "parameter")
    assert [r[0] for r in table.rows] == ["M", "B", "K_f", "B_f"]
    # importance factors α = u*/β
    assert [float(r[5]) for r in table.rows] == pytest.approx([0.8, -0.48, 0.0, 0.36])
    assert missing_units(c) == []
    pdf = render_pdf(c, tmp_path / "r.pdf")
    text = subprocess.run([_tool("pdftotext"), str(pdf), "-"], capture_output=True, text=True, check=True,
                          timeout=60).stdout
    for label in CHARTS["p_failure"]:
        assert label in text
    assert "Definition: docs/CERTIFICATION.md#p-stable-method" in text
    assert "importance sampling: 20000 samples, 812 failing" in text
    assert "design point θ*" in text


def test_a_chart_axis_without_a_unit_is_reported():
    c = _with_reliability()
    secs = [Section("robust", "Robust", [Block("chart", plot="p_failure", axes=["P(not stable)"])])]
    assert any("chart p_failure" in m for m in missing_units(c, secs))


def test_corner_plot_is_vector_text_in_the_pdf(tmp_path):
    """The corner plot's axis labels and tick numbers are PDF text (only its scatter is a raster);
    a parameter whose spread is 1e-9 of its size is drawn as the offset from a stated value."""
    rng = np.random.default_rng(3)
    k = 362.0 + 1e-6 * rng.standard_normal(800)
    b = 0.17 + 0.002 * rng.standard_normal(800)
    assert _corner_offset(k) != 0.0 and _corner_offset(b) == 0.0
    assert abs(_corner_offset(k) - 362.0) < 1e-6  # within the spread's decade
    corner = Series(title="Posterior (corner test)", kind="corner", x=list(map(float, range(800))),
                    x_label="draw [1]", y_label="value [parameter units]",
                    lines={"K_f [N.m/rad]": k.tolist(), "B [N.m.s/rad]": b.tolist()})
    pdf = render_pdf(_plot_cert({"corner_x": corner}), tmp_path / "c.pdf")
    text = subprocess.run([_tool("pdftotext"), str(pdf), "-"], capture_output=True, text=True, check=True,
                          timeout=60).stdout
    assert "Posterior (corner test)" in text
    assert "K_f − 362" in text and "[×10⁻⁶ N.m/rad]" in text  # offset and engineering scale in the label
    assert "B" in text and "[N.m.s/rad]" in text
    # tick labels are text too (rotated 45°: pdftotext splits them into pieces, joined here)
    assert re.search(r"0\.1[678]\d", "".join(text.split()))


def test_pretty_unit_prints_powers_as_superscripts():
    from hil.certify.units import pretty_unit, quantity_unit

    assert pretty_unit("kg.m^2") == "kg.m²" == quantity_unit("mass", "rotary")
    assert pretty_unit("rad/(N.m.s^2)") == "rad/(N.m.s²)" and pretty_unit("N.m/rad") == "N.m/rad"
