"""Issue 11, defect 5: the text table prints bands in physical rad/s, the same numbers as the JSON
(one definition: the detail line is formatted from the rescaled evidence)."""

import json
import re

import numpy as np

from hil.cli.main import EXIT_UNSTABLE, main
from hil.models import get_model
from hil.stability.criteria import check


def _bands_in(text: str) -> list[tuple[float, float]]:
    flat = re.sub(r"[│\s]+", " ", text)
    return [(float(a), float(b)) for a, b in re.findall(r"negative for ω in \[([-+0-9.e]+), ([-+0-9.e]+)\] ?rad/s",
                                                            flat)]


def test_text_table_and_json_print_the_same_physical_band(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    argv = ["stability", "--model", "sdea", "--set", "k22=500"]
    assert main([*argv, "--json"]) == EXIT_UNSTABLE
    d = json.loads(capsys.readouterr().out)
    assert main(argv) == EXIT_UNSTABLE
    text = capsys.readouterr().out
    cond = next(c for c in d["conditions"] if c["name"] == d["failed_condition"])
    ev = cond["evidence"]
    assert d["network"]["omega_scale"] != 1.0  # the case where normalized and physical differ
    lo, hi = ev["negative_bands_rad_s"][int(np.argmin(ev["band_depths"]))]
    shown = _bands_in(text)
    assert shown, text
    np.testing.assert_allclose(shown[0], (lo, hi), rtol=1e-5)
    np.testing.assert_allclose(_bands_in(cond["detail"])[0], (lo, hi), rtol=1e-5)
    # independent check that these are physical rad/s: the Hermitian part of the physical (not
    # frequency-normalized) hybrid matrix is indefinite inside the band, definite outside it
    tm = get_model("sdea").build(k22=500)
    for w, sign in ((np.sqrt(lo * hi), -1), (hi * 3.0, 1)):
        G = tm.freq(np.array([w]))[0]
        assert np.sign(np.linalg.det(G + G.conj().T).real) == sign


def test_pole_details_are_physical():
    from hil.stability.rational import S

    # a tank at 8192 rad/s with a *negative* residue, plus a far-away pole: w0 ≠ 1. (w a power of
    # two: the float product (s² + w²)(s + 0.01) keeps its poles exactly on the imaginary axis; with
    # w = 1e4 the rounded 0.01·1e8 moves them off the axis by ~1e-17 relative, into the LHP, and
    # the exact verdict is then decided by E{1} instead.)
    w = 8192.0
    z = 1 - S / (S**2 + w**2) * 1e4 + 1e-3 * S / (S + 1e-2)
    r = check(z)
    assert r.network["omega_scale"] != 1.0
    d = next(c for c in r.conditions if c.name.startswith("D[ω=") and c.status == "violated")
    assert abs(d.worst_frequency / w - 1) < 1e-9
    assert abs(float(d.name[4:-1]) / w - 1) < 1e-5
    assert "s = j8192 " in d.detail, d.detail
