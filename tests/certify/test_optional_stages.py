"""The optional certification stages (witness, plots, energy evidence): a failure inside one is
recorded in the certificate's ``errors`` with the stage's name, shown in the report, and leaves the
decision as the criterion made it (a NO-GO stays NO-GO and says why it has no witness); the
witness itself needs no optional package (sympy is gone)."""

from __future__ import annotations

import html
import importlib
import logging
import sys
from types import SimpleNamespace

import pytest
import yaml

from hil.certify.certificate import Certificate
from hil.certify.pipeline import certify_scene
from hil.errors import ModelError
from hil.scene.spec import load_scene, scene_from_dict


def _scene(name: str, **cert):
    """A built-in scene with the fewest posterior draws allowed (the stages under test do not
    depend on the number of draws; this keeps each certification to a few seconds)."""
    d = yaml.safe_load(load_scene(name).source_text)
    d["certification"]["draws"] = 20
    d["certification"].update(cert)
    return scene_from_dict(d, label=f"{name}-small")


@pytest.fixture
def no_sympy(monkeypatch):
    monkeypatch.setitem(sys.modules, "sympy", None)  # `import sympy` raises ImportError
    with pytest.raises(ImportError):
        importlib.import_module("sympy")  # (by name: tests/test_dependencies.py finds no sympy import)


@pytest.mark.timeout(300)
def test_bilateral_2dof_B_NO_GO_carries_its_witness_without_sympy(no_sympy, tmp_path):
    c = certify_scene(_scene("bilateral_2dof_B"), tmp_path, run_experiments=False)
    assert c.decision == "NO-GO", c.reasons
    assert c.witness is not None and c.witness.margin < 0
    assert c.witness.simulation["simulated"]
    assert c.witness.simulation["went_negative"] or c.witness.simulation["diverged"]
    assert c.errors == []


@pytest.mark.timeout(300)
def test_a_failing_witness_search_is_recorded_logged_and_reported(monkeypatch, tmp_path, caplog):
    pytest.importorskip("jinja2")
    import hil.stability.witness as W
    from hil.report.render import render_html

    def broken(*_a, **_k):
        raise ModuleNotFoundError("No module named 'sympy'")

    monkeypatch.setattr(W, "find_witness", broken)
    with caplog.at_level(logging.WARNING, logger="hil.certify.pipeline"):
        c = certify_scene(_scene("bilateral_2dof_B"), tmp_path, run_experiments=False)
    assert c.decision == "NO-GO", c.reasons  # the decision is the criterion's, not the witness's
    assert c.witness is None
    msg = "witness failed: ModuleNotFoundError: No module named 'sympy'"
    assert c.errors == [msg]
    assert any("witness search failed (ModuleNotFoundError" in r for r in c.reasons), c.reasons
    assert any("witness" in r.getMessage() and "sympy" in r.getMessage() for r in caplog.records)
    # the record keeps it, and the report's Errors section shows it
    again = Certificate.model_validate_json(c.model_dump_json())
    assert again.errors == [msg]
    page = html.unescape(render_html(c, tmp_path / "report.html").read_text(encoding="utf-8"))
    assert "Errors" in page and msg in page


@pytest.mark.timeout(300)
def test_failing_plots_and_witness_simulation_are_recorded_and_decide_nothing(monkeypatch, tmp_path):
    import hil.certify.evaluation as ev
    import hil.certify.pipeline as pl

    def plot_fails(*_a, **_k):
        raise ModelError("cannot normalize")  # a HilError: it used to turn the certificate into ERROR

    def sim_fails(*_a, **_k):
        raise FloatingPointError("overflow in expm")

    monkeypatch.setattr(pl, "_decided_plot", plot_fails)
    monkeypatch.setattr(pl, "_bode_plot", plot_fails)
    monkeypatch.setattr(ev, "_simulate_witness", sim_fails)  # called by the witness stage
    c = certify_scene(_scene("bilateral_2dof_B"), tmp_path, run_experiments=False)
    assert c.decision == "NO-GO", c.reasons
    assert c.errors == ["plots (decided quantities) failed: cannot normalize",
                        "plots (posterior Bode) failed: cannot normalize",
                        "witness simulation failed: FloatingPointError: overflow in expm"]
    assert c.witness is not None and c.witness.margin < 0  # the termination is kept without its simulation
    assert c.witness.simulation == {"simulated": False,
                                    "reason": "simulation failed: FloatingPointError: overflow in expm"}
    assert "decided" not in c.plots and "bode" not in c.plots and "witness_energy" not in c.plots


@pytest.mark.timeout(300)
def test_unreadable_energy_evidence_is_recorded_and_a_GO_is_not_given_without_it(tmp_path):
    broken = SimpleNamespace(status="completed", record=tmp_path / "missing.h5",
                             results={"type": "energy_injection", "went_negative": False, "port": "master"})
    scene = _scene("bilateral_2dof_A1", policy={"required_probability": 0.3})
    base = certify_scene(scene, tmp_path / "base", run_experiments=False)
    assert base.decision == "GO", base.reasons
    c = certify_scene(scene, tmp_path / "broken", outcomes={"inject": broken})
    assert c.errors == ["energy evidence (inject) failed: KeyError: 'min_energy'"]
    assert c.energy is None
    assert c.decision == "MARGINAL"
    assert any("energy injection evidence could not be read" in r for r in c.reasons), c.reasons


@pytest.mark.timeout(300)
def test_a_NO_GO_whose_scene_disables_the_witness_says_so(tmp_path):
    c = certify_scene(_scene("bilateral_2dof_B", witness=False), tmp_path, run_experiments=False)
    assert c.decision == "NO-GO" and c.witness is None and c.errors == []
    assert any("disables the witness search" in r for r in c.reasons), c.reasons
