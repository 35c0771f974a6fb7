"""A one-port whose Re Z(jω) is negative only in a band narrower than 1e-4 of its centre frequency.

Construction (independent of the library): Z = (s² + n1 s + n0)/(s² + d1 s + d0) with
Re(N(jω) D(-jω)) = (x - x0)² - ε², x = ω². Matching coefficients: n2 d2 = 1, n0 d0 = x0² - ε²,
n1 d1 - n0 d2 - n2 d0 = -2 x0. With D = s² + 2ζω0 s + ω0² (ω0² = x0): n0 = (x0² - ε²)/x0,
n1 = -ε²/(x0 d1). Re Z < 0 exactly for x in (x0 - ε, x0 + ε), i.e. ω in (√(x0-ε), √(x0+ε)).
"""

import math

import numpy as np
import pytest

from hil.stability.criteria import positive_real
from hil.stability.rational import Rational


def narrow_band_one_port(w0: float, rel_width: float, zeta: float = 0.3) -> tuple[Rational, float, float]:
    x0 = w0 * w0
    eps = rel_width * x0  # relative width in ω is ≈ ε/x0 (dω/ω = dx/2x over a band 2ε)
    d1 = 2 * zeta * w0
    n0 = (x0 * x0 - eps * eps) / x0
    n1 = -eps * eps / (x0 * d1)
    z = Rational.from_desc([1.0, n1, n0], [1.0, d1, x0])
    return z, math.sqrt(x0 - eps), math.sqrt(x0 + eps)


@pytest.mark.parametrize("w0", [1e-3, 100.0, 3e6])
def test_narrow_negative_band_found_and_located(w0):
    z, lo, hi = narrow_band_one_port(w0, 5e-5)
    assert (hi - lo) / w0 < 1e-4
    r = positive_real(z)
    assert r.verdict == "potentially_unstable"
    c = r.condition("E{1}")
    (blo, bhi), = c.evidence["negative_bands_rad_s"]
    assert blo == pytest.approx(lo, rel=1e-9) and bhi == pytest.approx(hi, rel=1e-9)
    assert lo <= r.worst_frequency <= hi


def test_a_grid_misses_it():
    # why exactness matters: 10^4 log-spaced points over four decades around w0 never land inside
    z, lo, hi = narrow_band_one_port(100.0, 5e-5)
    w = np.geomspace(1.0, 1e4, 10_000)
    assert not np.any((w > lo) & (w < hi))
    assert np.all(z.freq(w).real >= 0)
    assert positive_real(z).verdict == "potentially_unstable"
