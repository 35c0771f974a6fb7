"""Sensor imperfection models: each stage against its definition, chain order, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from hil.errors import ModelError
from hil.mocks.physics import mbk_plant
from hil.mocks.sensors import (
    Bias,
    Chain,
    Delay,
    GaussianNoise,
    Quantizer,
    Saturation,
    SensedJoints,
    SensorModel,
)
from hil.mocks.simulator import Simulator


def test_bias_quantizer_saturation() -> None:
    x = np.array([-2.26, -0.04, 0.0, 0.051, 3.3])
    np.testing.assert_array_equal(Bias(0.5)(x), x + 0.5)
    q = Quantizer(0.1)(x)
    np.testing.assert_allclose(q, np.round(x / 0.1) * 0.1)
    assert np.max(np.abs(q - x)) <= 0.05 + 1e-15  # within half a step
    np.testing.assert_array_equal(Quantizer(0.0)(x), x)
    np.testing.assert_array_equal(Saturation(-1.0, 2.0)(x), np.clip(x, -1.0, 2.0))
    with pytest.raises(ModelError):
        Saturation(1.0, -1.0)
    with pytest.raises(ModelError):
        Quantizer(-0.1)


def test_delay_line() -> None:
    d = Delay(3, initial=0.0)
    out = [float(d(np.array(float(i)))) for i in range(1, 8)]
    assert out == [0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 4.0]
    d2 = Delay(2)  # default: repeats the first sample until fresh data arrives
    assert [float(d2(np.array(v))) for v in (5.0, 6.0, 7.0)] == [5.0, 5.0, 5.0]
    d2.reset()
    assert float(d2(np.array(9.0))) == 9.0
    assert float(Delay(0)(np.array(4.0))) == 4.0
    with pytest.raises(ModelError):
        Delay(-1)


def test_noise_statistics_and_determinism() -> None:
    x = np.zeros(20000)
    std = 0.3
    a = GaussianNoise(std, seed=1)(x)
    b = GaussianNoise(std, seed=1)(x)
    c = GaussianNoise(std, seed=2)(x)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # sample mean ~ N(0, std^2/n): 5 sigma bound; sample std within 5 sigma of std (sd ~ std/sqrt(2n))
    n = x.size
    assert abs(a.mean()) <= 5 * std / np.sqrt(n)
    assert abs(a.std() - std) <= 5 * std / np.sqrt(2 * n)
    # reset replays the same sequence
    g = GaussianNoise(std, seed=3)
    first = g(np.zeros(5))
    g.reset()
    np.testing.assert_array_equal(g(np.zeros(5)), first)
    # matches numpy's documented PCG64 stream for that seed
    np.testing.assert_array_equal(first, std * np.random.default_rng(3).standard_normal(5))
    with pytest.raises(ModelError):
        GaussianNoise(-1.0)


def test_sensor_model_applies_stages_in_physical_order() -> None:
    seed = 11
    model = SensorModel(noise_std=0.01, bias=0.2, resolution=0.05, limits=(-1.0, 1.0), delay_ticks=2,
                        seed=seed)
    manual = Chain(Delay(2), Bias(0.2), GaussianNoise(0.01, seed), Saturation(-1.0, 1.0), Quantizer(0.05))
    xs = np.linspace(-2.0, 2.0, 50)
    out_model = np.array([model(np.array([v]))[0] for v in xs])
    out_manual = np.array([manual(np.array([v]))[0] for v in xs])
    np.testing.assert_array_equal(out_model, out_manual)
    assert np.all(np.abs(out_model) <= 1.0 + 1e-12)
    np.testing.assert_allclose(out_model / 0.05, np.round(out_model / 0.05), atol=1e-9)
    model.reset()
    np.testing.assert_array_equal(model(np.array([xs[0]])), [out_model[0]])
    # no imperfections -> identity
    np.testing.assert_array_equal(SensorModel()(xs), xs)


def _sensed_run(seed: int) -> np.ndarray:
    sim = Simulator(mbk_plant(0.5, 1.0, 100.0), 1e-3)
    h = SensedJoints(sim.joints("body"), position=SensorModel(noise_std=1e-4, resolution=1e-5, seed=seed),
                     velocity=SensorModel(delay_ticks=2))
    out = []
    for _ in range(200):
        p1 = h.position()
        p2 = h.position()  # same tick: the same sample (noise advances once per tick)
        np.testing.assert_array_equal(p1, p2)
        out.append(np.concatenate([p1, h.velocity()]))
        h.apply_effort([1.0])
        sim.tick()
    return np.array(out)


def test_sensed_joints_deterministic_per_seed_and_delayed() -> None:
    a, b, c = _sensed_run(1), _sensed_run(1), _sensed_run(2)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a[:, 0], c[:, 0])
    # the noise-free delayed velocity equals the true velocity two ticks earlier
    sim = Simulator(mbk_plant(0.5, 1.0, 100.0), 1e-3)
    true_v = []
    for _ in range(200):
        true_v.append(sim.joints("body").velocity()[0])
        sim.joints("body").apply_effort([1.0])
        sim.tick()
    np.testing.assert_array_equal(a[2:, 1], np.array(true_v)[:-2])
