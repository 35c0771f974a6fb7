"""Safety monitor and safe-stop context of the runner, with stand-in samples (no bench needed)."""

import os
import signal
from types import SimpleNamespace

import numpy as np
import pytest

from hil.errors import SafetyStop
from hil.run.runner import SafetyMonitor, safe_stop_context


def sample(seq, pos=0.0, vel=0.0):
    return SimpleNamespace(seq=seq, position=np.array([pos]), velocity=np.array([vel]))


def monitor(**kw):
    cfg = {"max_effort": 2.0, "max_velocity": 5.0, "position_limits": [-1.0, 1.0], "max_energy": 3.0,
           "watchdog_ms": 20}
    cfg.update(kw)
    return SafetyMonitor(cfg, rate_hz=1000.0)


def test_within_limits_passes():
    m = monitor()
    for k in range(50):
        m.check_feedback(k * 1e-3, {"a": sample(k, 0.5, 1.0)})
        m.check_command({"a": np.array([1.9])})
    m.check_energy({"op": 2.9})
    m.check_overrun(0.019)


@pytest.mark.parametrize("call,match", [
    (lambda m: m.check_command({"a": np.array([2.5])}), "effort"),
    (lambda m: m.check_command({"a": np.array([np.nan])}), "non-finite"),
    (lambda m: m.check_feedback(0.0, {"a": sample(0, 0.0, -6.0)}), "velocity"),
    (lambda m: m.check_feedback(0.0, {"a": sample(0, 1.2, 0.0)}), "position"),
    (lambda m: m.check_energy({"op": -3.5}), "energy"),
    (lambda m: m.check_overrun(0.05), "late"),
])
def test_each_limit_breach_raises_with_its_reason(call, match):
    with pytest.raises(SafetyStop, match=match):
        call(monitor())


def test_watchdog_on_stale_feedback():
    m = monitor()
    m.check_feedback(0.0, {"a": sample(7)})
    m.check_feedback(0.015, {"a": sample(7)})  # 15 ms without a new sample: still fine
    with pytest.raises(SafetyStop, match="stale"):
        m.check_feedback(0.021, {"a": sample(7)})


def _ctx(events):
    return safe_stop_context(lambda: events.append("zero effort"),
                             lambda reason, status: events.append((status, reason)))


def test_safe_stop_on_limit_breach_records_reason():
    events = []
    with _ctx(events):
        raise SafetyStop("limit: test")
    assert events == ["zero effort", ("safety_stop", "limit: test")]


def test_safe_stop_on_ctrl_c():
    events = []
    with _ctx(events):
        raise KeyboardInterrupt
    assert events[0] == "zero effort" and events[1][0] == "interrupted"


def test_other_exceptions_are_reraised_after_the_safe_stop():
    events = []
    with pytest.raises(ZeroDivisionError), _ctx(events):
        _ = 1 / 0
    assert events[0] == "zero effort" and events[1][0] == "error"


def test_sigterm_becomes_a_safe_stop():
    from hil.bench.stopflag import STOP

    events = []
    with _ctx(events):
        os.kill(os.getpid(), signal.SIGTERM)  # the handler only sets the flag ...
        assert events == []
        STOP.check()  # ... which the loop turns into a safe stop at its next safe point
    assert events == ["zero effort", ("safety_stop", "signal: SIGTERM")]
    assert signal.getsignal(signal.SIGTERM) is not None  # previous handler restored
