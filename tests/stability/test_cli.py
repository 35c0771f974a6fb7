"""The `hil stability` CLI: exit codes, JSON, one-line errors for malformed input."""

import json
import subprocess
import sys

import pytest

from hil.cli.main import EXIT_MARGINAL, EXIT_NOT_APPLICABLE, EXIT_OK, EXIT_UNSTABLE, EXIT_USAGE, main


def run(argv, capsys):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_model_json_fields(capsys):
    code, out, _ = run(["stability", "--model", "sdea", "--set", "k22=500", "--json"], capsys)
    d = json.loads(out)
    assert code == EXIT_UNSTABLE
    assert d["verdict"] == "potentially_unstable"
    for key in ("criterion", "margin", "worst_frequency", "failed_condition", "conditions"):
        assert key in d
    assert d["failed_condition"] == "E{1,2}"
    assert d["worst_frequency"] > 0


@pytest.mark.parametrize("argv,code", [
    (["stability", "--model", "mcet_trilateral", "--set", "k_vm1=64"], EXIT_OK),
    (["stability", "--model", "mcet_trilateral", "--set", "k_vm1=80"], EXIT_UNSTABLE),
    (["stability", "--model", "bilateral_2dof", "--set", "gains=B"], EXIT_UNSTABLE),
    (["stability", "--model", "T2"], EXIT_OK),
])
def test_exit_codes_distinguish_verdicts(argv, code, capsys):
    assert run(argv, capsys)[0] == code


def test_not_applicable_exit_code(tmp_path, capsys):
    # a 3-port whose cycle products differ (condition A of Theorem 1 fails)
    f = tmp_path / "net.yaml"
    f.write_text("type: impedance\ncriterion: absolute_stability\nmatrix:\n"
                 "  - [{num: [1, 2], den: [1, 1]}, {num: [1]}, {num: [2]}]\n"
                 "  - [{num: [3]}, {num: [1, 2], den: [1, 1]}, {num: [1]}]\n"
                 "  - [{num: [1]}, {num: [5]}, {num: [1, 2], den: [1, 1]}]\n")
    code, _out, _ = run(["stability", str(f)], capsys)
    assert code == EXIT_NOT_APPLICABLE


def test_lossless_one_port_is_weakly_stable(tmp_path, capsys):
    # parallel LC (Foster form) s/(s²+1): poles ±j with residue 1/2, Re Z(jω) ≡ 0
    f = tmp_path / "lc.json"
    f.write_text(json.dumps({"type": "impedance", "matrix": [[{"num": [1, 0], "den": [1, 0, 1]}]]}))
    code, out, _ = run(["stability", str(f), "--json"], capsys)
    d = json.loads(out)
    assert (d["verdict"], d["weak"], code) == ("stable", True, EXIT_OK)


def test_touching_real_part_is_weakly_stable_and_marginal_only_under_rtol(tmp_path, capsys):
    # Re Z(jω)|D|² = (ω² - 100)²: touches zero at ω = 10 rad/s (a double root). Exactly, the
    # condition holds with equality there: stable (weak). With --rtol the touching point can dip
    # below zero under a perturbation of the coefficients: marginal.
    f = tmp_path / "touch.yaml"
    f.write_text("type: impedance\nmatrix: [[{num: [1, 0, 100], den: [1, 6, 100]}]]\n")
    code, out, _ = run(["stability", str(f), "--json"], capsys)
    d = json.loads(out)
    assert (d["verdict"], d["weak"], code) == ("stable", True, EXIT_OK)
    e = next(c for c in d["conditions"] if c["name"] == "E{1}")
    assert e["status"] == "equality" and abs(e["worst_frequency"] - 10.0) < 1e-6
    code, out, _ = run(["stability", str(f), "--json", "--rtol", "1e-9"], capsys)
    assert (json.loads(out)["verdict"], code) == ("marginal", EXIT_MARGINAL)
    code, _, err = run(["stability", str(f), "--rtol", "-1"], capsys)
    assert code == EXIT_USAGE and "--rtol" in err and "\n" not in err.strip()


@pytest.mark.parametrize("content,field", [
    ("type: hybird\nmatrix: [[{num: [1]}]]\n", "type"),
    ("type: impedance\nmatrix: [[{num: [1], den: [1, x]}]]\n", "matrix[0][0].den[1]"),
    ("type: impedance\nmatrix: [[{num: [1]}, {num: [1]}]]\n", "matrix"),
    ("type: impedance\nmatrix: [[{nom: [1]}]]\n", "matrix[0][0]"),
    ("type: impedance\n", "matrix"),
    ("type: [unclosed\n", "YAML"),
])
def test_malformed_file_one_line_error(tmp_path, capsys, content, field):
    f = tmp_path / "bad.yaml"
    f.write_text(content)
    code, _out, err = run(["stability", str(f)], capsys)
    assert code == EXIT_USAGE
    assert err.count("\n") == 1 and "Traceback" not in err
    assert field in err and "bad.yaml" in err


def test_unknown_model_and_parameter_suggest(capsys):
    code, _, err = run(["stability", "--model", "sdae"], capsys)
    assert code == EXIT_USAGE and "did you mean 'sdea'" in err
    code, _, err = run(["stability", "--model", "sdea", "--set", "K22=1"], capsys)
    assert code == EXIT_USAGE and "did you mean 'k22'" in err


def test_console_script_runs_without_traceback():
    p = subprocess.run([sys.executable, "-m", "hil.cli.main", "stability", "--model", "sdea"], capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 0 and "stable" in p.stdout


@pytest.mark.parametrize("kind", ["impedance", "admittance", "hybrid", "inverse_hybrid"])
def test_passive_t_network_file_is_stable_in_every_form(tmp_path, capsys, kind):
    # issue 11, defect 3: the hybrid form used to crash ("entry denominator does not divide the
    # common denominator", exit 2) and the inverse hybrid was called potentially unstable
    # T-network z1 = 1, z2 = 2s, z3 = 3/s in its four forms, derived by hand (as in test_verdicts)
    from test_verdicts import T_FORMS

    f = tmp_path / f"t_{kind}.json"
    f.write_text(json.dumps({"type": kind, "ports": [1, 1], "matrix": T_FORMS[kind]}))
    for crit in ("passivity", "llewellyn"):
        code, out, err = run(["stability", str(f), "--criterion", crit, "--json"], capsys)
        assert (json.loads(out)["verdict"], code) == ("stable", EXIT_OK), err
