"""hil sweep: grid parsing, executor independence, resume from the cache, the refined boundary
against the design search, P(stable) per point against the per-draw exact path, and the CLI."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from hil.certify.sweep import (
    ProcessExecutor,
    SerialExecutor,
    SweepError,
    SweepSpec,
    iter_table,
    load_sweep,
    parse_grid,
    run_sweep,
    save_sweep,
)
from hil.models.design import k22_max
from hil.models.sdea import SDEA_TABLE1

SPEC_GRID = ["b22=0.05:0.19:4", "k22=150:450:7"]


def _spec(**kw):
    return SweepSpec("sdea", [parse_grid(g) for g in SPEC_GRID], criterion="passivity", chunk=5, **kw)


def _same(a, b) -> None:
    """Bit-for-bit equal tables (NaN where NaN)."""
    np.testing.assert_array_equal(a.verdict, b.verdict)
    np.testing.assert_array_equal(a.margin, b.margin)
    np.testing.assert_array_equal(a.worst_frequency, b.worst_frequency)
    for k in ("points", "axis", "bracket"):
        np.testing.assert_array_equal(a.boundary[k], b.boundary[k])
    assert a.evaluations == b.evaluations


@pytest.mark.parametrize("text, lo, hi, n, log", [("k22=100:600:11", 100, 600, 11, False),
                                                  ("b22=log:1e-3:1:4", 1e-3, 1, 4, True),
                                                  ("alpha=0.5:0.5:1", 0.5, 0.5, 1, False)])
def test_parse_grid(text, lo, hi, n, log) -> None:
    a = parse_grid(text)
    assert (a.lo, a.hi, a.n, a.log) == (lo, hi, n, log)
    v = a.values
    assert len(v) == n and v[0] == pytest.approx(lo) and v[-1] == pytest.approx(hi)
    if log and n > 2:  # log spacing: constant ratio
        assert np.allclose(v[1:] / v[:-1], (hi / lo) ** (1 / (n - 1)))


@pytest.mark.parametrize("bad", ["k22", "k22=1:2", "k22=a:2:3", "k22=2:1:5", "k22=1:2:0", "k22=log:0:1:3",
                                 "k22=1:inf:3", "=1:2:3"])
def test_parse_grid_refuses(bad) -> None:
    with pytest.raises(SweepError):
        parse_grid(bad)


def test_spec_refuses_unknown_and_duplicate_parameters() -> None:
    with pytest.raises(SweepError, match="no parameter"):
        SweepSpec("sdea", [parse_grid("k23=1:2:3")]).validate()
    with pytest.raises(SweepError, match="twice"):
        SweepSpec("sdea", [parse_grid("k22=1:2:3"), parse_grid("k22=1:2:3")]).validate()
    with pytest.raises(SweepError, match="also fixed"):
        SweepSpec("sdea", [parse_grid("k22=1:2:3")], params={"k22": 5.0}).validate()
    with pytest.raises(SweepError, match="unknown model"):
        SweepSpec("nope", [parse_grid("k22=1:2:3")]).validate()


def test_boundary_agrees_with_the_design_search() -> None:
    """Each refined crossing along k22 brackets k22_max(b22) of hil design (an independent bisection
    on the E{1,2} condition alone): |k - k22_max| ≤ tol·step (the sweep's bracket) + 1e-7·k (the
    design search's own tolerance)."""
    spec = _spec()
    res = run_sweep(spec)
    b, k = res.boundary_curve("k22")
    assert len(b) >= 3  # the grid crosses the boundary on several b22 lines
    step = (450 - 150) / 6
    for bi, ki in zip(b, k, strict=True):
        ref = k22_max(float(bi), 1.0, "passivity").k22_max
        assert abs(ki - ref) <= spec.boundary_tol * step + 1e-7 * ref, (bi, ki, ref)
    # the bracket's stable end is stable and its unstable end is not, by the exact criterion
    from hil.models.sdea import sdea_vsic
    from hil.stability.criteria import check

    sel = res.boundary["axis"] == 1
    for (bi, _), (s, u) in zip(res.boundary["points"][sel], res.boundary["bracket"][sel], strict=True):
        assert check(sdea_vsic(SDEA_TABLE1, k22=s, b22=bi), "passivity").verdict == "stable"
        assert check(sdea_vsic(SDEA_TABLE1, k22=u, b22=bi), "passivity").verdict != "stable"


def test_three_axes_give_one_boundary_curve_per_alpha() -> None:
    """k22_max(b22) for two feed-forward ratios (002 Table II's rows are its maxima over b22)."""
    spec = SweepSpec("sdea", [parse_grid("b22=0.08:0.16:3"), parse_grid("k22=200:500:4"), parse_grid("alpha=0.9:1:2")],
                     criterion="passivity", chunk=8)
    res = run_sweep(spec)
    for alpha in (0.9, 1.0):
        b, k = res.boundary_curve("k22", {"alpha": alpha})
        assert len(b) == 3
        for bi, ki in zip(b, k, strict=True):
            ref = k22_max(float(bi), alpha, "passivity").k22_max
            assert abs(ki - ref) <= spec.boundary_tol * 100 + 1e-7 * ref, (alpha, bi, ki, ref)


def test_grid_verdicts_are_the_exact_ones() -> None:
    from hil.models.sdea import sdea_vsic
    from hil.stability.criteria import check

    res = run_sweep(_spec(refine=False))
    rows = list(iter_table(res))
    assert len(rows) == 4 * 7 and not len(res.boundary["points"])
    for r in rows[::5]:
        ref = check(sdea_vsic(SDEA_TABLE1, k22=r["k22"], b22=r["b22"]), "passivity")
        assert r["verdict"] == str(ref.verdict) and r["margin"] == float(ref.margin)


def test_process_pool_matches_serial() -> None:
    ref = run_sweep(_spec(), SerialExecutor())
    ex = ProcessExecutor(2)
    try:
        got = run_sweep(_spec(), ex)
    finally:
        ex.close()
    _same(ref, got)


def test_dask_local_cluster_matches_serial() -> None:
    import distributed

    from hil.certify.sweep import DaskExecutor

    ref = run_sweep(_spec(), SerialExecutor())
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cl, \
            distributed.Client(cl) as client:
        got = run_sweep(_spec(), DaskExecutor(client))
    _same(ref, got)


class _Interrupt(Exception):
    pass


def test_interrupted_sweep_resumes_from_the_cache(tmp_path) -> None:
    """Stop after 3 tasks; the rerun computes only the rest and gives the same table."""
    ref = run_sweep(_spec(), cache_dir=None)
    calls = []

    def stop_after_three() -> None:
        calls.append(1)
        if len(calls) == 3:
            raise _Interrupt

    with pytest.raises(_Interrupt):
        run_sweep(_spec(), cache_dir=tmp_path, should_stop=stop_after_three)
    assert len(list(tmp_path.glob("*.npz"))) == 3
    again = run_sweep(_spec(), cache_dir=tmp_path)
    assert again.cache_hits == 3
    _same(ref, again)
    third = run_sweep(_spec(), cache_dir=tmp_path)  # everything cached now
    assert third.cache_hits == len(list(tmp_path.glob("*.npz")))
    _same(ref, third)


def test_damaged_cache_file_is_recomputed(tmp_path) -> None:
    ref = run_sweep(_spec(refine=False), cache_dir=tmp_path)
    for f in tmp_path.glob("*.npz"):
        f.write_bytes(b"not an npz")
    again = run_sweep(_spec(refine=False), cache_dir=tmp_path)
    assert again.cache_hits == 0
    _same(ref, again)


def test_cache_key_depends_on_content(tmp_path) -> None:
    run_sweep(_spec(refine=False), cache_dir=tmp_path)
    other = SweepSpec("sdea", [parse_grid(g) for g in SPEC_GRID], criterion="passivity", chunk=5, refine=False,
                      params={"alpha": 0.8})
    res = run_sweep(other, cache_dir=tmp_path)
    assert res.cache_hits == 0


def _posterior(n: int = 400, seed: int = 1) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {k: SDEA_TABLE1[k] * (1 + 0.05 * rng.standard_normal(n)) for k in ("M", "B", "K_f", "B_f")}


def test_p_stable_per_point_matches_the_per_draw_exact_path() -> None:
    """The vectorized SDEA path against one exact verdict per draw (the general path)."""
    from hil.certify.sweep import _draw_subset, _p_stable
    from hil.models.sdea import sdea_vsic
    from hil.stability.criteria import check

    post = _posterior()
    draws = _draw_subset(post, 60, "seed text")
    assert len(draws["M"]) == 60 and len(set(draws["M"])) == 60  # without replacement
    for k22 in (200.0, 330.0, 420.0):
        params = {"k22": k22, "b22": 0.15}
        exact = np.mean([check(sdea_vsic({**SDEA_TABLE1, **{k: float(v[i]) for k, v in draws.items()}, **params}),
                               "passivity").verdict == "stable" for i in range(60)])
        assert _p_stable("sdea", "passivity", params, draws) == pytest.approx(exact, abs=0)


def test_robust_map_is_deterministic_and_bounded() -> None:
    post = _posterior()

    def spec() -> SweepSpec:
        return SweepSpec("sdea", [parse_grid("k22=200:450:6")], params={"b22": 0.15}, criterion="passivity",
                         posterior=post, n_draws=80, chunk=2, refine=False)

    a = run_sweep(spec())
    ex = ProcessExecutor(2)
    try:
        b = run_sweep(spec(), ex)
    finally:
        ex.close()
    assert a.p_stable is not None and b.p_stable is not None
    np.testing.assert_array_equal(a.p_stable, b.p_stable)
    assert np.all((a.p_stable >= 0) & (a.p_stable <= 1))
    assert a.p_stable[0] > a.p_stable[-1]  # a stiffer coupler is less often passive


def test_save_and_load_roundtrip(tmp_path) -> None:
    res = run_sweep(_spec())
    p = save_sweep(res, tmp_path / "s.h5")
    d = load_sweep(p)
    np.testing.assert_array_equal(d["verdict"], res.verdict)
    np.testing.assert_array_equal(d["margin"], res.margin)
    np.testing.assert_array_equal(d["boundary"]["points"], res.boundary["points"])
    assert list(d["axes"]) == ["b22", "k22"] and d["spec"]["model"] == "sdea"


def _hil(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=300, check=False)


def test_cli_sweep_writes_table_map_and_boundary(tmp_path) -> None:
    out = tmp_path / "o"
    p = _hil("sweep", "--model", "sdea", "--grid", "b22=0.05:0.19:3", "--grid", "k22=150:450:4",
             "--executor", "serial", "--out", str(out), "--cache", str(tmp_path / "c"), "--json")
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["points"] == 12 and doc["boundary_points"] >= 1
    assert (out / "sweep.h5").exists() and (out / "boundary.csv").exists() and (out / "sweep.png").exists()
    rows = np.loadtxt(out / "boundary.csv", delimiter=",", skiprows=1, ndmin=2)
    assert rows.shape[1] == 2 + 3


@pytest.mark.parametrize("args, msg", [(["--grid", "k22=1:2"], "NAME=LO:HI:N"),
                                       (["--grid", "q=1:2:3"], "no parameter"),
                                       (["--grid", "k22=1:2:3", "--workers", "0"], "at least 1"),
                                       (["--grid", "k22=1:2:3", "--boundary-tol", "2"], "boundary-tol")])
def test_cli_sweep_bad_input_is_one_line(tmp_path, args, msg) -> None:
    p = _hil("sweep", "--model", "sdea", *args, "--out", str(tmp_path / "o"), "--no-cache")
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and msg in lines[0], p.stderr
    assert not (tmp_path / "o").exists()


def test_scene_network_sweep_uses_the_scenes_parameters() -> None:
    """--scene: the scene's model, gains and plant; a swept gain of a gain table replaces its entry."""
    from hil.certify.pipeline import build_network, model_params_from_scene
    from hil.scene.spec import load_scene
    from hil.stability.criteria import check

    sc = load_scene("sdea_bench")
    spec = SweepSpec.from_scene(sc, [parse_grid("k22=150:450:3")], refine=False)
    res = run_sweep(spec)
    fixed = model_params_from_scene(sc)
    for row in iter_table(res):
        ref = check(build_network("sdea", {**fixed, "k22": row["k22"]}), spec.criterion_name)
        assert row["verdict"] == str(ref.verdict) and row["margin"] == float(ref.margin)
    bi = load_scene("bilateral_2dof_B")
    spec = SweepSpec.from_scene(bi, [parse_grid("k_pmyz=450:550:2")], refine=False)
    res = run_sweep(spec)
    gains = model_params_from_scene(bi)["gains"]
    for row in iter_table(res):
        p = {**model_params_from_scene(bi), "gains": {**gains, "k_pmyz": row["k_pmyz"]}}
        assert row["verdict"] == str(check(build_network("bilateral_2dof", p), spec.criterion_name).verdict)


def test_mbk_boundary_is_where_the_mass_matrix_stops_being_psd() -> None:
    """Z = (M s² + B s + K)/s is PR iff M, B, K are PSD (the model's docstring); with M_00 = 1 and
    M_11 = 0.6 the mass matrix loses definiteness at M_01 = √0.6 (closed form)."""
    spec = SweepSpec("mbk_impedance", [parse_grid("M_01=0.6:0.9:7")], params={"M_00": 1.0, "M_11": 0.6})
    res = run_sweep(spec)
    (p,) = res.boundary["points"][:, 0]
    assert abs(p - np.sqrt(0.6)) <= spec.boundary_tol * 0.05
    s, u = res.boundary["bracket"][0]
    assert s < np.sqrt(0.6) < u


def test_posterior_from_a_stored_identification(tmp_path) -> None:
    """Sampled parameters plus the identification model's derived ones, kept where the network takes them."""
    import h5py

    from hil.certify.sweep import posterior_from_record
    from hil.identify.models import make_model

    mdl = make_model("mbk")
    rng = np.random.default_rng(0)
    z = np.array([mdl.nominal[n] for n in mdl.names]) if isinstance(getattr(mdl, "nominal", None), dict) else None
    samples = (np.ones(len(mdl.names)) if z is None else z) * (1 + 0.01 * rng.standard_normal((50, len(mdl.names))))
    path = tmp_path / "r.h5"
    with h5py.File(path, "w") as f:
        g = f.create_group("identification/mbk")
        g.create_dataset("samples", data=samples)
        g.create_dataset("summary", data=json.dumps({"model": "mbk", "sample_names": list(mdl.names)}))
    post = posterior_from_record(str(path), None, "mbk_impedance")
    derived = mdl.derived(samples)
    assert set(post) == set(derived)  # the Cholesky factors are not network parameters; M, B, K entries are
    for k, (v, _unit) in derived.items():
        np.testing.assert_array_equal(post[k], v)
    with pytest.raises(SweepError, match="none of its parameters"):
        posterior_from_record(str(path), None, "sdea")


def test_cli_sweep_sigint_keeps_finished_tasks_and_resumes(tmp_path) -> None:
    """Ctrl-C: exit 130 with one line, the finished tasks stay cached, the rerun completes from them."""
    import os
    import signal
    import time

    cache = tmp_path / "cache"
    # 100 one-point tasks: the signal, sent once 2 are cached, always arrives well before the end
    args = [sys.executable, "-m", "hil", "sweep", "--model", "sdea", "--grid", "b22=0.05:0.19:10",
            "--grid", "k22=150:450:10", "--chunk", "1", "--executor", "serial", "--no-refine", "--no-plot",
            "--cache", str(cache)]
    proc = subprocess.Popen([*args, "--out", str(tmp_path / "a")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and len(list(cache.glob("*.npz"))) < 2:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _out, err = proc.communicate(timeout=120)
    kept = len(list(cache.glob("*.npz")))
    assert proc.returncode == 130, err
    lines = [ln for ln in err.strip().splitlines() if "hil sweep" in ln and "error" in ln]
    assert len(lines) == 1 and "resume" in lines[0], err
    assert 2 <= kept < 100
    assert not list(cache.glob(".*.tmp"))  # no half-written cache file
    p = subprocess.run([*args, "--out", str(tmp_path / "b"), "--json"], capture_output=True, text=True,
                       timeout=300, check=False)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["cache_hits"] == kept
    fresh = run_sweep(SweepSpec("sdea", [parse_grid("b22=0.05:0.19:10"), parse_grid("k22=150:450:10")], chunk=1,
                                refine=False))
    np.testing.assert_array_equal(load_sweep(tmp_path / "b" / "sweep.h5")["margin"], fresh.margin)
    assert os.path.isdir(tmp_path / "a") is False or not any((tmp_path / "a").iterdir())
