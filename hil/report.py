"""Certificate reports: one self-contained HTML page and a PDF for signing, from the record alone.

Everything a report shows comes from a :class:`hil.certificate.Certificate` (plots included, as
data series), so ``hil report PATH`` rebuilds both documents later from ``certificate.json``.

* :func:`render_html` -- one HTML file, no external resources: CSS inline, plots as base64 PNG
  (matplotlib Agg), printable. Jinja2 templates from ``hil/templates/`` with autoescaping.
* :func:`render_pdf` -- a PDF laid out with matplotlib only (``PdfPages``): a title page (decision,
  reasons, policy, measurements; long tables continue on the next pages), one page per section
  present in the record, plot pages and a signature page.
* :func:`write_json` / :func:`load_certificate` -- the record itself (validated on load; broken or
  missing files raise :class:`ReportError` with a one-line message).
* :func:`build_reports` -- ``certificate.json`` (sealed: it carries its digest), ``report.html``
  and ``report.pdf`` in one folder.
* :func:`report_main` -- ``hil report PATH [--out DIR] [--public-key PUB] [--allow-modified]``:
  exit 0, or 2 with a one-line error.

Integrity (see :mod:`hil.verify`): the reports show the certificate's digest, its evidence files
and, on the signature page/section, who signed and whether the signature holds (when checked with
a public key). A certificate whose content does not match its digest (or has none, or whose
signature fails with the given key) is refused by ``hil report``; with ``--allow-modified`` it is
rendered, and then every PDF page and the HTML page (on screen and on every printed page) carry
``MODIFIED: NOT A VALID CERTIFICATE`` and the decision badge is grey, never the decision's colour.
The render functions apply the same marking whenever the digest does not match (or is missing), whoever
calls them.

Only the sections present in the record appear (an absent section is not rendered empty).
matplotlib and jinja2 (the ``report`` extra) are imported inside the functions that need them,
so importing this module costs neither.

Plot convention (:class:`hil.certificate.Series`): ``lines`` are drawn as lines over ``x`` when
``x`` is monotonic and as markers (a scatter, e.g. posterior draws of two parameters) when it is
not; ``bands`` are shaded between (lo, hi) in the colour of the line of the same name when there
is one; ``points`` are marked and named in the legend; ``hline`` is a dashed reference line.
``None`` values are gaps. A line whose length differs from ``x`` is left out of the figure and
the omission is noted under it (the report never fails on a malformed plot).
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import math
import os
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from hil.certificate import SCHEMA_VERSION, Certificate, Series, content_digest, seal
from hil.errors import HilError
from hil.inputs import read_text_file
from hil.verify import MODIFIED, IntegrityStatus, check_certificate

__all__ = [
    "ReportError",
    "build_reports",
    "load_certificate",
    "render_html",
    "render_pdf",
    "report_main",
    "write_json",
]

TEMPLATES = Path(__file__).resolve().parent / "templates"
CERT_NAME = "certificate.json"

# decision -> (css class, background, text colour); ERROR is purple so it never reads as NO-GO.
DECISION_STYLE: dict[str, tuple[str, str, str]] = {
    "GO": ("d-go", "#1b7f3b", "#ffffff"),
    "MARGINAL": ("d-marginal", "#f2a900", "#1d1d1d"),
    "NO-GO": ("d-nogo", "#c62828", "#ffffff"),
    "ERROR": ("d-error", "#6a3d9a", "#ffffff"),
}
# a certificate that does not match its digest: grey, whatever decision it claims
VOID_STYLE: tuple[str, str, str] = ("d-void", "#5f6368", "#ffffff")
# outcome -> (css class, light cell background)
OUTCOME_STYLE: dict[str, tuple[str, str]] = {
    "PASS": ("o-pass", "#d4efdc"),
    "FAIL": ("o-fail", "#f8d0d0"),
    "MARGINAL": ("o-marginal", "#fde9b3"),
    "ERROR": ("o-error", "#e6dcf2"),
    "INFO": ("o-info", "#e3e9f0"),
}
SECTION_TITLES: dict[str, str] = {
    "errors": "Errors",
    "measurements": "Measurements",
    "nominal": "Nominal verdict",
    "robust": "Robust certification",
    "identification": "Identification",
    "design": "Design guidance",
    "witness": "Instability witness",
    "energy": "Energy evidence",
    "multiport": "Multi-port network",
    "plots": "Plots",
}


class ReportError(HilError, ValueError):
    """A certificate could not be read or a report could not be written (one-line message)."""


# ---------------------------------------------------------------------------------------------
# formatting


def _one_line(s: Any) -> str:
    return " ".join(str(s).split())


def fmt(v: Any, digits: int = 4) -> str:
    """A value as a short human-readable string (None -> an em dash, NaN/inf spelled out)."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "NaN"
        if math.isinf(v):
            return "∞" if v > 0 else "−∞"
        if v == 0.0:
            return "0"
        return f"{v:.{digits}g}"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(fmt(x, digits) for x in v) + "]"
    if isinstance(v, dict):
        s = "{" + ", ".join(f"{k}: {fmt(x, digits)}" for k, x in v.items()) + "}"
        return s if len(s) <= 240 else s[:237] + "…"
    return str(v)


def fmt_p(v: float | None) -> str:
    """A probability with enough digits that a value below 1 never prints as 1."""
    if v is None or not isinstance(v, int | float) or not math.isfinite(v):
        return fmt(v)
    if v in (0.0, 1.0):
        return f"{v:.0f}"
    for d in range(4, 10):
        s = f"{v:.{d}f}"
        if float(s) not in (0.0, 1.0):
            return s
    return f"{v:.3g}"


def fmt_freq(w: Any) -> str:
    """A frequency in rad/s, with Hz in parentheses; strings (e.g. 'inf', 'dc') as given."""
    if isinstance(w, int | float) and not isinstance(w, bool) and math.isfinite(w):
        return f"{fmt(float(w))} rad/s ({fmt(float(w) / (2 * math.pi))} Hz)"
    return fmt(w)


def fmt_band(b: Any) -> str:
    if b is None:
        return "—"
    lo, hi = b
    return f"{fmt(lo)} … {fmt(hi)} rad/s"


def fmt_limits(lower: float | None, upper: float | None, unit: str = "") -> str:
    u = f" {unit}" if unit else ""
    if lower is not None and upper is not None:
        return f"{fmt(lower)} … {fmt(upper)}{u}"
    if lower is not None:
        return f"≥ {fmt(lower)}{u}"
    if upper is not None:
        return f"≤ {fmt(upper)}{u}"
    return "—"


def _value_unit(v: Any, unit: str) -> str:
    s = fmt(v)
    return f"{s} {unit}" if unit and v is not None and not isinstance(v, bool) else s


def _policy_label(key: str) -> str:
    return {"required_probability": "required P(stable)", "confidence": "confidence of the P(stable) interval",
            "credible": "credible region (worst case)"}.get(key, key.replace("_", " "))


def _status(cert: Certificate, integrity: IntegrityStatus | None) -> IntegrityStatus:
    """The integrity status to show: the caller's, or the digest check of ``cert`` itself."""
    return integrity if integrity is not None else check_certificate(cert)


def _style(cert: Certificate, st: IntegrityStatus) -> tuple[str, str, str]:
    return DECISION_STYLE[cert.decision] if st.valid else VOID_STYLE


def _digest_text(st: IntegrityStatus) -> str:
    if st.recorded_digest is None:
        return f"NONE recorded (content sha256 {st.computed_digest})"
    if st.digest_ok:
        return f"{st.recorded_digest} (matches the content)"
    return f"{st.recorded_digest} DOES NOT MATCH the content (sha256 {st.computed_digest})"


def _evidence_note(st: IntegrityStatus) -> str:
    if not st.evidence_checked:
        return "Evidence files are not checked by the report: hil verify DIR recomputes their SHA-256."
    if st.evidence_problems:
        return "Evidence check FAILED: " + "; ".join(st.evidence_problems)
    return f"All {st.n_evidence} evidence files match their recorded SHA-256."


def _present_sections(cert: Certificate) -> list[str]:
    out = ["errors"] if cert.errors else []
    out.append("measurements")
    for k in ("nominal", "robust", "identification", "design", "witness", "energy", "multiport"):
        if getattr(cert, k) is not None:
            out.append(k)
    if cert.plots:
        out.append("plots")
    return out


def _robust_status(cert: Certificate) -> tuple[str, str]:
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


def _gauge(cert: Certificate) -> dict[str, Any]:
    """Geometry of the P(stable) gauge (an inline SVG): axis [a, 1] zoomed on the interesting part."""
    r = cert.robust
    assert r is not None
    vals = [v for v in (r.lower, r.p_stable, r.required) if math.isfinite(v)]
    lo = min(vals) if vals else 0.0
    a = max(0.0, lo - max(0.25 * (1.0 - lo), 0.005))
    a = math.floor(a * 100) / 100 if a > 0.01 else 0.0
    x0, w = 30.0, 540.0

    def px(v: float) -> float:
        v = min(max(v, a), 1.0) if math.isfinite(v) else a
        return round(x0 + (v - a) / (1.0 - a) * w, 2)

    status, _ = _robust_status(cert)
    colour = {"PASS": "#1b7f3b", "MARGINAL": "#f2a900", "FAIL": "#c62828"}[status]
    p = px(r.p_stable)
    anchor, label_x = ("end", x0 + w) if p > x0 + w - 170 else ("start", x0) if p < x0 + 170 else ("middle", p)
    return {"a": fmt(a), "x0": x0, "x1": x0 + w, "lo": px(r.lower), "hi": px(r.upper),
            "p": p, "req": px(r.required), "colour": colour, "p_label": label_x, "p_anchor": anchor}


# ---------------------------------------------------------------------------------------------
# plots (matplotlib, imported lazily; Figure objects without pyplot, so no global state)

_POINT_MARKERS = ("o", "D", "s", "^", "v", "P", "X")
_PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22")


@dataclass
class _Plot:
    name: str
    title: str
    png_b64: str = ""
    notes: list[str] = field(default_factory=list)


def _arr(values: Sequence[float | None]) -> Any:
    import numpy as np

    return np.array([math.nan if v is None else float(v) for v in values], dtype=float)


def _mtext(s: str) -> str:
    """Record text shown literally by matplotlib (a '$' would otherwise start mathtext)."""
    return str(s).replace("$", r"\$")


def _monotonic(x: Any) -> bool:
    import numpy as np

    d = np.diff(x[np.isfinite(x)])
    return bool(np.all(d >= 0) or np.all(d <= 0))


def _draw_series(ax: Any, s: Series) -> list[str]:
    """Draw one Series on ``ax``; returns notes on anything left out."""
    import numpy as np

    notes: list[str] = []
    x = _arr(s.x)
    n = x.size
    scatter = n > 1 and not _monotonic(x)
    colours: dict[str, str] = {}

    def next_colour(i: int) -> str:
        return _PALETTE[i % len(_PALETTE)]

    k = 0
    drawn = 0
    for name, ys in s.lines.items():
        y = _arr(ys)
        if y.size != n:
            notes.append(f"line {name!r} left out: {y.size} values for {n} x values")
            continue
        c = next_colour(k)
        k += 1
        colours[name] = c
        if scatter:
            ax.plot(x, y, linestyle="none", marker=".", markersize=3, alpha=0.6, color=c, label=_mtext(name))
        else:
            ax.plot(x, y, color=c, linewidth=1.4, label=_mtext(name))
        drawn += int(np.isfinite(y).any())
    for name, (lo_v, hi_v) in s.bands.items():
        lo, hi = _arr(lo_v), _arr(hi_v)
        if lo.size != n or hi.size != n:
            notes.append(f"band {name!r} left out: {lo.size}/{hi.size} values for {n} x values")
            continue
        c = colours.get(name)
        if c is None:
            c = next_colour(k)
            k += 1
        ok = np.isfinite(x) & np.isfinite(lo) & np.isfinite(hi)
        order = np.argsort(x) if scatter else slice(None)
        ax.fill_between(x[order], lo[order], hi[order], where=ok[order], color=c, alpha=0.22, linewidth=0,
                        label=_mtext(name if name not in s.lines else f"{name} (band)"))
        drawn += int(ok.any())
    for i, (name, (px, py)) in enumerate(s.points.items()):
        if not (math.isfinite(px) and math.isfinite(py)):
            notes.append(f"point {name!r} left out: not finite")
            continue
        ax.plot([px], [py], linestyle="none", marker=_POINT_MARKERS[i % len(_POINT_MARKERS)], markersize=8,
                markerfacecolor="#d62728" if i == 0 else "#222222", markeredgecolor="white", markeredgewidth=1.0,
                zorder=5, label=_mtext(f"{name} ({fmt(px)}, {fmt(py)})"))
        drawn += 1
    if s.hline is not None and math.isfinite(s.hline):
        ax.axhline(s.hline, color="#555555", linestyle="--", linewidth=1.0, label=f"reference {fmt(s.hline)}")
    if s.log_x:
        ax.set_xscale("log")
    if s.log_y:
        ax.set_yscale("log")
    ax.set_title(_mtext(s.title), fontsize=11)
    ax.set_xlabel(_mtext(s.x_label))
    ax.set_ylabel(_mtext(s.y_label))
    ax.grid(True, which="major", alpha=0.35)
    if s.log_x or s.log_y:
        ax.grid(True, which="minor", alpha=0.12)
    if not drawn:
        ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center", color="#888888")
        notes.append("no finite data to draw")
    handles, _ = ax.get_legend_handles_labels()
    if handles:
        loc = "best" if n * max(1, len(s.lines)) <= 4000 else "upper right"
        ax.legend(loc=loc, fontsize=8, framealpha=0.85)
    return notes


def _safe_draw(ax: Any, s: Series) -> list[str]:
    """Draw a series; a plot that cannot be drawn becomes a note, never a failed report."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # e.g. log axes with non-positive values (masked)
            return _draw_series(ax, s)
    except Exception as exc:  # a bad series must not lose the whole report
        ax.clear()
        ax.set_axis_off()
        ax.text(0.5, 0.5, f"plot could not be drawn: {_mtext(_one_line(exc))[:120]}", transform=ax.transAxes,
                ha="center", va="center", color="#c62828")
        return [f"could not be drawn: {_one_line(exc)}"]


def _plots_png(cert: Certificate, dpi: int = 110) -> list[_Plot]:
    import warnings

    from matplotlib.figure import Figure

    out = []
    for name, s in cert.plots.items():
        fig = Figure(figsize=(9.0, 4.4), dpi=dpi, layout="constrained")
        ax = fig.add_subplot()
        notes = _safe_draw(ax, s)
        buf = io.BytesIO()
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"Glyph \d+ .* missing from", category=UserWarning)
            fig.savefig(buf, format="png", dpi=dpi, facecolor="white")
        out.append(_Plot(name, s.title, base64.b64encode(buf.getvalue()).decode("ascii"), notes))
    return out


# ---------------------------------------------------------------------------------------------
# JSON record


def _canonical_json(cert: Certificate) -> str:
    return cert.model_dump_json(indent=2) + "\n"


def _atomic_write(path: Path, data: bytes) -> Path:
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as exc:
        raise ReportError(f"{path}: cannot write: {exc.strerror or exc}") from None
    return path


def write_json(cert: Certificate, out_path: str | os.PathLike[str]) -> Path:
    """Write the record as ``certificate.json`` (indented UTF-8). The text is checked to load back:
    a non-finite number in a required field (JSON has no NaN) raises :class:`ReportError`."""
    text = _canonical_json(cert)
    try:
        Certificate.model_validate_json(text)
    except ValidationError as exc:
        raise ReportError(f"certificate does not survive JSON (non-finite number?): {_first_error(exc)}") from None
    return _atomic_write(Path(out_path), text.encode("utf-8"))


def _first_error(exc: ValidationError) -> str:
    errs = exc.errors()
    if not errs:
        return _one_line(exc)
    e = errs[0]
    loc = ".".join(str(p) for p in e.get("loc", ())) or "(root)"
    more = f" (and {len(errs) - 1} more)" if len(errs) > 1 else ""
    return _one_line(f"{loc}: {e.get('msg', 'invalid')}{more}")


def _resolve(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    if p.is_dir():
        p = p / CERT_NAME
    return p


def load_certificate(path: str | os.PathLike[str]) -> Certificate:
    """Read and validate a certificate (a ``certificate.json`` file, or a folder holding one)."""
    p = _resolve(path)
    text = read_text_file(p, "certificate", ReportError)  # missing, unreadable, binary, not UTF-8: one line
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ReportError(f"{p}: not valid JSON: line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    if not isinstance(data, dict):
        raise ReportError(f"{p}: not a certificate: the top level is not a JSON object")
    ver = str(data.get("schema_version", SCHEMA_VERSION))
    if ver.split(".")[0] != SCHEMA_VERSION.split(".")[0]:
        raise ReportError(f"{p}: schema_version {ver!r} is not supported (this version reads {SCHEMA_VERSION})")
    try:
        return Certificate.model_validate(data)
    except ValidationError as exc:
        raise ReportError(f"{p}: invalid certificate: {_first_error(exc)}") from None


# ---------------------------------------------------------------------------------------------
# HTML


def _jinja_env() -> Any:
    import jinja2

    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(TEMPLATES)), autoescape=True,
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
                             keep_trailing_newline=True)
    env.filters.update(fmt=fmt, fmt_p=fmt_p, fmt_freq=fmt_freq, fmt_band=fmt_band)
    env.globals.update(fmt_limits=fmt_limits, value_unit=_value_unit, policy_label=_policy_label,
                       outcome_class=lambda o: OUTCOME_STYLE.get(str(o), ("o-info", ""))[0],
                       status_class=_status_class)
    return env


def _html_context(cert: Certificate, st: IntegrityStatus) -> dict[str, Any]:
    ctx: dict[str, Any] = {
        "cert": cert,
        "title": (f"{MODIFIED} — " if not st.valid else "") + f"Certificate: {cert.scene.name} — {cert.decision}",
        "decision_class": _style(cert, st)[0],
        "modified": not st.valid,
        "modified_text": MODIFIED,
        "modified_reason": st.reason(),
        "integrity": st,
        "digest_text": _digest_text(st),
        "signature_text": st.signature_text(),
        "evidence_note": _evidence_note(st),
        "sections": [(k, SECTION_TITLES[k]) for k in _present_sections(cert)],
        "outcome_counts": _outcome_counts(cert),
        "plots": _plots_png(cert) if cert.plots else [],
        "robust_status": None,
        "gauge": None,
        "show_truth": False,
        "headroom": _headroom(cert.design) if cert.design is not None else "",
    }
    if cert.robust is not None:
        ctx["robust_status"] = _robust_status(cert)
        ctx["gauge"] = _gauge(cert)
    if cert.identification:
        ctx["show_truth"] = any(p.truth is not None for i in cert.identification for p in i.parameters)
    return ctx


def _outcome_counts(cert: Certificate) -> list[tuple[str, int]]:
    counts: dict[str, int] = {}
    for m in cert.measurements:
        counts[m.outcome] = counts.get(m.outcome, 0) + 1
    return [(o, counts[o]) for o in OUTCOME_STYLE if o in counts]


def render_html(cert: Certificate, out_path: str | os.PathLike[str], *,
                integrity: IntegrityStatus | None = None) -> Path:
    """Write the certificate as one self-contained, printable HTML file; returns its path.
    ``integrity`` (default: the digest check of ``cert``) decides the MODIFIED marking and the
    signature status shown."""
    env = _jinja_env()
    html = env.get_template("report.html.j2").render(**_html_context(cert, _status(cert, integrity)))
    return _atomic_write(Path(out_path), html.encode("utf-8"))


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
        self._t(self.ML, self.H - 0.45, f"hil-certify certificate · scene {c.scene.name}", 8, color="#555555")
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
        self.ensure(self._lh(size) + 0.5)  # keep a heading with what follows
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
              min_col: int = 5) -> None:
        """A monospaced table; columns shrink (cells wrap) to the page width, rows continue on
        the next page with the header row repeated."""
        ncol = len(headers)
        cells = [[_one_line(c) for c in r] for r in rows]
        gap = 2
        natural = [max(1, len(headers[j]), *(len(r[j]) for r in cells)) for j in range(ncol)]
        # a column is not narrowed below its longest word (numbers never break), up to 16 characters
        floor = [max(min_col, min(16, max(len(w) for c in [headers[j], *(r[j] for r in cells)]
                                          for w in (c.split() or [""])))) for j in range(ncol)]
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
                for i, line in enumerate(hl):
                    self._t(xs[j], self.y - pad - (i + 1) * lh + 0.25 * lh, line, size, family=_MONO, weight="bold")
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
                for i, line in enumerate(wl):
                    self._t(xs[j], self.y - pad - (i + 1) * lh + 0.25 * lh, line, size, family=_MONO)
            self.y -= h
        self._hrule(self.y, "#bbbbbb", 0.5)
        self.y -= 0.14

    def kv(self, pairs: Sequence[tuple[str, str]], size: float = 9.0) -> None:
        self.table(["quantity", "value"], [list(p) for p in pairs], size=size)

    def figure(self, s: Series, h: float = 4.3) -> None:
        """A plot in the flow (two fit on a page)."""
        self.ensure(h + 0.2)
        left = self.ML / self.W
        ax = self.fig.add_axes((left + 0.07, (self.y - h + 0.45) / self.H, self.width / self.W - 0.09,
                                (h - 0.8) / self.H))
        notes = _safe_draw(ax, s)
        self.y -= h
        for n in notes:
            self.para(f"Note: {n}", 8, color="#8a5a00")
        self.space(0.15)


def _pdf_title(doc: _PdfDoc, cert: Certificate) -> None:
    doc.new_page("title")
    bg, fg = doc.style[1:]
    doc.y -= 0.35
    doc._t(doc.ML, doc.y, "Stability certificate", 20, weight="bold", color="#1d2733")
    doc.y -= 0.38
    doc._t(doc.ML, doc.y, f"scene {cert.scene.name}", 13, color="#333333")
    doc._t(doc.W - doc.MR - 0.15, doc.y + 0.1, f"  {cert.decision}  ", 26, weight="bold", color=fg, ha="right",
           va="center", bbox={"boxstyle": "round,pad=0.35", "facecolor": bg, "edgecolor": "none"})
    doc.y -= 0.2
    if cert.scene.description:
        doc.para(cert.scene.description, 9, color="#444444")
    doc.para(f"scene sha256 {cert.scene.sha256}" + (f" · source {cert.scene.source}" if cert.scene.source else ""),
             8, color="#666666")
    doc.para(f"created {cert.created_utc} (UTC) · schema {cert.schema_version} · "
             + ", ".join(f"{k} {v}" for k, v in cert.software.items()), 8, color="#666666")
    doc.space(0.1)
    doc.subheading("Reasons")
    doc.bullets(cert.reasons or ["(no reasons recorded)"])
    if cert.errors:
        doc.subheading("Errors")
        doc.bullets(cert.errors)
    doc.subheading("Policy")
    if cert.policy:
        doc.kv([(_policy_label(k), fmt(v)) for k, v in cert.policy.items()])
    else:
        doc.para("(no policy recorded)", 9)
    doc.subheading("Measurements")
    if cert.measurements:
        rows, colours = [], []
        for m in cert.measurements:
            rows.append([m.name, _value_unit(m.value, m.unit), fmt_limits(m.lower, m.upper, m.unit), m.outcome,
                         m.description])
            colours.append([None, None, None, OUTCOME_STYLE.get(m.outcome, ("", None))[1], None])
        doc.table(["measurement", "value", "limits", "outcome", "description"], rows, colours)
    else:
        doc.para("(no measurements recorded)", 9)


def _pdf_sections(doc: _PdfDoc, cert: Certificate) -> None:
    if cert.nominal is not None:
        n = cert.nominal
        doc.new_page("nominal")
        doc.heading(SECTION_TITLES["nominal"])
        doc.kv([("network", n.network), ("criterion", n.criterion),
                ("verdict", n.verdict + (" (weak)" if n.weak else "")),
                ("margin", fmt(n.margin)), ("worst frequency", fmt_freq(n.worst_frequency)),
                ("failed condition", fmt(n.failed_condition))])
        if n.parameters:
            doc.subheading("Nominal parameters")
            doc.kv([(k, fmt(v)) for k, v in n.parameters.items()])
        if n.conditions:
            doc.subheading("Conditions")
            doc.table(["condition", "label", "status", "margin", "worst frequency", "detail"],
                      [[c.name, c.label, c.status, fmt(c.margin), fmt_freq(c.worst_frequency), c.detail]
                       for c in n.conditions],
                      [[None, None, _status_colour(c.status), None, None, None] for c in n.conditions])
    if cert.robust is not None:
        r = cert.robust
        status, sentence = _robust_status(cert)
        doc.new_page("robust")
        doc.heading(SECTION_TITLES["robust"])
        doc.para(f"{status}: {sentence}.", 10, weight="bold", color=_outcome_text_colour(status))
        doc.space(0.08)
        doc.kv([("P(stable)", fmt_p(r.p_stable)),
                (f"{r.confidence:.0%} confidence interval", f"[{fmt_p(r.lower)}, {fmt_p(r.upper)}]"),
                ("required (lower bound must clear)", fmt_p(r.required)),
                ("posterior draws", str(r.n_draws)),
                ("sampling (independent draws)", r.sampling or "—"),
                (f"worst-case margin over the {r.credible:.0%} credible region", fmt(r.worst_case_margin)),
                ("critical band", fmt_band(r.critical_band_rad_s)),
                ("method", r.method or "—")])
        if r.worst_case_parameters:
            doc.subheading("Worst-case parameters")
            doc.kv([(k, fmt(v)) for k, v in r.worst_case_parameters.items()])
    if cert.identification is not None:
        doc.new_page("identification")
        doc.heading(SECTION_TITLES["identification"])
        show_truth = any(p.truth is not None for i in cert.identification for p in i.parameters)
        for ident in cert.identification:
            doc.subheading(f"{ident.model} — " + ("converged" if ident.converged else "NOT converged"))
            doc.para(f"record {ident.record}" + (f" · {ident.reason}" if ident.reason else ""), 9, color="#444444")
            hdr = ["parameter", "unit", "mean", "median", "q05", "q95", "std", "LS std", "CRB std"]
            if show_truth:
                hdr.append("truth")
            rows = []
            for p in ident.parameters:
                row = [p.name, p.unit, fmt(p.mean), fmt(p.median), fmt(p.q05), fmt(p.q95), fmt(p.std), fmt(p.ls_std),
                       fmt(p.crb_std)]
                if show_truth:
                    row.append(fmt(p.truth))
                rows.append(row)
            doc.table(hdr, rows)
            if ident.diagnostics:
                doc.subheading("Diagnostics", 10)
                doc.kv([(k, fmt(v)) for k, v in ident.diagnostics.items()], size=8)
    if cert.design is not None:
        d = cert.design
        doc.new_page("design")
        doc.heading(SECTION_TITLES["design"])
        doc.kv([("free parameter", d.parameter + (f" [{d.unit}]" if d.unit else "")),
                ("current value", _value_unit(d.current, d.unit)),
                ("largest value meeting the requirement", _value_unit(d.max_value, d.unit)),
                ("P(stable) at that value", fmt_p(d.probability_at_max)),
                ("required", fmt_p(d.required))] + ([("headroom", _headroom(d))] if _headroom(d) else []))
        if d.note:
            doc.para(d.note, 9)
    if cert.witness is not None:
        w = cert.witness
        doc.new_page("witness")
        doc.heading(SECTION_TITLES["witness"])
        doc.para("A set of passive terminations under which the network delivers energy, with its simulation.", 9)
        doc.kv([("drive frequency", fmt_freq(w.drive_frequency_rad_s)), ("band", fmt_band(w.band_rad_s)),
                ("margin", fmt(w.margin))])
        doc.subheading("Terminations")
        doc.kv([(k, fmt(v)) for k, v in w.terminations.items()] or [("—", "—")])
        if w.simulation:
            doc.subheading("Simulation outcome")
            doc.kv([(k, fmt(v)) for k, v in w.simulation.items()])
    if cert.energy is not None:
        doc.new_page("energy")
        doc.heading(SECTION_TITLES["energy"])
        doc.table(["experiment", "port", "record", "E_s < 0", "min E_s", "noise bound", "first time"],
                  [[e.experiment, e.port, e.record, "YES" if e.went_negative else "no", fmt(e.min_energy), fmt(e.bound),
                    fmt(e.first_time)] for e in cert.energy],
                  [[None, None, None, OUTCOME_STYLE["FAIL" if e.went_negative else "PASS"][1], None, None, None]
                   for e in cert.energy])
    if cert.multiport is not None:
        mp = cert.multiport
        doc.new_page("multiport")
        doc.heading(SECTION_TITLES["multiport"])
        doc.kv([("ports", str(len(mp.ports))), ("DOFs per port", ", ".join(str(p) for p in mp.ports) or "—"),
                ("total DOFs", str(mp.dof_total)), ("symmetrization", mp.symmetrization or "—")])


def _headroom(d: Any) -> str:
    if d.current is None or d.max_value is None or not math.isfinite(d.max_value) or d.max_value == 0:
        return ""
    ratio = d.current / d.max_value
    return f"current is {ratio:.0%} of the largest value" + (" (EXCEEDS it)" if ratio > 1 else "")


def _status_outcome(status: str) -> str | None:
    """The outcome colour class of a condition status (free text in the record)."""
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


def _status_class(status: str) -> str:
    o = _status_outcome(status)
    return OUTCOME_STYLE[o][0] if o else ""


def _status_colour(status: str) -> str | None:
    o = _status_outcome(status)
    return OUTCOME_STYLE[o][1] if o else None


def _outcome_text_colour(o: str) -> str:
    return {"PASS": "#1b7f3b", "FAIL": "#c62828", "MARGINAL": "#9a6b00", "ERROR": "#6a3d9a"}.get(o, "#1d2733")


def _pdf_plots(doc: _PdfDoc, cert: Certificate) -> None:
    if not cert.plots:
        return
    doc.new_page("plots")
    doc.heading(SECTION_TITLES["plots"])
    for s in cert.plots.values():
        doc.figure(s)


def _pdf_signature(doc: _PdfDoc, cert: Certificate) -> None:
    doc.new_page("signature")
    doc.heading("Review and signature")
    bg, fg = doc.style[1:]
    st = doc.integrity
    doc.y -= 0.3
    doc._t(doc.ML, doc.y, "Decision:", 12)
    doc._t(doc.ML + 1.0, doc.y + 0.04, f"  {cert.decision}  ", 14, weight="bold", color=fg, va="center",
           bbox={"boxstyle": "round,pad=0.3", "facecolor": bg, "edgecolor": "none"})
    doc.y -= 0.25
    doc.subheading("Integrity", 10)
    doc.kv([("digest (sha256, hil-c14n/1)", _digest_text(st)), ("electronic signature", st.signature_text())],
           size=8)
    if cert.evidence:
        doc.table(["evidence", "role", "bytes", "sha256"], [[e.path, e.role, str(e.bytes), e.sha256]
                                                             for e in cert.evidence], size=7)
    doc.para(_evidence_note(st), 8, color="#444444" if st.valid else "#8e1616")
    doc.space(0.1)
    doc.para(f"I have reviewed this certificate for scene {cert.scene.name} (scene sha256 {cert.scene.sha256}; "
             f"digest {st.recorded_digest or 'none'}) and its evidence, and I accept the decision above.", 10)
    doc.space(0.3)
    for role in ("Reviewed by", "Approved by"):
        doc.ensure(1.9)
        doc.subheading(role)
        for label in ("Name", "Date", "Signature"):
            doc.y -= 0.48
            doc._t(doc.ML, doc.y + 0.03, label, 10, color="#333333")
            doc._hrule(doc.y, "#222222", 0.8, doc.ML + 1.1, doc.W - doc.MR)
        doc.space(0.35)


def render_pdf(cert: Certificate, out_path: str | os.PathLike[str], *,
               integrity: IntegrityStatus | None = None) -> Path:
    """Write the certificate as a PDF for signing (matplotlib ``PdfPages`` only); returns its path.
    ``integrity`` as for :func:`render_html` (a modified certificate is marked on every page)."""
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
                _pdf_title(doc, cert)
                _pdf_sections(doc, cert)
                _pdf_plots(doc, cert)
                _pdf_signature(doc, cert)
                doc.flush()
            os.replace(tmp, out)
        except OSError as exc:
            raise ReportError(f"{out}: cannot write: {exc.strerror or exc}") from None
        finally:
            tmp.unlink(missing_ok=True)
    return out


# ---------------------------------------------------------------------------------------------
# all three, and the command


def build_reports(cert: Certificate, out_dir: str | os.PathLike[str], *,
                  integrity: IntegrityStatus | None = None) -> dict[str, Path]:
    """Write ``certificate.json``, ``report.html`` and ``report.pdf`` into ``out_dir``.

    The written certificate carries its digest: an unsealed ``cert`` is sealed first; a sealed one
    whose content no longer matches its digest is refused (:class:`ReportError`), so a record is
    never written with a digest, or a signature, that does not hold. ``integrity`` is the status
    shown in the reports (default: the digest check; ``hil certify --sign`` passes the checked
    signature)."""
    d = Path(out_dir)
    if cert.integrity is None:
        cert = seal(cert)
    elif cert.integrity.digest != content_digest(cert):
        raise ReportError("the certificate was changed after its digest was computed; refusing to write it")
    return {"json": write_json(cert, d / CERT_NAME), "html": render_html(cert, d / "report.html", integrity=integrity),
            "pdf": render_pdf(cert, d / "report.pdf", integrity=integrity)}


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> Any:  # one line, exit 2 (instead of usage + message)
        raise ReportError(f"{self.prog}: {_one_line(message)}")


def report_main(argv: Sequence[str] | None = None) -> int:
    """``hil report PATH [--out DIR] [--public-key PUB] [--allow-modified]``: rebuild report.html
    and report.pdf from a stored certificate.json (PATH is the file or a folder holding it).

    A certificate that does not match its digest (or has none), or whose signature fails with
    ``--public-key``, is refused; ``--allow-modified`` renders it marked MODIFIED: NOT A VALID
    CERTIFICATE on every page. Exit 0, or 2 with one line."""
    import sys

    p = _Parser(prog="hil report", description="Rebuild the HTML and PDF reports from a stored certificate.json.")
    p.add_argument("path", metavar="PATH", help="certificate.json, or a folder containing it")
    p.add_argument("--out", metavar="DIR", help="output folder (default: the certificate's folder)")
    p.add_argument("--public-key", metavar="PUB", help="check the signature with this Ed25519 public key (PEM)")
    p.add_argument("--allow-modified", action="store_true",
                   help=f"render a certificate that fails its checks anyway, marked '{MODIFIED}'")
    try:
        args = p.parse_args(list(argv) if argv is not None else None)
        cert = load_certificate(args.path)
        key = None
        if args.public_key:
            from hil.signing import load_public_key

            key = load_public_key(args.public_key)
        st = check_certificate(cert, public_key=key)
        if key is not None and st.signature == "absent":
            st.signature, st.signature_detail = "invalid", "the certificate is not signed"
        if not st.valid and not args.allow_modified:
            raise ReportError(f"{_resolve(args.path)}: {st.reason()}; refusing to render it "
                              f"(--allow-modified renders it marked '{MODIFIED}')")
        out = Path(args.out) if args.out else _resolve(args.path).parent
        paths = {"html": render_html(cert, out / "report.html", integrity=st),
                 "pdf": render_pdf(cert, out / "report.pdf", integrity=st)}
    except HilError as exc:
        print(f"hil report: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help
        return int(exc.code or 0)
    mark = f" [{MODIFIED}]" if not st.valid else ""
    print(f"{cert.decision} {cert.scene.name}{mark}: {paths['html']} {paths['pdf']}")
    return 0
