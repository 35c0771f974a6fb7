"""The PDF report for signing (:func:`render_pdf`): matplotlib ``PdfPages`` only, a small page-flow
layout (:class:`PdfDoc`: headings, wrapped paragraphs, monospaced tables that continue on the next
page), a title page with the decision and what it rests on (its text shrinks, :data:`TITLE_TEXT_SCALES`,
rather than push the signature block to page 2), one page flow per section, the figures drawn once on
their pages."""

from __future__ import annotations

import base64
import io
import logging
import math
import os
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hil.certify.certificate import Certificate, Series
from hil.certify.verify import MODIFIED, IntegrityStatus
from hil.report.common import (
    BENCH_STYLE,
    OUTCOME_STYLE,
    SECTION_TITLES,
    ReportError,
    _digest_text,
    _evidence_note,
    _one_line,
    _outcome_counts,
    _status,
    _style,
    bench_banner,
)
from hil.report.drawing import HTML_DPI, _mtext, _Plot, _plot_height, chart_height, draw_chart, draw_plot, draw_pstable
from hil.report.sections import (
    Section,
    Table,
    _status_outcome,
    definition_link,
    fmt,
    fmt_p,
    fmt_signed,
    headroom,
    margin_note,
    measurements_table,
    policy_label,
    report_sections,
    robust_status,
)

logger = logging.getLogger(__name__)

__all__ = [
    "TITLE_TEXT_SCALES",
    "render_pdf",
    "summary_rows",
    "title_text_scale",
]


# ---------------------------------------------------------------------------------------------
# PDF (matplotlib text layout on A4 pages)


_MONO = ["DejaVu Sans Mono", "DejaVu Sans"]  # fallback for glyphs the mono face lacks (e.g. ⪰)
_SANS = ["DejaVu Sans"]


class _PdfDoc:
    """A tiny page-flow layout on matplotlib figures: headings, wrapped paragraphs and monospaced
    tables that continue on the next page (header row repeated). Coordinates in inches."""

    W, H = 8.27, 11.69
    ML, MR, MT, MB = 0.75, 0.75, 0.85, 0.8
    MONO_EM = 0.602  # DejaVu Sans Mono advance width per em
    SANS_EM = 0.56  # a conservative average for DejaVu Sans

    def __init__(self, pdf: Any, cert: Certificate, integrity: IntegrityStatus | None = None) -> None:
        self.pdf = pdf
        self.cert = cert
        self.integrity = _status(cert, integrity)
        self.modified = not self.integrity.valid
        self.style = _style(cert, self.integrity)
        self.fig: Any = None
        self.page = 0
        self.y = 0.0
        self.section = ""
        self.captions: dict[int, tuple[str, str | None]] = {}  # id(figure Series) -> (caption, definition link)
        self.keys: dict[int, str] = {}  # id(figure Series) -> its plot key
        #: key -> the figure as drawn on its PDF page, cropped to PNG for the HTML (one draw, two files);
        #: None: not collected
        self.images: dict[str, _Plot] | None = None
        self.current_section = ""

    @property
    def width(self) -> float:
        return self.W - self.ML - self.MR

    # pages
    def new_page(self, section: str | None = None) -> None:
        from matplotlib.figure import Figure

        self.flush()
        if section is not None:
            self.section = section
        self.page += 1
        self.fig = Figure(figsize=(self.W, self.H))
        c = self.cert
        bg, fg = self.style[1:]
        st = self.integrity
        self._t(self.ML, self.H - 0.45, f"hil-certify certificate · scene {c.scene.name} · {bench_banner(c)[0]}", 8,
                color="#555555")
        self._t(self.W - self.MR, self.H - 0.45, f" {c.decision} " if not self.modified else " MODIFIED ", 8,
                weight="bold", color=fg, ha="right",
                bbox={"boxstyle": "round,pad=0.25", "facecolor": bg, "edgecolor": "none"})
        self._hrule(self.H - 0.58, "#bbbbbb")
        dg = st.recorded_digest[:16] + "…" if st.recorded_digest else "none"
        self._t(self.ML, 0.45, f"created {c.created_utc} · digest sha256 {dg}", 7, color="#777777")
        self._t(self.W - self.MR, 0.45, f"page {self.page}", 7, color="#777777", ha="right")
        self.y = self.H - self.MT
        if self.modified:
            self._void_marks()

    def _void_marks(self) -> None:
        """MODIFIED: NOT A VALID CERTIFICATE, as a banner under the header and across the page."""
        self.fig.text(0.5, 0.5, MODIFIED, fontsize=30, weight="bold", color="#c62828", alpha=0.2, rotation=55,
                      ha="center", va="center", transform=self.fig.transFigure, zorder=10)
        y = self.H - self.MT + 0.02
        self._rect(self.ML - 0.04, y - 0.36, self.width + 0.08, 0.42, "#f8d0d0")
        self._t(self.ML + 0.04, y - 0.16, MODIFIED, 11, weight="bold", color="#8e1616")
        why = _one_line(self.integrity.reason())
        chars = int((self.width - 0.1) * 72 / (self.SANS_EM * 6.5))
        self._t(self.ML + 0.04, y - 0.31, why if len(why) <= chars else why[: chars - 1] + "…", 6.5, color="#8e1616")
        self.y = y - 0.5

    def flush(self) -> None:
        if self.fig is not None:
            self.pdf.savefig(self.fig)
            self.fig = None

    def ensure(self, h: float) -> bool:
        """Start a new page unless ``h`` inches fit; True if a page was started."""
        if self.fig is None or self.y - h < self.MB:
            self.new_page()
            return True
        return False

    # primitives
    def _t(self, x: float, y: float, s: str, size: float, **kw: Any) -> Any:
        return self.fig.text(x, y, _mtext(s), fontsize=size, transform=self.fig.dpi_scale_trans,
                             va=kw.pop("va", "baseline"), **kw)

    def _hrule(self, y: float, colour: str = "#999999", lw: float = 0.6, x0: float | None = None,
               x1: float | None = None) -> None:
        from matplotlib.lines import Line2D

        x0 = self.ML if x0 is None else x0
        x1 = self.W - self.MR if x1 is None else x1
        self.fig.add_artist(Line2D([x0, x1], [y, y], color=colour, linewidth=lw, transform=self.fig.dpi_scale_trans))

    def _rect(self, x: float, y: float, w: float, h: float, colour: str) -> None:
        from matplotlib.patches import Rectangle

        self.fig.add_artist(Rectangle((x, y), w, h, facecolor=colour, edgecolor="none",
                                      transform=self.fig.dpi_scale_trans, zorder=0))

    @staticmethod
    def _lh(size: float) -> float:
        return size * 1.38 / 72.0

    # flow elements
    def space(self, h: float = 0.12) -> None:
        self.y -= h

    def heading(self, s: str, size: float = 14) -> None:
        self.ensure(self._lh(size) + 0.95)  # keep a heading with what follows (a table header and two rows)
        self.y -= self._lh(size)
        self._t(self.ML, self.y, s, size, weight="bold", color="#1d2733")
        self.y -= 0.08
        self._hrule(self.y, "#1d2733", 0.8)
        self.y -= 0.16

    def subheading(self, s: str, size: float = 11) -> None:
        if not self.ensure(self._lh(size) + 0.6):
            self.y -= 0.12
        self.y -= self._lh(size)
        self._t(self.ML, self.y, s, size, weight="bold", color="#1d2733")
        self.y -= 0.08

    def para(self, s: str, size: float = 10, indent: float = 0.0, **kw: Any) -> None:
        chars = max(20, int((self.width - indent) * 72 / (self.SANS_EM * size)))
        for line in textwrap.wrap(_one_line(s), chars) or [""]:
            self.ensure(self._lh(size))
            self.y -= self._lh(size)
            self._t(self.ML + indent, self.y, line, size, **kw)
        self.y -= 0.08

    def bullets(self, items: Sequence[str], size: float = 10) -> None:
        chars = max(20, int((self.width - 0.25) * 72 / (self.SANS_EM * size)))
        for item in items:
            lines = textwrap.wrap(_one_line(item), chars) or [""]
            for j, line in enumerate(lines):
                self.ensure(self._lh(size))
                self.y -= self._lh(size)
                if j == 0:
                    self._t(self.ML + 0.08, self.y, "•", size)
                self._t(self.ML + 0.25, self.y, line, size)
            self.y -= 0.03

    def table(self, headers: Sequence[str], rows: Sequence[Sequence[str]],
              cell_colours: Sequence[Sequence[str | None]] | None = None, size: float = 8.0,
              min_col: int = 5, nowrap: Sequence[bool] | None = None, header_links: Sequence[str | None] | None = None,
              row_links: Sequence[str | None] | None = None) -> None:
        """A monospaced table; columns shrink (cells wrap) to the page width, rows continue on
        the next page with the header row repeated. A ``nowrap`` column keeps its widest cell on
        one line (condition names); ``header_links`` / ``row_links`` (first cell) link to the
        definitions."""
        ncol = len(headers)
        cells = [[_one_line(c) for c in r] for r in rows]
        gap = 2
        natural = [max(1, len(headers[j]), *(len(r[j]) for r in cells)) for j in range(ncol)]
        # a column is not narrowed below its longest word (numbers never break), up to 16 characters;
        # a no-wrap column not below its widest cell
        floor = [max(min_col, min(16, max(len(w) for c in [headers[j], *(r[j] for r in cells)]
                                          for w in (c.split() or [""])))) for j in range(ncol)]
        for j in range(ncol):
            if nowrap is not None and nowrap[j]:
                floor[j] = max(floor[j], *(len(r[j]) for r in cells)) if cells else floor[j]
        while True:
            avail = int(self.width * 72 / (self.MONO_EM * size)) - 1
            widths = list(natural)
            for lim in (floor, [min_col] * ncol):  # shrink to the floors first; hard breaks only at 6 pt
                while sum(widths) + gap * (ncol - 1) > avail:
                    cand = [i for i in range(ncol) if widths[i] > min(lim[i], natural[i])]
                    if not cand:
                        break
                    j = max(cand, key=lambda i: widths[i])
                    widths[j] -= 1
                if sum(widths) + gap * (ncol - 1) <= avail or size > 6.0:
                    break
            if sum(widths) + gap * (ncol - 1) <= avail or size <= 6.0:
                break
            size -= 0.5
        char_w = self.MONO_EM * size / 72.0
        xs = [self.ML]
        for w in widths[:-1]:
            xs.append(xs[-1] + (w + gap) * char_w)
        lh = self._lh(size)
        pad = 0.03

        def wrap(s: str, w: int) -> list[str]:
            return textwrap.wrap(s, w, break_long_words=True, break_on_hyphens=False) or [""]

        head = [wrap(h, widths[j]) for j, h in enumerate(headers)]
        head_h = max(len(h) for h in head) * lh + 2 * pad

        def draw_header() -> None:
            self._rect(self.ML - 0.04, self.y - head_h, self.width + 0.08, head_h, "#dfe3e8")
            for j, hl in enumerate(head):
                link = header_links[j] if header_links else None
                for i, line in enumerate(hl):
                    t = self._t(xs[j], self.y - pad - (i + 1) * lh + 0.25 * lh, line, size, family=_MONO,
                                weight="bold", color="#0b3d91" if link else "#000000")
                    if link:
                        t.set_url(link)
            self.y -= head_h

        self.ensure(head_h + lh + 2 * pad)
        draw_header()
        for r_i, r in enumerate(cells):
            wrapped = [wrap(c, widths[j]) for j, c in enumerate(r)]
            h = max(len(w) for w in wrapped) * lh + 2 * pad
            if self.ensure(h):
                self._t(self.ML, self.y - lh, "(table continued)", 8, color="#777777", style="italic")
                self.y -= lh + 0.06
                draw_header()
            if r_i % 2:
                self._rect(self.ML - 0.04, self.y - h, self.width + 0.08, h, "#f4f6f8")
            for j, wl in enumerate(wrapped):
                colour = cell_colours[r_i][j] if cell_colours else None
                if colour:
                    self._rect(xs[j] - 0.04, self.y - h, widths[j] * char_w + 0.08, h, colour)
                link = row_links[r_i] if (row_links and j == 0) else None
                for i, line in enumerate(wl):
                    t = self._t(xs[j], self.y - pad - (i + 1) * lh + 0.25 * lh, line, size, family=_MONO,
                                color="#0b3d91" if link else "#000000")
                    if link:
                        t.set_url(link)
            self.y -= h
        self._hrule(self.y, "#bbbbbb", 0.5)
        self.y -= 0.14

    def kv(self, pairs: Sequence[tuple[str, str]], size: float = 9.0) -> None:
        self.table(["quantity", "value"], [list(p) for p in pairs], size=size)

    def model_table(self, t: Table) -> None:
        """A table of the report model (units in the headers, outcome colours, definition links)."""
        colours = None
        if t.colours:
            colours = [[OUTCOME_STYLE[o][1] if o in OUTCOME_STYLE else None for o in row] for row in t.colours]
        row_links = [definition_link(f) for f in t.row_fields] if t.row_fields else None
        self.table([c.header for c in t.columns], t.rows, colours, size=t.size,
                   nowrap=[c.nowrap for c in t.columns], header_links=[c.link for c in t.columns],
                   row_links=row_links)

    def pstable(self, cert: Certificate) -> None:
        h = 1.5
        self.ensure(h + 0.1)
        ax = self.fig.add_axes((self.ML / self.W, (self.y - h + 0.45) / self.H, self.width / self.W,
                                (h - 0.75) / self.H))
        draw_pstable(ax, cert)
        self.y -= h + 0.05

    def fits(self, s: Series) -> bool:
        """Would the plot and its caption fit (the plot possibly shrunk to 72 %) in the space left on
        this page?"""
        h = min(_plot_height(s), self.H - self.MT - self.MB - 0.6)
        cap = self.caption_height(*self.captions.get(id(s), ("", None)))
        return self.fig is not None and 0.72 * h + cap <= self.y - self.MB - 0.25

    def caption(self, text: str, link: str | None) -> None:
        """A figure caption, with the link to the definition of what it shows."""
        if text:
            self.para(text, 7.5, color="#444444")
        if link:
            self.ensure(self._lh(7.5))
            self.y -= self._lh(7.5)
            t = self._t(self.ML, self.y, f"Definition: {link}", 7.5, color="#0b3d91")
            t.set_url(link)
            self.y -= 0.06

    def caption_height(self, text: str, link: str | None) -> float:
        chars = max(20, int(self.width * 72 / (self.SANS_EM * 7.5)))
        n = (len(textwrap.wrap(_one_line(text), chars)) if text else 0) + (1 if link else 0)
        return n * self._lh(7.5) + 0.14

    def chart(self, cert: Certificate, key: str, caption: str = "", link: str | None = None) -> None:
        """A chart drawn from the record (:func:`draw_chart`) in the flow, with its caption."""
        h = chart_height(cert, key)
        if h <= 0:
            return
        self.ensure(h + self.caption_height(caption, link) + 0.1)
        rect = (self.ML, self.y - h, self.width, h)
        before = self._artists()
        draw_chart(self.fig, cert, key, rect)
        self._keep_image(f"chart:{key}", caption, rect, before, [])
        self.y -= h
        self.caption(caption, link)
        self.space(0.1)

    # one draw, two files: the figure drawn on the PDF page is also the HTML's image
    def _artists(self) -> list[Any]:
        f = self.fig
        return [*f.axes, *f.texts, *f.artists, *f.patches, *f.lines, *f.images, *f.subfigs]

    def _keep_image(self, key: str, title: str, rect: tuple[float, float, float, float], before: list[Any],
                    notes: list[str]) -> None:
        """Save what was just drawn in ``rect`` of the page as PNG (the page's other artists hidden
        for the moment), so the HTML shows the very figure the PDF holds, drawn once."""
        if self.images is None:
            return
        import warnings

        from matplotlib.transforms import Bbox

        hidden = [a for a in before if a.get_visible()]
        for a in hidden:
            a.set_visible(False)
        buf = io.BytesIO()
        try:
            x, y, w, h = rect
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", category=UserWarning)
                self.fig.savefig(buf, format="png", dpi=HTML_DPI, facecolor="white",
                                 bbox_inches=Bbox.from_bounds(x - 0.05, y - 0.05, w + 0.1, h + 0.1))
        finally:
            for a in hidden:
                a.set_visible(True)
        self.images[key] = _Plot(key.removeprefix("chart:"), title, base64.b64encode(buf.getvalue()).decode("ascii"),
                                 list(notes))

    def figure(self, s: Series, caption: str = "", link: str | None = None) -> None:
        """A plot in the flow, 6.8 in wide; its height follows its panels."""
        cap = self.caption_height(caption, link)
        h = min(_plot_height(s), self.H - self.MT - self.MB - 0.6 - cap)
        room = self.y - self.MB - 0.25 - cap
        if self.fig is not None and 0.72 * h <= room < h:
            h = room - 0.02  # shrink a little rather than leave most of a page empty
        self.ensure(h + 0.25 + cap)  # the caption stays with its figure
        rect = (self.ML, self.y - h, self.width, h)
        before = self._artists()
        notes = draw_plot(self.fig, s, rect)
        key = self.keys.get(id(s))
        if key is not None:
            self._keep_image(key, s.title, rect, before, notes)
        self.y -= h
        self.caption(caption, link)
        for n in notes:
            self.para(f"Note: {n}", 8, color="#8a5a00")
        self.space(0.1)


def _decisive_row(cert: Certificate) -> Any:
    """The nominal condition that decides (violated with the smallest margin, else the smallest)."""
    n = cert.nominal
    if n is None:
        return None
    conds = [c for c in n.conditions if isinstance(c.margin, int | float) and math.isfinite(c.margin)
             and c.name not in ("A", "B", "A*")]
    failed = [c for c in conds if _status_outcome(c.status) == "FAIL"]
    pool = failed or conds
    return min(pool, key=lambda c: float(c.margin) if isinstance(c.margin, int | float) else math.inf) if pool \
        else None


def summary_rows(cert: Certificate, st: IntegrityStatus) -> list[tuple[str, str, str, str | None]]:
    """The one-page summary: (quantity, value, unit, field path) of what the decision rests on."""
    rows: list[tuple[str, str, str, str | None]] = [("decision", cert.decision, "—", "decision")]
    r = cert.robust
    if r is not None:
        status, _ = robust_status(cert)
        rows.append((f"P(stable) and its {r.confidence:.0%} interval",
                     f"{fmt_p(r.p_stable)} [{fmt_p(r.lower)}, {fmt_p(r.upper)}] ({status})", "1", "robust.p_stable"))
        rows.append(("required: the lower bound must clear", fmt_p(r.required), "1", "robust.required"))
        rows.append((f"worst-case margin ({r.credible:.0%} credible region)", fmt(r.worst_case_margin), "1",
                     "robust.worst_case_margin"))
        rel = r.reliability
        if rel is not None:
            rows.append(("reliability index β", f"{'≥ ' if rel.censored else ''}{fmt(rel.beta)} (a GO needs ≥ "
                                                 f"{fmt(rel.required_beta)}; Φ(β) = {fmt_p(rel.phi_beta)})", "1",
                         "robust.reliability.beta"))
        ev = r.rare_event
        if ev is not None:
            rows.append((f"P(stable) by importance sampling, {ev.confidence:.0%} interval",
                         f"{fmt_p(ev.p_stable)} [{fmt_p(ev.lower)}, {fmt_p(ev.upper)}]"
                         + ("" if ev.reliable else " (not reliable: nothing certified)"), "1", "robust.rare_event"))
    n = cert.nominal
    if n is not None:
        rows.append(("nominal verdict", n.verdict + (" (weak)" if n.weak else ""), "—", "nominal.verdict"))
        rows.append(("nominal margin", fmt(n.margin), "1", "nominal.margin"))
        dc = _decisive_row(cert)
        if dc is not None:
            rows.append(("decisive condition", f"{dc.name} ({dc.status}, margin {fmt(dc.margin)})", "—",
                         "nominal.failed_condition"))
    d = cert.design
    if d is not None and d.max_value is not None:
        rows.append((f"largest {d.parameter} meeting the requirement", fmt(d.max_value), d.unit or "—",
                     "design.max_value"))
        if d.current is not None:
            rows.append((f"current {d.parameter}", fmt(d.current) + (f" ({headroom(d)})" if headroom(d) else ""),
                         d.unit or "—", "design.current"))
    if d is not None and (d.nominal_headroom is not None or d.posterior_headroom is not None):
        rows.append((f"{d.parameter} headroom: nominal, posterior",
                     f"{fmt_signed(d.nominal_headroom)}, {fmt_signed(d.posterior_headroom)}", "1",
                     "design.posterior_headroom"))
    w = cert.witness
    if w is not None:
        from hil.certify.units import termination_units

        terms = []
        for t in w.terminations.values():
            if isinstance(t, dict) and "params" in t:
                tu = termination_units(t["params"], w.units or cert.scene.units)
                terms.append(f"{t.get('kind')} " + ", ".join(f"{k} = {fmt(v)} {tu.get(k, '')}".rstrip()
                                                              for k, v in t["params"].items()))
        rows.append(("destabilizing passive termination", "; ".join(terms) or "—", "—", "witness.terminations"))
        if w.growth_rate_1_s is not None:
            rows.append(("closed-loop growth rate σ", fmt(w.growth_rate_1_s), "1/s", "witness.growth_rate_1_s"))
        if w.time_to_limit_s is not None:
            rows.append((f"time to exceed the bench's {str(w.limit_exceeded).replace('_', ' ')}",
                         fmt(w.time_to_limit_s), "s", "witness.time_to_limit_s"))
    for e in cert.energy or []:
        rows.append((f"min port energy E_s ({e.experiment}, {e.port})",
                     f"{fmt(e.min_energy)} (noise bound {fmt(e.bound)})", "J", "energy.min_energy"))
    counts = _outcome_counts(cert)
    if counts:
        rows.append(("measurements", ", ".join(f"{k} {o}" for o, k in counts), "—", "measurements"))
    if cert.errors:
        rows.append(("errors", str(len(cert.errors)), "1", None))
    return rows


#: scales of page 1's flowing text (scene description, reasons, summary table, margin note, review
#: sentence; titles, banner and signature block keep their size), tried in turn until page 1 holds
#: the summary and the signature block; past the last one the signature block flows to page 2
TITLE_TEXT_SCALES = (1.0, 0.94, 0.88, 0.82)


class _NoPages:
    """Stands in for ``PdfPages`` in a trial layout: pages are counted, nothing is written."""

    def savefig(self, fig: Any) -> None:
        pass


def title_text_scale(cert: Certificate, integrity: IntegrityStatus | None = None) -> float | None:
    """The largest of :data:`TITLE_TEXT_SCALES` at which page 1 (summary and signature block) is one
    page, found by laying page 1 out without writing it; None if none fits."""
    for scale in TITLE_TEXT_SCALES:
        trial = _PdfDoc(_NoPages(), cert, integrity)
        _pdf_title_page(trial, cert, scale)
        if trial.page == 1:
            return scale
    return None


def _pdf_summary(doc: _PdfDoc, cert: Certificate) -> None:
    """Page 1: everything a signer needs, and the signature block, on one page: a long scene
    description or many reasons shrink page 1's flowing text (:func:`title_text_scale`) rather than
    push the signature block alone onto page 2."""
    scale = title_text_scale(cert, doc.integrity)
    if scale is None:
        logger.warning("page 1 of %s's report does not hold its signature block even at text scale %.2f",
                       cert.scene.name, TITLE_TEXT_SCALES[-1])
    _pdf_title_page(doc, cert, TITLE_TEXT_SCALES[-1] if scale is None else scale)


def _pdf_title_page(doc: _PdfDoc, cert: Certificate, scale: float = 1.0) -> None:
    """Lay out page 1 with its flowing text at ``scale`` times its size (see :data:`TITLE_TEXT_SCALES`)."""
    doc.new_page("title")
    bg, fg = doc.style[1:]
    doc.y -= 0.3
    doc._t(doc.ML, doc.y, "Stability certificate", 19, weight="bold", color="#1d2733")
    doc.y -= 0.34
    doc._t(doc.ML, doc.y, f"scene {cert.scene.name}", 12, color="#333333")
    doc._t(doc.W - doc.MR - 0.15, doc.y + 0.1, f"  {cert.decision}  ", 24, weight="bold", color=fg, ha="right",
           va="center", bbox={"boxstyle": "round,pad=0.35", "facecolor": bg, "edgecolor": "none"})
    doc.y -= 0.16
    _pdf_bench_banner(doc, cert)
    if cert.scene.description:
        doc.para(cert.scene.description, 7.5 * scale, color="#444444")
    doc.para(f"scene sha256 {cert.scene.sha256}" + (f" · source {cert.scene.source}" if cert.scene.source else "")
             + (f" · units {cert.scene.units} (SI)" if cert.scene.units else "")
             + f" · created {cert.created_utc} (UTC) · schema {cert.schema_version} · "
             + ", ".join(f"{k} {v}" for k, v in cert.software.items()), 6.5, color="#666666")
    doc.subheading("Reasons", 10)
    doc.bullets(cert.reasons or ["(no reasons recorded)"], 8.5 * scale)
    doc.subheading("Summary", 10)
    from hil.report.sections import _kv

    t = _kv(summary_rows(cert, doc.integrity))
    t.size = 8.0 * scale  # page 1 holds the summary and the signature block: one page a person can sign alone
    doc.model_table(t)
    if note := margin_note(cert):
        doc.y += 0.06
        doc.para(note, 7.5 * scale, color="#333333")
    st = doc.integrity
    doc.subheading("Review and signature", 10)
    doc.kv([("digest (sha256, hil-c14n/1)", _digest_text(st)), ("electronic signature", st.signature_text())],
           size=6.5)
    doc.para(f"I have reviewed this certificate for scene {cert.scene.name} (digest above), its evidence on the "
             "following pages, and I accept the decision above.", 8 * scale)
    # two signature columns side by side
    doc.ensure(1.15)
    col_w = (doc.width - 0.3) / 2
    top = doc.y
    for k, role in enumerate(("Reviewed by", "Approved by")):
        x0 = doc.ML + k * (col_w + 0.3)
        y = top - 0.15
        doc._t(x0, y, role, 9.5, weight="bold", color="#1d2733")
        for label in ("Name", "Date", "Signature"):
            y -= 0.31
            doc._t(x0, y + 0.03, label, 8.5, color="#333333")
            doc._hrule(y, "#222222", 0.8, x0 + 0.8, x0 + col_w)
    doc.y = top - 1.15


def _pdf_bench_banner(doc: _PdfDoc, cert: Certificate) -> None:
    """Page 1: where the evidence came from, in a coloured strip (label in bold, then its sentence)."""
    label, note, kind = bench_banner(cert)
    bg, fg = BENCH_STYLE[kind]
    chars = max(20, int((doc.width - 0.2) * 72 / (doc.SANS_EM * 7.5)))
    lines = textwrap.wrap(_one_line(note), chars) if note else []
    h = 0.27 + doc._lh(7.5) * len(lines) + 0.07
    doc._rect(doc.ML - 0.04, doc.y - h, doc.width + 0.08, h, bg)
    doc._t(doc.ML + 0.06, doc.y - 0.2, label, 10.5, weight="bold", color=fg)
    y = doc.y - 0.2
    for line in lines:
        y -= doc._lh(7.5)
        doc._t(doc.ML + 0.06, y, line, 7.5, color=fg)
    doc.y -= h + 0.1


def _pdf_block_flow(doc: _PdfDoc, cert: Certificate) -> None:
    """Pages 2…: measurements, policy, errors, then every evidence section with its figures,
    flowing (a section starts where the previous one ends), then the evidence files."""
    doc.new_page("measurements")
    if cert.errors:
        doc.heading(SECTION_TITLES["errors"])
        doc.bullets(cert.errors, 9)
    doc.heading(SECTION_TITLES["measurements"])
    if cert.measurements:
        doc.model_table(measurements_table(cert))
    else:
        doc.para("(no measurements recorded)", 9)
    doc.subheading("Policy", 10)
    if cert.policy:
        doc.table(["policy", "value [1]"], [[policy_label(k), fmt(v)] for k, v in cert.policy.items()], size=8,
                  row_links=[definition_link(f"policy.{k}") for k in cert.policy])
    else:
        doc.para("(no policy recorded)", 9)
    for sec in report_sections(cert):
        _pdf_section(doc, cert, sec)
    st = doc.integrity
    # the integrity block is kept together: a last page never holds only its tail
    doc.ensure(0.55 + 0.75 + 0.16 * (len(cert.evidence) + 1) + 0.4)
    doc.heading("Evidence and integrity", 12)
    doc.kv([("digest (sha256, hil-c14n/1)", _digest_text(st)), ("electronic signature", st.signature_text())],
           size=7.5)
    if cert.evidence:
        doc.table(["evidence", "role", "bytes [B]", "sha256"], [[e.path, e.role, str(e.bytes), e.sha256]
                                                                 for e in cert.evidence], size=6.5)
    doc.para(_evidence_note(st), 8, color="#444444" if st.valid else "#8e1616")


def _pdf_section(doc: _PdfDoc, cert: Certificate, sec: Section) -> None:
    """One section in the flow, its figures under its own heading: a figure that does not fit on
    the current page floats after the section's following tables and paragraphs, and is placed as
    soon as it fits, at the latest at the section's end (on a new page if it must): a figure never
    appears under another section's heading (issue 28)."""
    pending: list[Series] = []

    def place(force: bool = False) -> None:
        while pending and (force or doc.fits(pending[0])):
            f = pending.pop(0)
            doc.figure(f, *doc.captions.get(id(f), ("", None)))

    doc.heading(sec.title, 13)
    doc.current_section = sec.title
    for b in sec.blocks:
        if b.kind == "figure" and b.plot in cert.plots:
            s = cert.plots[b.plot]
            doc.captions[id(s)] = (b.text, b.link)
            doc.keys[id(s)] = b.plot
            if pending or not doc.fits(s):
                pending.append(s)
            else:
                doc.figure(s, *doc.captions[id(s)])
            continue
        _pdf_block(doc, cert, b)
        place()
    place(force=True)


def _pdf_block(doc: _PdfDoc, cert: Certificate, b: Any) -> None:
    if b.kind == "para":
        if b.style.startswith("strong-"):
            o = b.style.split("-", 1)[1]
            doc.para(b.text, 9.5, weight="bold", color=_outcome_text_colour(o))
        else:
            doc.para(b.text, 8.5 if b.style == "muted" else 9, color="#444444" if b.style == "muted" else "#000000")
    elif b.kind == "h3":
        doc.subheading(b.text, 10)
    elif b.kind == "table" and b.table is not None:
        doc.model_table(b.table)
    elif b.kind == "gauge" and cert.robust is not None:
        doc.pstable(cert)
    elif b.kind == "chart":
        doc.chart(cert, b.plot, b.text, b.link)



def _status_class(status: str) -> str:
    o = _status_outcome(status)
    return OUTCOME_STYLE[o][0] if o else ""


def _status_colour(status: str) -> str | None:
    o = _status_outcome(status)
    return OUTCOME_STYLE[o][1] if o else None


def _outcome_text_colour(o: str) -> str:
    return {"PASS": "#1b7f3b", "FAIL": "#c62828", "MARGINAL": "#9a6b00", "ERROR": "#6a3d9a"}.get(o, "#1d2733")


def render_pdf(cert: Certificate, out_path: str | os.PathLike[str], *,
               integrity: IntegrityStatus | None = None, images: dict[str, _Plot] | None = None) -> Path:
    """Write the certificate as a PDF for signing (matplotlib ``PdfPages`` only); returns its path.
    ``integrity`` as for :func:`render_html` (a modified certificate is marked on every page).
    ``images`` (a dict, filled here): each figure and chart as drawn on its page, cropped to PNG,
    for :func:`render_html` (one draw serves both documents)."""
    import warnings

    import matplotlib
    from matplotlib.backends.backend_pdf import PdfPages

    out = Path(out_path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ReportError(f"{out}: cannot write: {exc.strerror or exc}") from None
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    st = _status(cert, integrity)
    meta = {"Title": (f"{MODIFIED}: " if not st.valid else "") + f"Certificate {cert.scene.name}: {cert.decision}",
            "Subject": "hil-certify stability certificate",
            "Creator": "hil-certify " + cert.software.get("hil-certify", "")}
    # TrueType fonts: selectable, searchable text (pdftotext reads it)
    with matplotlib.rc_context({"pdf.fonttype": 42, "font.family": _SANS}), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Glyph \d+ .* missing from", category=UserWarning)
        try:
            with PdfPages(tmp, metadata=meta) as pdf:
                doc = _PdfDoc(pdf, cert, st)
                doc.images = images
                _pdf_summary(doc, cert)
                _pdf_block_flow(doc, cert)
                doc.flush()
            os.replace(tmp, out)
        except OSError as exc:
            raise ReportError(f"{out}: cannot write: {exc.strerror or exc}") from None
        finally:
            tmp.unlink(missing_ok=True)
    return out


