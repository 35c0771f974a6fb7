"""Each report figure is drawn once and serves both documents (issue 26, item 3): the PDF draws it on
its page, and the HTML shows that very drawing (cropped to PNG), instead of a second drawing of its
own; the PDF's fonts are embedded once per document (not per page); the reports of an ERROR
certificate are short (no figures)."""

from __future__ import annotations

import base64
import re
import subprocess

import pytest

pytest.importorskip("matplotlib")
pytest.importorskip("jinja2")

from test_report import _tool, error_cert, sdea_go

import hil.report.drawing as D
import hil.report.pdf as P
import hil.report.render as R
from hil.report.sections import report_sections


def _count(monkeypatch, name: str) -> list[str]:
    """Count the calls of the drawing function ``name`` wherever the report modules call it (the
    PDF's pages, and the HTML's own drawings when it has none from the PDF)."""
    calls: list[str] = []
    real = getattr(D, name)

    def counted(fig, s_or_cert, *a, **k):
        calls.append(getattr(s_or_cert, "title", name))
        return real(fig, s_or_cert, *a, **k)

    for mod in (D, P):
        monkeypatch.setattr(mod, name, counted)
    return calls


def test_every_figure_is_drawn_once_for_both_documents(tmp_path, monkeypatch):
    cert = sdea_go()
    plots = _count(monkeypatch, "draw_plot")
    charts = _count(monkeypatch, "draw_chart")
    files = R.build_reports(cert, tmp_path)
    drawn = {b.plot for sec in report_sections(cert) for b in sec.blocks if b.kind == "figure"}
    assert len(plots) == len(drawn) == len(cert.plots)  # once each (it was twice: PNG for HTML, vectors for PDF)
    assert len(charts) <= 1
    html = files["html"].read_text(encoding="utf-8")
    imgs = re.findall(r'<img src="data:image/png;base64,([^"]+)"', html)
    assert len(imgs) == len(drawn) + len(charts)
    for b64 in imgs:  # real PNG images
        assert base64.b64decode(b64)[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_html_alone_still_draws_its_figures(tmp_path, monkeypatch):
    """render_html without the PDF's drawings (the API, used alone) draws each figure itself."""
    cert = sdea_go()
    plots = _count(monkeypatch, "draw_plot")
    R.render_html(cert, tmp_path / "r.html")
    assert len(plots) == len(cert.plots)


def _fonts(pdf) -> list[str]:
    out = subprocess.run([_tool("pdffonts"), str(pdf)], capture_output=True, text=True, check=True,
                         timeout=60).stdout.splitlines()[2:]
    return sorted(line.split()[0].split("+", 1)[-1] for line in out if line.strip())


def test_fonts_are_embedded_once_per_document_not_per_page(tmp_path):
    short = error_cert()
    long = error_cert()
    long.measurements = [long.measurements[0].model_copy(update={"name": f"row {i}", "description": "x" * 60})
                         for i in range(400)]
    a = R.render_pdf(short, tmp_path / "short.pdf")
    b = R.render_pdf(long, tmp_path / "long.pdf")
    pages = [int(re.search(r"Pages:\s+(\d+)", subprocess.run([_tool("pdfinfo"), str(p)], capture_output=True,
                                                             text=True, check=True).stdout).group(1))
             for p in (a, b)]
    assert pages[1] >= pages[0] + 5
    # each font is embedded (subset) once for the whole document, not once per page: a few entries per
    # face (matplotlib writes a face's glyphs in at most two subsets), however many pages use it
    for fonts, n in ((_fonts(a), pages[0]), (_fonts(b), pages[1])):
        counts = {f: fonts.count(f) for f in fonts}
        assert max(counts.values()) <= 2, (counts, n)
    assert set(_fonts(a)) <= set(_fonts(b))


def test_an_error_certificate_has_a_short_report(tmp_path, monkeypatch):
    cert = error_cert()
    cert.plots = dict(sdea_go().plots)  # figures the broken evidence left behind
    plots = _count(monkeypatch, "draw_plot")
    files = R.build_reports(cert, tmp_path)
    assert plots == []  # no figure is drawn
    assert "<img" not in files["html"].read_text(encoding="utf-8")
    info = subprocess.run([_tool("pdfinfo"), str(files["pdf"])], capture_output=True, text=True, check=True).stdout
    assert int(re.search(r"Pages:\s+(\d+)", info).group(1)) <= 3
