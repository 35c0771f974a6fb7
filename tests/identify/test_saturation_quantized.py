"""Saturation check on quantized channels (hil.identify.diagnostics.check_saturation) and the
rounding floor of a channel on an integer grid (hil.identify.frf.rounding_variance).

A drive with integer wire units (CiA 402 target torque in per mille of rated torque, a CubeMars
12-bit field) sits on its peak level for several samples at every slow peak of a smooth command:
that is rounding, not clipping. A limit that cuts a peak is still clipping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil.identify.diagnostics import check_saturation, quantization_step, run_checks
from hil.identify.frf import rounding_variance

FS = 2000.0
Q = 1e-3  # 1 mN.m: the cia402_bench torque step (1 per mille of 1 N.m)


def _log_chirp(periods: int = 2, amp: float = 0.2) -> np.ndarray:
    """cia402_bench's periodic excitation: log sweep 1 -> 200 Hz over 2 s, amplitude 0.2 N.m."""
    t = (np.arange(round(2.0 * FS * periods)) / FS) % 2.0
    k = math.log(200.0)
    return amp * np.sin(2 * np.pi * (2.0 / k) * (np.exp(k * t / 2.0) - 1.0))


def _q(x: np.ndarray, q: float = Q) -> np.ndarray:
    return np.round(x / q) * q


def test_quantization_step_is_the_grid():
    x = _log_chirp()
    assert quantization_step(_q(x)) == pytest.approx(Q, rel=1e-9)
    assert quantization_step(_q(x, 2 * math.pi / 131072)) == pytest.approx(2 * math.pi / 131072, rel=1e-9)
    assert quantization_step(x) == 0.0  # a float signal has no common step
    assert quantization_step(np.random.default_rng(0).normal(size=5000)) == 0.0


def test_quantized_chirp_is_not_clipping():
    u = _q(_log_chirp())
    # the flat tops are real: the old rule (no step known) reads them as clipping
    flat = check_saturation({"u": u}, steps={"u": 0.0})
    assert flat and flat[0].details["levels"] == [pytest.approx(0.2), pytest.approx(-0.2)]
    # explained by the step, given or detected
    assert check_saturation({"u": u}) == []
    assert check_saturation({"u": u}, steps={"u": Q}) == []
    assert check_saturation({"u": _log_chirp()}) == []  # and the float chirp never was


@pytest.mark.parametrize("cut_steps", [3, 5, 20])
def test_clipped_quantized_chirp_is_clipping(cut_steps):
    x = _log_chirp()
    lim = 0.2 - cut_steps * Q
    u = _q(np.clip(x, -lim, lim))
    (d,) = check_saturation({"u": u})
    assert d.kind == "saturation"
    assert d.details["levels"] == [pytest.approx(lim), pytest.approx(-lim)]
    # independent count: the samples the limit holds (|x| above it), less those of the slow
    # peaks' rounding (at most all samples at the level) -- the flagged fraction lies between
    clipped = float(np.mean(np.abs(x) >= lim))
    at_level = float(np.mean(np.abs(np.abs(u) - lim) < Q / 2))
    assert clipped * 0.5 <= d.details["fraction"] <= at_level


def test_random_quantized_sines_no_false_alarm_and_clips_found():
    """Sines of 8..500 steps amplitude, 0.2..100 Hz, random phase and offset: no flat peak is read
    as clipping; cut by 5 steps, every one is (the rule's resolution is about one step)."""
    rng = np.random.default_rng(3)
    t = np.arange(8000) / FS
    compared = 0
    for _ in range(40):
        amp = Q * math.exp(rng.uniform(math.log(8), math.log(500)))
        f = math.exp(rng.uniform(math.log(0.2), math.log(100)))
        x = amp * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) + rng.uniform(-0.5, 0.5) * Q
        assert check_saturation({"u": _q(x)}) == [], (amp / Q, f)
        lim = amp - 5 * Q
        if check_saturation({"u": np.clip(x, -lim, lim)}):  # clipped enough to show in a float signal
            assert check_saturation({"u": _q(np.clip(x, -lim, lim))}), (amp / Q, f)
            compared += 1
    assert compared >= 30  # most cuts show (a few peaks of a slow sine in 4 s may not reach 0.2 %)


def test_run_checks_accepts_the_quantized_torque_of_a_record():
    t = np.arange(_log_chirp().size) / FS
    rep = run_checks(t, {"torque": _q(_log_chirp())}, {"velocity": np.cumsum(_log_chirp()) / FS})
    assert rep.ok, [d.message for d in rep.failures]


def test_rounding_floor_of_an_integer_grid():
    """An output on a grid of step q (velocity actual in counts/s) has rounding variance q^2/12
    (uniform error over one step), not the float32 spacing's; an input recorded as sent on the wire
    (grid=False) keeps the format's floor only."""
    q = 2 * math.pi / 131072
    v = _q(5.0 * _log_chirp(), q)
    assert rounding_variance(v, "float32") == pytest.approx(q * q / 12, rel=1e-9)
    with np.errstate(over="ignore"):
        sp = np.spacing(np.abs(v).astype(np.float32)).astype(float)
    assert rounding_variance(v, "float32", grid=False) == pytest.approx(np.mean(sp**2) / 12, rel=1e-12)
    x = _log_chirp()  # a float signal: unchanged
    with np.errstate(over="ignore"):
        sp = np.spacing(np.abs(x).astype(np.float32)).astype(float)
    assert rounding_variance(x, "float32") == pytest.approx(np.mean(sp**2) / 12, rel=1e-12)
