"""The report's figures, drawn with matplotlib (imported lazily; Figure objects without pyplot, so no
global state): the certificate's data series (:func:`draw_plot`; the plot convention is in
:mod:`hil.report.render`) and its charts (:func:`draw_chart`, :func:`draw_pstable`). Each figure is drawn
once, on its PDF page, and cropped to PNG for the HTML (:class:`Plot`)."""

from __future__ import annotations

import base64
import io
import logging
import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from hil.certify.certificate import Certificate, Series
from hil.report.common import _one_line
from hil.report.sections import (
    CHARTS,
    failure_estimates,
    fmt,
    fmt_p,
    report_sections,
    robust_status,
)

logger = logging.getLogger(__name__)

__all__ = [
    "HTML_DPI",
    "chart_height",
    "draw_chart",
    "draw_plot",
    "draw_pstable",
    "place_legend",
]


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


