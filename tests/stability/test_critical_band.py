"""Issue 31, item 4: the critical band contains the region where the binding condition is within
its stated fraction (10 %) of its minimum, and the whole violation. Before, the certificate took an
octave either side of the worst frequency: (4.8, 19.3) rad/s for a negative band (4.25, 16.43) in
Gustavsen's fitted model, and no band at all for a ring-slot fit whose worst frequency is 0 although
its violation reaches 1.7e11 rad/s. (The property over random networks: test_margin_properties.)"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil.stability.criteria import check, positive_real
from hil.stability.margins import critical_band
from hil.stability.rational import Rational, S


def _negative_band(r) -> tuple[float, float]:
    c = r.condition(r.failed_condition)
    (lo, hi), = c.evidence["negative_bands_rad_s"]
    return lo, hi


def test_the_band_contains_a_mid_frequency_violation_the_octave_missed():
    # a resistor minus a damped resonance at √70 ≈ 8.4 rad/s: Re Z < 0 from 1.7 to 42 rad/s, far
    # beyond an octave either side of the worst frequency (like Gustavsen's fitted model)
    k, b = 100.0, 20.0
    z = 1 - k * S / (S**2 + b * S + 70)
    r = positive_real(z)
    assert str(r.verdict) == "potentially_unstable"
    nlo, nhi = _negative_band(r)
    # independent: Re Z(jω) = 1 - k b x/((70 - x)² + b² x) vanishes at the roots of
    # x² - (140 + kb - b²) x + 4900
    xs = np.sort(np.roots([1.0, -(140 + k * b - b * b), 4900.0]).real)
    assert (nlo, nhi) == pytest.approx(tuple(np.sqrt(xs)), rel=1e-9)
    lo, hi = critical_band(r)
    assert lo <= nlo and nhi <= hi and lo <= r.worst_frequency <= hi
    w = r.worst_frequency
    assert not (w / 2 <= nlo and nhi <= 2 * w)  # the old octave rule did not contain the violation


def test_a_violation_from_dc_to_1_7e11_rad_s_gets_a_band_from_0():
    # Z = (s - a)/(s + b): Re Z(jω) = (ω² - ab)/(ω² + b²) < 0 below √(ab) = 1.7e11 rad/s; the
    # margin's worst frequency is 0 (Re Z(0) = -a/b), where the old rule gave no band
    a, b = 1e9, 2.89e13
    r = positive_real(Rational.from_desc([1.0, -a], [1.0, b]))
    assert str(r.verdict) == "potentially_unstable" and r.worst_frequency == 0.0
    nlo, nhi = _negative_band(r)
    assert nlo == 0.0 and nhi == pytest.approx(math.sqrt(a * b), rel=1e-9)
    lo, hi = critical_band(r)
    assert lo == 0.0 and hi >= nhi


def test_the_band_of_a_stable_network_holds_the_region_within_ten_percent_of_the_minimum():
    # Z_ε = (s² + εs + 1)/(s² + s + 1): ρ(x) = (x² + (ε - 2)x + 1)/(x² + (ε + 2)x + 1), minimum
    # μ = ε/(ε + 4) at x = 1; the band is where ρ ≤ θ = μ + 0.1(1 - μ): the roots of
    # (1 - θ)x² + ((ε - 2) - θ(ε + 2))x + (1 - θ) (closed form, reciprocal in x)
    e = 0.3
    r = positive_real(Rational.from_desc([1.0, e, 1.0], [1.0, 1.0, 1.0]))
    mu = e / (e + 4)
    theta = mu + 0.1 * (1 - mu)
    xs = np.sort(np.roots([1 - theta, (e - 2) - theta * (e + 2), 1 - theta]).real)
    lo, hi = critical_band(r)
    assert (lo, hi) == pytest.approx(tuple(np.sqrt(xs)), rel=1e-9)
    assert lo < 1.0 < hi


def test_no_band_without_a_frequency_condition_or_margins():
    r = check(1 + S / (S**2 + 1), margins=False)
    assert critical_band(r) is None
    # a constant ratio: the whole axis
    r = check(Rational.const(2.0))
    assert critical_band(r) == (0.0, math.inf)
