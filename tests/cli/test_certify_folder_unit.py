"""``hil certify --out D [--overwrite]`` writes the certificate folder as a unit (issue 27 item 5).

Before: ``hil certify OTHER --out D --overwrite`` killed after the new certificate.json was written
left it (verifying OK) beside the old scene's reports and records; ``--overwrite`` refused as soon
as a record of the same name existed; and a symbolic link planted in D was followed, so a record
landed outside D.

Now everything is built in a sibling ``D.incomplete-<hex>`` and moved into place by one atomic
exchange (:class:`hil.record.outdir.StagedFolder`). The kill matrix below kills a forked
``hil certify`` with SIGKILL at every stage, from the first record block to the removal of the
replaced folder, and checks that D is then exactly the old folder (byte for byte) or the complete
new one (``hil verify`` OK, the new scene, no record of the old one).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from hil.cli.main import main
from hil.scene.spec import load_scene

pytest.importorskip("matplotlib")
pytest.importorskip("jinja2")


def _scene(folder: Path, name: str) -> Path:
    """bilateral_2dof_B with 20 draws and a 0.3 s energy-injection run (one record, a few seconds)."""
    d = yaml.safe_load(load_scene("bilateral_2dof_B").source_text)
    d["name"] = name
    d["certification"]["draws"] = 20
    d["experiments"][0]["duration"] = 0.3
    p = folder / f"{name}.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False), encoding="utf-8")
    return p


def _tree(folder: Path) -> dict[str, str]:
    """Every entry under ``folder``: relative path -> SHA-256 (files), 'dir' or 'link -> target'."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if p.is_symlink():
            out[rel] = f"link -> {os.readlink(p)}"
        elif p.is_dir():
            out[rel] = "dir"
        else:
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("scenes")
    return {"old": _scene(d, "old_scene"), "new": _scene(d, "new_scene")}


@pytest.fixture(scope="module")
def old_folder(tmp_path_factory, scenes) -> Path:
    out = tmp_path_factory.mktemp("old") / "D"
    assert main(["certify", str(scenes["old"]), "--out", str(out), "--json"]) == 11  # NO-GO
    assert (out / "records" / "00_energy_injection.h5").is_file()
    return out


def _verify(folder: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hil", "verify", str(folder)], capture_output=True, text=True,
                          timeout=120)


# ---------------------------------------------------------------------------------------------
# --overwrite as documented, links never followed


def test_overwrite_replaces_the_folder_as_a_whole(old_folder, scenes, tmp_path, capsys):
    d = tmp_path / "D"
    shutil.copytree(old_folder, d)
    code = main(["certify", str(scenes["new"]), "--out", str(d), "--overwrite", "--json"])
    capsys.readouterr()
    assert code == 11  # before: "a record already exists; refusing to overwrite it", exit 2
    v = _verify(d)
    assert v.returncode == 0, v.stderr
    text = (d / "certificate.json").read_text(encoding="utf-8")
    assert '"name": "new_scene"' in text and "old_scene" not in text
    assert sorted(p.name for p in d.iterdir()) == ["certificate.json", "records", "report.html", "report.pdf",
                                                   "scene.yaml"]
    assert not [p for p in tmp_path.iterdir() if ".incomplete-" in p.name or ".replaced-" in p.name]
    # the record paths the certificate names are relative to its folder (issue 28), never the staging one's
    assert '"record": "records/00_energy_injection.h5"' in text and ".incomplete-" not in text


def test_a_link_planted_in_the_folder_is_never_followed(old_folder, scenes, tmp_path, capsys):
    d = tmp_path / "D"
    shutil.copytree(old_folder, d)
    outside = tmp_path / "outside"
    outside.mkdir()
    shutil.rmtree(d / "records")
    os.symlink(outside, d / "records")  # before: the new record was written into `outside`
    victim = tmp_path / "victim.html"
    victim.write_text("not yours")
    (d / "report.html").unlink()
    os.symlink(victim, d / "report.html")
    code = main(["certify", str(scenes["new"]), "--out", str(d), "--overwrite", "--json"])
    capsys.readouterr()
    assert code == 11
    assert list(outside.iterdir()) == [] and victim.read_text() == "not yours"
    assert not (d / "records").is_symlink() and (d / "records" / "00_energy_injection.h5").is_file()
    assert not (d / "report.html").is_symlink()
    assert _verify(d).returncode == 0


@pytest.mark.parametrize(("how", "phrase"), [
    ("foreign file", "holds 'notes.txt', which this command does not write"),
    ("folder is a link", "is a symbolic link"),
    ("no --overwrite", "exists and is not empty; use --overwrite"),
])
def test_overwrite_refuses_what_it_would_sweep_away(old_folder, scenes, tmp_path, capsys, how, phrase):
    d = tmp_path / "D"
    shutil.copytree(old_folder, d)
    target = d
    if how == "foreign file":
        (d / "notes.txt").write_text("mine")
    elif how == "folder is a link":
        target = tmp_path / "L"
        os.symlink(d, target)
    before = _tree(d)
    argv = ["certify", str(scenes["new"]), "--out", str(target), "--json"]
    code = main(argv + ([] if how == "no --overwrite" else ["--overwrite"]))
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and len(err) == 1 and phrase in err[0], err
    assert _tree(d) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["D"] + (["L"] if how == "folder is a link" else []))


# ---------------------------------------------------------------------------------------------
# the kill matrix


def _kill() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _after(module: str, name: str, n: int = 1) -> Callable[[pytest.MonkeyPatch], None]:
    """Patch ``module.name`` to SIGKILL the process after its ``n``-th call returned."""

    def patch(mp: pytest.MonkeyPatch) -> None:
        import importlib

        mod = importlib.import_module(module)
        orig = getattr(mod, name)
        calls = [0]

        def wrapper(*a, **k):
            r = orig(*a, **k)
            calls[0] += 1
            if calls[0] >= n:
                _kill()
            return r

        mp.setattr(mod, name, wrapper)

    return patch


def _before(module: str, name: str) -> Callable[[pytest.MonkeyPatch], None]:
    def patch(mp: pytest.MonkeyPatch) -> None:
        import importlib

        mp.setattr(importlib.import_module(module), name, lambda *a, **k: _kill())

    return patch


def _half_discard(mp: pytest.MonkeyPatch) -> None:
    """The replaced folder's removal killed after its first file."""
    from hil.record import outdir

    def discard(p: Path) -> None:
        next(q for q in sorted(p.rglob("*")) if q.is_file()).unlink()
        _kill()

    mp.setattr(outdir, "_discard", discard)


def _after_commit(mp: pytest.MonkeyPatch) -> None:
    from hil.record import outdir

    orig = outdir.StagedFolder.commit

    def commit(self):
        r = orig(self)
        _kill()
        return r

    mp.setattr(outdir.StagedFolder, "commit", commit)


def _no_exchange_then(kill_after_renames: int) -> Callable[[pytest.MonkeyPatch], None]:
    """No renameat2 (another OS or file system): the two-rename fallback, killed after ``n`` renames."""

    def patch(mp: pytest.MonkeyPatch) -> None:
        from hil.record import outdir

        mp.setattr(outdir, "_exchange", lambda a, b: False)
        orig, calls = os.rename, [0]

        def rename(a, b):
            orig(a, b)
            if ".replaced-" in str(b) or ".replaced-" in str(a) or calls[0]:
                calls[0] += 1
                if calls[0] >= kill_after_renames:
                    _kill()

        mp.setattr(outdir.os, "rename", rename)

    return patch


#: stage of ``hil certify`` -> patch that SIGKILLs the child there (D must then be the old folder:
#: nothing is written at D before the commit)
KILLS: dict[str, Callable[[pytest.MonkeyPatch], None]] = {
    "run: first record rows written": _after("hil.record.hdf5", "_write_rows"),
    "identify starts": _before("hil.certify.pipeline", "stage_identify"),
    "sealed (scene copy and evidence hashed)": _after("hil.certify.pipeline", "_seal"),
    "certificate.json written": _after("hil.report.render", "write_json"),
    "report.pdf written (the last file)": _after("hil.report.render", "render_pdf"),
}

#: step of :meth:`StagedFolder.commit` -> (patch that SIGKILLs there, what D must be afterwards)
COMMIT_KILLS: dict[str, tuple[Callable[[pytest.MonkeyPatch], None], str]] = {
    "before the exchange": (_before("hil.record.outdir", "_exchange"), "old"),
    "right after the exchange": (_after("hil.record.outdir", "_exchange"), "new"),
    "before the old folder is removed": (_before("hil.record.outdir", "_discard"), "new"),
    "the old folder half removed": (_half_discard, "new"),
    "after the commit": (_after_commit, "new"),
    "fallback without exchange: after the second rename": (_no_exchange_then(2), "new"),
    # the documented gap of the fallback: between its two renames D does not exist, and the old
    # folder is whole beside it as D.replaced-<hex>
    "fallback without exchange: between the two renames": (_no_exchange_then(1), "old, moved aside"),
}


def _forked(patch: Callable[[pytest.MonkeyPatch], None], body: Callable[[], object]) -> int:
    """Fork; the child patches and runs ``body``, and must die by SIGKILL. Returns the status."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
            patch(pytest.MonkeyPatch())
            body()
        finally:
            os._exit(3)
    _, status = os.waitpid(pid, 0)
    return status


def _killed(status: int) -> bool:
    return os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL


@pytest.mark.slow
@pytest.mark.parametrize("stage", list(KILLS))
def test_a_kill_during_certify_leaves_the_old_folder(old_folder, scenes, tmp_path, stage):
    d = tmp_path / "D"
    shutil.copytree(old_folder, d)
    old = _tree(d)
    argv = ["certify", str(scenes["new"]), "--out", str(d), "--overwrite", "--json"]
    status = _forked(KILLS[stage], lambda: main(argv))
    assert _killed(status), f"not killed at {stage}: {status}"
    assert _tree(d) == old, f"killed at {stage}: D is not the old folder"
    left = [p.name for p in tmp_path.iterdir() if p.name != "D"]
    assert len(left) == 1 and left[0].startswith("D.incomplete-"), left  # the partial build, named so


def _fake_certificate(folder: Path, scene: str, records: int) -> None:
    folder.mkdir()
    (folder / "certificate.json").write_text(f'{{"scene": "{scene}"}}')
    (folder / "report.html").write_text(scene)
    (folder / "records").mkdir()
    for i in range(records):
        (folder / "records" / f"{i:02d}_{scene}.h5").write_bytes(os.urandom(1000))


@pytest.mark.parametrize("step", list(COMMIT_KILLS))
def test_a_kill_during_the_commit_leaves_the_old_folder_or_the_new_one(tmp_path, step):
    """The commit on its own, on small folders (the same code ``hil certify`` ends with)."""
    from hil.record.outdir import stage_out_dir

    patch, expect = COMMIT_KILLS[step]
    d = tmp_path / "D"
    _fake_certificate(d, "old", 3)
    old = _tree(d)
    staged = stage_out_dir(d, default_stem="x", overwrite=True, owned=("certificate.json", "report.html", "records"))
    shutil.rmtree(staged.path)
    _fake_certificate(staged.path, "new", 2)
    new = _tree(staged.path)
    status = _forked(patch, lambda: staged.commit())
    assert _killed(status), f"not killed at {step}: {status}"
    if expect == "old, moved aside":
        assert not d.exists()
        aside = [p for p in tmp_path.iterdir() if p.name.startswith("D.replaced-")]
        assert len(aside) == 1 and _tree(aside[0]) == old
        return
    assert d.is_dir() and not d.is_symlink()
    assert _tree(d) == (old if expect == "old" else new), f"killed {step}: D is neither the old nor the new folder"
    left = sorted(p.name for p in tmp_path.iterdir() if p.name != "D")
    assert all(n.startswith(("D.incomplete-", "D.replaced-")) for n in left), left


def test_commit_without_a_kill_leaves_only_the_new_folder(tmp_path):
    from hil.record.outdir import stage_out_dir

    d = tmp_path / "D"
    _fake_certificate(d, "old", 3)
    staged = stage_out_dir(d, default_stem="x", overwrite=True, owned=("certificate.json", "report.html", "records"))
    shutil.rmtree(staged.path)
    _fake_certificate(staged.path, "new", 2)
    new = _tree(staged.path)
    assert staged.commit() == d
    assert _tree(d) == new and [p.name for p in tmp_path.iterdir()] == ["D"]


# ---------------------------------------------------------------------------------------------
# SIGTERM during hil certify (issue 27 item 9): exit 20 at any stage, the folder in order


@pytest.mark.slow
@pytest.mark.parametrize("stage", ["run", "robust"])
def test_sigterm_during_certify_exits_20_and_keeps_the_old_folder(old_folder, scenes, tmp_path, stage):
    """Before: a SIGTERM outside the bench (identification, the robust stage, ...) ended the
    process by the signal (exit -15) and left a folder half written."""
    d = tmp_path / "D"
    shutil.copytree(old_folder, d)
    old = _tree(d)
    p = subprocess.Popen([sys.executable, "-m", "hil", "certify", str(scenes["new"]), "--out", str(d), "--overwrite"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = []
    assert p.stderr is not None
    for line in p.stderr:
        lines.append(line)
        if f": {stage} ..." in line:
            p.send_signal(signal.SIGTERM)
            break
    rest = p.stderr.read()
    code = p.wait(timeout=300)
    last = rest.strip().splitlines()[-1] if rest.strip() else ""
    assert code == 20, (code, lines, rest)
    assert last.startswith("hil certify: error: stopped: signal: SIGTERM"), rest
    assert "Traceback" not in rest
    assert _tree(d) == old
    left = [q for q in tmp_path.iterdir() if q.name != "D"]
    if stage == "run" and not left:  # the stop came before the first record: nothing was written
        assert "no record was written" in last or "nothing was written" in last
    else:  # the records taken so far, beside the old folder, named in the message
        assert len(left) == 1 and left[0].name.startswith("D.incomplete-") and str(left[0]) in last
        assert list((left[0] / "records").glob("*.h5"))
