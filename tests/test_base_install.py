"""A base install answers (issue 9, item 2): with ``pip install hil-certify`` and no extras, every
command that needs an extra exits 2 with ONE stderr line naming what is missing and the
``pip install 'hil-certify[...]'`` that installs it, before anything is created on disk.

The base install is simulated in a subprocess: a meta-path finder inserted first raises
ModuleNotFoundError for the optional distributions (python-can, pyserial, pymodbus, dynamixel-sdk,
matplotlib, jinja2), exactly what Python does when they are not installed.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from hil.protocols import registry
from hil.scene.spec import load_scene

BLOCKED = ("can", "serial", "pymodbus", "dynamixel_sdk", "matplotlib", "jinja2")

_RUNNER = textwrap.dedent("""
    import sys

    BLOCKED = set(sys.argv[1].split(","))

    class _NotInstalled:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None

    sys.meta_path.insert(0, _NotInstalled())
    from hil.cli.main import main

    sys.exit(main(sys.argv[2:]))
""")


def _base_install(tmp_path: Path, *argv: str, blocked: tuple[str, ...] = BLOCKED) -> tuple[int, list[str]]:
    work = tmp_path / "work"
    work.mkdir()
    proc = subprocess.run([sys.executable, "-c", _RUNNER, ",".join(blocked), *argv], cwd=work,
                          capture_output=True, text=True, timeout=120)
    assert "Traceback" not in proc.stderr, proc.stderr
    created = sorted(p.name for p in work.iterdir())
    assert created == [], f"{argv}: created {created} before refusing"
    return proc.returncode, proc.stderr.strip().splitlines()


CASES = [
    # (argv, fragments of the one line)
    (["run", "sdea_bench", "--out", "tmp/x"],
     ["hil run sdea_bench:", "the simulated ODrive needs python-can", "the simulated Bota F/T sensor needs pyserial",
      "pip install 'hil-certify[can,serial]'"]),
    (["run", "dynamixel_leader_follower"],
     ["hil run dynamixel_leader_follower:", "needs dynamixel-sdk", "pip install 'hil-certify[dynamixel]'"]),
    (["certify", "--out", "tmp/x"],
     ["hil certify sdea_bench:", "python-can", "the report needs matplotlib and jinja2",
      "pip install 'hil-certify[can,serial,report]'"]),
    (["certify", "bilateral_2dof_B", "--no-experiments", "--out", "tmp/x"],
     ["hil certify bilateral_2dof_B:", "the report needs matplotlib", "pip install 'hil-certify[report]'"]),
    (["report", "tmp/x"], ["hil report tmp/x:", "the report needs", "pip install 'hil-certify[report]'"]),
    (["mock", "serve", "dual_master_3dof", "--duration", "1"],
     ["hil mock serve dual_master_3dof:", "python-can", "pymodbus", "pip install 'hil-certify[can,serial,modbus]'"]),
    (["mock", "serve", "--duration", "1"],
     ["hil mock serve:", "python-can", "pyserial", "pip install 'hil-certify[can,serial]'"]),
]


@pytest.mark.parametrize(("argv", "fragments"), CASES, ids=[" ".join(c[0][:2]) for c in CASES])
def test_base_install_names_the_extra(tmp_path: Path, argv: list[str], fragments: list[str]) -> None:
    code, err = _base_install(tmp_path, *argv)
    assert code == 2, err
    assert len(err) == 1, err
    for frag in fragments:
        assert frag in err[0], (frag, err[0])


def test_only_what_is_missing_is_named(tmp_path: Path) -> None:
    # python-can present, pyserial missing: the line names pyserial and the serial extra only
    code, err = _base_install(tmp_path, "run", "sdea_bench", blocked=("serial",))
    assert code == 2 and len(err) == 1, err
    assert "pyserial" in err[0] and "python-can" not in err[0]
    assert err[0].endswith("pip install 'hil-certify[serial]'"), err[0]


def test_a_dynamixel_chain_is_served_without_extras(tmp_path: Path) -> None:
    # the simulated DYNAMIXEL chain is a plain pty: serving it needs no extra (its adapter does)
    code, err = _base_install(tmp_path, "mock", "serve", "dynamixel_leader_follower", "--duration", "0.2")
    assert code == 0, err


def test_extras_message_follows_the_registry(monkeypatch: pytest.MonkeyPatch) -> None:
    scene = load_scene("sdea_bench")
    assert registry.extras_message(scene, report=True) is None  # the test environment has [all]
    missing = {"can", "jinja2"}
    monkeypatch.setattr(registry, "importable", lambda m: m not in missing)
    assert registry.missing_extras(scene) == ["the simulated ODrive needs python-can"]
    assert registry.extras_message(scene, report=True) == (
        "the simulated ODrive needs python-can, the report needs jinja2: pip install 'hil-certify[can,report]'")
    assert registry.extras_message(scene, adapters=False) == (
        "the simulated ODrive needs python-can: pip install 'hil-certify[can]'")
    assert registry.extras_message(None, report=True) == "the report needs jinja2: pip install 'hil-certify[report]'"


def test_every_driver_has_its_requirements_and_a_label() -> None:
    drivers = set(registry.available_drivers())
    assert drivers == set(registry.ADAPTER_REQUIRES) == set(registry.SIMULATOR_REQUIRES) == set(registry.DEVICE_LABELS)
    extras = {"can", "canopen", "serial", "modbus", "dynamixel", "report"}
    for reqs in (*registry.ADAPTER_REQUIRES.values(), *registry.SIMULATOR_REQUIRES.values(), registry.REPORT):
        assert {r.extra for r in reqs} <= extras


def test_extras_are_declared_in_pyproject() -> None:
    import tomllib

    root = Path(__file__).resolve().parents[1]
    extras = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"]
    reqs = {r for v in registry.ADAPTER_REQUIRES.values() for r in v} | set(registry.REPORT)
    for r in reqs:
        declared = " ".join(extras[r.extra]).lower()
        assert r.distribution.lower() in declared, (r, extras[r.extra])
