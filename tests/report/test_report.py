"""Certificate reports (hil.report.render): JSON round trip against the schema, only the sections present
in the record appear, the HTML renders in headless Chromium without console errors, the PDF
rasterizes, ``hil report`` rebuilds from a stored record and fails in one line on a broken one.

Chromium and poppler-utils (pdftotext, pdftoppm) are system tools: .ci/run installs them. Without
them these tests fail under CI (``CI=true``) and are skipped locally.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")
pytest.importorskip("jinja2")

from hil.certify.certificate import Certificate
from hil.cli.main import main as hil_main
from hil.errors import HilError
from hil.report.render import (
    ReportError,
    build_reports,
    load_certificate,
    render_html,
    render_pdf,
    write_json,
)
from hil.report.sections import DEFINITIONS_DOC

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = ROOT / "docs" / "certificate.schema.json"
SECTIONS = {  # section key -> heading, in the HTML (id sec-<key>) and in the PDF
    "nominal": "Nominal verdict",
    "robust": "Robust certification",
    "identification": "Identification",
    "design": "Design guidance",
    "witness": "Instability witness",
    "energy": "Energy evidence",
    "multiport": "Multi-port network",
    "plots": "Plots",
    "errors": "Errors",
}
COLOURS = {"GO": (0x1B, 0x7F, 0x3B), "NO-GO": (0xC6, 0x28, 0x28), "ERROR": (0x6A, 0x3D, 0x9A)}


# ---------------------------------------------------------------------------------------------
# certificates


def _base(decision: str, scene: str, **kw) -> dict:
    return {"created_utc": "2026-11-22T10:00:00Z", "software": {"hil-certify": "0.1.0", "python": "3.11"},
            "scene": {"name": scene, "sha256": "ab" * 32, "description": f"{scene} on the mocked bench",
                      "source": f"builtin:{scene}", "units": "rotary" if scene.startswith("sdea") else "linear"},
            "decision": decision, "policy": {"required_probability": 0.95, "confidence": 0.95, "credible": 0.9}, **kw}


def sdea_go() -> Certificate:
    w = np.logspace(0, 3, 120)
    mag = 20 * np.log10(1.0 / np.abs(1 - (w / 200.0) ** 2 + 0.2j * w / 200.0))
    margin = 0.3 + 0.5 * np.tanh((w - 40) / 60)
    rng = np.random.default_rng(1)
    k_draws = 1200 + 15 * rng.standard_normal(300)
    b_draws = 2.0 + 0.01 * (k_draws - 1200) + 0.05 * rng.standard_normal(300)
    i_worst = int(np.argmin(margin))
    t = np.linspace(0, 2, 200)
    return Certificate.model_validate(_base(
        "GO", "sdea_bench",
        reasons=["P(stable) ≥ 0.9981 (lower 95% bound) clears 0.95; nominal margin 0.112 > 0"],
        measurements=[
            {"name": "p_stable_lower", "value": 0.99812, "lower": 0.95, "outcome": "PASS",
             "description": "lower Clopper-Pearson bound of P(stable)"},
            {"name": "nominal_margin", "value": 0.112, "lower": 0.0, "outcome": "PASS"},
            {"name": "worst_case_margin", "value": 0.0412, "lower": 0.0, "outcome": "PASS"},
            {"name": "k22_headroom", "value": 0.8, "upper": 1.0, "outcome": "MARGINAL", "unit": "",
             "description": "current k22 over the largest passive k22"},
            {"name": "posterior_converged", "value": True, "outcome": "PASS"},
            {"name": "r_hat_max", "value": 1.004, "upper": 1.01, "outcome": "INFO"},
        ],
        nominal={"network": "sdea_vsic", "criterion": "two_port_passivity", "verdict": "stable", "margin": 0.112,
                 "worst_frequency": 62.8, "failed_condition": None, "weak": False,
                 "parameters": {"M": 0.0032, "B": 0.9, "K_f": 1200.0, "B_f": 2.0, "k22": 400.0},
                 "conditions": [
                     {"name": "poles", "label": "no RHP poles", "status": "satisfied", "margin": None,
                      "worst_frequency": None},
                     {"name": "re_z11", "label": "Re z11 ≥ 0", "status": "satisfied", "margin": 0.34,
                      "worst_frequency": 120.0, "detail": "Sturm: no sign change"},
                     {"name": "det_minor", "label": "4 Re z11 Re z22 − |z12 + z21*|² ≥ 0", "status": "equality",
                      "margin": 0.112, "worst_frequency": "inf", "detail": "identically zero at high ω"}]},
        robust={"n_draws": 4000, "p_stable": 0.99925, "lower": 0.99812, "upper": 0.99979, "confidence": 0.95,
                "required": 0.95, "credible": 0.9, "worst_case_margin": 0.0412,
                "worst_case_parameters": {"M": 0.0033, "B": 0.85, "K_f": 1180.0, "B_f": 1.9},
                "critical_band_rad_s": [40.0, 95.0], "method": "closed form (batch)"},
        identification=[{"model": "sdea_locked", "record": "runs/00_chirp_locked.h5", "converged": True,
                         "reason": "tau 42, 50 tau, acceptance 0.31, split-R̂ 1.004",
                         "parameters": [
                             {"name": "M", "unit": "kg m²", "truth": 0.0032, "mean": 0.00321, "median": 0.0032,
                              "q05": 0.0031, "q95": 0.0033, "std": 6e-5, "ls_std": 5.8e-5, "crb_std": 5.5e-5},
                             {"name": "B", "unit": "N m s", "truth": 0.9, "mean": 0.901, "median": 0.9,
                              "q05": 0.88, "q95": 0.92, "std": 0.012, "ls_std": 0.011, "crb_std": None},
                             {"name": "K_f", "unit": "N m/rad", "mean": 1201.3, "median": 1200.9, "q05": 1176.0,
                              "q95": 1226.0, "std": 15.2},
                             {"name": "B_f", "unit": "N m s/rad", "truth": 2.0, "mean": 2.01, "median": 2.0,
                              "q05": 1.93, "q95": 2.09, "std": 0.05, "ls_std": 0.05, "crb_std": 0.048}],
                         "diagnostics": {"coherence_min": 0.97, "saturated": False, "gaps": 0,
                                         "tau": [40.1, 41.7, 42.0, 39.9]}}],
        design={"parameter": "k22", "unit": "N m/rad", "current": 400.0, "max_value": 500.0,
                "probability_at_max": 0.9512, "required": 0.95,
                "note": "largest virtual-coupler stiffness keeping the lower bound of P(stable) ≥ 0.95"},
        plots={
            "bode": {"title": "Bode magnitude with 90% credible band", "x": w.tolist(), "x_label": "ω [rad/s]",
                     "y_label": "|G| [dB re 1 N.m.s/rad]", "log_x": True, "lines": {"posterior mean": mag.tolist(),
                                                                      "measured H1": (mag + 0.3).tolist()},
                     "bands": {"posterior mean": ((mag - 1.5).tolist(), (mag + 1.5).tolist())}},
            "margin": {"title": "Passivity margin vs frequency", "x": w.tolist(), "x_label": "ω [rad/s]",
                       "y_label": "normalized margin [1]", "log_x": True, "lines": {"margin": margin.tolist()},
                       "points": {"worst": (float(w[i_worst]), float(margin[i_worst]))}, "hline": 0.0},
            "corner": {"title": "Posterior draws: K_f vs B_f ($ literal)", "x": k_draws.tolist(),
                       "x_label": "K_f [N m/rad]", "y_label": "B_f [N m s/rad]", "lines": {"draws": b_draws.tolist()},
                       "points": {"truth": (1200.0, 2.0)}},
            "step": {"title": "Locked response with a gap", "x": t.tolist(), "x_label": "t [s]", "y_label": "θ [rad]",
                     "lines": {"measured": [None if 50 <= i < 60 else math.sin(5 * v) for i, v in enumerate(t)],
                               "broken": [1.0, 2.0]}},
        }))


def two_port_nogo() -> Certificate:
    t = np.linspace(0, 10, 500)
    e = 0.02 * np.sin(3 * t) - 0.004 * t ** 1.5
    i_min = int(np.argmin(e))
    return Certificate.model_validate(_base(
        "NO-GO", "bilateral_2dof_B",
        reasons=["at its nominal parameters (posterior medians) the network fails the exact stability criterion",
                 "energy injection: E_s(t) went below its noise bound at the operator port"],
        measurements=[
            {"name": "nominal_margin", "value": -0.21, "lower": 0.0, "outcome": "FAIL"},
            {"name": "min_port_energy", "value": -0.0789, "unit": "J", "lower": -0.002, "outcome": "FAIL"},
            {"name": "witness_margin", "value": -0.21, "outcome": "INFO"},
        ],
        nominal={"network": "bilateral_2dof", "criterion": "absolute_stability", "verdict": "potentially_unstable",
                 "margin": -0.21, "worst_frequency": 12.5, "failed_condition": "B2", "weak": False,
                 "parameters": {"mm_yy": 1.0, "ms_yy": 1.0}, "conditions": [
                     {"name": "A", "label": "cycle products", "status": "satisfied", "margin": 0.5,
                      "worst_frequency": 3.0},
                     {"name": "B2", "label": "η(ω) ≥ 1 on block 2", "status": "violated", "margin": -0.21,
                      "worst_frequency": 12.5}]},
        witness={"terminations": {"operator": {"type": "spring", "k": 350.0},
                                  "environment": {"type": "mass", "m": 2.0}},
                 "drive_frequency_rad_s": 12.5, "band_rad_s": [9.0, "inf"], "margin": -0.21,
                 "simulation": {"energy_delivered_J": 0.41, "grew": True, "duration_s": 10.0}},
        energy=[{"experiment": "energy_injection", "port": "operator", "record": "runs/01_energy.h5",
                 "went_negative": True, "min_energy": -0.0789, "bound": 0.002, "first_time": 3.12},
                {"experiment": "energy_injection", "port": "environment", "record": "runs/01_energy.h5",
                 "went_negative": False, "min_energy": -0.0004, "bound": 0.002}],
        multiport={"ports": [2, 2], "dof_total": 4, "symmetrization": "Z' = D Z D⁻¹ (rational D)"},
        plots={"energy": {"title": "Port energy E_s(t)", "x": t.tolist(), "x_label": "t [s]", "y_label": "E_s [J]",
                          "lines": {"operator port": e.tolist()},
                          "bands": {"noise bound": ([-0.002] * t.size, [0.002] * t.size)},
                          "points": {"minimum": (float(t[i_min]), float(e[i_min]))}, "hline": 0.0}},
    ))


def error_cert() -> Certificate:
    return Certificate.model_validate(_base(
        "ERROR", "sdea_bench",
        reasons=["no posterior draws", "<script>alert('x')</script> & friends"],
        measurements=[{"name": "p_stable_lower", "value": None, "lower": 0.95, "outcome": "ERROR",
                       "description": "no draws"},
                      {"name": "nominal_margin", "value": float("nan"), "lower": 0.0, "outcome": "ERROR"}],
        errors=["identification failed: record runs/00_chirp.h5 has no channel motor.velocity",
                "parameter K_f: 12 non-finite draws"],
    ))


CERTS = {"go": sdea_go, "nogo": two_port_nogo, "error": error_cert}
PRESENT = {
    "go": {"nominal", "robust", "identification", "design", "plots"},
    "nogo": {"nominal", "witness", "energy", "multiport"},  # its energy plot sits in the energy section
    "error": {"errors"},
}


# ---------------------------------------------------------------------------------------------
# tools


def _in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


def _tool(*names: str) -> str:
    for n in names:
        exe = shutil.which(n)
        if exe:
            return exe
    msg = f"{names[0]} is not installed (apt-get install chromium poppler-utils; .ci/run installs them)"
    if _in_ci():
        pytest.fail(msg)
    pytest.skip(msg)


def _png_stats(path: Path) -> tuple[float, np.ndarray]:
    import matplotlib.image as mpimg

    img = mpimg.imread(str(path))[..., :3]
    return float(img.std()), img


def _colour_pixels(img: np.ndarray, rgb: tuple[int, int, int], tol: float = 0.06) -> int:
    return int(np.all(np.abs(img - np.array(rgb) / 255.0) < tol, axis=-1).sum())


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, Path]]:
    out = {}
    for key, make in CERTS.items():
        out[key] = build_reports(make(), tmp_path_factory.mktemp(key))
    return out


# ---------------------------------------------------------------------------------------------
# JSON


@pytest.mark.parametrize("key", list(CERTS))
def test_json_round_trip_validates(built, key):
    cert = CERTS[key]()
    text = built[key]["json"].read_text(encoding="utf-8")
    again = Certificate.model_validate_json(text)
    # (a NaN value is stored as null); build_reports writes the certificate sealed (with its digest)
    assert again.model_dump_json(exclude={"integrity"}) == cert.model_dump_json(exclude={"integrity"})
    assert again.integrity is not None
    assert load_certificate(built[key]["json"]) == again
    assert load_certificate(built[key]["json"].parent) == again  # a folder holding certificate.json
    try:
        import jsonschema
    except ImportError:  # optional: pydantic validation above is the contract
        return
    schema = json.loads(SCHEMA.read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator(schema).validate(json.loads(text))


def test_write_json_refuses_a_record_that_cannot_load_back(tmp_path):
    cert = sdea_go()
    cert.robust.p_stable = float("nan")  # JSON has no NaN: it would be written as null
    with pytest.raises(ReportError, match=r"robust\.p_stable"):
        write_json(cert, tmp_path / "certificate.json")
    assert not (tmp_path / "certificate.json").exists()


@pytest.mark.parametrize("content, match", [
    (None, "no such file"),
    (b"{\"decision\": \"GO\",", "not valid JSON: line 1"),
    (b"[1, 2]", "top level is not a JSON object"),
    (b"\xff\xfe{", "not UTF-8 text"),
    (b"\x00\x01", "binary data"),
    (json.dumps({"decision": "MAYBE"}).encode(), "invalid certificate: "),
    (json.dumps({"schema_version": "2.0"}).encode(), "schema_version '2.0' is not supported"),
])
def test_load_certificate_errors_are_one_line(tmp_path, content, match):
    p = tmp_path / "certificate.json"
    if content is not None:
        p.write_bytes(content)
    with pytest.raises(ReportError, match=re.escape(match)) as ei:
        load_certificate(p)
    assert isinstance(ei.value, HilError)
    assert "\n" not in str(ei.value) and str(p) in str(ei.value)


# ---------------------------------------------------------------------------------------------
# HTML


@pytest.mark.parametrize("key", list(CERTS))
def test_html_has_only_present_sections(built, key):
    html = built[key]["html"].read_text(encoding="utf-8")
    cert = CERTS[key]()
    assert f'class="badge d-{cert.decision.lower().replace("-", "")}"' in html
    for sec in ("reasons", "policy", "measurements", "signature"):
        assert f'id="sec-{sec}"' in html
    for sec, heading in SECTIONS.items():
        present = sec in PRESENT[key]
        assert (f'id="sec-{sec}"' in html) == present, sec
        assert (f">{heading}</h2>" in html) == present, sec
    # every stored plot, and the P(not stable) chart drawn from the record when there is a robust section
    assert html.count("data:image/png;base64,") == len(cert.plots) + (cert.robust is not None)
    assert ('id="chart-p_failure"' in html) == (cert.robust is not None)
    for m in cert.measurements:
        assert m.name in html


def test_html_is_self_contained_and_escaped(built):
    for paths in built.values():
        html = paths["html"].read_text(encoding="utf-8")
        for attr in re.findall(r'(?:src|href)\s*=\s*"([^"]*)"', html):
            # inline data, in-page anchors, and the links of numbers to their definitions
            assert attr.startswith(("data:", "#", f"{DEFINITIONS_DOC}#")), attr
        assert "<link" not in html and "<script" not in html and "@import" not in html
        assert not re.search(r"url\((?!\s*['\"]?(data:|#))", html)
    html = built["error"]["html"].read_text(encoding="utf-8")
    assert "&lt;script&gt;alert(" in html and "&amp; friends" in html


def test_html_details(built):
    html = built["go"]["html"].read_text(encoding="utf-8")
    assert 'class="o-marginal">MARGINAL<' in html and 'class="o-pass">PASS<' in html
    assert ">0.9992<" in html and "[0.9981, 0.9998]" in html  # P(stable) and its interval
    assert "<td>40 … 95</td><td>rad/s</td>" in html  # critical band, its unit in the unit column
    assert ">truth<" in html and "CRB std" in html
    assert "current is 80% of the largest value" in html
    assert "line &#39;broken&#39; left out: 2 values for 200 x values" in html  # broken plot noted, not fatal
    nogo = built["nogo"]["html"].read_text(encoding="utf-8")
    assert "<td>9 … inf</td><td>rad/s</td>" in nogo and "<td>12.5 (1.989 Hz)</td><td>rad/s</td>" in nogo
    assert 'class="o-fail">YES<' in nogo and 'class="o-fail">violated<' in nogo
    err = built["error"]["html"].read_text(encoding="utf-8")
    assert "has no channel motor.velocity" in err and ">NaN<" in err


def _chromium_shot(html: Path, tmp_path: Path) -> tuple[Path, str]:
    exe = _tool("chromium", "chromium-browser", "google-chrome")
    png = tmp_path / f"{html.parent.name}.png"
    profile = tmp_path / f"profile-{html.parent.name}"
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--host-resolver-rules=MAP * ~NOTFOUND", f"--user-data-dir={profile}", "--enable-logging=stderr",
           "--v=0", f"--screenshot={png}", "--window-size=1280,2000", html.resolve().as_uri()]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert png.exists(), f"no screenshot (exit {p.returncode}): {p.stderr[-2000:]}"
    return png, p.stderr


def _console_errors(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if "Uncaught" in ln or "CONSOLE" in ln]


def test_console_error_detection_is_not_vacuous(tmp_path):
    d = tmp_path / "bad"
    d.mkdir()
    (d / "page.html").write_text("<!DOCTYPE html><p>x</p><script>undefinedFunction();</script>")
    _, stderr = _chromium_shot(d / "page.html", tmp_path)
    assert _console_errors(stderr), stderr[-2000:]


@pytest.mark.parametrize("key", ["go", "error"])
def test_html_renders_in_headless_chromium(built, key, tmp_path):
    png, stderr = _chromium_shot(built[key]["html"], tmp_path)
    assert png.stat().st_size > 20_000
    assert not _console_errors(stderr), _console_errors(stderr)
    std, img = _png_stats(png)
    assert img.shape[0] >= 1500 and img.shape[1] >= 1200
    assert std > 0.05  # not a blank page
    decision = CERTS[key]().decision
    assert _colour_pixels(img, COLOURS[decision]) > 2000  # the decision badge is drawn in its colour
    if decision == "ERROR":
        assert _colour_pixels(img, COLOURS["NO-GO"]) < 200  # ERROR is not painted like NO-GO


# ---------------------------------------------------------------------------------------------
# PDF


def _pdftext(pdf: Path) -> str:
    exe = _tool("pdftotext")
    return subprocess.run([exe, "-layout", str(pdf), "-"], capture_output=True, text=True, timeout=30,
                          check=True).stdout


@pytest.mark.parametrize("key", list(CERTS))
def test_pdf_has_only_present_sections(built, key):
    text = _pdftext(built[key]["pdf"])
    cert = CERTS[key]()
    assert "Stability certificate" in text and "Review and signature" in text
    assert cert.decision in text and "Measurements" in text and "Policy" in text
    for sec, heading in SECTIONS.items():
        assert (heading in text) == (sec in PRESENT[key]), sec
    for m in cert.measurements:
        assert m.name in text
    for r in cert.reasons[:1]:
        assert r.split()[0] in text


@pytest.mark.parametrize("key", list(CERTS))
def test_pdf_rasterizes(built, key, tmp_path):
    exe = _tool("pdftoppm")
    subprocess.run([exe, "-png", "-r", "50", str(built[key]["pdf"]), str(tmp_path / "page")], check=True,
                   timeout=60, capture_output=True)
    pages = sorted(tmp_path.glob("page-*.png"))
    assert len(pages) >= 2  # the signable summary, then the evidence flowing on the next pages
    for pg in pages:
        assert pg.stat().st_size > 3000
        assert _png_stats(pg)[0] > 0.02
    _, title = _png_stats(pages[0])
    assert _colour_pixels(title, COLOURS[CERTS[key]().decision], 0.08) > 100  # decision badge on page 1


#: a page (other than the last) must be filled at least this far down by content: sections flow
#: onto pages (a figure that does not fit floats after the next tables, or shrinks to 72 %), so a
#: page is only cut short when a whole figure plus the table rows around it cannot fill it
MIN_PAGE_FILL = 0.6
#: the last page holds at least the end of the evidence table (the integrity block)
MIN_LAST_PAGE_FILL = 0.12


def page_fills(pdf: Path, top_in: float = 0.7, bottom_in: float = 0.7) -> list[float]:
    """Per page, how far down the body (between the running header and footer, ``top_in`` and
    ``bottom_in`` inches from the edges) its content reaches, as a fraction of the body height: the
    lowest word that pdftotext finds (tables, paragraphs and the tick labels of figures are text)."""
    exe = _tool("pdftotext")
    xml = subprocess.run([exe, "-bbox", str(pdf), "-"], capture_output=True, text=True, timeout=60,
                         check=True).stdout
    out = []
    for _w, h, body in re.findall(r'<page width="([\d.]+)" height="([\d.]+)">(.*?)</page>', xml, re.S):
        t0, t1 = top_in * 72, float(h) - bottom_in * 72
        ys = [(float(a), float(b)) for a, b in re.findall(r'yMin="([\d.]+)" xMax="[\d.]+" yMax="([\d.]+)"', body)]
        ys = [(a, b) for a, b in ys if a > t0 and b < t1]
        out.append(0.0 if not ys else (max(b for _, b in ys) - t0) / (t1 - t0))
    return out


def assert_pages_carry_content(pdf: Path) -> list[float]:
    fills = page_fills(pdf)
    assert fills, "no pages"
    for i, f in enumerate(fills[:-1]):
        assert f >= MIN_PAGE_FILL, f"page {i + 1} of {len(fills)} is only {f:.0%} full: {fills}"
    assert fills[-1] >= MIN_LAST_PAGE_FILL, fills
    return fills


def test_page_fill_detects_a_near_empty_page(tmp_path):
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure

    pdf = tmp_path / "two.pdf"
    with PdfPages(pdf) as pp:
        for frac in (0.95, 0.2):
            fig = Figure(figsize=(8.27, 11.69))
            for k in range(12):
                y = 11.69 - 0.9 - k * (11.69 - 1.6) * frac / 11
                fig.text(0.1, y / 11.69, f"line {k}")
            pp.savefig(fig)
    fills = page_fills(pdf)
    assert fills[0] > 0.9 and fills[1] < 0.25, fills


@pytest.mark.parametrize("key", list(CERTS))
def test_pdf_pages_carry_content(built, key):
    assert_pages_carry_content(built[key]["pdf"])


def test_pdf_paginates_a_long_measurement_table(tmp_path):
    cert = error_cert()
    cert.measurements = [cert.measurements[0].model_copy(update={
        "name": f"m{i:03d}_" + "x" * (i % 7), "description": "a long description " * (1 + i % 4)})
        for i in range(150)]
    pdf = render_pdf(cert, tmp_path / "long.pdf")
    text = _pdftext(pdf)
    assert "m000_" in text and "m149_" in text and "(table continued)" in text
    pages = text.count("\f")
    assert pages >= 4


# ---------------------------------------------------------------------------------------------
# hil report


def test_hil_report_rebuilds_from_stored_record(built, tmp_path, capsys):
    src = built["nogo"]["json"]
    folder = tmp_path / "stored"
    folder.mkdir()
    shutil.copy(src, folder / "certificate.json")
    assert hil_main(["report", str(folder)]) == 0
    assert (folder / "report.html").stat().st_size > 10_000 and (folder / "report.pdf").stat().st_size > 10_000
    out = tmp_path / "elsewhere"
    assert hil_main(["report", str(folder / "certificate.json"), "--out", str(out)]) == 0
    assert (out / "report.html").read_text(encoding="utf-8") == (folder / "report.html").read_text(encoding="utf-8")
    assert "NO-GO bilateral_2dof_B" in capsys.readouterr().out


@pytest.mark.parametrize("argv_fn", [
    lambda d: [str(d / "certificate.json")],  # malformed
    lambda d: [str(d / "missing")],  # no such file
    lambda d: [],  # no PATH
    lambda d: [str(d), "--bogus"],
])
def test_hil_report_errors_exit_2_with_one_line(tmp_path, capsys, argv_fn):
    (tmp_path / "certificate.json").write_text('{"decision": "GO", "reasons": 3}')
    assert hil_main(["report", *argv_fn(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hil report: error: ") and err.count("\n") == 1, err
    assert not (tmp_path / "report.html").exists()


def test_render_functions_return_paths_and_create_folders(tmp_path):
    cert = error_cert()
    h = render_html(cert, tmp_path / "a" / "b" / "r.html")
    p = render_pdf(cert, tmp_path / "c" / "r.pdf")
    assert h.is_file() and p.is_file() and p.read_bytes().startswith(b"%PDF")


def test_module_imports_neither_matplotlib_nor_jinja2():
    code = "import sys, hil.report.render; print(sorted(m for m in ('matplotlib', 'jinja2') if m in sys.modules))"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert p.stdout.strip() == "[]"
