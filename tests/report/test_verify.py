"""Tamper-evident certificates: the digest of the canonical content (hil-c14n/1), the SHA-256 of the
records and scene a certificate rests on, ``hil verify``, ``hil report`` refusing (or, when asked,
marking on every page) a modified certificate, and optional Ed25519 signatures.

The certificates come from the NO-GO teleoperator scene ``bilateral_2dof_B`` with fewer posterior
draws (a few seconds), once with a short energy-injection run (so there are records to tamper
with) and once through ``hil certify --no-experiments --sign``.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from hil.certify.certificate import Certificate, canonical_json, content_digest, seal
from hil.certify.pipeline import certify_scene
from hil.cli.main import main
from hil.report.render import ReportError, build_reports
from hil.scene.spec import load_scene

pytest.importorskip("matplotlib")
pytest.importorskip("jinja2")
from test_report import COLOURS, _colour_pixels, _png_stats, _tool

ROOT = Path(__file__).resolve().parents[2]
MARK = "MODIFIED: NOT A VALID CERTIFICATE"
RECORD = "records/00_energy_injection.h5"


# ---------------------------------------------------------------------------------------------
# fixtures


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory) -> Path:
    d = yaml.safe_load(load_scene("bilateral_2dof_B").source_text)
    d["certification"]["draws"] = 20  # (the minimum) the robust stage per draw is the slow part
    p = tmp_path_factory.mktemp("scene") / "bilateral_2dof_B_small.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False), encoding="utf-8")
    return p


@pytest.fixture(scope="module")
def nogo_dir(tmp_path_factory, scene_file) -> Path:
    """A NO-GO certificate with one (short) energy-injection record and the scene as evidence."""
    out = tmp_path_factory.mktemp("nogo")
    cert = certify_scene(load_scene(scene_file), out, max_ticks=300)
    assert cert.decision == "NO-GO", cert.reasons
    build_reports(cert, out)
    return out


@pytest.fixture(scope="module")
def keys(tmp_path_factory) -> dict[str, Path]:
    pytest.importorskip("cryptography")  # the `sign` extra (in `all`); the digest tests need none
    d = tmp_path_factory.mktemp("keys")
    assert main(["keygen", "--out", str(d / "alice")]) == 0
    assert main(["keygen", "--out", str(d / "mallory")]) == 0
    return {"priv": d / "alice" / "hil_signing_key.pem", "pub": d / "alice" / "hil_signing_key.pub.pem",
            "other_priv": d / "mallory" / "hil_signing_key.pem", "other_pub": d / "mallory" / "hil_signing_key.pub.pem"}


@pytest.fixture(scope="module")
def signed_dir(tmp_path_factory, scene_file, keys) -> Path:
    out = tmp_path_factory.mktemp("signed")
    code = main(["certify", str(scene_file), "--no-experiments", "--out", str(out), "--sign", str(keys["priv"]),
                 "--signer", "A. Reviewer", "--json"])
    assert code == 11  # NO-GO
    return out


def _copy(src: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "cert"
    shutil.copytree(src, dst)
    return dst


def _edit(folder: Path, fn) -> None:
    p = folder / "certificate.json"
    d = json.loads(p.read_text(encoding="utf-8"))
    fn(d)
    p.write_text(json.dumps(d, indent=2, ensure_ascii=False), encoding="utf-8")


def _run(argv: list[str], capsys) -> tuple[int, list[str], list[str]]:
    code = main(argv)
    cap = capsys.readouterr()
    return code, cap.out.splitlines(), cap.err.splitlines()


def _pdf_pages(pdf: Path) -> list[str]:
    exe = _tool("pdftotext")
    text = subprocess.run([exe, "-layout", str(pdf), "-"], capture_output=True, text=True, timeout=60,
                          check=True).stdout
    pages = text.split("\f")
    return pages[:-1] if pages and not pages[-1].strip() else pages


def _measurement(d: dict, name: str) -> dict:
    return next(m for m in d["measurements"] if m["name"] == name)


# ---------------------------------------------------------------------------------------------
# the digest


def test_canonical_json_is_the_documented_form():
    value = {"b": 1.0, "a": [float("nan"), float("inf"), 0.1, 1e-05, -0.0, 1e300, 3, True, None],
             "é": "ü 𝄞", "c": {"z": (1, 2), "y": "x"}}
    expected = (b'{"a":[null,null,0.1,1e-05,-0.0,1e+300,3,true,null],"b":1.0,"c":{"y":"x","z":[1,2]},'
                b'"\\u00e9":"\\u00fc \\ud834\\udd1e"}')
    assert canonical_json(value) == expected


def test_digest_round_trip(nogo_dir, tmp_path, capsys):
    text = (nogo_dir / "certificate.json").read_text(encoding="utf-8")
    raw = json.loads(text)
    cert = Certificate.model_validate(raw)
    assert cert.integrity is not None and cert.integrity.canonicalization == "hil-c14n/1"
    # independently of the model: SHA-256 of the canonical JSON of the file minus its integrity block
    raw.pop("integrity")
    assert hashlib.sha256(canonical_json(raw)).hexdigest() == cert.integrity.digest == content_digest(cert)
    assert Certificate.model_validate_json(cert.model_dump_json()).integrity == cert.integrity
    # evidence: the scene text and the record, hashed as they are on disk
    ev = {e.path: e for e in cert.evidence}
    assert set(ev) == {"scene.yaml", RECORD}
    for path, e in ev.items():
        data = (nogo_dir / path).read_bytes()
        assert e.sha256 == hashlib.sha256(data).hexdigest() and e.bytes == len(data)
    assert ev["scene.yaml"].role == "scene" and ev["scene.yaml"].sha256 == cert.scene.sha256
    assert ev[RECORD].role == "record"
    # layout is not content: re-indented, keys reordered, the certificate still verifies
    d = _copy(nogo_dir, tmp_path)
    obj = json.loads(text)
    (d / "certificate.json").write_text(json.dumps(dict(reversed(list(obj.items()))), indent=None), encoding="utf-8")
    code, out, err = _run(["verify", str(d)], capsys)
    assert code == 0 and err == [] and len(out) == 1
    assert out[0].startswith("OK ") and "2 evidence files match" in out[0] and "not signed" in out[0]


def test_seal_and_build_reports_refuse_a_certificate_changed_after_sealing(nogo_dir, tmp_path):
    cert = Certificate.model_validate_json((nogo_dir / "certificate.json").read_text(encoding="utf-8"))
    changed = cert.model_copy(update={"decision": "GO"})
    assert content_digest(changed) != cert.integrity.digest
    with pytest.raises(ReportError, match="changed after its digest"):
        build_reports(changed, tmp_path / "x")
    assert not (tmp_path / "x" / "certificate.json").exists()
    assert seal(changed).integrity.digest == content_digest(changed)


# ---------------------------------------------------------------------------------------------
# a modified certificate: verify names the digest, report refuses it or marks every page


TAMPER = {
    "decision NO-GO -> GO": lambda d: d.update(decision="GO"),
    "measurement value": lambda d: _measurement(d, "P(stable), lower confidence bound").update(value=0.999),
    "a reason removed": lambda d: d["reasons"].pop(),
    "evidence hash replaced": lambda d: d["evidence"][1].update(sha256="0" * 64),
    "digest removed": lambda d: d.pop("integrity"),
}


@pytest.mark.parametrize("how", list(TAMPER))
def test_verify_and_report_refuse_a_modified_certificate(nogo_dir, tmp_path, capsys, how):
    d = _copy(nogo_dir, tmp_path)
    html_before = (d / "report.html").read_bytes()
    _edit(d, TAMPER[how])
    code, out, err = _run(["verify", str(d)], capsys)
    assert code == 2 and out == [] and len(err) == 1, err
    assert "NOT VALID" in err[0] and "digest" in err[0] and "Traceback" not in err[0]
    if how == "digest removed":
        assert "no digest" in err[0]
    else:
        assert "digest mismatch" in err[0]
    code, out, err = _run(["report", str(d)], capsys)
    assert code == 2 and out == [] and len(err) == 1, err
    assert err[0].startswith("hil report: error: ") and "digest" in err[0] and "--allow-modified" in err[0]
    assert (d / "report.html").read_bytes() == html_before  # nothing rebuilt


def test_allow_modified_marks_every_page_and_the_badge_is_not_green(nogo_dir, tmp_path, capsys):
    d = _copy(nogo_dir, tmp_path)
    pages_before = _pdf_pages(d / "report.pdf")
    assert not any(MARK in p for p in pages_before)  # the genuine report carries no mark
    _edit(d, TAMPER["decision NO-GO -> GO"])
    code, out, err = _run(["report", str(d), "--allow-modified"], capsys)
    assert code == 0 and err == [] and len(out) == 1 and MARK in out[0]
    pages = _pdf_pages(d / "report.pdf")
    assert len(pages) >= 4
    for i, page in enumerate(pages):
        assert MARK in page, f"page {i + 1} lacks the mark"
    html = (d / "report.html").read_text(encoding="utf-8")
    assert html.count(MARK) >= 3 and "digest mismatch" in html
    assert 'class="badge d-void"' in html and not re.search(r'class="[^"]*\bd-go\b', html)
    # PDF page 1 rasterized: no pixel in the GO green (the badge is grey)
    exe = _tool("pdftoppm")
    subprocess.run([exe, "-png", "-r", "50", "-f", "1", "-l", "1", str(d / "report.pdf"), str(tmp_path / "pg")],
                   check=True, timeout=60, capture_output=True)
    _, img = _png_stats(next(tmp_path.glob("pg-*.png")))
    assert _colour_pixels(img, COLOURS["GO"], 0.08) == 0
    # the HTML printed by Chromium: the mark on every printed page
    chrome = _tool("chromium", "chromium-browser", "google-chrome")
    pdf = tmp_path / "html.pdf"
    subprocess.run([chrome, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                    "--disable-background-networking", "--host-resolver-rules=MAP * ~NOTFOUND",
                    f"--user-data-dir={tmp_path / 'profile'}", "--no-pdf-header-footer", f"--print-to-pdf={pdf}",
                    (d / "report.html").resolve().as_uri()], capture_output=True, timeout=120)
    printed = _pdf_pages(pdf)
    assert len(printed) >= 2
    for i, page in enumerate(printed):
        assert MARK in page, f"printed HTML page {i + 1} lacks the mark"


def test_a_genuine_certificate_reports_without_a_mark(nogo_dir, tmp_path, capsys):
    d = _copy(nogo_dir, tmp_path)
    code, out, _ = _run(["report", str(d)], capsys)
    assert code == 0 and MARK not in out[0]
    html = (d / "report.html").read_text(encoding="utf-8")
    assert MARK not in html and 'class="badge d-nogo"' in html
    assert RECORD in html and "(matches the content)" in html and "not signed" in html


# ---------------------------------------------------------------------------------------------
# evidence files


@pytest.mark.parametrize("how", ["changed", "missing", "scene changed"])
def test_verify_names_a_changed_or_missing_evidence_file(nogo_dir, tmp_path, capsys, how):
    d = _copy(nogo_dir, tmp_path)
    if how == "changed":
        data = bytearray((d / RECORD).read_bytes())
        data[len(data) // 2] ^= 0x01  # one bit, same size
        (d / RECORD).write_bytes(bytes(data))
    elif how == "missing":
        (d / RECORD).unlink()
    else:
        with open(d / "scene.yaml", "a", encoding="utf-8") as f:
            f.write("# edited\n")
    code, out, err = _run(["verify", str(d)], capsys)
    assert code == 2 and out == [] and len(err) == 1, err
    assert "digest" not in err[0]  # the certificate itself is intact
    name = "scene.yaml" if how == "scene changed" else RECORD
    assert name in err[0] and ("missing" if how == "missing" else "changed") in err[0]
    if how == "scene changed":
        assert " bytes)" in err[0]  # the size changed too


# ---------------------------------------------------------------------------------------------
# signatures


def test_keygen_writes_a_private_key_readable_by_its_owner_only_and_never_overwrites(keys, capsys):
    mode = stat.S_IMODE(os.stat(keys["priv"]).st_mode)
    assert mode == 0o600
    assert b"PRIVATE KEY" in keys["priv"].read_bytes() and b"PUBLIC KEY" in keys["pub"].read_bytes()
    before = keys["priv"].read_bytes()
    code, _out, err = _run(["keygen", "--out", str(keys["priv"].parent)], capsys)
    assert code == 2 and len(err) == 1 and "already exists" in err[0] and "refusing" in err[0]
    assert keys["priv"].read_bytes() == before


def test_signature_holds_with_the_signers_key(signed_dir, keys, capsys):
    cert = Certificate.model_validate_json((signed_dir / "certificate.json").read_text(encoding="utf-8"))
    sig = cert.integrity.signature
    assert sig is not None and sig.signer == "A. Reviewer" and sig.algorithm == "ed25519"
    from hil.certify.signing import load_public_key

    assert sig.public_key_sha256 == load_public_key(keys["pub"]).fingerprint
    code, out, err = _run(["verify", str(signed_dir), "--public-key", str(keys["pub"])], capsys)
    assert code == 0 and err == [] and len(out) == 1
    assert "signature holds" in out[0] and "A. Reviewer" in out[0] and "1 evidence file matches" in out[0]
    code, out, _ = _run(["verify", str(signed_dir)], capsys)  # without a key: OK, but says it did not check
    assert code == 0 and "signature not checked" in out[0]
    # the report written by hil certify shows who signed and that the signature holds
    html = (signed_dir / "report.html").read_text(encoding="utf-8")
    assert "signed by A. Reviewer" in html and "the signature HOLDS" in html
    sig_page = _pdf_pages(signed_dir / "report.pdf")[-1]
    assert "A. Reviewer" in sig_page and "HOLDS" in sig_page


def test_signature_with_the_wrong_key_fails(signed_dir, keys, capsys, tmp_path):
    code, out, err = _run(["verify", str(signed_dir), "--public-key", str(keys["other_pub"])], capsys)
    assert code == 2 and out == [] and len(err) == 1
    assert "signature" in err[0] and "not with the given public key" in err[0]
    d = _copy(signed_dir, tmp_path)
    code, out, err = _run(["report", str(d), "--public-key", str(keys["other_pub"])], capsys)
    assert code == 2 and len(err) == 1 and "signature" in err[0]
    code, out, _ = _run(["report", str(d), "--public-key", str(keys["pub"])], capsys)
    assert code == 0
    assert "the signature HOLDS" in (d / "report.html").read_text(encoding="utf-8")


@pytest.mark.parametrize("how", ["content re-sealed", "signer renamed", "digest edited"])
def test_signature_fails_when_tampered_after_signing(signed_dir, keys, capsys, tmp_path, how):
    d = _copy(signed_dir, tmp_path)
    p = d / "certificate.json"
    cert = Certificate.model_validate_json(p.read_text(encoding="utf-8"))
    if how == "content re-sealed":  # an editor who recomputes the digest cannot recompute the signature
        changed = cert.model_copy(update={"decision": "GO"})
        integ = cert.integrity.model_copy(update={"digest": content_digest(changed)})
        cert = changed.model_copy(update={"integrity": integ})
    elif how == "signer renamed":
        sig = cert.integrity.signature.model_copy(update={"signer": "Somebody Else"})
        cert = cert.model_copy(update={"integrity": cert.integrity.model_copy(update={"signature": sig})})
    else:
        cert = cert.model_copy(update={"integrity": cert.integrity.model_copy(update={"digest": "f" * 64})})
    p.write_text(cert.model_dump_json(indent=2), encoding="utf-8")
    code, out, err = _run(["verify", str(d), "--public-key", str(keys["pub"])], capsys)
    assert code == 2 and out == [] and len(err) == 1, err
    assert "signature" in err[0] and "does not verify" in err[0]
    if how == "digest edited":
        assert "digest mismatch" in err[0]
    else:
        assert "digest mismatch" not in err[0]  # the digest matches the (edited) content; only the signature catches it


def test_signing_inputs_fail_in_one_line(tmp_path, keys, scene_file, capsys):
    cases = [
        (["certify", str(scene_file), "--no-experiments", "--out", str(tmp_path / "a"), "--sign",
          str(tmp_path / "nokey.pem")], "no such private key file"),
        (["certify", str(scene_file), "--no-experiments", "--out", str(tmp_path / "b"), "--sign", str(keys["pub"])],
         "this is a public key"),
        (["certify", str(scene_file), "--no-experiments", "--out", str(tmp_path / "c"), "--signer", "X"],
         "--signer names who signs"),
        (["verify", str(tmp_path), "--public-key", str(keys["pub"])], "no such file"),
        (["verify", str(tmp_path / "missing")], "no such file"),
    ]
    for argv, msg in cases:
        code, _out, err = _run(argv, capsys)
        assert code == 2 and len(err) == 1 and msg in err[0], (argv, err)
    for sub in ("a", "b", "c"):
        assert not (tmp_path / sub).exists()  # refused before anything ran or was written


# ---------------------------------------------------------------------------------------------
# the sign extra is optional


_BLOCK = """
import sys
class _NoCryptography:
    def find_spec(self, name, path=None, target=None):
        if name == "cryptography" or name.startswith("cryptography."):
            raise ModuleNotFoundError(f"No module named {name!r}")
        return None
sys.meta_path.insert(0, _NoCryptography())
from hil.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


def test_missing_cryptography_extra_is_one_line_naming_the_extra(tmp_path, keys, signed_dir, scene_file):
    cases = [["keygen", "--out", str(tmp_path / "k")],
             ["certify", str(scene_file), "--no-experiments", "--out", str(tmp_path / "c"),
              "--sign", str(keys["priv"])],
             ["verify", str(signed_dir), "--public-key", str(keys["pub"])],
             ["report", str(signed_dir), "--out", str(tmp_path / "r"), "--public-key", str(keys["pub"])]]
    for argv in cases:
        p = subprocess.run([sys.executable, "-c", _BLOCK, *argv], capture_output=True, text=True, timeout=120)
        err = p.stderr.splitlines()
        assert p.returncode == 2 and len(err) == 1, (argv, p.stderr)
        assert "pip install 'hil-certify[sign]'" in err[0] and "Traceback" not in p.stderr
    assert not (tmp_path / "k").exists() and not (tmp_path / "c").exists() and not (tmp_path / "r").exists()
    # verifying the digest and the evidence needs no extra
    p = subprocess.run([sys.executable, "-c", _BLOCK, "verify", str(signed_dir)], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0 and p.stdout.startswith("OK "), p.stderr


# ---------------------------------------------------------------------------------------------
# the exported schema


def test_exported_schema_is_the_model_schema():
    text = (ROOT / "docs" / "certificate.schema.json").read_text(encoding="utf-8")
    assert text == json.dumps(Certificate.model_json_schema(), indent=1, ensure_ascii=False), (
        "regenerate: python -c \"import json; from hil.certify.certificate import Certificate; "
        "open('docs/certificate.schema.json', 'w').write(json.dumps(Certificate.model_json_schema(), indent=1, "
        "ensure_ascii=False))\"")
    props = json.loads(text)["properties"]
    assert "integrity" in props and "evidence" in props
