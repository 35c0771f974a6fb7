"""End to end on the mocks: experiments -> identification -> criteria over the posterior ->
GO / MARGINAL / NO-GO, with a witness for NO-GO, and the exit codes of `hil certify`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from hil.certify.certificate import Certificate
from hil.certify.pipeline import certify_scene
from hil.cli.main import main
from hil.models.batch import sdea_passivity_batch
from hil.models.sdea import SDEA_TABLE1
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict


def _sdea_scene(k22: float | None = None):
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = [e for e in d["experiments"] if e.get("name") == "chirp_locked"]
    if k22 is not None:
        d["controller"]["k22"] = k22
    return scene_from_dict(d, label=f"sdea_bench-k22-{k22}")


@pytest.fixture(scope="module")
def sdea_run(tmp_path_factory):
    """One locked-output chirp on the mocked SDEA bench, shared by the certification variants."""
    sc = _sdea_scene()
    out = tmp_path_factory.mktemp("sdea_run")
    o = Runner(sc, out).run()[0]
    assert o.status == "completed"
    return {"chirp_locked": o}


@pytest.mark.timeout(600)
def test_sdea_inside_passive_region_is_GO(sdea_run, tmp_path):
    c = certify_scene(_sdea_scene(300.0), tmp_path, outcomes=sdea_run)
    assert c.decision == "GO", c.reasons
    ident = c.identification[0]
    assert ident.converged
    for p in ident.parameters:  # the simulated plant's truth lies in the 90 % interval
        assert p.q05 <= SDEA_TABLE1[p.name] <= p.q95, p
    assert c.robust.lower >= 0.95 and c.robust.worst_case_margin > 0
    # issue 11: worst ≤ nominal (same function; the centre is a candidate), β beyond Φ⁻¹(0.95),
    # positive k22 headroom at the nominal plant and over the posterior, P(stable) by Monte Carlo
    assert c.robust.worst_case_margin <= c.nominal.margin
    rel = c.robust.reliability
    assert rel.beta >= rel.required_beta and not rel.censored and c.robust.p_stable_method == "monte_carlo"
    assert rel.phi_beta >= c.robust.lower  # consistent with the sampled bound (all draws stable)
    assert c.design.nominal_headroom == pytest.approx(c.design.nominal_limit / 300.0 - 1, rel=1e-12)
    assert c.design.nominal_headroom > 0.3
    assert 0 < c.design.posterior_headroom <= c.design.nominal_headroom + 1e-6
    assert 400 < c.design.max_value < 420  # the exact design limit at Table I is 408.05
    Certificate.model_validate_json(c.model_dump_json())  # the record validates against its schema
    # defect 8: P(stable) rests on independent draws of the thinned chain, and says how many
    r = c.robust
    diag = ident.diagnostics
    n_indep = diag["n_walkers"] * -(-diag["n_kept"] // math.ceil(max(diag["tau"].values())))
    assert r.n_independent == n_indep and r.n_requested == 4000
    assert r.n_draws == min(4000, n_indep) and f"{n_indep} independent draws" in r.sampling
    m = next(m for m in c.measurements if m.name == "P(stable), lower confidence bound")
    assert f"over {r.n_draws} independent draws" in m.description
    # defect 9: the critical band has positive width and contains the worst frequency of the
    # coupler condition at the nominal parameters
    lo, hi = r.critical_band_rad_s
    nominal = {k: np.array([v]) for k, v in c.nominal.parameters.items() if k in SDEA_TABLE1}
    w = sdea_passivity_batch(nominal, band=True)["worst_omega"][0]
    assert 0 < lo < w < hi and hi / lo > 1.2
    pts = c.plots["critical_band"].points  # plotted, with the band's edges and the worst frequency
    assert lo < pts["worst (nominal)"][0] < hi
    assert pts["critical band, low edge (over the draws)"][0] == lo


@pytest.mark.timeout(600)
def test_sdea_above_the_passive_limit_is_NO_GO_with_a_witness(sdea_run, tmp_path):
    c = certify_scene(_sdea_scene(450.0), tmp_path, outcomes=sdea_run)
    assert c.decision == "NO-GO", c.reasons
    assert c.nominal.verdict == "potentially_unstable"
    # a negative margin is FAIL, never MARGINAL (OpenHTF: MARGINAL is within tolerance of a limit)
    outcomes = {m.name: m.outcome for m in c.measurements}
    assert outcomes["nominal margin"] == "FAIL"
    assert all(o != "MARGINAL" for n, o in outcomes.items() if "margin" in n)
    w = c.witness
    assert w is not None and w.margin < 0
    sim = w.simulation
    assert sim["simulated"] and (sim["went_negative"] or sim["diverged"])


@pytest.mark.timeout(600)
def test_nominal_no_go_skips_work_that_cannot_change_it(sdea_run, tmp_path, monkeypatch):
    """Issue 26: a nominal NO-GO is decided whatever the worst case over the credible region or β,
    so neither is searched (the search is never called); one INFO row says so; P(stable), the design
    guidance (how to reach a GO) and the witness are still there."""
    import hil.certify.pipeline as pl

    def no_search(*a, **k):
        raise AssertionError("worst-case search on a nominal NO-GO")

    monkeypatch.setattr(pl, "worst_case_margin", no_search)
    monkeypatch.setattr(pl, "_reliability_stage", no_search)
    c = certify_scene(_sdea_scene(450.0), tmp_path, outcomes=sdea_run)
    assert c.decision == "NO-GO" and c.nominal.verdict == "potentially_unstable"
    r = c.robust
    assert r.worst_case_margin is None and r.worst_case_parameters is None and r.reliability is None
    row = next(m for m in c.measurements if m.name == pl.NOT_SEARCHED_ROW)
    assert row.value == "not searched" and row.outcome == "INFO"
    assert 0.0 <= r.p_stable <= 1.0 and r.n_draws > 0
    assert c.design is not None and c.design.max_value < 450.0 and c.witness is not None


def test_certify_runs_only_the_experiments_it_uses(tmp_path, monkeypatch):
    """Issue 26: `hil certify` runs the experiments whose records certification reads (identify
    entries, energy injections) and says which it left out; `hil run` runs them all. The runner is
    asked for exactly those indices (here: chirp_locked of sdea_bench, not chirp_free or
    static_hold), and the certificate has one INFO "skipped" row per other experiment."""
    from hil.certify.pipeline import experiments_used

    scene = load_scene("sdea_bench")
    names = [e["name"] for e in scene.experiment_configs()]
    assert experiments_used(scene.certification, scene.experiment_configs()) == {"chirp_locked"}
    asked: list = []

    def fake_run(self, select=None):
        asked.append(select)
        return []  # nothing ran: the certificate is ERROR, which is not what this test checks

    monkeypatch.setattr(Runner, "run", fake_run)
    said: list[str] = []
    c = certify_scene(scene, tmp_path, progress=said.append)
    assert asked == [[names.index("chirp_locked")]]
    skipped = {m.name.removeprefix("experiment "): m for m in c.measurements if m.value == "skipped"}
    assert set(skipped) == set(names) - {"chirp_locked"} and all(m.outcome == "INFO" for m in skipped.values())
    assert all(any(f"experiment {n} skipped" in s for s in said) for n in skipped)
    # an energy-injection experiment is evidence: it is used without an identify entry
    bil = load_scene("bilateral_2dof_B")
    cfgs = bil.experiment_configs()
    assert experiments_used(bil.certification, cfgs) == {e["name"] for e in cfgs if e["type"] == "energy_injection"}


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_sdea_near_the_limit_is_MARGINAL(sdea_run, tmp_path):
    """k22 at the 5 % quantile of the posterior's passive limit: P(stable) ≈ 0.95, so its
    confidence interval straddles the required 0.95."""
    certify_scene(_sdea_scene(300.0), tmp_path / "base", outcomes=sdea_run)  # stores the posterior
    from hil.identify.api import load_identification

    stored = load_identification(sdea_run["chirp_locked"].record)
    names = stored["summary"]["sample_names"]
    S = np.asarray(stored["samples"])[:, : len(names)]
    draws = {n: S[:, names.index(n)] for n in ("M", "B", "K_f", "B_f")}
    # each draw's passive limit by bisection on the vectorized path
    lo, hi = np.full(S.shape[0], 300.0), np.full(S.shape[0], 600.0)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        ok = sdea_passivity_batch({**draws, "k22": mid}, band=False, exact_fallback=False)["passive"]
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    k22 = float(np.quantile(lo, 0.05))
    c = certify_scene(_sdea_scene(k22), tmp_path / "near", outcomes=sdea_run)
    assert c.decision == "MARGINAL", (k22, c.reasons, c.robust)
    assert c.robust.lower < 0.95 <= c.robust.upper
    # β consistent with P(stable) within its sampling error: Φ(β) inside the 99.9 % Clopper-Pearson
    # interval of the sampled fraction (FORM is exact only for a linear limit state; near the
    # default scene's boundary it agrees to ~1e-3, measured)
    from scipy.stats import beta as beta_dist

    r = c.robust
    k, n = round(r.p_stable * r.n_draws), r.n_draws
    lo, hi = beta_dist.ppf(0.0005, k, n - k + 1), beta_dist.ppf(0.9995, k + 1, n - k)
    assert lo <= r.reliability.phi_beta <= hi, (r.reliability, r.p_stable)
    assert r.worst_case_margin <= c.nominal.margin


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("gains,expected", [("A1", "GO"), ("A2", "GO"), ("B", "NO-GO")])
def test_bilateral_2dof_table2(gains, expected, tmp_path):
    c = certify_scene(load_scene(f"bilateral_2dof_{gains}"), tmp_path, run_experiments=False)
    assert c.decision == expected, c.reasons
    assert c.multiport is not None and c.multiport.ports == [2, 2]
    if expected == "NO-GO":  # a passive termination whose exact simulation shows the instability
        sim = c.witness.simulation
        assert sim["simulated"] and (sim["diverged"] or sim["went_negative"])


@pytest.mark.timeout(600)
def test_certify_cli_exit_codes_and_json(tmp_path, capsys):
    code = main(["certify", "bilateral_2dof_B", "--no-experiments", "--out", str(tmp_path), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 11 and out["decision"] == "NO-GO"
    cert = Certificate.model_validate_json((tmp_path / "certificate.json").read_text())
    assert cert.decision == "NO-GO"


def test_scene_without_certification_is_an_ERROR_certificate(tmp_path):
    d = yaml.safe_load(load_scene("mcet_trilateral").source_text)
    d.pop("certification")
    c = certify_scene(scene_from_dict(d, label="x"), tmp_path)
    assert c.decision == "ERROR" and c.errors


def test_independent_samples_thin_the_chain_without_duplicates():
    """The emcee chain (steps × walkers) is thinned every ⌈τ⌉ steps per walker, in the flat order
    of PosteriorResult.samples; every kept sample is a distinct stored one."""
    from types import SimpleNamespace

    from hil.certify.pipeline import _independent_samples

    n_steps, n_walkers = 100, 4
    chain = np.arange(n_steps * n_walkers * 2, dtype=float).reshape(n_steps, n_walkers, 2)
    samples = chain.reshape(-1, 2)
    res = SimpleNamespace(names=("a", "b"), model=SimpleNamespace(name="m"), posterior=SimpleNamespace(
        samples=samples, chain_z=chain, diagnostics=SimpleNamespace(tau=np.array([3.0, 9.5]))))
    kept, note = _independent_samples(res)
    assert kept.shape == (n_walkers * 10, 2)  # ⌈9.5⌉ = 10: steps 0, 10, ..., 90
    steps = kept[:, 0] // (2 * n_walkers)
    assert set(steps.tolist()) == set(range(0, n_steps, 10))
    assert len(np.unique(kept[:, 0])) == kept.shape[0]
    assert "40 independent draws" in note and "⌈τ⌉ = 10" in note


def test_certify_without_runs_or_identification_loads_neither():
    """Issue 26: a certification that runs nothing and identifies nothing (a scene certified from
    its stated uncertainty) does not import the record, runner or identification code, h5py,
    emcee or scipy.stats (0.5 s CPU to import; the Clopper-Pearson and normal quantiles come from
    scipy.special) -- checked in a fresh interpreter: this process has them all."""
    import subprocess
    import sys

    code = ("import sys, tempfile\n"
            "from hil.certify.pipeline import certify_scene\n"
            "from hil.scene.spec import load_scene\n"
            "with tempfile.TemporaryDirectory() as d:\n"
            "    c = certify_scene(load_scene('bilateral_2dof_B'), d, run_experiments=False)\n"
            "print(c.decision)\n"
            "print(' '.join(m for m in ('h5py', 'emcee', 'scipy.stats', 'hil.record.hdf5', 'hil.run.runner',\n"
            "                           'hil.run.realtime', 'hil.identify.api', 'hil.identify.posterior')\n"
            "               if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True)
    decision, loaded = [*out.stdout.splitlines(), ""][:2]
    assert decision == "NO-GO"
    assert loaded == "", f"loaded although unused: {loaded}"


def test_posterior_bode_from_the_coefficient_map_equals_exact_builds():
    """The posterior Bode plot of a general network takes each draw's entry (1,1) from the robust
    stage's measured coefficient map (one exact build per draw saved: ~60 builds of a 4x4 teleop
    network); the plotted median and band equal those of exact per-draw builds (the map is checked
    affine to 1e-9 relative at exact builds: 1e-6 dB is far above that and far below a plot's ink)."""
    from hil.certify import pipeline as pl
    from hil.models.batch_general import coefficient_map

    sc = load_scene("bilateral_2dof_A1")
    params = pl.model_params_from_scene(sc)
    rng = np.random.default_rng(3)
    draws = {k: u.value * np.exp(u.rel_std * rng.standard_normal(200)) for k, u in sc.certification.uncertain.items()}
    names = sorted(draws)
    X = np.column_stack([draws[k] for k in names])
    cmap = coefficient_map(lambda th: pl.build_network(sc.certification.model, {**params, **th}), names, X)
    assert cmap is not None
    fast: dict = {}
    slow: dict = {}
    pl._bode_plot(fast, sc.certification.model, params, draws, 0, sc.units, cmap)
    pl._bode_plot(slow, sc.certification.model, params, draws, 0, sc.units)
    f, s = fast["bode"], slow["bode"]
    assert f.x == s.x
    np.testing.assert_allclose(f.lines["median"], s.lines["median"], rtol=0, atol=1e-6)
    for a, b in zip(f.bands["90 % credible"], s.bands["90 % credible"], strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
