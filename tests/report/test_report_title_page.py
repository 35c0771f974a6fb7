"""Page 1 of the PDF is one page a person can sign alone: the summary and the signature block
(Reviewed by / Approved by, Name, Date, Signature). A long scene description (the built-in scenes
name their papers in it) shrinks page 1's flowing text rather than push the signature block alone
onto page 2 (found on sdea_bench: page 2 held only the signature block, 12 % full)."""

from __future__ import annotations

import logging
import subprocess
from pathlib import Path

import pytest

pytest.importorskip("matplotlib")

from test_report import _tool, assert_pages_carry_content, sdea_go

from hil.certify.certificate import Certificate, seal
from hil.report import pdf as render  # the PDF layout (hil.report.pdf)

SENTENCE = ("SDEA of the SDEA paper's Table I, Mengilli et al., with an ODrive motor on a virtual CAN bus and the "
            "spring torque from a Bota sensor on a pty; ")


def _with_description(n_sentences: int) -> Certificate:
    """The GO certificate of test_report with a description of ``n_sentences`` sentences, sealed
    (its digest holds: no MODIFIED banner or watermark on the pages)."""
    c = sdea_go()
    return seal(c.model_copy(update={"scene": c.scene.model_copy(
        update={"description": SENTENCE * n_sentences})}))


def _page_text(pdf: Path, page: int) -> str:
    return subprocess.run([_tool("pdftotext"), "-layout", "-f", str(page), "-l", str(page), str(pdf), "-"],
                          capture_output=True, text=True, timeout=30, check=True).stdout


def _signature_page(pdf: Path) -> int:
    """The page whose text holds the signature block (both columns and their lines)."""
    for page in (1, 2):
        text = _page_text(pdf, page)
        if all(w in text for w in ("Reviewed by", "Approved by", "Name", "Date", "Signature")):
            return page
    raise AssertionError("no signature block on pages 1-2")


def _overflowing_length() -> int:
    """The fewest description sentences at which page 1 at full text size no longer holds the
    signature block (laid out without writing)."""
    for n in range(1, 40):
        trial = render._PdfDoc(render._NoPages(), _with_description(n))
        render._pdf_title_page(trial, _with_description(n), 1.0)
        if trial.page > 1:
            return n
    raise AssertionError("page 1 never overflows")


def test_a_long_description_keeps_the_signature_block_on_page_1(tmp_path, monkeypatch):
    n = _overflowing_length()
    cert = _with_description(n)
    assert render.title_text_scale(cert) is not None and render.title_text_scale(cert) < 1.0
    pdf = render.render_pdf(cert, tmp_path / "fit.pdf")
    assert _signature_page(pdf) == 1
    assert "Measurements" in _page_text(pdf, 2)  # page 2 starts the evidence
    assert_pages_carry_content(pdf)
    # the same certificate at full text size only (the layout before the fix): the signature block
    # alone on page 2, which the page-fill rule refuses
    monkeypatch.setattr(render, "TITLE_TEXT_SCALES", (1.0,))
    old = render.render_pdf(cert, tmp_path / "old.pdf")
    assert _signature_page(old) == 2
    with pytest.raises(AssertionError, match="page 2 of"):
        assert_pages_carry_content(old)


def test_a_short_description_keeps_full_size_text():
    assert render.title_text_scale(_with_description(1)) == 1.0


def test_a_description_too_long_for_any_scale_flows_on_and_says_so(tmp_path, caplog):
    cert = _with_description(3 * _overflowing_length() + 10)
    assert render.title_text_scale(cert) is None
    with caplog.at_level(logging.WARNING, logger="hil.report.render"):
        pdf = render.render_pdf(cert, tmp_path / "long.pdf")
    assert _signature_page(pdf) == 2 and "does not hold its signature block" in caplog.text
