"""Evidence plots and the witness response, as certificate data (:class:`hil.certify.certificate.Series`).

Called by the plot builders of :mod:`hil.certify.pipeline` (one line each); rendered by :mod:`hil.report.render`.
Every axis label ends with its SI unit in brackets (``[1]`` for a dimensionless quantity), from
the scene's ``units`` (:mod:`hil.certify.units`).

* :func:`identification_plots` -- per FRF output: magnitude (measured H1 with its confidence band
  from the coherence, the posterior median and its 90 % band), phase, coherence and normalized
  residuals stacked; a corner plot of the posterior (``corner`` package, ``report`` extra).
* :func:`decided_plot` -- the decisive frequency condition of the criterion (the failing one
  with the smallest margin for a NO-GO, the one with the smallest margin otherwise), its negative
  region shaded and its worst frequency marked; imaginary-axis and infinity conditions (which
  have no frequency curve) as bars of their residue margins.
* :func:`witness_response` -- the closed-loop poles a destabilizing termination creates, the
  growth rate, and the exact simulation of the driven port until it crosses the bench's safety
  limits (time to the limit and the port energy then), instead of an energy from a diverging
  simulation.

Confidence band of the measured FRF (Bendat & Piersol, random error of an H1 estimate with
``n_d`` averages and squared coherence γ²): ε = √(1 − γ²) / (|γ| √(2 n_d)); the band is
|H1|·(1 ± 2ε) (≈ 95 %), clipped at a factor 10⁻³ below.
"""

from __future__ import annotations

import logging
import math
import re
from typing import Any

import numpy as np

from hil.certify.certificate import Series
from hil.certify.units import frf_unit, parameter_unit, quantity_unit
from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["decided_plot", "decisive_condition", "design_point_axes", "design_point_plot", "headroom_plot",
           "identification_plots", "immittance_db_label", "limit_trace_height", "limit_trace_resolution",
           "witness_response"]


def _clean(a: Any) -> list[float | None]:
    return [float(x) if math.isfinite(x) else None for x in np.asarray(a, float)]


def _db(a: Any) -> list[float | None]:
    """20 log10 |a| (a real or complex)."""
    return _clean(20 * np.log10(np.maximum(np.abs(np.asarray(a)), 1e-300)))


def immittance_db_label(kind: str, units: str | None) -> str:
    """The y label of an immittance magnitude in dB: ``|Z| [dB re 1 N.s/m]`` (a hybrid (1,1)
    entry is an impedance)."""
    q = "admittance" if kind == "admittance" else "impedance"
    return f"|{kind} entry (1,1)| [dB re 1 {quantity_unit(q, units)}]"


# ---------------------------------------------------------------------------------------------
# identification


def identification_plots(plots: dict[str, Series], name: str, res: Any, seed: int, units: str | None) -> None:
    """FRF evidence per output (first input) and the posterior corner plot (see the module docstring)."""
    est, mdl = res.frf, res.model
    samp = np.asarray(res.posterior.samples)[:, : mdl.n_params]
    rng = np.random.default_rng(seed + 2)
    pick = samp[rng.choice(samp.shape[0], size=min(150, samp.shape[0]), replace=False)]
    Hd = mdl.frf(pick, est.w)
    Hm = mdl.frf(np.median(samp, axis=0), est.w)
    no = est.H.shape[1]
    f = est.f.tolist()
    n_avg = max(float(est.n_avg), 1.0)
    for o in range(min(no, 2)):
        i = 0
        H = est.H[:, o, i]
        ins = est.input_names[i] if est.input_names else "input"
        outs = est.output_names[o] if est.output_names else f"output {o}"
        u = frf_unit(outs, ins, units) or "1"
        g2 = np.clip(np.asarray(est.coherence[:, o], float), 1e-12, 1.0)
        eps = np.sqrt(1.0 - g2) / (np.sqrt(g2) * math.sqrt(2.0 * n_avg))
        lo_m, hi_m = np.abs(H) * np.maximum(1.0 - 2.0 * eps, 1e-3), np.abs(H) * (1.0 + 2.0 * eps)
        q05, q95 = np.quantile(np.abs(Hd[:, :, o, i]), [0.05, 0.95], axis=0)
        ph_d = np.degrees(np.unwrap(np.angle(Hd[:, :, o, i]), axis=1))
        ph_m = np.degrees(np.unwrap(np.angle(Hm[:, o, i])))
        ph_h = np.degrees(np.unwrap(np.angle(H)))
        ph_h += 360.0 * np.round((np.median(ph_m - ph_h)) / 360.0)  # same branch as the model
        p05, p95 = np.quantile(ph_d, [0.05, 0.95], axis=0)
        shift = 360.0 * np.round(np.median(ph_m - np.median(ph_d, axis=0)) / 360.0)
        sig = np.asarray(est.sigma[:, o, i], float)
        with np.errstate(invalid="ignore", divide="ignore"):
            r = (Hm[:, o, i] - H) / np.where(sig > 0, sig, np.nan)
        n = len(f)
        plots[f"frf_{name}_{o}"] = Series(
            title=f"FRF fit ({name}): {ins} → {outs}", x=f, x_label="f [Hz]",
            y_label=f"|H| [dB re 1 {u}]" if u != "1" else "|H| [dB re 1]",
            log_x=True,
            lines={"posterior median": _db(Hm[:, o, i]), "measured H1": _db(H)},
            bands={"posterior median": (_db(q05), _db(q95)), "measured H1": (_db(lo_m), _db(hi_m))},
            panels=[
                Series(title="phase", x=f, x_label="f [Hz]", y_label="phase [deg]", log_x=True,
                       lines={"posterior median": _clean(ph_m), "measured H1": _clean(ph_h)},
                       bands={"posterior median": (_clean(p05 + shift), _clean(p95 + shift))}),
                Series(title="coherence", x=f, x_label="f [Hz]", y_label="γ² [1]", log_x=True,
                       lines={"coherence γ²": _clean(g2)}),
                Series(title="normalized residual (posterior median − H1)/σ", x=f, x_label="f [Hz]",
                       y_label="residual [1]", log_x=True,
                       lines={"real part": _clean(r.real), "imaginary part": _clean(r.imag)},
                       bands={"±2 (95 %)": ([-2.0] * n, [2.0] * n)}, hline=0.0),
            ])
    names = list(res.names)[: samp.shape[1]]
    if samp.shape[1] >= 2:
        units_of = dict(zip(mdl.names, mdl.units, strict=False))
        sub = samp[:: max(1, samp.shape[0] // 1500)]
        plots[f"corner_{name}"] = Series(
            title=f"Posterior of the identified parameters ({name})", kind="corner",
            x=[float(k) for k in range(sub.shape[0])], x_label="draw [1]", y_label="value [parameter units]",
            lines={f"{p} [{units_of.get(p) or parameter_unit(p, units) or '1'}]": sub[:, k].tolist()
                   for k, p in enumerate(names)})


# ---------------------------------------------------------------------------------------------
# the decisive condition


def decisive_condition(r: Any) -> Any:
    """The condition that decides: of a potentially unstable result, the violated one with the
    smallest margin; otherwise the one with the smallest finite margin (preconditions A, B, A*
    excluded). None when no condition has a finite margin."""
    conds = [c for c in r.conditions if c.margin is not None and math.isfinite(c.margin)
             and c.name not in ("A", "B", "A*")]
    failed = [c for c in conds if c.status == "violated"]
    pool = failed or conds
    return min(pool, key=lambda c: c.margin) if pool else None


def _is_frequency(c: Any) -> bool:
    return c.name.startswith("E")


def _indices(name: str) -> list[int] | None:
    m = re.search(r"[{\[]([\d,\s]+)[}\]]", name)
    return [int(t) - 1 for t in m.group(1).split(",")] if m else None


def _condition_curve(tm: Any, r: Any, c: Any) -> tuple[np.ndarray, np.ndarray]:
    """(ω [rad/s], the normalized margin function of condition ``c``) on a grid over the network's
    poles and zeros: the same ratio the criterion minimizes (hil.stability.criteria)."""
    from hil.stability import criteria as C

    tmn, w0 = C._normalized(tm)
    lo, hi = C._freq_range(tmn.entries)
    w = np.geomspace(lo, hi, 800)
    idx = _indices(c.name)
    if idx is None:
        raise HilError(f"condition {c.name}: no index set")
    entries = tmn.entries
    if "Z'" in c.label:  # Theorem 1: minors of the symmetrized Z'
        entries = _symmetrized(tmn, idx) or entries
        if entries is not tmn.entries:
            idx = list(range(len(idx))) if len(entries) == len(idx) else idx
    sub = [[entries[a][b] for b in idx] for a in idx]
    fn = C._eta_ratio(sub) if "Llewellyn" in c.label and len(idx) == 2 else C._hermitian_ratio(sub)
    with np.errstate(all="ignore"):
        y = np.asarray(fn(w), float)
    return w * w0, y


def _symmetrized(tmn: Any, idx: list[int]) -> list[list[Any]] | None:
    """Z' (z'_ij = γ_ij √(z_ij z_ji)) restricted to the index set ``idx`` when it is rational, as
    the criterion forms it; None otherwise."""
    from hil.stability import criteria as C

    n = tmn.n
    W = {}
    for i in range(n):
        for j in range(i + 1, n):
            if i in idx and j in idx and not (tmn[i, j].is_zero or tmn[j, i].is_zero):
                rt = C._rational_sqrt(tmn[i, j], tmn[j, i])
                if rt is None:
                    return None
                W[(i, j)] = rt
    try:
        Zs = C._symmetrize(tmn, sorted(idx), W)
    except Exception:
        return None
    return Zs


def _margin_curve(tm: Any, r: Any, c: Any) -> tuple[np.ndarray, np.ndarray, bool]:
    """(ω [rad/s], curve, exact) of a frequency condition: when the condition carries the ratio its
    margin minimizes (``Condition.ratio``: the exact condition polynomial p and the magnitude
    polynomial m_r, in the criterion's normalized frequency), ρ(ω) = p(x)/m_r(x) at x = (ω/ω₀)²
    itself -- the function whose minimum over ω is the margin the table prints (``exact`` True);
    otherwise (a condition decided on a grid) the criterion's normalized function on a grid."""
    from hil.stability import criteria as C
    from hil.stability.minimize import _Ratio
    from hil.stability.rational import _qpoly_floats

    tmn, w0 = C._normalized(tm)
    lo, hi = C._freq_range(tmn.entries)
    w = np.geomspace(lo * w0, hi * w0, 800)
    wf = c.worst_frequency
    if wf is not None and math.isfinite(wf) and wf > 0:
        w = np.unique(np.concatenate([w, [float(wf)]]))  # the table's worst frequency is on the curve
    ratio = getattr(c, "ratio", None)
    if ratio is not None:
        p, m_r = ratio
        rho = _Ratio(np.array(_qpoly_floats(p), float), np.asarray(m_r, float))
        scale = float((getattr(r, "network", None) or {}).get("omega_scale", w0))
        return w, np.asarray(rho((w / scale) ** 2), float), True
    wc, y = _condition_curve(tm, r, c)
    return wc, y, False


def decided_plot(plots: dict[str, Series], tm: Any, r: Any) -> None:
    """The ``decided`` plot (see the module docstring). One source with the conditions table: the
    curve is the condition's own margin function p/m_r (from the same evidence as its margin), the
    marked point is the row's (worst frequency, margin), and every number in the legend is printed
    by :func:`hil.certify.numbers.fmt`, the table's formatter."""
    from hil.certify.numbers import fmt

    dec = decisive_condition(r)
    freq = [c for c in r.conditions if _is_frequency(c) and c.margin is not None and math.isfinite(c.margin)]
    shown = dec if dec is not None and _is_frequency(dec) else None
    if shown is None and freq:
        failed = [c for c in freq if c.status == "violated"]
        shown = min(failed or freq, key=lambda c: c.margin)
    residues = {c.name: float(c.margin) for c in r.conditions
                if (c.name.startswith(("C", "D"))) and c.margin is not None and math.isfinite(c.margin)}
    if shown is None:
        plots["decided"] = Series(title=f"Decisive condition ({r.criterion}): {dec.name if dec else '—'}",
                                  x=[], x_label="ω [rad/s]", y_label="normalized margin [1]", bars=residues)
        return
    w, y, exact = _margin_curve(tm, r, shown)
    pts: dict[str, tuple[float, float]] = {}
    wf = shown.worst_frequency
    m = float(shown.margin)
    name = f"{shown.name}: {shown.label}"
    if wf is None:  # ρ constant in ω: the minimum is attained at every frequency (no single point)
        name += f" (margin {fmt(m)}, the same at every ω)"
    elif math.isfinite(wf) and wf > 0:
        pts[f"margin {shown.name} = {fmt(m)} at ω = {fmt(float(wf))} rad/s"] = (float(wf), m)
    else:  # attained as ω → 0 or ω → ∞ (the table's "0" / "inf"): drawn at that end of the axis
        at_zero = wf == 0
        end = float(w[0] if at_zero else w[-1])
        pts[f"margin {shown.name} = {fmt(m)} at ω = {'0' if at_zero else 'inf'} rad/s (its limit, drawn at the "
            f"{'left' if at_zero else 'right'} edge)"] = (end, m)
    if not exact:
        name += " (on a grid)"
    if shown is dec:
        title = f"Decisive condition {shown.name} ({r.criterion})"
    else:
        title = (f"Decisive condition {dec.name}: a residue (bars, right)\ncurve: the frequency condition with "
                 f"the {'most negative' if shown.status == 'violated' else 'smallest'} margin, {shown.name}")
    plots["decided"] = Series(
        title=title, x=[float(v) for v in w], x_label="ω [rad/s]",
        y_label="margin p(ω²)/m_r(ω²) [1]" if exact else "normalized margin [1]", log_x=True,
        lines={name: _clean(y)}, points=pts, hline=0.0, shade_negative=True, bars=residues)


# ---------------------------------------------------------------------------------------------
# witness


def witness_response(w: Any, plots: dict[str, Series], scene: Any = None) -> dict[str, Any]:
    """Closed-loop poles of the terminated network driven by a force at the operator port (the
    poles of Y_in = Z_in⁻¹), the growth rate σ = max Re p [1/s], and the exact-ZOH simulation of
    V = Y_in F under F = F0 d sin(ωt) (F0 = 1 N or N.m, d the most non-passive direction) until
    the velocity, position (∫V) or port energy crosses the scene's safety limits. Returns the
    simulation summary; the keys in ``witness_response.FIELDS`` are Witness fields."""
    from hil.lti import StateSpace, tf_matrix

    y = w.z_in.to("admittance")
    m = y.n
    units = getattr(scene, "units", None)
    poles = np.asarray(y.poles(), complex)
    order = np.argsort(-poles.real)
    poles = poles[order]
    growth = float(poles.real.max()) if poles.size else None
    out: dict[str, Any] = {"closed_loop_poles": [(float(p.real), float(p.imag)) for p in poles[:12]],
                           "growth_rate_1_s": growth}
    try:
        ss: StateSpace = tf_matrix([[None if e.is_zero else (e.num[::-1].tolist(), e.den[::-1].tolist())
                                     for e in row] for row in y.entries])
    except HilError as exc:  # an improper admittance cannot be simulated as given
        return {**out, "simulated": False, "reason": f"admittance not realizable: {exc}"}
    safety = getattr(scene, "safety", None)
    limits: dict[str, float] = {}
    if safety is not None:
        limits["max_velocity"] = float(safety.max_velocity)
        if safety.position_limits is not None:
            limits["max_position"] = float(min(abs(safety.position_limits[0]), abs(safety.position_limits[1])))
        limits["max_energy"] = float(safety.max_energy)
    wd = float(w.drive_frequency)
    period = 2 * math.pi / wd
    dt = min(1e-3, period / 200)
    t_end = min(max(40 * period, 30.0 / growth if growth and growth > 0 else 0.0), 120.0)
    n = int(min(t_end / dt, 300_000))
    t = np.arange(n) * dt
    d = np.asarray(w.direction, float).reshape(-1)[:m]
    d = d / (np.linalg.norm(d) or 1.0)
    F0 = 1.0
    F = F0 * np.outer(np.sin(wd * t), d)
    with np.errstate(all="ignore"):
        _, V = ss.discretize(dt).simulate(F)
        V = np.asarray(V).reshape(n, -1)[:, :m]
        X = np.cumsum(V, axis=0) * dt
        power = np.einsum("ij,ij->i", F, V)
        E = np.concatenate([[0.0], np.cumsum(0.5 * (power[1:] + power[:-1]) * dt)])
        vmag = np.max(np.abs(V), axis=1)
        xmag = np.max(np.abs(X), axis=1)
    finite = np.isfinite(vmag) & np.isfinite(E) & np.isfinite(xmag)
    n_ok = int(np.argmin(finite)) if not finite.all() else n
    crossed: dict[str, int] = {}
    if limits:
        for key, arr in (("max_velocity", vmag), ("max_position", xmag), ("max_energy", np.abs(E))):
            if key in limits:
                hit = np.nonzero(arr[:n_ok] > limits[key])[0]
                if hit.size:
                    crossed[key] = int(hit[0])
    else:
        ref = float(np.max(vmag[: max(1, n_ok // 10)]))
        hit = np.nonzero(vmag[:n_ok] > 1e3 * max(ref, 1e-12))[0]
        if hit.size:
            crossed["1000 × the initial velocity"] = int(hit[0])
    first = min(crossed, key=lambda name: crossed[name]) if crossed else None
    n_keep = (crossed[first] + 1) if first else n_ok
    n_keep = max(2, min(n_keep, n_ok))
    t, E, vmag = t[:n_keep], E[:n_keep], vmag[:n_keep]
    step = max(1, n_keep // 800)
    vu, eu = quantity_unit("velocity", units), quantity_unit("effort", units)
    panels = [Series(title="port energy", x=t[::step].tolist(), x_label="t [s]", y_label="E_s [J]",
                     lines={"E_s = ∫ F·V dt": _clean(E[::step])}, hline=0.0)]
    plots["witness_energy"] = Series(
        title=f"Witness: response to a {F0:g} {eu} drive at {wd:.4g} rad/s under the destabilizing termination",
        x=t[::step].tolist(), x_label="t [s]", y_label=f"|V| [{vu}]", log_y=True,
        lines={"|V|": _clean(vmag[::step])},
        hline=limits.get("max_velocity"), panels=panels,
        vlines={f"{first} exceeded": float(t[-1])} if first else {})
    out.update({"simulated": True, "duration_s": float(t[-1]), "drive_frequency_rad_s": wd,
                "drive_amplitude": F0, "limits": limits, "limit_exceeded": first,
                "time_to_limit_s": float(t[-1]) if first else None,
                "energy_to_limit_J": float(E[-1]) if first else None,
                "min_energy": float(np.min(E)), "went_negative": bool(np.min(E) < 0),
                "diverged": bool(growth is not None and growth > 0),
                "method": "exact-ZOH simulation (hil.lti) of V = Y_in F"})
    return out


witness_response.FIELDS = ("closed_loop_poles", "growth_rate_1_s", "drive_amplitude", "limits",  # type: ignore[attr-defined]
                           "limit_exceeded", "time_to_limit_s", "energy_to_limit_J")



# ---------------------------------------------------------------------------------------------
# design headroom


def headroom_plot(plots: dict[str, Series], cert_cfg: Any, params: Any, draws: Any, policy: Any,
                  design: Any, n_grid: int = 41) -> None:
    """P(stable) and its lower confidence bound against the SDEA design parameter (k22 or b22)
    over the scene's design range, with the requirement, the current value and the largest value
    meeting the requirement (where the lower bound crosses it: the headroom) marked."""
    from hil.certify.numbers import fmt, fmt_signed
    from hil.certify.statistics import probability_of_stability
    from hil.models.batch import sdea_passivity_batch

    d = cert_cfg.design
    if cert_cfg.model != "sdea" or d is None or d.parameter not in ("k22", "b22") or design is None:
        return
    fixed = {k: float(v) for k, v in params.items() if isinstance(v, int | float)}
    n = len(next(iter(draws.values())))

    def curve(xs: np.ndarray) -> tuple[list[float], list[float]]:
        phat, lower = [], []
        for x in xs:
            dd = dict(draws)
            dd[d.parameter] = np.full(n, x)
            p, lo, _ = probability_of_stability(sdea_passivity_batch(dd, fixed=fixed)["passive"],
                                                policy.confidence)
            phat.append(p)
            lower.append(lo)
        return phat, lower

    limit = design.posterior_limit if design.posterior_limit is not None else design.max_value
    has_limit = limit is not None and math.isfinite(limit)
    xs = np.linspace(float(d.range[0]), float(d.range[1]), n_grid)
    if has_limit:
        xs = np.unique(np.concatenate([xs, [limit]]))
    phat, lower = curve(xs)
    unit = design.unit or parameter_unit(d.parameter, "rotary", "sdea")
    req = float(policy.required_probability)
    pts: dict[str, tuple[float, float]] = {}
    vl: dict[str, float] = {}
    # legend numbers: the design table's fields printed by its formatters (one source)
    if has_limit:
        hr = design.posterior_headroom if design.posterior_limit is not None else None
        what = "posterior limit" if design.posterior_limit is not None else "largest value meeting the requirement"
        pts[f"requirement crossing ({what}): {d.parameter} = {fmt(float(limit))} {unit}"
            + ("" if hr is None else f", headroom {fmt_signed(hr)}")] = (float(limit), req)
    if design.current is not None:
        vl[f"current {d.parameter}"] = float(design.current)
    if design.nominal_limit is not None and math.isfinite(design.nominal_limit):
        hn = design.nominal_headroom
        vl[f"nominal limit {d.parameter}_max" + ("" if hn is None else f" (headroom {fmt_signed(hn)})")] = \
            float(design.nominal_limit)
    panels = []
    if has_limit and limit > 0:  # a zoom on the crossing: the drop is steep at the scale of the design range
        span = [float(limit)] + [v for v in (design.nominal_limit,) if v is not None and math.isfinite(v)]
        a, b = 0.97 * min(span), 1.03 * max(span)
        zx = np.unique(np.concatenate([np.linspace(a, b, 25), span]))  # 25 points: the drop is within a few %
        zp, zl = curve(zx)
        zv = {k.split(" (")[0]: v for k, v in vl.items() if a <= v <= b}
        panels.append(Series(title=f"zoom on the requirement crossing ({d.parameter} in [{a:.4g}, {b:.4g}] {unit})",
                             x=zx.tolist(), x_label=f"{d.parameter} [{unit}]", y_label="P(stable) [1]",
                             lines={"P̂(stable)": _clean(zp), f"lower {policy.confidence:.0%} bound": _clean(zl)},
                             points={f"posterior limit {fmt(float(limit))}": (float(limit), req)} if has_limit else {},
                             vlines=zv, hline=req))
    plots["headroom"] = Series(
        title=f"Headroom: P(stable) against {d.parameter} (the lower {policy.confidence:.0%} bound must stay "
              f"≥ {policy.required_probability})", x=xs.tolist(), x_label=f"{d.parameter} [{unit}]",
        y_label="P(stable) [1]", lines={"P̂(stable)": _clean(phat), f"lower {policy.confidence:.0%} bound":
                                        _clean(lower)},
        points=pts, vlines=vl, hline=req, panels=panels)


# ---------------------------------------------------------------------------------------------
# reliability: the design point in posterior-standardized coordinates

#: 99 % of a 2-D standard normal lies within this radius: √χ²₂(0.99) = √(−2 ln 0.01)
R99_2D = math.sqrt(-2.0 * math.log(0.01))


def _circle(x: np.ndarray, r2: float) -> tuple[list[float | None], list[float | None]]:
    """Upper and lower halves of the circle x² + y² = r2 over x (None outside it)."""
    with np.errstate(invalid="ignore"):
        y = np.sqrt(r2 - x * x)
    y = np.where(np.isfinite(y), y, np.nan) if r2 > 0 else np.full(x.shape, np.nan)
    return _clean(y), _clean(-y)


def design_point_axes(u_star: Any) -> tuple[int, int]:
    """The two coordinates of the projection: (i, j) with the largest |u*ₖ| (the FORM importance
    factors αₖ = u*ₖ/β), ties in the coordinates' order. i is drawn upwards, j across."""
    u = np.abs(np.asarray(u_star, float).reshape(-1))
    order = sorted(range(u.size), key=lambda k: (-u[k], k))
    return order[0], order[1]


#: the limit-state trace of :func:`design_point_plot`: (columns, grid rows, bisection steps) with a
#: cheap verdict (``fast``) and with the exact criterion
LIMIT_TRACE_FAST = (121, 40, 24)
LIMIT_TRACE_EXACT = (7, 4, 4)


def limit_trace_height(beta: float) -> float:
    """The height [1] up to which :func:`design_point_plot` looks for the limit state along each
    column: max(1.3 |β|, |β| + 3)."""
    return max(1.3 * abs(beta), abs(beta) + 3.0)


def limit_trace_resolution(beta: float, fast: bool) -> float:
    """Width [1] of the bracket within which :func:`design_point_plot` places the limit state on
    each traced column: the grid step top/n_grid halved n_bisect times. The drawn point is the
    bracket's far end (the first point where the verdict has turned), so it lies between 0 and this
    width beyond the column's boundary."""
    _, n_grid, n_bisect = LIMIT_TRACE_FAST if fast else LIMIT_TRACE_EXACT
    return limit_trace_height(beta) / n_grid / 2 ** n_bisect


def design_point_plot(plots: dict[str, Series], stable_u: Any, reliability: Any, names: list[str],
                      model: str = "", fast: bool = True) -> None:
    """The ``reliability`` plot: the slice of posterior-standardized space u = L⁻¹(θ − μ) through
    the design point u* along the two coordinates of largest importance (:func:`design_point_axes`;
    the others held at their u* values). Drawn: the limit state g = 0 where the verdict
    ``stable_u`` ((n, d) u-points → n bools) first differs from the centre's along u_i (columns
    across u_j, grid then bisection), the region beyond it, the section of the sphere ‖u‖ = β (it
    touches g = 0 at u*: β is the distance to the nearest non-stable point), the section of
    ‖u‖ = β_required (what a GO needs), the 99 % circle of the 2-D standard-normal marginal of
    (u_i, u_j), the design point and the centre. ``fast``: the verdict is cheap (SDEA closed form):
    61 columns; otherwise 7 columns of the exact criterion (a coarse curve)."""
    u_star = np.asarray(reliability.design_point_u, float).reshape(-1)
    d = u_star.size
    beta = float(reliability.beta)
    if d < 2 or reliability.censored or not math.isfinite(beta) or beta == 0.0 or len(names) != d:
        return
    i, j = design_point_axes(u_star)
    centre_ok = beta > 0
    R = abs(beta)
    rho2 = float(sum(u_star[k] ** 2 for k in range(d) if k not in (i, j)))
    sgn = 1.0 if u_star[i] >= 0 else -1.0
    half = max(1.25 * R, 4.0)
    n_cols, n_grid, n_bisect = LIMIT_TRACE_FAST if fast else LIMIT_TRACE_EXACT
    req = float(getattr(reliability, "required_beta", float("nan")))
    radii = [r for r in (math.sqrt(max(R * R - rho2, 0.0)), math.sqrt(max(req * req - rho2, 0.0))
                         if math.isfinite(req) else 0.0, R99_2D) if 0 < r < half]
    dense = np.unique(np.concatenate([np.linspace(-half, half, 161), [u_star[j]], radii, [-r for r in radii]]))
    xs = dense if fast else np.unique(np.concatenate([np.linspace(-half, half, n_cols), [u_star[j]]]))
    top = limit_trace_height(R)
    base = u_star.copy()
    base[i] = base[j] = 0.0

    def points(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        U = np.repeat(base[None, :], x.size, axis=0)
        U[:, j], U[:, i] = x, sgn * y
        return U

    grid = np.linspace(top / n_grid, top, n_grid)
    X, Y = np.meshgrid(xs, grid, indexing="ij")
    same = np.asarray(stable_u(points(X.ravel(), Y.ravel())), bool).reshape(X.shape) == centre_ok
    has = ~same.all(axis=1)
    k = np.argmax(~same, axis=1)
    hi = np.where(has, grid[k], np.nan)
    lo = np.where(has & (k > 0), grid[np.maximum(k - 1, 0)], 0.0)
    idx = np.nonzero(has)[0]
    for _ in range(n_bisect):
        if idx.size == 0:
            break
        mid = 0.5 * (lo[idx] + hi[idx])
        s = np.asarray(stable_u(points(xs[idx], mid)), bool) == centre_ok
        lo[idx] = np.where(s, mid, lo[idx])
        hi[idx] = np.where(s, hi[idx], mid)
    yb = sgn * hi
    if not fast:  # the exact criterion on a few columns: the curve between them is interpolated
        keep = np.isfinite(yb)
        yb = np.interp(dense, xs[keep], yb[keep], left=np.nan, right=np.nan) if keep.sum() >= 2 else \
            np.full(dense.shape, np.nan)
        has = np.isfinite(yb)
        xs = dense
    pu = names[i]
    pj = names[j]
    what = "non-stable" if centre_ok else "stable"
    how = "" if fast else f", exact criterion on {n_cols} columns, interpolated"
    lines: dict[str, list[float | None]] = {f"limit state g = 0 (the verdict turns {what}{how})": _clean(yb)}
    up, dn = _circle(xs, R * R - rho2)
    lines[f"‖u‖ = β = {R:.4g} (in this slice)"] = up
    lines["_‖u‖ = β lower half"] = dn
    small = " (a dot at the centre at this scale)"
    if math.isfinite(req) and req * req > rho2:
        up, dn = _circle(xs, req * req - rho2)
        lines[f"‖u‖ = β required = {req:.4g}" + (small if req < 0.04 * half else "")] = up
        lines["_‖u‖ = β required lower half"] = dn
    up, dn = _circle(xs, R99_2D ** 2)
    lines[f"99 % of the posterior in (u[{pj}], u[{pu}])" + (small if 0.04 * half > R99_2D else "")] = up
    lines["_99 % lower half"] = dn
    pts = {f"design point u* (β = {beta:.4g})": (float(u_star[j]), float(u_star[i]))}
    if rho2 == 0.0:
        pts["posterior centre u = 0"] = (0.0, 0.0)
    plots["reliability"] = Series(
        title=f"Design point u* and limit state g = 0 in standardized coordinates u = L⁻¹(θ − μ) "
              f"({model or 'network'}): the slice through u* along u[{pj}] and u[{pu}]"
              + ("" if rho2 == 0.0 else ", other coordinates at their u* values"),
        x=[float(v) for v in xs], x_label=f"u[{pj}] (standardized) [1]", y_label=f"u[{pu}] (standardized) [1]",
        lines=lines, bands={f"{what} side of g = 0": (_clean(yb), _clean(np.where(has, sgn * top, np.nan)))},
        points=pts)
