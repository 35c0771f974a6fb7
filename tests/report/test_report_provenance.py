"""A certificate that stands on its own (issue 28): it says where its evidence came from (a simulated
bench or hardware, on which clock) on page 1, in every page header, in the HTML as a browser
renders it, in the signed JSON and on ``hil verify``'s OK line; and ``hil report`` re-hashes the
evidence, so a record swapped after certification is refused (or marked on every page).

The certificate is the NO-GO teleoperator scene ``bilateral_2dof_B`` with 20 posterior draws and a
300-tick energy-injection run on its simulated (lockstep) bench: a few seconds.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest
import yaml

from hil.certify.certificate import Certificate
from hil.certify.pipeline import certify_scene
from hil.certify.provenance import bench_info
from hil.cli.main import main
from hil.report.render import build_reports
from hil.scene.spec import load_scene

pytest.importorskip("matplotlib")
pytest.importorskip("jinja2")
from test_report import _tool, sdea_go

MARK = "MODIFIED: NOT A VALID CERTIFICATE"
RECORD = "records/00_energy_injection.h5"


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory) -> Path:
    d = yaml.safe_load(load_scene("bilateral_2dof_B").source_text)
    d["certification"]["draws"] = 20
    p = tmp_path_factory.mktemp("scene") / "bilateral_2dof_B_small.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False), encoding="utf-8")
    return p


@pytest.fixture(scope="module")
def cert_dir(tmp_path_factory, small_scene) -> Path:
    out = tmp_path_factory.mktemp("nogo")
    cert = certify_scene(load_scene(small_scene), out, max_ticks=300)
    assert cert.decision == "NO-GO", cert.reasons
    build_reports(cert, out)
    return out


def _pages(pdf: Path) -> list[str]:
    text = subprocess.run([_tool("pdftotext"), "-layout", str(pdf), "-"], capture_output=True, text=True,
                          timeout=60, check=True).stdout
    pages = text.split("\f")
    return pages[:-1] if pages and not pages[-1].strip() else pages


def _printed_html(html: Path, tmp_path: Path) -> list[str]:
    """The HTML as headless Chromium renders and prints it, read back as text page by page."""
    chrome = _tool("chromium", "chromium-browser", "google-chrome")
    pdf = tmp_path / f"{html.parent.name}-printed.pdf"
    subprocess.run([chrome, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                    "--disable-background-networking", "--host-resolver-rules=MAP * ~NOTFOUND",
                    f"--user-data-dir={tmp_path / 'profile'}", "--no-pdf-header-footer", f"--print-to-pdf={pdf}",
                    html.resolve().as_uri()], capture_output=True, timeout=120)
    assert pdf.is_file(), "chromium printed nothing"
    return _pages(pdf)


# ---------------------------------------------------------------------------------------------
# where the evidence came from


def _scene(simulated: bool, mode: str = "lockstep") -> SimpleNamespace:
    devs = [SimpleNamespace(name="motor", driver="odrive_can"), SimpleNamespace(name="spring_ft", driver="bota_serial")]
    return SimpleNamespace(devices=devs, simulation=object() if simulated else None, run_mode=mode)


def _outcome(mode: str) -> SimpleNamespace:
    return SimpleNamespace(stats={"ticks": 10, "overruns": 0, "mode": mode})


@pytest.mark.parametrize("simulated,mode,label", [
    (True, "lockstep", "SIMULATED BENCH — lockstep"),
    (True, "realtime", "SIMULATED BENCH — realtime"),
    (False, "realtime", "HARDWARE — realtime, devices: motor (odrive_can), spring_ft (bota_serial)"),
])
def test_bench_label_follows_the_scene_and_the_clock_the_runner_used(simulated, mode, label):
    b = bench_info(_scene(simulated, "lockstep"), {"chirp": _outcome(mode)})  # the outcome's clock, not the scene's
    assert b.label == label and b.clock == mode
    assert b.kind == ("simulated" if simulated else "hardware")
    assert b.devices == ["motor (odrive_can)", "spring_ft (bota_serial)"]
    assert ("no hardware was measured" in b.note) == simulated


def test_no_run_is_no_bench():
    b = bench_info(_scene(True), {})
    assert b.kind == "none" and b.clock is None and b.label == "NO BENCH RUN" and "not on measurements" in b.note


def test_the_bench_is_in_the_signed_json_and_on_page_1_and_every_header(cert_dir, tmp_path, capsys):
    data = json.loads((cert_dir / "certificate.json").read_text(encoding="utf-8"))
    assert data["bench"]["kind"] == "simulated" and data["bench"]["clock"] == "lockstep"
    assert data["bench"]["label"] == "SIMULATED BENCH — lockstep"
    # part of the digested content: editing it is a digest mismatch
    d = tmp_path / "edited"
    shutil.copytree(cert_dir, d)
    data["bench"] = {**data["bench"], "kind": "hardware", "label": "HARDWARE — realtime, devices: x"}
    (d / "certificate.json").write_text(json.dumps(data), encoding="utf-8")
    assert main(["verify", str(d)]) == 2
    assert "digest mismatch" in capsys.readouterr().err
    # PDF: page 1 carries the banner and its sentence, every page header the label
    pages = _pages(cert_dir / "report.pdf")
    assert "SIMULATED BENCH — lockstep" in pages[0] and "no hardware was measured" in " ".join(pages[0].split())
    for i, p in enumerate(pages):
        head = p.strip().splitlines()[0]
        assert "SIMULATED BENCH — lockstep" in head, f"page {i + 1} header: {head!r}"
    # HTML as Chromium prints it: the banner, and the badge says the bench was simulated
    printed = " ".join(" ".join(_printed_html(cert_dir / "report.html", tmp_path)).split())
    assert "SIMULATED BENCH — lockstep" in printed and "no hardware was measured" in printed
    assert "SIMULATED BENCH" in printed.upper()


def test_hil_verify_prints_the_bench(cert_dir, capsys):
    assert main(["verify", str(cert_dir)]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("OK ") and out.endswith("bench: SIMULATED BENCH — lockstep")


def test_a_certificate_without_the_field_says_the_bench_is_not_recorded(tmp_path):
    cert = sdea_go()
    assert cert.bench is None
    files = build_reports(cert, tmp_path)
    pages = _pages(files["pdf"])
    assert "BENCH NOT RECORDED" in pages[0]
    assert "BENCH NOT RECORDED" in files["html"].read_text(encoding="utf-8")
    # old certificates keep their digest: the new field at its default is not part of the content
    data = json.loads(files["json"].read_text(encoding="utf-8"))
    assert "bench" not in data
    Certificate.model_validate(data)


# ---------------------------------------------------------------------------------------------
# hil report re-hashes the evidence


def _swap(cert_dir: Path, tmp_path: Path) -> Path:
    """The certificate folder with its record replaced by another run's record (a different file)."""
    d = tmp_path / "swapped"
    shutil.copytree(cert_dir, d)
    rec = d / RECORD
    data = bytearray(rec.read_bytes())
    data[len(data) // 3] ^= 0x01
    rec.write_bytes(bytes(data))
    return d


def test_hil_report_refuses_a_swapped_record(cert_dir, tmp_path, capsys):
    d = _swap(cert_dir, tmp_path)
    before = (d / "report.pdf").read_bytes()
    out = tmp_path / "elsewhere"
    code = main(["report", str(d), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert RECORD in err[0] and "changed" in err[0] and "--allow-modified" in err[0]
    assert not out.exists() and (d / "report.pdf").read_bytes() == before  # nothing written
    assert main(["verify", str(d)]) == 2  # the same answer as hil verify


def test_hil_report_allow_modified_marks_every_page_of_a_swapped_record(cert_dir, tmp_path, capsys):
    d = _swap(cert_dir, tmp_path)
    out = tmp_path / "marked"
    assert main(["report", str(d), "--out", str(out), "--allow-modified"]) == 0
    capsys.readouterr()
    pages = _pages(out / "report.pdf")
    assert len(pages) >= 3
    for i, p in enumerate(pages):
        assert MARK in p, f"page {i + 1} lacks the mark"
    html = (out / "report.html").read_text(encoding="utf-8")
    assert MARK in html and RECORD in html and 'class="badge d-void"' in html


def test_hil_report_of_an_intact_folder_says_the_evidence_matches(cert_dir, tmp_path, capsys):
    d = tmp_path / "intact"
    shutil.copytree(cert_dir, d)
    assert main(["report", str(d)]) == 0
    capsys.readouterr()
    text = " ".join(" ".join(_pages(d / "report.pdf")).split())
    assert "All 2 evidence files match their recorded SHA-256" in text and MARK not in text


# ---------------------------------------------------------------------------------------------
# the folder is self-contained: records named relative to it


def test_records_are_named_relative_to_the_certificate_folder_and_a_moved_folder_verifies(tmp_path, small_scene,
                                                                                          capsys, monkeypatch):
    """Certified with a relative --out from another working directory, the certificate names its
    records relative to its own folder; the folder, moved elsewhere, verifies and reports."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["certify", str(small_scene), "--out", "reports/today", "--json"]) == 11
    capsys.readouterr()
    data = json.loads((work / "reports" / "today" / "certificate.json").read_text(encoding="utf-8"))
    named = [e["record"] for e in data["energy"]]
    assert named == [RECORD], named
    assert all(not Path(e["path"]).is_absolute() and ".." not in e["path"] for e in data["evidence"])
    moved = tmp_path / "archive" / "cert"
    moved.parent.mkdir()
    shutil.move(str(work / "reports" / "today"), str(moved))
    monkeypatch.chdir(tmp_path)
    assert main(["verify", str(moved)]) == 0
    assert main(["report", str(moved)]) == 0
    html = (moved / "report.html").read_text(encoding="utf-8")
    assert RECORD in html and str(work) not in html
