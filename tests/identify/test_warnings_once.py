"""Each identification warns once per finding: the identifiability check runs twice (at the
initial guess, before the fit, and at the fit), and only the second one logs at WARNING. An
ill-conditioned but regular Fisher matrix alone (every parameter identifiable and well determined)
is information: logged at INFO, never printed as a warning on a default run (issue 28)."""

from __future__ import annotations

import functools
import logging

from conftest import SDEA_SETUP

from hil.identify.api import identify_arrays
from hil.identify.fisher import check_identifiability


def _warnings(caplog, text):
    return [r for r in caplog.records if r.levelno >= logging.WARNING and text in r.getMessage()]


def test_ill_conditioned_fisher_warning_printed_once_per_identification(sdea_record, caplog, monkeypatch) -> None:
    import hil.identify.api as api

    # a threshold every experiment exceeds, so that both checks make the finding
    monkeypatch.setattr(api, "check_identifiability", functools.partial(check_identifiability, cond_warn=1.0))
    rec = sdea_record
    kw = dict(model="sdea_locked", band=SDEA_SETUP["band"], period=SDEA_SETUP["period"], seed=0, max_steps=150)
    with caplog.at_level(logging.DEBUG, logger="hil.identify"):
        res = identify_arrays(rec.t, {"torque": rec.u[:, 0]}, {"velocity": rec.y[:, 0], "force": rec.y[:, 1]}, **kw)
    # the finding is real (the fit's report carries it) and was made by both checks ...
    assert any("Fisher matrix ill-conditioned" in m for m in res.identifiability.messages)
    both = [r for r in caplog.records if "Fisher matrix ill-conditioned" in r.getMessage()]
    assert len(both) == 2
    # ... and, every parameter being identifiable and well determined, it is information: at INFO
    # once (the fit's check), never a WARNING
    assert not _warnings(caplog, "Fisher matrix ill-conditioned")
    assert [r.levelno for r in both] == [logging.DEBUG, logging.INFO]


def test_check_identifiability_logs_at_the_level_asked(caplog) -> None:
    from hil.identify.models import MbkModel

    m = MbkModel(1)
    w = [1.0, 2.0, 3.0]
    with caplog.at_level(logging.DEBUG, logger="hil.identify"):
        rep_default = check_identifiability(m, w=w, sigma=[[[1e-9]]] * 3, cond_warn=1.0)
        n_warn = len(_warnings(caplog, "identifiability"))
        caplog.clear()
        check_identifiability(m, w=w, sigma=[[[1e-9]]] * 3, cond_warn=1.0, log_level=logging.DEBUG)
    serious = [m for m in rep_default.messages if not m.startswith("Fisher matrix ill-conditioned")]
    assert rep_default.messages and n_warn == (len(rep_default.messages) if serious else 0)
    assert not _warnings(caplog, "identifiability")
