"""Experiments: signal properties against closed forms / independent implementations, check()
errors naming the field, and the port-energy integral and its noise bound."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal as sps

from hil.errors import SceneError
from hil.experiments import (
    EnergyInjection,
    Excitation,
    Multisine,
    StaticHold,
    force_profile,
    make_experiment,
    port_energy,
    schroeder_phases,
)
from hil.experiments.signals import crest_factor
from hil.mocks.physics import Scene as PhysScene
from hil.mocks.simulator import Simulator
from hil.mocks.terminations import Human
from hil.protocols.base import JointSample

pytestmark = pytest.mark.timeout(120)


def scene(dof: int = 1, max_effort: float = 5.0, **extra):
    """A minimal scene mapping (check() accepts mappings as well as hil.scene.spec.Scene)."""
    base = {
        "devices": [{"name": "motor", "role": "actuator", "dof": dof, "body": "motor"},
                    {"name": "ft", "role": "force_sensor", "dof": dof, "body": "motor", "axes": list(range(dof))}],
        "safety": {"max_effort": max_effort, "position_limits": [-1.0, 1.0]},
        "network": {"ports": [{"name": "operator", "actuator": "motor", "force_sensor": "ft", "dofs": dof}]},
    }
    base.update(extra)
    return base


def play(exp, n: int | None = None) -> np.ndarray:
    """Effort samples of ``exp`` on ``motor`` for its whole duration (no measurements needed)."""
    n = round(exp.duration * exp.rate_hz) if n is None else n
    return np.array([exp.excitation(k, k / exp.rate_hz, {}).effort["motor"] for k in range(n)])


# ---------------------------------------------------------------------------------------------
# chirp


@pytest.mark.parametrize(("sweep", "method"), [("linear", "linear"), ("log", "logarithmic")])
def test_chirp_matches_scipy_and_instantaneous_frequency(sweep, method):
    fs, f0, f1, T = 10_000.0, 2.0, 400.0, 2.0
    exp = make_experiment({"type": "chirp", "f0": f0, "f1": f1, "duration": T, "amplitude": 0.7, "sweep": sweep,
                           "target": "motor"}, rate_hz=fs)
    exp.check(scene())
    u = play(exp)[:, 0]
    t = np.arange(u.size) / fs
    # independent implementation: scipy's chirp is cos(phase); ours is sin(phase) = cos(phase - 90°)
    ref = 0.7 * sps.chirp(t, f0=f0, t1=T, f1=f1, method=method, phi=-90.0)
    np.testing.assert_allclose(u, ref, atol=1e-9)
    # instantaneous frequency from zero crossings (linear interpolation), closed form at midpoints
    s = np.sign(u)
    i = np.nonzero(s[:-1] * s[1:] < 0)[0]
    tz = t[i] - u[i] * (t[i + 1] - t[i]) / (u[i + 1] - u[i])
    f_meas = 0.5 / np.diff(tz)  # a half cycle between zero crossings
    a, b = tz[:-1], tz[1:]
    # closed form: mean of the instantaneous frequency f(t) over [a, b] (f = f0 + (f1-f0) t/T or f0 r^(t/T))
    if sweep == "linear":
        f_mean = f0 + (f1 - f0) * (a + b) / (2 * T)
    else:
        r = f1 / f0
        f_mean = f0 * T / math.log(r) * (r ** (b / T) - r ** (a / T)) / (b - a)
    # linear interpolation of a crossing of sin misplaces it by <~ dt (ω dt)^2/12, i.e. a relative
    # frequency error <~ (ω dt)^3/(6π) = 8e-4 at 400 Hz, 10 kHz (far below the 5e-3 by which the
    # frequency at the half-cycle midpoint differs from the mean for the log sweep at 4 Hz)
    np.testing.assert_allclose(f_meas, f_mean, rtol=1e-3)


def test_periodic_chirp_is_exactly_periodic_and_faded_per_period():
    fs, n_per, periods, fade = 1000.0, 1000, 4, 0.1
    exp = make_experiment({"type": "chirp", "f0": 2.0, "f1": 80.0, "duration": 4.0, "amplitude": 1.0,
                           "sweep": "log", "fade": fade, "periodic": True, "periods": periods,
                           "target": "motor"}, rate_hz=fs)
    exp.check(scene())
    u = play(exp)[:, 0]
    assert u.size == n_per * periods and exp.period == pytest.approx(1.0)
    for p in range(1, periods):
        assert np.array_equal(u[p * n_per:(p + 1) * n_per], u[:n_per])  # bit-identical periods
    # raised-cosine fade: u = A w(i) sin φ(i) with w = (1 - cos(π i/n_f))/2 over the first n_f samples
    n_f = round(fade * fs)
    raw, _ = sps.chirp(np.arange(n_per) / fs, f0=2.0, t1=1.0, f1=80.0, method="logarithmic", phi=-90.0), None
    w = 0.5 * (1 - np.cos(np.pi * np.arange(n_f) / n_f))
    np.testing.assert_allclose(u[:n_f], w * raw[:n_f], atol=1e-9)
    np.testing.assert_allclose(u[n_per - n_f:n_per], w[::-1] * raw[n_per - n_f:], atol=1e-9)
    assert u[0] == 0.0 and np.max(np.abs(u)) <= 1.0
    res = exp.finish({"t": np.arange(u.size) / fs, "motor.excitation": u[:, None]}, {})
    assert res["nperseg"] == n_per and res["skip"] == pytest.approx(1.0) and res["period"] == pytest.approx(1.0)


def test_periodic_chirp_gives_unbiased_h1_with_one_period_segments():
    """What the identification relies on: a stable LTI system driven by the periodic chirp, Welch
    segments of exactly one period (boxcar, no overlap) after one transient period -> H1 equals the
    true FRF at every excited bin to round-off (no leakage, no bias)."""
    fs = 1000.0
    exp = make_experiment({"type": "chirp", "f0": 2.0, "f1": 100.0, "duration": 6.0, "amplitude": 1.0,
                           "periodic": True, "periods": 6, "target": "motor"}, rate_hz=fs)
    exp.check(scene())
    u = play(exp)[:, 0]
    b, a = sps.butter(2, 30.0 / (fs / 2))  # the "plant": discrete, poles well inside the unit circle
    y = sps.lfilter(b, a, u)
    n = exp.n_period
    f, Puy = sps.csd(u[n:], y[n:], fs=fs, window="boxcar", nperseg=n, noverlap=0, detrend=False)
    _, Puu = sps.welch(u[n:], fs=fs, window="boxcar", nperseg=n, noverlap=0, detrend=False)
    band = (f >= 2.0) & (f <= 100.0)
    H1 = Puy[band] / Puu[band]
    _, Htrue = sps.freqz(b, a, worN=f[band], fs=fs)
    np.testing.assert_allclose(H1, Htrue, rtol=1e-8)


def test_chirp_sequential_and_simultaneous_dofs():
    cfg = {"type": "chirp", "f0": 1.0, "f1": 50.0, "duration": 1.0, "amplitude": 0.5, "target": "motor"}
    seq = make_experiment(cfg, rate_hz=1000.0)
    seq.check(scene(dof=2))  # dofs omitted -> all DOFs of the target, one after the other
    assert seq.duration == pytest.approx(2.0)
    u = play(seq)
    assert np.all(u[1000:, 0] == 0) and np.all(u[:1000, 1] == 0)
    np.testing.assert_array_equal(u[:1000, 0], u[1000:, 1])
    assert seq.segments() == [{"dofs": [0], "t_start": 0.0, "t_end": 1.0}, {"dofs": [1], "t_start": 1.0, "t_end": 2.0}]
    sim = make_experiment({**cfg, "simultaneous": True, "dofs": [0, 1]}, rate_hz=1000.0)
    sim.check(scene(dof=2))
    v = play(sim)
    assert sim.duration == pytest.approx(1.0) and np.array_equal(v[:, 0], v[:, 1])


def test_chirp_motion_excitation_servo_law():
    exp = make_experiment({"type": "chirp", "f0": 1.0, "f1": 20.0, "duration": 2.0, "amplitude": 0.01,
                           "target": "motor", "excite": "motion", "servo": {"kp": 200.0, "kv": 5.0}},
                          rate_hz=1000.0)
    exp.check(scene(max_effort=10.0))
    x0 = np.array([0.3])
    e0 = exp.excitation(0, 0.0, {"motor": JointSample(0.0, 0, x0, np.zeros(1))}).effort["motor"]
    assert e0[0] == pytest.approx(5.0 * exp.wave_rate[0, 0])  # r(0) = 0: only the velocity feed
    k = 123
    x, v = np.array([0.305]), np.array([0.02])
    e = exp.excitation(k, k / 1000, {"motor": JointSample(k / 1000, k, x, v)}).effort["motor"]
    r = exp.wave[0, k]
    rd = (exp.wave[0, k + 1] - exp.wave[0, k - 1]) * 500.0
    assert e[0] == pytest.approx(200.0 * (0.3 + r - 0.305) + 5.0 * (rd - 0.02))
    with pytest.raises(SceneError, match=r"amplitude: peak effort .* exceeds safety\.max_effort"):
        exp.check(scene(max_effort=1.0))  # stalled servo effort kp A + kv max|r'| > 1
    with pytest.raises(SceneError, match=r"experiments\[chirp\]\.servo: excite: motion needs servo"):
        make_experiment({"type": "chirp", "f0": 1.0, "f1": 20.0, "duration": 2.0, "amplitude": 0.01,
                         "target": "motor", "excite": "motion"}, rate_hz=1000.0)


# ---------------------------------------------------------------------------------------------
# multisine


def test_multisine_zippered_lines_flat_spectrum_and_crest_factor():
    fs = 1000.0
    exp = make_experiment({"type": "multisine", "f0": 1.0, "f1": 64.0, "n_lines": 32, "duration": 4.0,
                           "periods": 2, "amplitude": 0.4, "target": "motor", "dofs": [0, 1]}, rate_hz=fs)
    exp.check(scene(dof=2))
    assert isinstance(exp, Multisine) and exp.period == pytest.approx(2.0)
    u = play(exp)
    n = exp.n_period
    np.testing.assert_array_equal(u[n:2 * n], u[:n])
    spec = np.fft.rfft(u[:n], axis=0)
    lines = [np.round(np.asarray(f) * exp.period).astype(int) for f in exp.line_frequencies()]
    assert len(lines[0]) == len(lines[1]) == 32
    assert set(lines[0]).isdisjoint(lines[1])  # every line carries exactly one input
    grid = np.sort(np.concatenate(lines))
    assert np.all(np.diff(grid) >= 1) and grid[0] >= 1.0 * exp.period and grid[-1] <= 64.0 * exp.period
    for j in range(2):
        mag = np.abs(spec[:, j])
        on = mag[lines[j]]
        np.testing.assert_allclose(on, on[0], rtol=1e-9)  # flat amplitude on its lines
        off = np.delete(mag, lines[j])
        assert np.max(off) < 1e-9 * on[0]  # nothing elsewhere (in particular on the other DOF's lines)
        assert np.max(np.abs(u[:, j])) == pytest.approx(0.4)  # peak scaled to amplitude
    # Schroeder phases: crest factor near a single sine's √2 (well below random phases)
    cf = [crest_factor(u[:n, j]) for j in range(2)]
    rng = np.random.default_rng(1)
    i = np.arange(n)
    rand = [crest_factor(np.sum(np.cos(2 * np.pi * np.outer(lines[0], i) / n + rng.uniform(0, 2 * np.pi, (32, 1))),
                                axis=0)) for _ in range(20)]
    assert max(cf) < 2.0 < np.median(rand)


def test_schroeder_phases_closed_form():
    np.testing.assert_allclose(schroeder_phases(4), [0.0, -np.pi / 2, -3 * np.pi / 2, -3 * np.pi])


def test_multisine_not_enough_lines_names_field():
    with pytest.raises(SceneError, match=r"experiments\[ms\]\.n_lines: .*lengthen the period"):
        make_experiment({"type": "multisine", "name": "ms", "f0": 1.0, "f1": 10.0, "n_lines": 40, "duration": 1.0,
                         "amplitude": 0.1, "target": "motor"}, rate_hz=1000.0)


# ---------------------------------------------------------------------------------------------
# check() errors


CHIRP = {"type": "chirp", "name": "c", "f0": 1.0, "f1": 50.0, "duration": 2.0, "amplitude": 0.5, "target": "motor"}


@pytest.mark.parametrize(("cfg", "sc", "match"), [
    ({**CHIRP, "f1": 150.0}, scene(), r"experiments\[c\]\.f1: 150.0 Hz exceeds Nyquist/5 = 100 Hz"),
    ({**CHIRP, "amplitude": 6.0}, scene(),
     r"experiments\[c\]\.amplitude: peak effort 5\.99\d* exceeds safety\.max_effort 5"),
    ({**CHIRP, "target": "motr"}, scene(), r"experiments\[c\]\.target: no device 'motr'"),
    ({**CHIRP, "target": "ft"}, scene(), r"experiments\[c\]\.target: device 'ft' is not an actuator"),
    ({**CHIRP, "dofs": [1]}, scene(), r"experiments\[c\]\.dofs: \[1\] not distinct DOF indices"),
    ({"type": "static_hold", "name": "h", "target": "motor", "effort": 9.0, "duration": 1.0}, scene(),
     r"experiments\[h\]\.effort: peak effort 9"),
    ({"type": "energy_injection", "name": "e", "port": "elbow", "duration": 1.0,
      "profile": {"kind": "sine", "amplitude": 1.0, "freq": 1.0}}, scene(), r"experiments\[e\]\.port: no network port"),
    ({"type": "energy_injection", "name": "e", "port": "operator", "duration": 1.0, "via": "actuator",
      "profile": {"kind": "step", "amplitude": 7.0}}, scene(), r"experiments\[e\]\.profile\.amplitude: peak effort 7"),
    ({"type": "energy_injection", "name": "e", "port": "operator", "duration": 1.0, "via": "human",
      "profile": {"kind": "step", "amplitude": 1.0}}, scene(), r"experiments\[e\]\.via: 'human' needs a simulated"),
])
def test_check_errors_name_the_field(cfg, sc, match):
    exp = make_experiment(cfg, rate_hz=1000.0)
    with pytest.raises(SceneError, match=match):
        exp.check(sc)


@pytest.mark.parametrize(("cfg", "match"), [
    ({**CHIRP, "duration": 0.0}, r"experiments\[c\]\.duration: Input should be greater than 0"),
    ({**CHIRP, "f1": 0.5}, r"experiments\[c\]\.f1: f1 \(0.5 Hz\) must exceed f0"),
    ({**CHIRP, "sweep": "cubic"}, r"experiments\[c\]\.sweep"),
    ({**CHIRP, "wobble": 1}, r"experiments\[c\]\.wobble: unknown key 'wobble'"),
    ({**CHIRP, "fade": 1.5}, r"experiments\[c\]\.fade: .* exceeds the period"),
    ({"type": "static_hold", "name": "h", "target": "motor", "effort": 1.0, "duration": 1.0, "settle": 1.0},
     r"experiments\[h\]\.settle"),
    ({"type": "energy_injection", "name": "e", "port": "operator", "duration": -1.0,
      "profile": {"kind": "sine", "amplitude": 1.0}}, r"experiments\[e\]\.duration: Input should be greater than 0"),
    ({"type": "sweep"}, r"experiments\[\?\]\.type: unknown experiment 'sweep'"),
])
def test_construction_errors_name_the_field(cfg, match):
    with pytest.raises(SceneError, match=match):
        make_experiment(cfg, rate_hz=1000.0)


def test_builtin_scene_experiments_through_the_pydantic_models():
    from hil.scene.spec import load_scene

    sc = load_scene("dynamixel_leader_follower")
    for cfg in sc.experiment_configs():
        exp = make_experiment(cfg, rate_hz=sc.rate_hz)
        exp.check(sc)
        assert exp.duration > 0
        assert isinstance(exp.excitation(0, 0.0, {}), Excitation)


# ---------------------------------------------------------------------------------------------
# port energy


def test_port_energy_matches_closed_form_and_detects_generation():
    """F = A cos ωt, V = B cos(ωt - φ): E(t) = AB/2 [t cos φ + (sin(2ωt - φ) + sin φ)/(2ω)].
    Trapezoid error <= t dt² max|P''|/12 = t dt² AB (2ω)²/24."""
    A, B, w, dt = 2.0, 0.3, 2 * np.pi * 1.5, 1e-3
    t = np.arange(0, 4.0, dt)
    for phi in (0.4, 2.0):
        res = port_energy(t, A * np.cos(w * t), B * np.cos(w * t - phi))
        E = A * B / 2 * (t * np.cos(phi) + (np.sin(2 * w * t - phi) + np.sin(phi)) / (2 * w))
        err_bound = t * dt**2 * A * B * (2 * w) ** 2 / 24 + 1e-12
        assert np.all(np.abs(res.energy - E) <= err_bound)
        assert res.went_negative == (phi > np.pi / 2)
    # phi = 2.0 (> 90°): the port generates energy; first time E < 0 from the closed form (±1 sample)
    first = t[np.argmax(E < -1e-9)]
    assert res.first_time == pytest.approx(first, abs=1.5 * dt)
    assert res.min_energy == pytest.approx(E.min(), abs=1e-6)
    # multi-DOF: sum of the per-DOF powers
    F2 = np.stack([A * np.cos(w * t), np.ones_like(t)], axis=1)
    V2 = np.stack([B * np.cos(w * t - 0.4), np.zeros_like(t)], axis=1)
    np.testing.assert_allclose(port_energy(t, F2, V2).energy, port_energy(t, F2[:, 0], V2[:, 0]).energy)


def test_port_energy_noise_bound_calibrated_on_pure_noise_and_passive_system():
    """A passive damper F = b V driven by a sine (E_true >= 0) and the same system at rest (pure
    noise), measured with white noise: across 400 seeds the accumulated energy error has the
    predicted std (bound / k_sigma, within 15 %), and E_s never goes below -bound."""
    fs, T, b = 1000.0, 2.0, 3.0
    t = np.arange(0, T, 1 / fs)
    sf, sv = 0.05, 0.02
    for amp in (0.2, 0.0):
        V = amp * np.sin(2 * np.pi * 2.0 * t)
        F = b * V
        E_true = port_energy(t, F, V).energy
        rng = np.random.default_rng(7)
        errs, neg = [], 0
        for _ in range(400):
            Fm = F + sf * rng.standard_normal(t.size)
            Vm = V + sv * rng.standard_normal(t.size)
            res = port_energy(t, Fm, Vm, sf, sv)
            neg += res.went_negative
            errs.append(res.energy[-1] - E_true[-1])
        sigma_pred = res.bound[-1] / 4.0
        assert np.std(errs) == pytest.approx(sigma_pred, rel=0.15)
        assert neg == 0


def test_port_energy_fixed_bound_and_shapes():
    t = np.linspace(0, 1, 11)
    res = port_energy(t, -np.ones(11), np.ones(11), fixed_bound=0.5)
    assert res.went_negative and res.first_time == pytest.approx(0.6)  # E = -t crosses -0.5 after 0.5
    assert res.min_margin == pytest.approx(-0.5)
    run = port_energy(t, np.ones(11), np.ones(11), 0.1, 0.1, bound_mode="running")
    assert run.bound[0] < run.bound[-1]  # grows like sqrt(t); "final" is constant
    fin = port_energy(t, np.ones(11), np.ones(11), 0.1, 0.1)
    assert np.allclose(fin.bound, fin.bound[0]) and fin.bound[0] == pytest.approx(run.bound[-1], rel=1e-9)
    with pytest.raises(ValueError, match="same shape"):
        port_energy(t, np.ones((11, 2)), np.ones((11, 3)))


# ---------------------------------------------------------------------------------------------
# energy injection and static hold in closed loop with the physics


def _handle_scene():
    sc = scene(simulation={"human": {"port": "motor", "mass": 0.5, "damping": 2.0},
                           "sensor_noise": {"force_std": 0.0, "velocity_std": 0.0}})
    sc["devices"][1]["sim"] = {"measure": "body"}  # the handle's body force = force on the hand = -F_h
    return sc


def _run_injection(exp: EnergyInjection, neg_damping: float, n: int):
    """Device: 1-DOF mass 1 kg, damping 0.5 N.s/m, held by a human (0.5 kg, 2 N.s/m); its
    'controller' adds +neg_damping·v (an active port when neg_damping > 0.5). The force sensor on
    the handle reads the body's force (the force the handle exerts on the hand = -F_h)."""
    ps = PhysScene("linear")
    ps.add_body("motor", 1.0, 0.5)
    ps.add_human("motor", Human(mass=0.5, damping=2.0, name="hand"))
    sim = Simulator(ps.build(), 1.0 / exp.rate_hz, exact_sum=False)
    h = sim.joints("motor")
    data = {"t": np.zeros(n), "ft.wrench": np.zeros((n, 1)), "motor.velocity": np.zeros((n, 1)),
            "motor.excitation": np.zeros((n, 1))}
    for k in range(n):
        t = k / exp.rate_hz
        meas = {"motor": JointSample(t, k, h.position(), h.velocity())}
        exc = exp.excitation(k, t, meas)
        u = neg_damping * h.velocity() + exc.effort.get("motor", 0.0)
        h.apply_effort(u)
        if exc.human:
            sim.set_input("hand.active", exc.human["operator"])
        data["t"][k], data["ft.wrench"][k], data["motor.velocity"][k] = t, h.measured_force(), h.velocity()
        data["motor.excitation"][k] = exc.effort.get("motor", 0.0)
        sim.tick()
    return exp.finish(data, {})


@pytest.mark.parametrize("via", ["human", "actuator"])
def test_energy_injection_passive_vs_active_port(via):
    cfg = {"type": "energy_injection", "port": "operator", "duration": 3.0, "via": via,
           "profile": {"kind": "sine", "amplitude": 2.0, "freq": 1.5}}
    if via == "actuator":
        cfg["force_sign"] = -1.0
    exp = make_experiment(cfg, rate_hz=1000.0)
    exp.check(_handle_scene())
    assert exp.force_sign == -1.0 and exp.via == via
    passive = _run_injection(exp, 0.0, 3000)
    assert not passive["went_negative"] and passive["final_energy"] > 0
    active = _run_injection(exp, 1.5, 3000)  # device damping 0.5 - 1.5 < 0: the port gives energy
    assert active["went_negative"] and active["min_energy"] < 0 and active["first_time"] > 0


def test_energy_injection_force_sign_from_scene_measure_mode():
    sc = _handle_scene()
    sc["devices"][1]["sim"] = {"measure": "auto"}
    exp = make_experiment({"type": "energy_injection", "port": "operator", "duration": 1.0,
                           "profile": {"kind": "noise", "amplitude": 1.0, "freq": 5.0, "seed": 3}}, rate_hz=1000.0)
    exp.check(sc)
    assert exp.via == "human" and exp.force_sign == 1.0  # bench 'auto' with a human reports F_h itself
    sc["devices"][1]["sim"] = {"measure": "body"}
    exp.check(sc)
    assert exp.force_sign == -1.0


def test_force_profiles():
    fs = 1000.0
    x = force_profile({"kind": "noise", "amplitude": 0.5, "freq": 4.0, "seed": 1}, 20000, fs, 2)
    assert x.shape == (20000, 2) and np.std(x[:, 0]) == pytest.approx(0.5)
    y = force_profile({"kind": "noise", "amplitude": 0.5, "freq": 4.0, "seed": 1}, 20000, fs, 2)
    assert np.array_equal(x, y)  # seeded
    f, P = sps.welch(x[:, 0], fs=fs, nperseg=4096)
    assert np.sum(P[f > 20]) < 1e-3 * np.sum(P)  # smoothed: nothing well above the cutoff
    s = force_profile({"kind": "sine", "amplitude": 2.0, "freq": 1.0, "direction": [1.0, -0.5]}, 1000, fs, 2)
    np.testing.assert_allclose(s[250], [2.0, -1.0])
    m = force_profile({"kind": "multisine", "amplitude": 1.0, "freqs": [1.0, 2.0, 3.0]}, 1000, fs, 1)
    spec = np.abs(np.fft.rfft(m[:, 0])) / 500
    np.testing.assert_allclose(spec[[1, 2, 3]], 1 / 3, rtol=1e-9)
    with pytest.raises(SceneError, match=r"profile\.direction"):
        force_profile({"kind": "sine", "amplitude": 1.0, "direction": [1, 2, 3]}, 10, fs, 2)


def test_static_hold_stiffness_on_spring_mass():
    """Body K = 250 N/m, B = 20 N.s/m, M = 0.5 kg: after settling x = F/K (transient e^{-20 t})."""
    exp = make_experiment({"type": "static_hold", "target": "motor", "effort": 1.5, "duration": 2.0,
                           "settle": 1.0}, rate_hz=1000.0)
    assert isinstance(exp, StaticHold)
    exp.check(scene())
    ps = PhysScene("linear")
    ps.add_body("motor", 0.5, 20.0, 250.0)
    sim = Simulator(ps.build(), 1e-3, exact_sum=False)
    h = sim.joints("motor")
    n = round(exp.duration * 1000)
    x = np.zeros((n, 1))
    for k in range(n):
        x[k] = h.position()
        h.apply_effort(exp.excitation(k, k / 1000, {}).effort["motor"])
        sim.tick()
    res = exp.finish({"t": np.arange(n) / 1000, "motor.position": x}, {})
    assert res["stiffness"][0] == pytest.approx(250.0, rel=1e-6)
    assert abs(res["drift_per_s"][0]) < 1e-8
