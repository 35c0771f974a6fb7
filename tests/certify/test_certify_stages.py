"""hil certify as stages (hil.certify.stages, hil.certify.pipeline.stage_*): measurements that declare
their limits as data and derive their outcome, a stage that raises is ERROR (never FAIL), and the
refactor into stages changed no certificate (reference certificates written by the pipeline before
it, tests/data/certify_reference/).

The reference files hold every field of a certificate but its wall-clock fields (``created_utc``,
the run-time row, ``integrity``), the software versions and the plots' data (only each plot's
title, line and band names and lengths): they were written by the single-function pipeline of
commit 326bb3a (``python tests/certify/test_certify_stages.py --write DIR`` with that commit's ``hil`` on
the path). Rewrite them only for an intended change of the certificate's content.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hil.certify.pipeline import certify_scene
from hil.certify.stages import (
    HEADROOM_TOL,
    MARGIN_TOL,
    NOMINAL_MARGIN,
    Expect,
    Limit,
    MeasurementSpec,
    judge,
    p_stable_spec,
    worst_case_spec,
)
from hil.certify.statistics import Policy
from hil.scene.spec import load_scene, scene_from_dict

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "certify_reference"


# ---------------------------------------------------------------------------------------------
# limits and outcomes


@pytest.mark.parametrize("margin,verdict,expected", [
    (0.3, "stable", "PASS"), (-0.2, None, "FAIL"), (-1e-6, None, "FAIL"), (0.0, "stable", "MARGINAL"),
    (5e-10, None, "MARGINAL"), (1e-3, "marginal", "MARGINAL"), (0.3, "potentially_unstable", "FAIL"),
    (float("nan"), None, "ERROR"), (None, None, "ERROR"), (None, "potentially_unstable", "FAIL"),
    (-MARGIN_TOL, None, "MARGINAL"), (MARGIN_TOL, None, "MARGINAL"), (2 * MARGIN_TOL, None, "PASS")])
def test_margin_outcome_negative_is_FAIL_not_MARGINAL(margin, verdict, expected):
    """A margin against its limit 0 with the closed MARGINAL band [-tol, tol]; the verdict behind
    it (when given) fails it or caps it at MARGINAL; a missing margin is ERROR unless the verdict
    fails (a failure decided by evidence that exists stands)."""
    spec = NOMINAL_MARGIN if verdict is not None else worst_case_spec(Policy())
    kw = {"result": verdict} if verdict is not None else {}
    assert spec.outcome(margin, **kw) == expected


def test_limit_at_zero_tolerance_passes_at_the_limit_and_judges_intervals_whole():
    lim = Limit(lower=0.95)
    assert lim.outcome(0.95) == "PASS" and lim.outcome(0.9499999) == "FAIL" and lim.outcome(1.0) == "PASS"
    # an interval: PASS wholly above, FAIL wholly below, MARGINAL straddling
    assert lim.outcome(0.97, interval=(0.96, 0.99)) == "PASS"
    assert lim.outcome(0.90, interval=(0.85, 0.949)) == "FAIL"
    assert lim.outcome(0.94, interval=(0.94, 0.96)) == "MARGINAL"
    assert lim.outcome(0.9, interval=(float("nan"), 0.96)) == "ERROR"
    two = Limit(lower=-1.0, upper=1.0, tol=0.1)
    assert [two.outcome(v) for v in (-1.2, -1.05, -0.5, 0.0, 0.95, 1.1, 1.2)] == [
        "FAIL", "MARGINAL", "PASS", "PASS", "MARGINAL", "MARGINAL", "FAIL"]
    assert two.outcome(0.0, interval=(-2.0, 2.0)) == "MARGINAL"  # spans both limits: not wholly outside
    assert Limit(lower=0.0, tol=HEADROOM_TOL).outcome(0.5 * HEADROOM_TOL) == "MARGINAL"
    for bad in (None, "0.3", True, float("inf")):
        assert lim.outcome(bad) == "ERROR"


def test_expect_matches_type_and_value_and_judge_orders_outcomes():
    e = Expect({True: "PASS"}, otherwise="MARGINAL")
    assert e.outcome(True) == "PASS" and e.outcome(np.bool_(True)) == "PASS"
    assert e.outcome(1) == "MARGINAL" and e.outcome(False) == "MARGINAL"  # 1 is not True
    s = Expect({"completed": "PASS", "safety_stop": "FAIL"})
    assert [s.outcome(x) for x in ("completed", "safety_stop", "error", None)] == ["PASS", "FAIL", "ERROR", "ERROR"]
    assert judge([]) == "INFO" and judge(["INFO"]) == "INFO"
    assert judge(["PASS", "MARGINAL"]) == "MARGINAL"
    assert judge(["MARGINAL", "ERROR"]) == "ERROR" and judge(["ERROR", "FAIL"]) == "FAIL"


def test_a_spec_records_its_limits_and_an_invalid_estimate_is_ERROR_even_below_the_limit():
    spec = p_stable_spec(Policy(required_probability=0.99))
    m = spec.measure(0.5, interval=(0.4, 0.6))
    assert (m.lower, m.upper, m.outcome, m.name) == (0.99, None, "FAIL", "P(stable), lower confidence bound")
    assert spec.measure(0.5, interval=(0.4, 0.6), invalid=True).outcome == "ERROR"
    info = MeasurementSpec("run time", unit="s").measure(1.5, description="run 1.5 s")
    assert (info.outcome, info.unit, info.lower, info.description) == ("INFO", "s", None, "run 1.5 s")
    shown = MeasurementSpec("E", expect=Expect({False: "PASS"}, otherwise="FAIL")).measure(-3.0, result=True,
                                                                                           lower=-1.0)
    assert (shown.outcome, shown.lower) == ("FAIL", -1.0)


# ---------------------------------------------------------------------------------------------
# scenes (tiny: no experiments, priors only)


def _tiny(name: str, draws: int) -> dict[str, Any]:
    d = yaml.safe_load(load_scene(name).source_text)
    d["experiments"] = []
    d["certification"]["draws"] = draws
    return d


def _sdea(k22: float, draws: int = 200) -> dict[str, Any]:
    """The SDEA bench certified from its simulated plant's M and B known to 5 and 10 %: the
    vectorized path, the design search and its headroom."""
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = []
    d["controller"]["k22"] = k22
    c = d["certification"]
    c.pop("identify")
    c["uncertain"] = {"M": {"value": 6.399e-4, "rel_std": 0.05}, "B": {"value": 0.169, "rel_std": 0.1}}
    c["draws"] = draws
    return d


def _nocert() -> dict[str, Any]:
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d.pop("certification")
    return d


SCENES = {  # name -> (scene, decision the reference holds)
    "mcet": (lambda: _tiny("mcet_trilateral", 20), "MARGINAL"),
    "sdea300": (lambda: _sdea(300.0), "GO"),
    "sdea404": (lambda: _sdea(404.0), "NO-GO"),
    "sdea450": (lambda: _sdea(450.0), "NO-GO"),
    "nocert": (_nocert, "ERROR"),
    "B": (lambda: _tiny("bilateral_2dof_B", 20), "NO-GO"),
}


def _content(cert: Any) -> dict[str, Any]:
    """A certificate's content without wall-clock fields, software versions and plot data."""
    c = json.loads(cert.model_dump_json())
    for k in ("created_utc", "integrity", "software"):
        c.pop(k)
    c["measurements"] = [m for m in c["measurements"] if m["name"] != "run time"]
    c["plots"] = {k: {"title": p["title"], "lines": {n: len(v) for n, v in p["lines"].items()},
                      "bands": {n: [len(v[0]), len(v[1])] for n, v in p["bands"].items()}}
                  for k, p in c["plots"].items()}
    return c


def _certify(key: str, out: Path) -> Any:
    make, _ = SCENES[key]
    return certify_scene(scene_from_dict(make(), label=key), out, run_experiments=False)


def _same(a: Any, b: Any, where: str = "") -> list[str]:
    """Paths where ``a`` and ``b`` differ: numbers to 1e-9 relative (1e-12 absolute) -- the
    refactor moved code, so the arithmetic is the same; the tolerance only absorbs a platform's
    last-bit differences in BLAS and libm -- everything else exactly."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{where}.{k}: missing" for k in a.keys() ^ b.keys()]
        for k in a.keys() & b.keys():
            out += _same(a[k], b[k], f"{where}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: length {len(a)} != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in _same(x, y, f"{where}[{i}]")]
    if isinstance(a, float) and isinstance(b, float | int) and not isinstance(b, bool):
        return [] if math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12) else [f"{where}: {a!r} != {b!r}"]
    return [] if a == b else [f"{where}: {a!r} != {b!r}"]


def _intended(ref: dict[str, Any]) -> dict[str, Any]:
    """The reference with the certificate changes made on purpose since it was written.

    Issue 26: on a nominal NO-GO (nominal network potentially unstable) the worst-case search over
    the credible region, β (FORM) and importance sampling are not run -- they cannot change the
    decision; one INFO row says so where the worst-case row stood."""
    from hil.certify.pipeline import NOT_SEARCHED_ROW

    ref = json.loads(json.dumps(ref))
    if ref.get("nominal") and ref["nominal"]["verdict"] == "potentially_unstable" and ref.get("robust"):
        rob = ref["robust"]
        rob.update(worst_case_margin=None, worst_case_parameters=None, reliability=None, rare_event=None,
                   p_stable_method="monte_carlo")
        rows = []
        for m in ref["measurements"]:
            if m["name"].startswith("worst-case margin over"):
                rows.append({"name": NOT_SEARCHED_ROW, "value": "not searched", "unit": "", "lower": None,
                             "upper": None, "outcome": "INFO",
                             "description": "the nominal network is potentially unstable: NO-GO whatever the "
                                            "worst case over the credible region or β"})
            elif not m["name"].startswith(("reliability index β", "P(stable), importance sampling")):
                rows.append(m)
        ref["measurements"] = rows
        ref["plots"].pop("design_point", None)
    return ref


@pytest.mark.parametrize("key", list(SCENES))
def test_certificates_are_unchanged_by_the_stages(key, tmp_path):
    ref = _intended(json.loads((REFERENCE / f"{key}.json").read_text()))
    cert = _certify(key, tmp_path)
    assert cert.decision == SCENES[key][1] == ref["decision"]
    got = _content(cert)
    diffs = _same(ref, got)
    assert not diffs, diffs[:10]
    # every judged row's outcome follows from its own numbers (the limits it records)
    for m in cert.measurements:
        if m.name == "P(stable), lower confidence bound":
            lo, hi, req = cert.robust.lower, cert.robust.upper, cert.robust.required
            assert m.lower == req and m.value == lo
            assert m.outcome == ("PASS" if lo >= req else "FAIL" if hi < req else "MARGINAL")
        elif m.name == "reliability index β":
            assert m.outcome == ("PASS" if m.value >= m.lower else "FAIL")


def test_a_stage_that_raises_is_ERROR_with_its_reason_never_FAIL(monkeypatch, tmp_path):
    """A defect inside a stage (here the robust stage's evaluation raising ZeroDivisionError) ends
    the certification as ERROR naming the stage and the reason; what the stages before it measured
    is kept, and no row is FAIL."""
    import hil.certify.pipeline as pl

    def broken(*a: Any, **k: Any) -> Any:
        raise ZeroDivisionError("division by zero in the robust evaluation")

    monkeypatch.setattr(pl, "_robust_eval", broken)
    cert = _certify("sdea300", tmp_path)
    assert cert.decision == "ERROR"
    assert cert.reasons == ["stage robust failed: ZeroDivisionError: division by zero in the robust evaluation"]
    assert cert.errors == cert.reasons
    names = [m.name for m in cert.measurements]
    assert "nominal margin" in names and "P(stable), lower confidence bound" not in names
    assert all(m.outcome != "FAIL" for m in cert.measurements)
    assert cert.nominal is None and cert.robust is None  # only a completed certification carries sections
    from hil.certify.verify import check_certificate

    assert check_certificate(cert, tmp_path).valid  # still a sealed, verifiable record


def test_stage_outputs_are_frozen():
    import dataclasses

    from hil.certify.stages import PosteriorDraws, Verdict
    from hil.certify.statistics import Decision

    v = Verdict(decision=Decision.GO, reasons=("x",))
    with pytest.raises(dataclasses.FrozenInstanceError):
        v.reasons = ()  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        PosteriorDraws(draws={}).converged = False  # type: ignore[misc]


if __name__ == "__main__":  # write the reference certificates (see the module docstring)
    if len(sys.argv) != 3 or sys.argv[1] != "--write":
        sys.exit("usage: python tests/certify/test_certify_stages.py --write DIR")
    import tempfile

    target = Path(sys.argv[2])
    target.mkdir(parents=True, exist_ok=True)
    for k in SCENES:
        with tempfile.TemporaryDirectory() as tmp:
            c = _certify(k, Path(tmp))
        (target / f"{k}.json").write_text(json.dumps(_content(c), indent=1, sort_keys=True) + "\n")
        print(k, c.decision)


def test_an_error_of_ours_in_a_stage_propagates_with_its_exit_code(monkeypatch, tmp_path):
    """A HilError (a device that cannot be opened, a record that cannot be written) is not a
    defect: it reaches the CLI, which maps it to one line and its exit code, as before the stages."""
    import hil.certify.pipeline as pl
    from hil.record.hdf5 import RecordError

    def unwritable(*a: Any, **k: Any) -> Any:
        raise RecordError("x.h5: cannot create record: disk full")

    monkeypatch.setattr(pl, "_robust_eval", unwritable)
    with pytest.raises(RecordError, match="disk full"):
        _certify("sdea300", tmp_path)
