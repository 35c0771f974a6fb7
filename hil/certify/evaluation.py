"""The computations behind the certification stages of :mod:`hil.certify.pipeline`: the nominal
section, the robust evaluation over the posterior draws (batched where a model has a batch path,
exact verdicts otherwise), the exact margin and verdict functions the worst-case search and the
reliability (β, importance sampling) stage use, the design guidance, the instability witness, and
the run's small helpers (independent posterior samples, the twins' truth, software versions)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hil.certify.certificate import (
    ConditionRow,
    DecisionStr,
    Design,
    Nominal,
    Series,
    VerdictStr,
    Witness,
)
from hil.certify.stages import (
    Sheet,
)
from hil.certify.statistics import (
    Decision,
    Policy,
    max_safe_parameter,
)
from hil.errors import HilError
from hil.models import build_network

logger = logging.getLogger(__name__)


def _criterion(model: str, cfg: str) -> str:
    from hil.models import get_model

    if cfg != "auto":
        return cfg
    return get_model(model).criterion


def _check(tm: Any, criterion: str, margins: bool = True) -> Any:
    from hil.stability.criteria import check

    if margins:
        return check(tm, criterion)
    from hil.stability import criteria as C

    if criterion == "passivity":
        return C.two_port_passivity(tm, margins=False) if tm.n_ports == 2 else C.positive_real(tm, margins=False)
    if criterion == "llewellyn":
        return C.llewellyn(tm, margins=False)
    return check(tm, criterion)


def _f(v: Any) -> float | None:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _independent_samples(res: Any) -> tuple[np.ndarray, str]:
    """The identification's posterior samples thinned to independent draws: every walker of the
    kept emcee chain keeps one sample per ⌈τ⌉ steps, τ the largest integrated autocorrelation time
    over the parameters (``diagnostics.tau``, or estimated from the chain when missing). Returns the
    (n_independent, p) samples and one sentence saying how they were obtained."""
    from hil.certify.statistics import autocorrelation_time, thin_indices

    post = res.posterior
    samples = np.asarray(post.samples)[:, : len(res.names)]
    chain = np.asarray(post.chain_z)
    if chain.ndim != 3 or chain.shape[0] * chain.shape[1] != samples.shape[0]:
        return samples, (f"{res.model.name}: {samples.shape[0]} stored samples, chain layout unknown: "
                         "not thinned")
    n_steps, n_walkers = chain.shape[:2]
    tau_d = np.asarray(post.diagnostics.tau, float)
    tau = float(np.max(tau_d)) if tau_d.size and np.all(np.isfinite(tau_d)) else autocorrelation_time(chain)
    idx = thin_indices(n_steps, n_walkers, tau)
    note = (f"{res.model.name}: {samples.shape[0]} stored samples ({n_walkers} walkers × {n_steps} steps) "
            f"thinned every ⌈τ⌉ = {max(1, math.ceil(tau))} steps (τ = {tau:.1f}, the largest integrated "
            f"autocorrelation time): {idx.size} independent draws")
    return samples[idx], note


def friction_truth(scene: Any, device: str) -> dict[str, float]:
    """The simulated twin's friction of ``device`` (and a 1-DOF body's M and B), identification's names."""
    from hil.bench.mechanics import body_truth
    from hil.bench.mechanics import friction_truth as _ft

    return {**body_truth(scene, device), **_ft(scene, device)} if device else {}


def _truth(scene: Any) -> dict[str, float]:
    """Parameters of the simulated plant (known on a mocked bench; shown next to the estimates)."""
    sim = scene.simulation
    if sim is None or sim.sdea is None:
        return {}
    sd = sim.sdea
    return {"M": float(sd.M), "B": float(sd.B), "K_f": float(sd.K_f), "B_f": float(sd.B_f)}


def _versions() -> dict[str, str]:
    import platform

    import scipy

    import hil

    return {"hil": hil.__version__, "numpy": np.__version__, "scipy": scipy.__version__,
            "python": platform.python_version()}


_VERDICTS: dict[str, VerdictStr] = {"stable": "stable", "marginal": "marginal",
                                    "potentially_unstable": "potentially_unstable", "not_applicable": "not_applicable"}
_DECISIONS: dict[Decision, DecisionStr] = {Decision.GO: "GO", Decision.MARGINAL: "MARGINAL", Decision.NO_GO: "NO-GO",
                                           Decision.ERROR: "ERROR"}


def _nominal_section(model: str, r: Any, params: Mapping[str, Any]) -> Nominal:
    rows = [ConditionRow(name=c.name, label=c.label, status=c.status, margin=_f(c.margin),
                         worst_frequency=None if c.worst_frequency is None else (
                             "inf" if math.isinf(c.worst_frequency) else float(c.worst_frequency)), detail=c.detail)
            for c in r.conditions]
    wf = r.worst_frequency
    wf_out = None if wf is None else ("inf" if math.isinf(wf) else float(wf))
    return Nominal(network=r.network.get("name", model), criterion=r.criterion, verdict=_VERDICTS[str(r.verdict)],
                   margin=_f(r.margin), worst_frequency=wf_out,
                   failed_condition=r.failed_condition, weak=bool(r.weak),
                   parameters={k: float(v) for k, v in params.items() if isinstance(v, int | float)}, conditions=rows)


def _robust_eval(model: str, criterion: str, params: Mapping[str, Any], draws: Mapping[str, np.ndarray]
                 ) -> tuple[np.ndarray, Callable[[Mapping[str, np.ndarray]], np.ndarray] | None, str,
                            tuple[float, float] | None, Any]:
    """Stability of every draw, a cheap vectorized proxy margin that ranks parameter sets from
    least to most stable (the model's vectorized criterion, e.g. the SDEA's closed-form margin; None
    on the general path), the method,
    the critical band (5 % quantile of the draws' lower edges to 95 % of their upper edges, see
    hil.models.batch) (None when the path does not provide it), and the general path's measured
    coefficient map (:func:`hil.models.batch_general.coefficient_map`, None when not affine or on
    the closed-form path). Without a closed-form batch, the
    exact criterion decides every draw that hil.models.batch_general's vectorized screen does not
    reject on a clearly violated necessary condition (the same per-draw verdicts, fewer exact runs)."""
    from hil.models import get_model

    n = len(next(iter(draws.values())))
    batch = get_model(model).vectorized(criterion)
    if batch is not None:
        fixed = {k: float(v) for k, v in params.items() if isinstance(v, int | float)}

        def margin(d: Mapping[str, np.ndarray]) -> np.ndarray:
            return batch(d, fixed=fixed, band=False)["margin"]

        res = batch(draws, fixed=fixed, band=True)
        # the critical band (hil.models.batch): per draw, where the coupler condition (c-ii) is
        # within 10 % of its minimum; over the draws, the 5 % quantile of the lower edges to the 95 %
        # quantile of the upper edges
        lo_e, hi_e = res["band_lo"], res["band_hi"]
        ok = np.isfinite(lo_e) & np.isfinite(hi_e) & (hi_e > lo_e)
        band = (float(np.quantile(lo_e[ok], 0.05)), float(np.quantile(hi_e[ok], 0.95))) if ok.any() else None
        return (res["passive"], margin, "vectorized closed form (Theorem 5), exact fallback near the boundary", band,
                None)
    from hil.models.batch_general import screened_stability

    def exact_one(q: Mapping[str, Any]) -> bool:
        return exactly_stable(model, criterion, q)

    # draws the vectorized screen rejects on a necessary condition (beyond its error bound) skip the
    # exact path; every other draw is decided exactly (hil.models.batch_general)
    # the certificate's method stays the exact criterion's: the screen only skips it where its
    # verdict is already determined, so every per-draw verdict is the exact criterion's
    res = screened_stability(model, criterion, params, draws, exact_one)
    assert res["stable"].shape == (n,)
    logger.info("robust draws: %s", res["method"])
    return res["stable"], None, "general exact criterion per draw", None, res.get("cmap")


def _exact_margin_fn(model: str, criterion: str, params: Mapping[str, Any],
                     names: list[str]) -> Callable[[np.ndarray], np.ndarray]:
    """θ rows (columns ``names``) → the exact criterion's margin, ``check(network(θ), criterion).margin``,
    the same function that gives the nominal margin at the posterior centre. A parameter set whose
    network cannot be built (HilError) or whose margin is not finite gets -1, the bottom of the
    normalized scale."""
    def fn(T: np.ndarray) -> np.ndarray:
        T = np.atleast_2d(T)
        out = np.empty(T.shape[0])
        for i, row in enumerate(T):
            q = dict(params)
            q.update({k: float(v) for k, v in zip(names, row, strict=True)})
            try:
                m = float(_check(build_network(model, q), criterion).margin)
            except HilError:
                m = -1.0
            out[i] = m if math.isfinite(m) else -1.0
        return out

    return fn


def _verdict_fn(model: str, criterion: str, params: Mapping[str, Any], names: list[str],
                fast: bool) -> Callable[[np.ndarray], np.ndarray]:
    """θ rows (columns ``names``) → stable (bool): the SDEA's vectorized closed-form verdict (its
    sign also within round-off of the boundary, where a bisection converges: the design point is
    then checked with the exact criterion) or the exact criterion per point (a network that cannot
    be built is not stable)."""
    from hil.models import get_model

    batch = get_model(model).vectorized(criterion) if fast else None
    if batch is not None:
        fixed = {k: float(v) for k, v in params.items() if isinstance(v, int | float)}

        def vec(T: np.ndarray) -> np.ndarray:
            T = np.atleast_2d(T)
            return batch(dict(zip(names, T.T, strict=True)), fixed=fixed, band=False,
                                        exact_fallback=False)["passive"]

        return vec

    def one(T: np.ndarray) -> np.ndarray:
        return np.array([exactly_stable(model, criterion, {**params, **dict(zip(names, map(float, row), strict=True))})
                         for row in np.atleast_2d(T)], dtype=bool)

    return one


def exactly_stable(model: str, criterion: str, params: Mapping[str, Any]) -> bool:
    """Whether the network of ``model`` at ``params`` is ``stable`` under the exact ``criterion``
    (verdict only, no margins); a network that cannot be built is not stable. The per-draw
    reference of every vectorized path."""
    try:
        return str(_check(build_network(model, params), criterion, margins=False).verdict) == "stable"
    except HilError:
        return False


#: the design point is checked with the exact criterion at (1 ∓ this)·u*
VERIFY_OFFSET = 0.05

#: importance-sampling sample sizes of the rare-event path (vectorized SDEA path, general path)
IS_SAMPLES = (20000, 300)


def _reliability_stage(model: str, criterion: str, params: Mapping[str, Any], names: list[str], X: np.ndarray,
                       centre: np.ndarray, stable_draws: np.ndarray, policy: Policy, fast: bool, seed: int,
                       worst_theta: Mapping[str, float] | None) -> tuple[Any, Any, Any]:
    """β by FORM in posterior-standardized coordinates (hil.stability.reliability) around the
    posterior centre (the nominal point), and, when plain Monte Carlo on the available draws
    cannot reach the requirement even with every draw stable, P(stable) by importance sampling
    around the design point. Returns (Reliability, FormResult, RareEvent) (None where not made)."""
    from scipy.special import ndtr  # Φ

    from hil.certify.certificate import RareEvent, Reliability
    from hil.certify.statistics import beta_required
    from hil.stability.reliability import Standardization, form, importance_sampling

    st = Standardization.from_draws(X)
    st = Standardization(centre, st.L)  # centred exactly on the nominal point
    verdict = _verdict_fn(model, criterion, params, names, fast)

    def stable_u(U: np.ndarray) -> np.ndarray:
        return verdict(st.to_theta(U))

    hints = []
    bad = ~np.asarray(stable_draws, bool)
    if bad.any():
        Ub = st.to_u(X[bad])
        hints += list(Ub[np.argsort(np.linalg.norm(Ub, axis=1))[:8]])
    if worst_theta is not None:
        hints.append(st.to_u(np.array([[worst_theta[k] for k in names]]))[0])
    b_req = beta_required(policy.required_probability)
    r_max = max(8.0, b_req + 3.0)
    d = len(names)
    kw: dict[str, Any] = {} if fast else {"n_random": 0, "n_grid": 6, "n_bisect": 7, "refine_iter": 1,
                                          "n_refine_starts": 1, "budget": 40 * d}
    if fast:  # cheap verdicts: a tight posterior's β is measured, not only bounded by r_max
        kw["r_limit"] = 8 ** 4 * r_max
    fr = form(stable_u, d, hints=hints, r_max=r_max, seed=seed, **kw)
    verified = None
    if not fr.censored:
        u = fr.design_point_u
        # the exact criterion on both sides of the design point (the search's verdict may be the
        # vectorized closed form, whose sign within ~1e-8 of the boundary is round-off), 5 % of β
        # inside and outside along its ray
        inner, outer = st.to_theta(u * (1 - VERIFY_OFFSET)), st.to_theta(u * (1 + VERIFY_OFFSET))
        def exact(T: np.ndarray) -> str:
            q = dict(params)
            q.update({k: float(v) for k, v in zip(names, np.atleast_2d(T)[0], strict=True)})
            try:
                return str(_check(build_network(model, q), criterion, margins=False).verdict)
            except HilError:
                return "potentially_unstable"

        centre_ok = fr.beta > 0
        vi, vo = exact(inner), exact(outer)
        # None: the exact criterion calls a side marginal (its rounding bound straddles zero there)
        verified = None if "marginal" in (vi, vo) else bool((vi == "stable") == centre_ok
                                                           and (vo == "stable") != centre_ok)
    theta_star = st.to_theta(fr.design_point_u)[0]
    rel = Reliability(beta=float(fr.beta), phi_beta=float(ndtr(fr.beta)), required_beta=b_req,
                      design_point={k: float(v) for k, v in zip(names, theta_star, strict=True)},
                      design_point_u=[float(v) for v in fr.design_point_u], censored=fr.censored,
                      bracket=(float(fr.bracket[0]), float(fr.bracket[1])) if math.isfinite(fr.bracket[1]) else None,
                      evaluations=fr.evaluations, verified=verified,
                      method=("FORM by verdict-only ray search (axes, random and hint directions; tangent-plane "
                              "refinement)" + ("" if fast else f", budget {40 * d} exact verdicts")))
    rare = None
    n = int(np.asarray(stable_draws).size)
    best_mc_lower = (0.5 * (1 - policy.confidence)) ** (1.0 / n)  # Clopper-Pearson lower bound when k = n
    if best_mc_lower < policy.required_probability and fr.beta > 0 and not fr.censored:
        isr = importance_sampling(stable_u, fr.design_point_u, n=IS_SAMPLES[0] if fast else IS_SAMPLES[1],
                                  confidence=policy.confidence, seed=seed + 7)
        rare = RareEvent(method="importance sampling, proposal N(u*, I) around the FORM design point, on the "
                                "Gaussian approximation N(μ, Σ) of the posterior; normal-approximation interval",
                         n=isr.n, n_fail=isr.n_fail, p_failure=isr.p_failure, std_error=isr.std_error,
                         p_stable=isr.p_stable, lower=1.0 - isr.upper, upper=1.0 - isr.lower,
                         confidence=isr.confidence, ess=isr.ess, reliable=isr.reliable)
    return rel, fr, rare


def _design_point_plot(plots: dict[str, Series], model: str, criterion: str, params: Mapping[str, Any],
                       names: list[str], X: np.ndarray, centre: np.ndarray, reliability: Any, fast: bool) -> None:
    """The design point in the posterior-standardized coordinates of :func:`_reliability_stage`
    with the limit state traced by the same verdict; see :func:`hil.certify.figures.design_point_plot`."""
    from hil.certify.figures import design_point_plot
    from hil.stability.reliability import Standardization

    st = Standardization(centre, Standardization.from_draws(X).L)
    verdict = _verdict_fn(model, criterion, params, names, fast)
    design_point_plot(plots, lambda U: verdict(st.to_theta(U)), reliability, names, model=model, fast=fast)


def _design(cert: Any, params: Mapping[str, Any], draws: Mapping[str, np.ndarray], policy: Policy,
            nominal_params: Mapping[str, Any] | None = None) -> Design | None:
    from hil.models import get_model

    d = cert.design
    m = get_model(cert.model)
    crit = _criterion(cert.model, cert.criterion)
    batch = m.vectorized(crit)
    if batch is None or d.parameter not in m.design:
        return Design(parameter=d.parameter, max_value=None, probability_at_max=None,
                      required=policy.required_probability,
                      note="design search is implemented for the SDEA coupler (k22, b22)")
    dp = m.design[d.parameter]

    fixed = {k: float(v) for k, v in params.items() if isinstance(v, int | float)}

    def stable(x: float) -> np.ndarray:
        dd = dict(draws)
        dd[d.parameter] = np.full(len(next(iter(draws.values()))), x)
        return batch(dd, fixed=fixed, band=False)["passive"]

    x, p = max_safe_parameter(stable, d.range[0], d.range[1], policy.required_probability, policy.confidence)
    unit = dp.unit
    head: dict[str, Any] = {}
    cur = fixed.get(d.parameter)
    if dp.headroom is not None and cur is not None and cur > 0:
        # parametric headroom (docs/CERTIFICATION.md): k22_max/k22 − 1 at the nominal plant, and the
        # posterior limit (lower bound of P(stable) = required) / k22 − 1
        from hil.certify.statistics import posterior_limit

        plant = {k: float(v) for k, v in (nominal_params or params).items()
                 if k in m.defaults and isinstance(v, int | float)}
        km, hn = dp.headroom(cur, plant)
        xl, kind = posterior_limit(stable, cur, policy.required_probability, policy.confidence)
        head = {"nominal_limit": km, "nominal_headroom": hn, "posterior_limit": xl, "posterior_limit_kind": kind,
                "posterior_headroom": xl / cur - 1.0}
    return Design(parameter=d.parameter, unit=unit, current=cur, max_value=_f(x),
                  probability_at_max=_f(p), required=policy.required_probability,
                  note=f"largest {d.parameter} in [{d.range[0]:g}, {d.range[1]:g}] whose lower "
                       f"{policy.confidence:.0%} bound of P(stable) stays ≥ {policy.required_probability}", **head)


def _witness(tm: Any, plots: dict[str, Series], opt: Sheet, scene: Any = None) -> Witness | None:
    """Search a passive termination set and simulate the driven, terminated one-port exactly
    (a failure of the simulation is recorded by ``opt``; the witness is kept without it). With the
    scene, the witness says what a reader needs: the closed-loop poles the termination creates,
    and when the response crosses the bench's safety limits (hil.certify.figures.witness_response)."""
    from hil.certify.figures import witness_response
    from hil.stability.witness import find_witness, termination_family

    port = 0
    cands = termination_family(max(tm.port_dofs))[::2]
    w = find_witness(tm, port, cands, first=True)
    if w is None:
        return None
    units = getattr(scene, "units", None)
    sim = opt.optional("witness simulation", _simulate_witness, w, plots, scene)
    if sim is None:
        sim = {"simulated": False, "reason": f"simulation failed: {opt.failed['witness simulation']}"}
    band = None if w.band_rad_s is None else (float(w.band_rad_s[0]),
                                             "inf" if math.isinf(w.band_rad_s[1]) else float(w.band_rad_s[1]))
    fields: tuple[str, ...] = witness_response.FIELDS  # type: ignore[attr-defined]  # set on the function there
    extra = {k: sim.pop(k) for k in list(sim) if k in fields}
    return Witness(terminations={str(k): v.to_dict() for k, v in w.terminations.items()},
                   drive_frequency_rad_s=w.drive_frequency, band_rad_s=band, margin=float(w.result.margin),
                   simulation=sim, units=units, **extra)

def _simulate_witness(w: Any, plots: dict[str, Series], scene: Any = None) -> dict[str, Any]:
    """Drive the terminated network's operator port with F(t) = F0 d sin(ωt) (d = the most
    non-passive direction, F0 = 1 N or N.m) and integrate E_s(t) = ∫ Fᵀ V dt, V = Y_in(s) F, with the
    exact-ZOH engine of hil.mocks (admittance state space from the exact rational Y_in = Z_in⁻¹),
    until the response crosses the scene's safety limits (or grows a thousandfold without a scene);
    see :func:`hil.certify.figures.witness_response`."""
    from hil.certify.figures import witness_response

    return witness_response(w, plots, scene)
