"""Certificate reports: one self-contained HTML page and a PDF for signing, from the record alone.

Everything a report shows comes from a :class:`hil.certify.certificate.Certificate` (plots included, as
data series), so ``hil report PATH`` rebuilds both documents later from ``certificate.json``.

* :func:`render_html` -- one HTML file, no external resources: CSS inline, plots as base64 PNG
  (matplotlib Agg), printable. Jinja2 templates from ``hil/report/templates/`` with autoescaping.
* :func:`render_pdf` -- a PDF laid out with matplotlib only (``PdfPages``): a title page (decision,
  reasons, policy, measurements; long tables continue on the next pages), one page per section
  present in the record, plot pages and a signature page.
* :func:`write_json` / :func:`load_certificate` -- the record itself (validated on load; broken or
  missing files raise :class:`ReportError` with a one-line message).
* :func:`build_reports` -- ``certificate.json`` (sealed: it carries its digest), ``report.html``
  and ``report.pdf`` in one folder.
* :func:`rebuild_reports` -- what ``hil report PATH [--out DIR] [--public-key PUB] [--allow-modified]``
  does (hil.cli.main parses it): exit 0, or 2 with a one-line error.

Integrity (see :mod:`hil.certify.verify`): the reports show the certificate's digest, its evidence files
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

Plot convention (:class:`hil.certify.certificate.Series`): ``lines`` are drawn as lines over ``x`` when
``x`` is monotonic and as markers (a scatter, e.g. posterior draws of two parameters) when it is
not; ``bands`` are shaded between (lo, hi) in the colour of the line of the same name when there
is one; ``points`` are marked and named in the legend; ``hline`` is a dashed reference line.
``None`` values are gaps. A line whose length differs from ``x`` is left out of the figure and
the omission is noted under it (the report never fails on a malformed plot).
"""

from __future__ import annotations

import base64
import io
import json
import logging
import math
import os
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from hil.certify.certificate import SCHEMA_VERSION, Certificate, Series, content_digest, seal
from hil.certify.verify import MODIFIED, IntegrityStatus, check_certificate
from hil.errors import HilError
from hil.report.sections import (
    CHARTS,
    Section,
    Table,
    _status_outcome,
    definition_link,
    failure_estimates,
    fmt,
    fmt_p,
    fmt_range,
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
    "ReportError",
    "build_reports",
    "load_certificate",
    "rebuild_reports",
    "render_html",
    "render_pdf",
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


def fmt_freq(w: Any) -> str:
    """A frequency in rad/s, with Hz in parentheses; strings (e.g. 'inf', 'dc') as given."""
    if isinstance(w, int | float) and not isinstance(w, bool) and math.isfinite(w):
        return f"{fmt(float(w))} rad/s ({fmt(float(w) / (2 * math.pi))} Hz)"
    return fmt(w)


def fmt_band(b: Any) -> str:
    """A band in rad/s; two different ends never print alike (more digits when needed)."""
    if b is None:
        return "—"
    return f"{fmt_range(*b)} rad/s"


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
    return policy_label(key)


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


def bench_banner(cert: Certificate) -> tuple[str, str, str]:
    """(banner label, sentence, kind) saying where the evidence came from (the certificate's
    ``bench`` block); a certificate written before that block existed says so."""
    b = cert.bench
    if b is None:
        return ("BENCH NOT RECORDED", "This certificate does not record whether its evidence came from a "
                "simulated bench or from hardware (written before schema 1.2 recorded it).", "unknown")
    return b.label, b.note, b.kind


#: bench kind -> (banner background, text colour): a simulated bench is never mistaken for hardware
BENCH_STYLE: dict[str, tuple[str, str]] = {"simulated": ("#fff1c2", "#6b4e00"), "hardware": ("#dbe8f6", "#0b3d91"),
                                           "none": ("#eceff1", "#37474f"), "unknown": ("#eceff1", "#37474f")}


def _present_sections(cert: Certificate) -> list[str]:
    out = ["errors"] if cert.errors else []
    out.append("measurements")
    out += [sec.key for sec in report_sections(cert)]
    return out


def _robust_status(cert: Certificate) -> tuple[str, str]:
    return robust_status(cert)


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
#: resolution of the HTML's figure images, cropped from the PDF's pages (6.8 in wide: 745 px)
HTML_DPI = 110
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
    first_line = None
    for name, ys in s.lines.items():
        y = _arr(ys)
        if y.size != n:
            notes.append(f"line {name!r} left out: {y.size} values for {n} x values")
            continue
        if name.startswith("_") and k:  # a continuation (e.g. a circle's lower half): same colour, no legend
            c = _PALETTE[(k - 1) % len(_PALETTE)]
        else:
            c = next_colour(k)
            k += 1
        colours[name] = c
        if first_line is None:
            first_line = y
        if scatter:
            ax.plot(x, y, linestyle="none", marker=".", markersize=3, alpha=0.6, color=c, label=_mtext(name))
        elif name.startswith("measured"):  # measured data as markers over the fit: never hidden under it
            ax.plot(x, y, linestyle="none", marker="o", markersize=1.6, alpha=0.6, color=c, label=_mtext(name),
                    zorder=4)
        else:
            ax.plot(x, y, color=c, linewidth=1.4, label=_mtext(name), zorder=3)
        drawn += int(np.isfinite(y).any())
    for name, (lo_v, hi_v) in s.bands.items():
        lo, hi = _arr(lo_v), _arr(hi_v)
        if lo.size != n or hi.size != n:
            notes.append(f"band {name!r} left out: {lo.size}/{hi.size} values for {n} x values")
            continue
        bc = colours.get(name)
        if bc is None and name.startswith(("non-stable", "unstable")):
            bc = "#c62828"
        if bc is None:
            bc = next_colour(k)
            k += 1
        c = bc
        ok = np.isfinite(x) & np.isfinite(lo) & np.isfinite(hi)
        order = np.argsort(x) if scatter else slice(None)
        ax.fill_between(x[order], lo[order], hi[order], where=ok[order], color=c, alpha=0.22, linewidth=0,
                        label=_mtext(name if name not in s.lines else f"{name} (band)"))
        drawn += int(ok.any())
    if s.shade_negative and first_line is not None and not scatter:
        neg = np.isfinite(first_line) & (first_line < 0)
        if neg.any():
            ax.fill_between(x, first_line, 0.0, where=neg, color="#c62828", alpha=0.30, linewidth=0,
                            label="negative: condition violated", zorder=2)
    for i, (name, (px, py)) in enumerate(s.points.items()):
        if not (math.isfinite(px) and math.isfinite(py)):
            notes.append(f"point {name!r} left out: not finite")
            continue
        ax.plot([px], [py], linestyle="none", marker=_POINT_MARKERS[i % len(_POINT_MARKERS)], markersize=8,
                markerfacecolor="#d62728" if i == 0 else "#222222", markeredgecolor="white", markeredgewidth=1.0,
                zorder=5, label=_mtext(name if "=" in name or "(" in name else f"{name} ({fmt(px)}, {fmt(py)})"))
        drawn += 1
    for i, (name, xv) in enumerate(s.vlines.items()):
        if math.isfinite(xv):
            c, ls = (("#c62828", ":"), ("#6a3d9a", "-."), ("#8c564b", (0, (5, 2))))[i % 3]
            ax.axvline(xv, color=c, linestyle=ls, linewidth=1.2, label=_mtext(f"{name}: {fmt(xv)}"))
    if s.hline is not None and math.isfinite(s.hline):
        ax.axhline(s.hline, color="#555555", linestyle="--", linewidth=1.0, label=f"reference {fmt(s.hline)}")
    if s.log_x:
        ax.set_xscale("log")
    if s.log_y:
        ax.set_yscale("log")
    if s.y_label.startswith("γ²"):  # a coherence: always on [0, 1]
        ax.set_ylim(0.0, 1.05)
    if _standardized(s):  # posterior-standardized coordinates: a circle ‖u‖ = β must look like one
        ax.set_aspect("equal", adjustable="datalim")
    width_in = ax.get_position().width * ax.figure.get_figwidth()
    ax.set_title(_mtext(_wrap_title(s.title, width_in)), fontsize=10)
    ax.set_xlabel(_mtext(s.x_label), fontsize=9)
    ylab = s.y_label
    if len(ylab) > 28 and " [" in ylab:  # a long label in two lines (name, then [unit]) stays inside the axes
        head, _, unit = ylab.rpartition(" [")
        ylab = f"{head}\n[{unit}"
    ax.set_ylabel(_mtext(ylab), fontsize=9 if len(s.y_label) <= 28 else 8)
    ax.tick_params(labelsize=8)
    ax.grid(True, which="major", alpha=0.35)
    if s.log_x or s.log_y:
        ax.grid(True, which="minor", alpha=0.12)
    if not drawn:
        ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center", color="#888888")
        notes.append("no finite data to draw")
    handles, _ = ax.get_legend_handles_labels()
    if handles:
        place_legend(ax, fontsize=7 if width_in >= 4.5 else 6)
    return notes


_LEGEND_LOCS = ("upper right", "upper left", "lower right", "lower left", "center right", "center left",
                "upper center", "lower center")


def _legend_cover(ax: Any, leg: Any, renderer: Any) -> tuple[int, int]:
    """(marked points, data vertices) of ``ax`` that the legend's box covers, in display space; a
    marked point (a Line2D drawn as markers only with at most a few vertices: a named point) counts
    with its marker's radius, and so does a text annotation the box overlaps."""
    import numpy as np

    bb = leg.get_window_extent(renderer)
    points = vertices = 0
    for line in ax.get_lines():
        xy = np.asarray(line.get_xydata(), float)
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if xy.size == 0:
            continue
        d = ax.transData.transform(xy[:: max(1, len(xy) // 400)])
        marker_only = line.get_linestyle() in ("None", "none", "", " ") and len(xy) <= 4
        pad = (line.get_markersize() * ax.figure.dpi / 72.0) / 2 if marker_only else 0.0
        inside = ((d[:, 0] >= bb.x0 - pad) & (d[:, 0] <= bb.x1 + pad) & (d[:, 1] >= bb.y0 - pad)
                  & (d[:, 1] <= bb.y1 + pad))
        if marker_only:
            points += int(inside.sum())
        else:
            vertices += int(inside.sum())
    for t in ax.texts:  # an annotation (a value printed next to its marker) is never covered either
        if t.get_text().strip() and bb.overlaps(t.get_window_extent(renderer)):
            points += 1
    return points, vertices


def place_legend(ax: Any, fontsize: float = 7) -> Any:
    """A legend that never covers a marked point (issue 28): of the inside locations the one
    covering no marked point and the fewest data vertices; when every location covers a marked
    point, the y range is extended upwards to make room for it above the data. Returns the legend."""
    leg = ax.legend(loc="upper right", fontsize=fontsize, framealpha=0.85)
    try:
        renderer = ax.figure._get_renderer()
        ax.apply_aspect()
        scores = []
        for loc in _LEGEND_LOCS:
            leg.set_loc(loc)
            scores.append((_legend_cover(ax, leg, renderer), loc))
        (best_points, _), best = min(scores)
        leg.set_loc(best)
        if best_points:  # every place covers a marked point: room above the data for it
            leg.set_loc("upper right")
            frac = leg.get_window_extent(renderer).height / max(ax.get_window_extent(renderer).height, 1.0)
            lo, hi = ax.get_ylim()
            grow = min(frac + 0.06, 0.7) / max(1.0 - frac - 0.06, 0.3)
            if ax.get_yscale() == "log" and lo > 0 and hi > 0:
                import math

                ax.set_ylim(lo, 10 ** (math.log10(hi) + grow * (math.log10(hi) - math.log10(lo))))
            else:
                ax.set_ylim(lo, hi + grow * (hi - lo))
            for loc in _LEGEND_LOCS[:2]:
                leg.set_loc(loc)
                if _legend_cover(ax, leg, renderer)[0] == 0:
                    break
    except Exception as exc:  # placement is cosmetic: never lose the plot over it
        logger.debug("legend placement fell back to 'best': %s", exc)
        leg.set_loc("best")
    return leg


def _wrap_title(title: str, width_in: float) -> str:
    """A title wrapped to an axes ``width_in`` inches wide at 10 pt (its own line breaks kept)."""
    chars = max(30, int(width_in / 0.068))
    return "\n".join(textwrap.fill(line, chars) for line in str(title).split("\n"))


def _draw_bars(ax: Any, bars: dict[str, float]) -> None:
    names = list(bars)
    vals = [bars[k] for k in names]
    colours = ["#c62828" if v < 0 else "#1b7f3b" for v in vals]
    ax.barh(range(len(names)), vals, color=colours, alpha=0.8)
    ax.set_yticks(range(len(names)), [_mtext(n) for n in names], fontsize=8)
    ax.axvline(0.0, color="#555555", linestyle="--", linewidth=1.0)
    ax.set_xlabel("margin [1]", fontsize=9)
    ax.set_title("pole and residue conditions", fontsize=9, loc="right")  # the narrow panel: spill left
    ax.tick_params(axis="x", labelsize=7)
    ax.grid(True, axis="x", alpha=0.3)


def _superscript(e: int) -> str:
    return str(e).translate(str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹"))


def _corner_offset(x: Any) -> float:
    """A round reference value to subtract from a parameter's draws when their spread is below
    10⁻³ of their size (then plain tick labels would need ten digits): the median rounded one
    decade below the spread. 0 when no offset is needed."""
    import numpy as np

    if x.size < 2:
        return 0.0
    med = float(np.median(x))
    spread = float(np.quantile(x, 0.95) - np.quantile(x, 0.05))
    if not (math.isfinite(med) and math.isfinite(spread)) or spread <= 0 or abs(med) < 1e3 * spread:
        return 0.0
    step = 10.0 ** (math.floor(math.log10(spread)) - 1)
    return float(round(med / step) * step)


def _draw_corner(fig: Any, s: Series, rect: tuple[float, float, float, float]) -> None:
    """A corner plot of the series' lines (each a parameter's draws, named ``p [unit]``) drawn
    into ``rect`` (inches) of ``fig`` as vector axes, ticks and labels; only the scatter of the
    draws is rasterized (``corner`` does that for its data points, the fallback grid with
    ``rasterized=True``), so a PDF keeps its text selectable without carrying thousands of markers."""
    import numpy as np
    from matplotlib.gridspec import GridSpec

    from hil.certify.units import pretty_unit

    data = np.column_stack([_arr(s.lines[k]) for k in s.lines])
    data = data[np.all(np.isfinite(data), axis=1)]
    names = []
    for j, label in enumerate(s.lines):
        name, _, unit = label.rpartition(" [")
        name, unit = (name, "[" + pretty_unit(unit)) if name else (label, "")
        ref = _corner_offset(data[:, j])
        if ref:
            data[:, j] -= ref
            name = f"{name} − {fmt(ref, 10)}"
        big = float(np.max(np.abs(data[:, j]))) if data.shape[0] else 0.0
        e = 3 * math.floor(math.log10(big) / 3) if big > 0 and math.isfinite(big) else 0
        if e < -3 or e > 3:  # engineering scale in the unit: ticks stay short, no floating "1e-6"
            data[:, j] *= 10.0 ** (-e)
            unit = f"[×10{_superscript(e)} {unit[1:]}" if unit else f"[×10{_superscript(e)}]"
        names.append(f"{name}\n{unit}" if unit else name)
    try:
        import corner
    except ImportError:  # declared in the report extra; a plain grid otherwise
        corner = None
    k = len(names)
    # a subfigure holds exactly the k x k axes corner expects; they are placed in ``rect`` afterwards
    sub = fig.add_subfigure(GridSpec(1, 1, figure=fig)[0])
    sub.set_facecolor("none")
    axes = np.atleast_2d(np.asarray(sub.subplots(k, k, squeeze=False)))
    if corner is not None:
        corner.corner(data, labels=[_mtext(n) for n in names], quantiles=[0.05, 0.5, 0.95], fig=sub,
                      label_kwargs={"fontsize": 8}, max_n_ticks=3, plot_datapoints=True, labelpad=0.12)
        axes = np.asarray(sub.axes).reshape(k, k)
        for ax in sub.axes:
            ax.tick_params(labelsize=6)
            for axis in (ax.xaxis, ax.yaxis):  # plain numbers, no "1e-12+3.62e2" offsets
                fm = axis.get_major_formatter()
                if hasattr(fm, "set_useOffset"):
                    fm.set_useOffset(False)
    else:
        for r in range(k):
            for c in range(k):
                ax = axes[r, c]
                if c > r:
                    ax.set_axis_off()
                elif r == c:
                    ax.hist(data[:, c], bins=30, histtype="step", color="k")
                else:
                    ax.plot(data[:, c], data[:, r], ",", color="k", alpha=0.4, rasterized=True)
                ax.tick_params(labelsize=6)
                if r == k - 1:
                    ax.set_xlabel(_mtext(names[c]), fontsize=7)
                if c == 0 and r > 0:
                    ax.set_ylabel(_mtext(names[r]), fontsize=7)
    fw, fh = fig.get_size_inches()
    x0, y0, w, h = rect
    left, right, top, bottom, gap = 0.85, 0.25, 0.35, 0.85, 0.06
    side = min((w - left - right - gap * (k - 1)) / k, (h - top - bottom - gap * (k - 1)) / k)
    gx = x0 + left + max(0.0, (w - left - right - k * side - gap * (k - 1)) / 2)
    for r in range(k):
        for c in range(k):
            axes[r, c].set_position(((gx + c * (side + gap)) / fw, (y0 + h - top - (r + 1) * side - r * gap) / fh,
                                     side / fw, side / fh))
    fig.text((x0 + w / 2) / fw, (y0 + h - 0.12) / fh, _mtext(s.title), fontsize=10, ha="center", va="top")


def _standardized(s: Series) -> bool:
    return "(standardized)" in s.x_label and "(standardized)" in s.y_label


def _plot_height(s: Series) -> float:
    """Height in inches of a plot 6.8 in wide (panels stacked beneath the main axes)."""
    if s.kind == "corner":
        return min(6.8, 1.5 * max(2, len(s.lines)) + 0.8)
    if _standardized(s):
        return 4.6
    return 2.9 + 1.35 * len(s.panels)


def draw_plot(fig: Any, s: Series, rect: tuple[float, float, float, float] | None = None, dpi: int = 110
              ) -> list[str]:
    """Draw a Series (main axes, stacked panels beneath, a bar panel on the right, or a corner
    plot) into ``rect`` = (x, y, width, height) in inches on ``fig`` (default: the whole figure);
    returns notes on anything left out. Never raises for a bad series."""
    import warnings

    fw, fh = fig.get_size_inches()
    x0, y0, w, h = rect if rect is not None else (0.0, 0.0, float(fw), float(fh))

    def axes(x: float, y: float, ww: float, hh: float, **kw: Any) -> Any:
        return fig.add_axes((x / fw, y / fh, ww / fw, hh / fh), **kw)

    made: list[Any] = []
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # e.g. log axes with non-positive values (masked)
            if s.kind == "corner":
                n_sub = len(fig.subfigs)
                try:
                    _draw_corner(fig, s, (x0, y0, w, h))
                except Exception:
                    for sf in fig.subfigs[n_sub:]:
                        sf.remove()
                    raise
                return []
            left, right, top, bottom, gap = 0.75, 0.15, 0.3, 0.5, 0.7
            bars_w = 1.9 if s.bars else 0.0
            main_w = w - left - right - (bars_w + 0.35 if s.bars else 0.0)
            top += 0.17 * _wrap_title(s.title, main_w).count("\n")  # a wrapped title needs its lines
            n_p = len(s.panels)
            avail = h - top - bottom - gap * n_p
            unit = avail / (2.0 + n_p)
            y = y0 + h - top - 2.0 * unit
            ax = axes(x0 + left, y, main_w, 2.0 * unit)
            made.append(ax)
            notes = _draw_series(ax, s)
            if s.bars:
                bx = axes(x0 + left + main_w + 0.35 + 1.1, y, bars_w - 1.1, 2.0 * unit)
                made.append(bx)
                _draw_bars(bx, s.bars)
            for p in s.panels:
                y -= gap + unit
                pax = axes(x0 + left, y, main_w, unit, sharex=ax if p.log_x == s.log_x and p.x == s.x else None)
                made.append(pax)
                notes += [f"panel {p.title}: {n}" for n in _draw_series(pax, p)]
            return notes
    except Exception as exc:  # a bad series must not lose the whole report
        for a in made:
            a.remove()
        fig.text((x0 + w / 2) / fw, (y0 + h / 2) / fh, f"plot could not be drawn: {_mtext(_one_line(exc))[:120]}",
                 ha="center", va="center", color="#c62828")
        return [f"could not be drawn: {_one_line(exc)}"]


def _safe_draw(ax: Any, s: Series) -> list[str]:
    """Draw a series on one axes (kept for callers drawing a single panel)."""
    return _draw_series(ax, s)


def _plots_png(cert: Certificate, dpi: int = 110) -> dict[str, _Plot]:
    import warnings

    from matplotlib.figure import Figure

    out = {}
    for name, s in cert.plots.items():
        fig = Figure(figsize=(9.0, 1.25 * _plot_height(s)), dpi=dpi)
        notes = draw_plot(fig, s, dpi=dpi)
        buf = io.BytesIO()
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"Glyph \d+ .* missing from", category=UserWarning)
            warnings.filterwarnings("ignore", category=UserWarning)
            fig.savefig(buf, format="png", dpi=dpi, facecolor="white")
        out[name] = _Plot(name, s.title, base64.b64encode(buf.getvalue()).decode("ascii"), notes)
    return out


# ---------------------------------------------------------------------------------------------
# JSON record


def _canonical_json(cert: Certificate) -> str:
    """The stored text: every field, except those added after schema 1.1 while at their default
    (so the file minus ``integrity`` is exactly the digested content, hil-c14n/1)."""
    from hil.certify.certificate import drop_new_defaults

    data = json.loads(cert.model_dump_json())
    drop_new_defaults(cert, data)
    return json.dumps(data, indent=2, ensure_ascii=False) + "\n"


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
    from hil.certify.strict_json import StrictJsonError, loads

    text = _canonical_json(cert)
    try:  # read back as hil verify reads it (strict JSON), so nothing is written that it would refuse
        Certificate.model_validate(loads(text))
    except StrictJsonError as exc:
        raise ReportError(f"certificate would not read back: {exc}") from None
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
    from hil.certify.strict_json import StrictJsonError, read_json_file

    p = _resolve(path)
    try:  # a regular file, bounded, no duplicate member, only finite numbers (docs/INTEGRITY.md)
        data = read_json_file(p)
    except StrictJsonError as exc:
        raise ReportError(str(exc)) from None
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
                       status_class=_status_class, link=definition_link, cell_class=_cell_class)
    return env


def _html_context(cert: Certificate, st: IntegrityStatus, images: dict[str, _Plot] | None = None
                  ) -> dict[str, Any]:
    """The template's context. ``images``: the figures as :func:`render_pdf` drew them (one draw for
    both documents); without them (the HTML alone) each figure is drawn here."""
    short = cert.decision == "ERROR"  # an ERROR certificate's report is short: no figures
    if images is not None:
        plots = {k: v for k, v in images.items() if not k.startswith("chart:")}
        charts = {k.removeprefix("chart:"): v for k, v in images.items() if k.startswith("chart:")}
    else:
        plots = _plots_png(cert) if cert.plots and not short else {}
        charts = _charts_png(cert) if cert.robust is not None and not short else {}
    ctx: dict[str, Any] = {
        "cert": cert,
        "title": (f"{MODIFIED} — " if not st.valid else "") + f"Certificate: {cert.scene.name} — {cert.decision}",
        "decision_class": _style(cert, st)[0],
        "modified": not st.valid,
        "modified_text": MODIFIED,
        "modified_reason": st.reason(),
        "bench": dict(zip(("label", "note", "kind"), bench_banner(cert), strict=True)),
        "integrity": st,
        "digest_text": _digest_text(st),
        "signature_text": st.signature_text(),
        "evidence_note": _evidence_note(st),
        "toc": [(k, SECTION_TITLES[k]) for k in _present_sections(cert)],
        "sections": report_sections(cert),
        "summary": _kv_table(summary_rows(cert, st)),
        "margin_note": margin_note(cert),
        "measurements": measurements_table(cert),
        "outcome_counts": _outcome_counts(cert),
        "plots": plots,
        "charts": charts,
        "robust_status": None,
        "gauge": None,
        "show_truth": False,
        "headroom": headroom(cert.design) if cert.design is not None else "",
    }
    if cert.robust is not None:
        ctx["robust_status"] = _robust_status(cert)
        ctx["gauge"] = _gauge(cert)
    if cert.identification:
        ctx["show_truth"] = any(p.truth is not None for i in cert.identification for p in i.parameters)
    return ctx


def _kv_table(rows: list[tuple[str, str, str, str | None]]) -> Table:
    from hil.report.sections import _kv

    return _kv(rows)


def _cell_class(t: Table, i: int, j: int) -> str:
    """CSS class of a model-table cell: its outcome colour, else num / nowrap."""
    o = t.colours[i][j] if t.colours else None
    if o in OUTCOME_STYLE:
        return OUTCOME_STYLE[o][0]
    c = t.columns[j]
    return " ".join(k for k, on in (("num", c.num), ("nowrap", c.nowrap)) if on)


def _outcome_counts(cert: Certificate) -> list[tuple[str, int]]:
    counts: dict[str, int] = {}
    for m in cert.measurements:
        counts[m.outcome] = counts.get(m.outcome, 0) + 1
    return [(o, counts[o]) for o in OUTCOME_STYLE if o in counts]


def render_html(cert: Certificate, out_path: str | os.PathLike[str], *,
                integrity: IntegrityStatus | None = None, images: dict[str, _Plot] | None = None) -> Path:
    """Write the certificate as one self-contained, printable HTML file; returns its path.
    ``integrity`` (default: the digest check of ``cert``) decides the MODIFIED marking and the
    signature status shown."""
    env = _jinja_env()
    html = env.get_template("report.html.j2").render(**_html_context(cert, _status(cert, integrity), images))
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


def draw_pstable(ax: Any, cert: Certificate) -> None:
    """The P(stable) figure: the estimate and its confidence interval against the required level
    (the lower bound must clear it), on an axis zoomed on [a, 1]."""
    r = cert.robust
    assert r is not None
    status, _ = robust_status(cert)
    colour = {"PASS": "#1b7f3b", "MARGINAL": "#f2a900", "FAIL": "#c62828"}[status]
    vals = [v for v in (r.lower, r.p_stable, r.required) if math.isfinite(v)]
    lo = min(vals) if vals else 0.0
    a = max(0.0, lo - max(0.25 * (1.0 - lo), 0.005))
    ax.barh([0], [r.upper - r.lower], left=[r.lower], height=0.5, color=colour, alpha=0.35, edgecolor=colour,
            label=f"{r.confidence:.0%} interval [{fmt_p(r.lower)}, {fmt_p(r.upper)}]")
    ax.plot([r.p_stable], [0], "o", color=colour, markersize=9, label=f"P̂ = {fmt_p(r.p_stable)}")
    ax.axvline(r.required, color="#1d2733", linestyle="--", linewidth=1.5, label=f"required {fmt_p(r.required)}")
    ax.set_xlim(a, 1.0 + 0.02 * (1.0 - a))
    ax.set_ylim(-0.8, 0.8)
    ax.set_yticks([])
    ax.set_xlabel("P(stable) [1]", fontsize=9)
    ax.set_title(f"P(stable) against the requirement: {status}", fontsize=10)
    ax.tick_params(labelsize=8)
    ax.grid(True, axis="x", alpha=0.3)
    ax.legend(loc="upper left", fontsize=7, ncol=3, framealpha=0.9)


def chart_height(cert: Certificate, key: str) -> float:
    """Height in inches of a chart drawn from the record (:data:`hil.report.sections.CHARTS`)."""
    if key == "p_failure" and cert.robust is not None:
        return 1.25 + 0.55 * len(failure_estimates(cert)) + (1.3 if cert.robust.reliability is not None else 0.0)
    return 0.0


def draw_chart(fig: Any, cert: Certificate, key: str, rect: tuple[float, float, float, float]) -> None:
    """Draw a chart of the record into ``rect`` (inches) of ``fig``; only ``p_failure`` exists: every
    estimate of P(not stable) = 1 − P(stable) (sampled with its Clopper-Pearson interval, FORM Φ(−β),
    importance sampling with its interval) on one logarithmic axis against the allowance
    1 − required, and β against the β a GO needs."""
    r = cert.robust
    if key != "p_failure" or r is None:
        return
    labels = CHARTS[key]
    est = failure_estimates(cert)
    allow = 1.0 - r.required
    rel = r.reliability
    fw, fh = fig.get_size_inches()
    x0, y0, w, h = rect
    beta_h = 1.3 if rel is not None else 0.0
    ax = fig.add_axes(((x0 + 0.2) / fw, (y0 + beta_h + 0.5) / fh, (w - 0.35) / fw, (h - beta_h - 0.85) / fh))
    cands = [v for e in est for v in (e.value, e.lower, e.upper) if v is not None and v > 0 and math.isfinite(v)]
    cands = [v for v in [*cands, allow] if v >= 1e-15]
    floor = max(10.0 ** (math.floor(math.log10(min(cands))) - 1), 1e-15) if cands else 1e-6
    n = len(est)
    ax.axvspan(allow, 1.3, color="#c62828", alpha=0.10, linewidth=0, label="above the allowance: not certified")
    ax.axvline(allow, color="#1d2733", linestyle="--", linewidth=1.3, label=f"allowance 1 − required = {fmt(allow)}")
    for k, e in enumerate(est):
        y = n - 1 - k
        c = "#0b3d91" if e.decides else "#6b7785"
        if e.lower is not None and e.upper is not None:
            lo, hi = max(e.lower, floor), max(e.upper, floor)
            ax.barh([y], [max(hi - lo, 0.0)], left=[lo], height=0.28, color=c, alpha=0.35, edgecolor=c)
        vtxt = fmt(e.value)
        if e.value is not None and e.value > floor:
            ax.plot([e.value], [y], "o", color=c, markersize=7)
        elif e.value is not None:  # below the axis: at its left end, value printed
            ax.plot([floor], [y], "<", color=c, markersize=8, clip_on=False)
            if e.value == 0.0 and e.log10_value is None:
                vtxt = "0"
            elif e.log10_value is not None:
                vtxt = f"10{_superscript(round(e.log10_value))}" if e.log10_value < -300 else fmt(e.value)
        rng = "" if e.lower is None or e.upper is None else f", interval [{fmt(e.lower)}, {fmt(e.upper)}]"
        text = f"{e.label}: {vtxt}{rng}" + (" — the decision uses it" if e.decides else "") + \
            (f" ({e.note})" if e.note else "")
        ax.text(floor * 1.15, y + 0.24, _mtext(text), fontsize=7.5, color=c, va="bottom",
                weight="bold" if e.decides else "normal")
    ax.set_xscale("log")
    ax.set_xlim(floor, 1.3)
    ax.set_ylim(-0.5, n - 0.1)
    ax.set_yticks([])
    ax.set_xlabel(_mtext(labels[0]), fontsize=9)
    status, _ = robust_status(cert)
    ax.set_title(f"P(not stable) against the allowance: {status}", fontsize=10)
    ax.tick_params(labelsize=8)
    ax.grid(True, axis="x", which="major", alpha=0.35)
    place_legend(ax, fontsize=7)
    if rel is None:
        return
    bx = fig.add_axes(((x0 + 0.2) / fw, (y0 + 0.45) / fh, (w - 0.35) / fw, (beta_h - 0.75) / fh))
    b, breq = float(rel.beta), float(rel.required_beta)
    ok = b >= breq
    colour = "#1b7f3b" if ok else "#c62828"
    bx.barh([0], [b], height=0.42, color=colour, alpha=0.75)
    bx.axvline(breq, color="#1d2733", linestyle="--", linewidth=1.3)
    lo_x = min(0.0, b, breq)
    hi_x = max(b, breq, 0.0)
    pad = 0.08 * (hi_x - lo_x or 1.0)
    bx.set_xlim(lo_x - pad, hi_x + pad)
    bx.set_ylim(-0.75, 0.75)
    right = (breq - lo_x) < 0.6 * (hi_x - lo_x)  # room right of the required line for its label
    bx.text(breq + (0.01 if right else -0.01) * (hi_x - lo_x), 0.3, f" required β = Φ⁻¹({fmt_p(r.required)}) = "
            f"{fmt(breq)} ", fontsize=7.5, ha="left" if right else "right", va="bottom", color="#1d2733")
    bx.text(b, -0.3, f" β = {'≥ ' if rel.censored else ''}{fmt(b)}, Φ(β) = {fmt_p(rel.phi_beta)} ", fontsize=7.5,
            ha="right" if b > lo_x + 0.5 * (hi_x - lo_x) else "left", va="top", color=colour, weight="bold")
    bx.set_yticks([])
    bx.set_xlabel(_mtext(labels[1]), fontsize=9)
    bx.tick_params(labelsize=8)
    bx.grid(True, axis="x", alpha=0.35)
    bx.set_title(f"reliability index β against the β a GO needs: {'PASS' if ok else 'FAIL'}", fontsize=9)


def _charts_png(cert: Certificate, dpi: int = 110) -> dict[str, _Plot]:
    """The charts of the report model (drawn from the record), as PNG for the HTML page."""
    import warnings

    from matplotlib.figure import Figure

    out: dict[str, _Plot] = {}
    keys = {b.plot for sec in report_sections(cert) for b in sec.blocks if b.kind == "chart"}
    for key in sorted(keys):
        h = chart_height(cert, key)
        if h <= 0:
            continue
        fig = Figure(figsize=(9.0, 1.25 * h), dpi=dpi)
        draw_chart(fig, cert, key, (0.3, 0.0, 8.6, 1.25 * h))
        buf = io.BytesIO()
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=UserWarning)
            fig.savefig(buf, format="png", dpi=dpi, facecolor="white")
        out[key] = _Plot(key, key, base64.b64encode(buf.getvalue()).decode("ascii"))
    return out


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
    if integrity is None:  # the evidence was hashed from this folder: the reports say it matches
        integrity = check_certificate(cert, d)
    json_path = write_json(cert, d / CERT_NAME)
    images: dict[str, _Plot] = {}  # each figure drawn once, on its PDF page; the HTML shows that drawing
    pdf = render_pdf(cert, d / "report.pdf", integrity=integrity, images=images)
    return {"json": json_path, "html": render_html(cert, d / "report.html", integrity=integrity, images=images),
            "pdf": pdf}


def rebuild_reports(path: str | Path, out: str | Path | None = None, public_key: str | Path | None = None,
                    allow_modified: bool = False) -> tuple[Certificate, IntegrityStatus, dict[str, Path]]:
    """What ``hil report PATH [--out DIR] [--public-key PUB] [--allow-modified]`` does (parsed by
    hil.cli.main): rebuild report.html and report.pdf from a stored certificate.json (``path`` is the file
    or a folder holding it) into ``out`` (default: the certificate's folder). Returns the
    certificate, its integrity status and the two paths.

    A certificate that does not match its digest (or has none), whose evidence files (records,
    scene copy, relative to the certificate's folder) no longer match their recorded SHA-256, or
    whose signature fails with ``public_key``, raises :class:`ReportError`; ``allow_modified``
    renders it marked MODIFIED: NOT A VALID CERTIFICATE on every page."""
    cert = load_certificate(path)
    key = None
    if public_key:
        from hil.certify.signing import load_public_key

        key = load_public_key(public_key)
    # the evidence files are re-hashed too: a record swapped after certification is refused (or,
    # with --allow-modified, marked on every page), as hil verify refuses it
    st = check_certificate(cert, _resolve(path).parent, public_key=key)
    if key is not None and st.signature == "absent":
        st.signature, st.signature_detail = "invalid", "the certificate is not signed"
    if not st.valid and not allow_modified:
        raise ReportError(f"{_resolve(path)}: {st.reason()}; refusing to render it "
                          f"(--allow-modified renders it marked '{MODIFIED}')")
    folder = Path(out) if out else _resolve(path).parent
    images: dict[str, _Plot] = {}
    pdf = render_pdf(cert, folder / "report.pdf", integrity=st, images=images)
    paths = {"html": render_html(cert, folder / "report.html", integrity=st, images=images), "pdf": pdf}
    return cert, st, paths
