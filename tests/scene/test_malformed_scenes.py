"""Malformed scene files through the command line (issue 9, item 3: the scene rows of the
malformed-input table). Each one: exit code 2, exactly one stderr line, the file name and the field
in it, no traceback, and nothing written (no runs/ or reports/ folder, no --out folder).

The scenes are built from the built-in ``sdea_bench`` text by one textual edit, so YAML-level
mistakes (duplicate keys, broken syntax, bytes that are not UTF-8) are in the table too.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.cli.main import main
from hil.scene.spec import load_scene


def _one_line_error(argv: list[str], capsys: pytest.CaptureFixture[str], must_contain: list[str]) -> str:
    """Run ``hil ARGV`` in-process: exit 2, one stderr line holding every ``must_contain``, no traceback."""
    code = main(argv)
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2, (argv, code, captured.err)
    assert len(lines) == 1, (argv, captured.err)
    assert "Traceback" not in captured.err
    for frag in must_contain:
        assert frag in lines[0], (frag, lines[0])
    return lines[0]


SDEA = load_scene("sdea_bench").source_text

# (id, old text, new text, fragments of the message besides the file name)
CASES: list[tuple[str, str, str, list[str]]] = [
    ("duplicate top-level key", "seed: 0\n", "seed: 0\nseed: 3\n", ["seed: duplicate key 'seed'", "first at line"]),
    ("duplicate key in a flow mapping", "{name: chirp_locked, type: chirp,",
     "{name: chirp_locked, type: chirp, f0: 2.0,", ["experiments[0].f0: duplicate key 'f0'"]),
    ("duplicate key in the controller", "  P_m: 0.28\n", "  P_m: 0.28\n  P_m: 0.3\n",
     ["controller.P_m: duplicate key 'P_m'"]),
    ("mistyped top-level key", "experiments:\n", "experimnets:\n",
     ["experimnets: unknown key 'experimnets', did you mean 'experiments'?"]),
    ("mistyped device key", "    driver: odrive_can\n", "    drivr: odrive_can\n",
     ["devices[0].drivr: unknown key 'drivr', did you mean 'driver'?"]),
    ("mistyped certification key", "  identify:\n", "  identfy:\n",
     ["certification.identfy: unknown key 'identfy', did you mean 'identify'?"]),
    ("unknown driver", "driver: odrive_can", "driver: odrive_cna",
     ["devices[0].driver: unknown driver 'odrive_cna'", "did you mean 'odrive_can'"]),
    ("negative seed", "seed: 0\n", "seed: -5\n", ["seed: expected an integer seed in [0, 2**32-1], got -5"]),
    ("seed too large", "seed: 0\n", "seed: 4294967296\n", ["seed:", "got 4294967296"]),
    ("reversed design range", "range: [50.0, 800.0]", "range: [800, 50]",
     ["certification.design.range: expected [low, high] with low < high"]),
    ("identify names a missing experiment", "- {experiment: chirp_locked,", "- {experiment: chirp_lockd,",
     ["certification.identify[0].experiment: no experiment 'chirp_lockd'", "did you mean 'chirp_locked'"]),
    ("duplicate experiment names", "{name: chirp_free,", "{name: chirp_locked,",
     ["experiments[1].name: duplicate experiment name 'chirp_locked'"]),
    ("map names an unknown parameter", "map: {M: M,", "map: {MM: M,",
     ["certification.identify[0].map.MM: identification model sdea_locked has no parameter 'MM'"]),
    ("map onto a parameter the network lacks", "B_f: B_f}", "B_f: B_ff}",
     ["certification.identify[0].map.B_f:", "'B_ff', which is not a parameter of model sdea"]),
    ("unknown network model", "  model: sdea\n", "  model: sdae\n",
     ["certification.model: unknown model 'sdae' (did you mean 'sdea'?)"]),
    ("draws below the minimum", "draws: 4000", "draws: 0", ["certification.draws:", "greater than or equal to 20"]),
    ("policy probability of 1", "  draws: 4000", "  draws: 4000\n  policy: {required_probability: 1.0}",
     ["certification.policy.required_probability:", "less than 1"]),
    ("chirp above Nyquist/5", "f1: 200.0,\n     duration: 16.0, amplitude: 0.05",
     "f1: 450.0,\n     duration: 16.0, amplitude: 0.05", ["experiments[chirp_free].f1:", "exceeds Nyquist/5"]),
    ("excitation above the effort limit", "effort: 0.5,", "effort: 5.0,",
     ["experiments[static_hold].effort", "exceeds safety.max_effort"]),
    ("unit string in a number", "max_effort: 2.0", "max_effort: 2 Nm",
     ["safety.max_effort: expected a number in N or N.m, got '2 Nm'"]),
    ("invalid YAML", "devices:\n", "devices: [\n", ["not valid YAML (line "]),
    ("a scene holding code", "seed: 0\n", "seed: !!python/object/apply:os.getpid []\n", ["not valid YAML"]),
]


@pytest.mark.parametrize(("desc", "old", "new", "fragments"), CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("command", ["run", "certify"])
def test_malformed_scene_is_one_line_and_writes_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str], command: str, desc: str,
                                                        old: str, new: str, fragments: list[str]) -> None:
    assert SDEA.count(old) == 1, old
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    scene = tmp_path / "malformed.yaml"
    scene.write_text(SDEA.replace(old, new), encoding="utf-8")
    out = tmp_path / "tmp" / "x"
    _one_line_error([command, str(scene), "--out", str(out)], capsys, ["malformed.yaml", *fragments])
    assert not out.exists() and not out.parent.exists()
    assert list(work.iterdir()) == []


@pytest.mark.parametrize(("desc", "content", "fragments"), [
    ("not UTF-8", b"name: x\ndescription: \xff\xfe\n", ["binary.yaml: cannot read"]),
    ("binary file", bytes(range(256)), ["binary.yaml: cannot read"]),
    ("empty file", b"", ["binary.yaml: expected a mapping", "an empty file"]),
    ("a list at the top level", b"- a\n- b\n", ["binary.yaml: expected a mapping", "got list"]),
])
def test_unreadable_scene_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
                               desc: str, content: bytes, fragments: list[str]) -> None:
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "binary.yaml"
    p.write_bytes(content)
    _one_line_error(["run", str(p), "--out", str(tmp_path / "x")], capsys, fragments)
    assert sorted(q.name for q in tmp_path.iterdir()) == ["binary.yaml"]


def test_scene_that_is_a_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    d = tmp_path / "scene.yaml"
    d.mkdir()
    _one_line_error(["run", str(d), "--out", str(tmp_path / "x")], capsys, ["scene.yaml: cannot read"])
    assert not (tmp_path / "x").exists()
    # hil certify takes a folder as a fleet of scenes: an empty one is refused before anything is written
    _one_line_error(["certify", str(d), "--out", str(tmp_path / "x")], capsys, ["holds no scene files"])
    assert not (tmp_path / "x").exists()


def test_malformed_scene_for_mock_serve(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = tmp_path / "serve.yaml"
    scene.write_text(SDEA.replace("seed: 0\n", "seed: 0\nseed: 1\n"), encoding="utf-8")
    _one_line_error(["mock", "serve", str(scene), "--duration", "1"], capsys,
                    ["serve.yaml: seed: duplicate key 'seed'"])
