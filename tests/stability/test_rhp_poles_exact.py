"""Issue 31, item 1: right-half-plane poles are named exactly (isolated with Arb, counted exactly),
never taken from ``numpy.roots``, whose rounding can see fewer right-half-plane poles than exist and
then picked the pole at s = 0 (a ZeroDivisionError, exit 1) or a left-half-plane pole."""

from __future__ import annotations

import json

import numpy as np
import pytest
from flint import fmpq, fmpq_poly

from hil.cli.main import EXIT_UNSTABLE, main
from hil.stability.criteria import check
from hil.stability.exact import exact_poles
from hil.stability.rational import Rational, TransferMatrix
from hil.stability.roots import isolate_roots, rhp_roots

# the reproducers (``hil stability FILE``)
A = 9.095224573485439e-13
B = 9.096057240753908e-13
ONE_PORT = ("type: impedance\nports: [1]\ncriterion: positive_real\nmatrix:\n"
            f"  - [{{num: [1.0, {-A!r}, 5.0, {-B!r}, 5.0], den: [1.0, {-A!r}, 5.0, {-B!r}, 4.0, 0.0]}}]\n")
T_NETWORK = """type: impedance
ports: [1, 1]
criterion: passivity
matrix:
  - [{num: [1.25785, 0.93011063, 0.4593343331129073], den: [1.0, 0.4918, 0.339]},
     {num: [1.236, 0.9193648, 0.45192718311290725], den: [1.0, 0.4918, 0.339]}]
  - [{num: [1.236, 0.9193648, 0.45192718311290725], den: [1.0, 0.4918, 0.339]},
     {num: [63.986, 53.12923868483705, 878.0915170603668, 647.0203234241083, 395.2167269805107, 74.46719427627168],
      den: [1.0, 0.4918, 13.55857448833637, 6.5013867333638276, 4.48143575154603, 0.0]}]
"""


def _q(desc: list[float]) -> fmpq_poly:
    return fmpq_poly([fmpq(*float(v).as_integer_ratio()) for v in desc[::-1]])


def _cli(tmp_path, capsys, text: str, *args: str) -> tuple[int, dict]:
    f = tmp_path / "net.yaml"
    f.write_text(text)
    code = main(["stability", str(f), "--json", *args])
    return code, json.loads(capsys.readouterr().out)


def test_one_port_reproducer_names_the_four_rhp_poles_exactly(tmp_path, capsys):
    code, d = _cli(tmp_path, capsys, ONE_PORT)
    assert (code, d["verdict"]) == (EXIT_UNSTABLE, "potentially_unstable")
    c = next(c for c in d["conditions"] if c["name"] == "C")
    poles = sorted((complex(p["pole"]["re"], p["pole"]["im"]) for p in c["evidence"]["rhp_poles"]),
                   key=lambda z: (abs(z.imag), z.imag))
    assert len(poles) == 4  # the exact count; numpy.roots sees 2 and the pole at 0
    # independent: first-order perturbation of the roots ±j, ±2j of (s² + 1)(s² + 4) by
    # δq = -A s³ - B s: δr = -δq(r0)/q'(r0), i.e. (B - A)/6 at ±j and (8A - 2B)/12 at ±2j (the
    # second-order terms are O(A²) ~ 1e-24, far below the 1e-6 relative tolerance)
    expect = [(B - A) / 6, (B - A) / 6, (8 * A - 2 * B) / 12, (8 * A - 2 * B) / 12]
    for z, re, im in zip(poles, expect, [-1.0, 1.0, -2.0, 2.0], strict=True):
        assert z.real == pytest.approx(re, rel=1e-6) and z.imag == pytest.approx(im, rel=1e-12)


@pytest.mark.parametrize("criterion", ["passivity", "llewellyn", "absolute_stability", "positive_real"])
def test_t_network_reproducer_decides_every_criterion(tmp_path, capsys, criterion):
    code, d = _cli(tmp_path, capsys, T_NETWORK, "--criterion", criterion)
    assert (code, d["verdict"]) == (EXIT_UNSTABLE, "potentially_unstable")
    c = next(c for c in d["conditions"] if c["name"] == "C")
    named = [complex(p["pole"]["re"], p["pole"]["im"]) for p in c["evidence"]["rhp_poles"]]
    den = _q([1.0, 0.4918, 13.55857448833637, 6.5013867333638276, 4.48143575154603, 0.0])
    assert len(named) == exact_poles(den).n_rhp > 0 and all(z.real > 0 for z in named)
    assert all(p["entry"] == [2, 2] for p in c["evidence"]["rhp_poles"])


@pytest.mark.parametrize("criterion", ["positive_real", "passivity", "llewellyn", "absolute_stability"])
def test_verdict_only_path_does_not_crash_either(criterion):
    tm = TransferMatrix.from_coefficients(
        [[{"num": [1.25785, 0.93011063, 0.4593343331129073], "den": [1.0, 0.4918, 0.339]},
          {"num": [1.236, 0.9193648, 0.45192718311290725], "den": [1.0, 0.4918, 0.339]}],
         [{"num": [1.236, 0.9193648, 0.45192718311290725], "den": [1.0, 0.4918, 0.339]},
          {"num": [63.986, 53.12923868483705, 878.0915170603668, 647.0203234241083, 395.2167269805107,
                   74.46719427627168],
           "den": [1.0, 0.4918, 13.55857448833637, 6.5013867333638276, 4.48143575154603, 0.0]}]])
    assert str(check(tm, criterion, margins=False).verdict) == "potentially_unstable"


def test_no_left_half_plane_value_is_named_as_a_right_half_plane_pole():
    # without a pole at 0 the old code named the 4 rightmost float roots: two of them have a
    # negative real part in floats (-1.7e-16), although all four are right-half-plane poles
    den = [1.0, 0.999999999998892, 3.249999999998892, 3.2499999999975078, 2.2499999999975078, 2.25]
    old = sorted(np.roots(den), key=lambda z: -z.real)[:4]
    assert any(z.real <= 0 for z in old)  # the defect this guards against
    r = check(Rational.from_desc([1.0, 2.0, 3.0], den), "positive_real")
    named = [p["pole"] for p in r.condition("C").evidence["rhp_poles"]]
    assert len(named) == exact_poles(_q(den)).n_rhp == 4
    assert all(z.real > 0 for z in named)
    assert sorted(abs(z.imag) for z in named) == pytest.approx([1.0, 1.0, 1.5, 1.5], rel=1e-9)


@pytest.mark.parametrize("seed", range(12))
def test_isolated_roots_match_roots_built_in(seed):
    """Polynomials built exactly from known roots -- pairs a ± jb with real parts down to 2^-60 of
    their modulus on both sides of the axis, pairs on the axis, the origin, a double pair -- are
    classified with the exact counts and located to double precision (the roots are the
    independent reference)."""
    rng = np.random.default_rng(seed)
    roots: list[tuple[fmpq, fmpq]] = []  # (re, im) exact dyadics; a pair for im != 0
    for _ in range(int(rng.integers(3, 6))):
        b = fmpq(int(rng.integers(1, 2**20)), 2**int(rng.integers(10, 20)))
        side = int(rng.choice([-1, 0, 1]))
        a = side * b * fmpq(1, 2**int(rng.integers(20, 60)))
        roots.append((a, b))
    roots.append(roots[0])  # a repeated pair: multiplicity 2
    d = fmpq_poly([0, 1])  # a root at the origin
    for a, b in roots:
        d *= fmpq_poly([a * a + b * b, -2 * a, 1])  # (s - a)² + b²
    got = isolate_roots(d)
    assert sum(r.multiplicity for r in got) == d.degree()
    assert next(r for r in got if r.region == "origin").multiplicity == 1
    want: dict[tuple[str, float], int] = {}
    for a, b in roots:
        region = "rhp" if a > 0 else "lhp" if a < 0 else "axis"
        for im in (float(b), -float(b)):
            want[(region, im)] = want.get((region, im), 0) + 1
    for r in got:
        if r.region == "origin":
            continue
        key = min(want, key=lambda k: abs(k[1] - r.value.imag) + (k[0] != r.region))
        assert key[0] == r.region and r.value.imag == pytest.approx(key[1], rel=1e-14)
        assert r.multiplicity == want.pop(key)
        exact_re = next(float(a) for a, b in roots if float(b) == abs(key[1]) and
                        ("rhp" if a > 0 else "lhp" if a < 0 else "axis") == r.region)
        assert r.value.real == pytest.approx(exact_re, rel=1e-12, abs=0.0)
    assert not want
    assert len(rhp_roots(d)) == exact_poles(d).n_rhp
