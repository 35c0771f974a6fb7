"""``hil verify`` under attack (issue 27 items 1-4): a table of tampered certificate folders, each
refused with exit 2 and one line on stderr, and answered rather than hung.

Every case runs ``python -m hil verify`` in a child process with a timeout. The timeout is a hang
detector, not a speed requirement: before issue 27, a FIFO or ``/dev/zero`` behind an evidence
path made ``hil verify`` read forever (even with a wrong digest or a public key), a duplicated
``"decision"`` member or ``1e999`` / ``NaN`` in place of ``null`` verified "OK", and 100 000
nested ``[`` ended in a RecursionError (exit 1). The seconds each case took are kept in
``ANSWERED`` and printed by the last test, for the report.

The strict reader itself (``hil.certify.strict_json``) is tested directly at the end.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import test_verify as _tv

from hil.certify.certificate import Certificate, seal
from hil.certify.strict_json import INT_LIMIT, MAX_BYTES, StrictJsonError, loads, read_regular_file

# the certificates of test_verify (module-scoped fixtures, rebuilt for this module)
scene_file, nogo_dir, keys, signed_dir = _tv.scene_file, _tv.nogo_dir, _tv.keys, _tv.signed_dir
RECORD = _tv.RECORD
HANG_S = 60.0  # a case not answered by then hangs (the old reader on a FIFO never returned)
ANSWERED: dict[str, float] = {}


def _verify(folder: Path, *extra: str) -> tuple[int, str, str, float]:
    t0 = time.monotonic()
    try:
        p = subprocess.run([sys.executable, "-m", "hil", "verify", str(folder), *extra], capture_output=True,
                           text=True, timeout=HANG_S, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        pytest.fail(f"hil verify {folder} did not answer within {HANG_S} s (it hangs)")
    return p.returncode, p.stdout, p.stderr, time.monotonic() - t0


# ---------------------------------------------------------------------------------------------
# edits of certificate.json as text (the attacker's view: any bytes, not the model)


def _text(folder: Path) -> str:
    return (folder / "certificate.json").read_text(encoding="utf-8")


def _write(folder: Path, text: str) -> None:
    (folder / "certificate.json").write_text(text, encoding="utf-8")


def _sub(pattern: str, repl: str) -> Callable[[Path], None]:
    """Replace the first match of ``pattern`` in certificate.json (it must match)."""

    def edit(folder: Path) -> None:
        text = _text(folder)
        new, n = re.subn(pattern, repl, text, count=1)
        assert n == 1, f"{pattern!r} not in the certificate"
        _write(folder, new)

    return edit


def _resealed(fn: Callable[[dict], None], keep_signature: bool = False) -> Callable[[Path], None]:
    """Edit the parsed certificate and recompute its digest, as anyone without the signing key can:
    only the evidence checks (or a signature) can catch these."""

    def edit(folder: Path) -> None:
        d = json.loads(_text(folder))
        old = d.pop("integrity")
        fn(d)
        cert = seal(Certificate.model_validate(d))
        out = json.loads(cert.model_dump_json())
        if keep_signature:
            out["integrity"]["signature"] = old["signature"]
        _write(folder, json.dumps(out, indent=2))

    return edit


def _record_replaced(make: Callable[[Path, Path], None]) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        rec = folder / RECORD
        keep = folder.parent / "kept.h5"
        shutil.move(rec, keep)
        make(rec, keep)

    return edit


def _records_dir_linked(folder: Path) -> None:
    elsewhere = folder.parent / "elsewhere"
    shutil.move(folder / "records", elsewhere)
    os.symlink(elsewhere, folder / "records")


def _cert_replaced(make: Callable[[Path], None]) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        (folder / "certificate.json").unlink()
        make(folder / "certificate.json")

    return edit


def _flip_bit(folder: Path) -> None:
    data = bytearray((folder / RECORD).read_bytes())
    data[len(data) // 2] ^= 0x01
    (folder / RECORD).write_bytes(bytes(data))


def _truncate(folder: Path) -> None:
    with open(folder / RECORD, "r+b") as f:
        f.truncate(1000)


def _old_record_left(folder: Path) -> None:
    shutil.copy(folder / RECORD, folder / "records" / "00_chirp_locked.h5")


def _both(*edits: Callable[[Path], None]) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        for e in edits:
            e(folder)

    return edit


def _evidence_path(path: str) -> Callable[[Path], None]:
    return _resealed(lambda d: d["evidence"][1].update(path=path))


DUP_BEFORE = _sub(r'"decision": "NO-GO"', '"decision": "GO",\n  "decision": "NO-GO"')
FIFO_RECORD = _record_replaced(lambda rec, _: os.mkfifo(rec))

#: case -> (edit of a copy of the NO-GO folder, a phrase the one stderr line must hold)
CASES: dict[str, tuple[Callable[[Path], None], str]] = {
    # the content: the digest, or the strict reader, refuses
    "decision NO-GO -> GO": (_sub(r'"decision": "NO-GO"', '"decision": "GO"'), "digest mismatch"),
    "duplicate decision GO before the real one": (DUP_BEFORE, "'decision' appears twice"),
    "duplicate decision GO after the real one": (
        _sub(r'"decision": "NO-GO"', '"decision": "NO-GO",\n  "decision": "GO"'), "'decision' appears twice"),
    "duplicate member in a measurement": (_sub(r'"outcome": "PASS"', '"outcome": "FAIL", "outcome": "PASS"'),
                                          "'outcome' appears twice"),
    "duplicate digest": (_sub(r'"digest": ', '"digest": "' + "0" * 64 + '", "digest": '), "'digest' appears twice"),
    "upper null -> 1e999": (_sub(r'"upper": null', '"upper": 1e999'), "outside the range of a double"),
    "upper null -> -1e999": (_sub(r'"upper": null', '"upper": -1e999'), "outside the range of a double"),
    "upper null -> NaN": (_sub(r'"upper": null', '"upper": NaN'), "NaN is not a JSON number"),
    "upper null -> Infinity": (_sub(r'"upper": null', '"upper": Infinity'), "Infinity is not a JSON number"),
    "upper null -> -Infinity": (_sub(r'"upper": null', '"upper": -Infinity'), "-Infinity is not a JSON number"),
    "lower 0.0 -> 1e-999 (underflows to the same value)": (_sub(r'"lower": 0\.0,', '"lower": 1e-999,'),
                                                           "underflows to zero"),
    "a 401-digit integer": (_sub(r'"upper": null', '"upper": 1' + "0" * 400), "outside ±(2**53 - 1)"),
    "a lone surrogate in a reason": (_sub(r'"reasons": \[\n    "', '"reasons": [\n    "\\\\ud800'),
                                     "lone UTF-16 surrogate"),
    "100 000 nested [": (lambda f: _write(f, "[" * 100_000), "more than 64 deep"),
    "a 17 MiB certificate": (lambda f: _write(f, " " * (17 * 2**20) + _text(f)), "more than the 16777216"),
    "text after the JSON value": (lambda f: _write(f, _text(f) + "{}"), "Extra data"),
    "digest removed": (lambda f: _write(f, json.dumps({k: v for k, v in json.loads(_text(f)).items()
                                                       if k != "integrity"})), "no digest"),
    "evidence hash replaced": (_sub(r'"sha256": "[0-9a-f]{64}",\n      "bytes"', '"sha256": "' + "0" * 64
                                    + '",\n      "bytes"'), "digest mismatch"),
    "certificate.json is a FIFO": (_cert_replaced(os.mkfifo), "is a FIFO"),
    "certificate.json -> /dev/zero": (_cert_replaced(lambda p: os.symlink("/dev/zero", p)), "character device"),
    # the evidence, with the digest recomputed (no key): the evidence checks refuse
    "evidence path ../../../../dev/zero": (_evidence_path("../../../../dev/zero"), "leaves the certificate folder"),
    "evidence path /dev/zero": (_evidence_path("/dev/zero"), "is absolute"),
    "evidence path records/./x": (_evidence_path("records/./00_energy_injection.h5"), "not normalized"),
    "evidence listed twice": (_resealed(lambda d: d["evidence"].append(d["evidence"][1])), "listed twice"),
    "record's evidence entry removed": (_resealed(lambda d: d["evidence"].pop(1)), "not in the evidence"),
    "record -> FIFO": (FIFO_RECORD, "is a FIFO"),
    "record -> symlink to /dev/zero": (_record_replaced(lambda rec, _: os.symlink("/dev/zero", rec)),
                                       "symbolic link"),
    "record -> symlink to an identical copy": (_record_replaced(lambda rec, keep: os.symlink(keep, rec)),
                                               "symbolic link"),
    "records/ -> symlink to a copy elsewhere": (_records_dir_linked, "symbolic link (records)"),
    "record -> a folder": (_record_replaced(lambda rec, _: rec.mkdir()), "is a folder"),
    "record: one bit flipped": (_flip_bit, "changed (sha256"),
    "record truncated": (_truncate, "bytes)"),
    "another scene's record left in records/": (_old_record_left, "records/00_chirp_locked.h5 is in the folder"),
    "FIFO record and a wrong digest": (_both(FIFO_RECORD, _sub(r'"decision": "NO-GO"', '"decision": "GO"')),
                                       "evidence files not checked"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_tampered_folder_is_refused_in_one_line(nogo_dir, tmp_path, case):
    edit, phrase = CASES[case]
    folder = tmp_path / "cert"
    shutil.copytree(nogo_dir, folder)
    edit(folder)
    code, out, err, seconds = _verify(folder)
    ANSWERED[case] = seconds
    lines = err.splitlines()
    assert code == 2 and out == "" and len(lines) == 1, (code, out, err)
    assert phrase in lines[0] and "Traceback" not in err and "internal error" not in err, lines[0]


#: signed certificates, checked with the signer's public key
SIGNED: dict[str, tuple[Callable[[Path], None], str]] = {
    "duplicate decision (with the key)": (DUP_BEFORE, "'decision' appears twice"),
    "upper null -> NaN (with the key)": (_sub(r'"upper": null', '"upper": NaN'), "NaN is not a JSON number"),
    "edited and resealed, signature kept": (_resealed(lambda d: d.update(decision="GO"), keep_signature=True),
                                            "signature"),
    "FIFO evidence and a wrong digest (with the key)": (
        _both(lambda f: os.mkfifo(f / "records.fifo"),
              _resealed(lambda d: d["evidence"].append({"path": "records.fifo", "sha256": "0" * 64, "bytes": 0,
                                                        "role": "record"})),
              _sub(r'"decision": "NO-GO"', '"decision": "GO"')), "digest mismatch"),
    "signature removed (with the key)": (_resealed(lambda d: None), "not signed"),
}


@pytest.mark.parametrize("case", list(SIGNED))
def test_a_tampered_signed_certificate_is_refused_with_the_key(signed_dir, keys, tmp_path, case):
    edit, phrase = SIGNED[case]
    folder = tmp_path / "cert"
    shutil.copytree(signed_dir, folder)
    code, _, _, _ = _verify(folder, "--public-key", str(keys["pub"]))
    assert code == 0  # the genuine one holds
    edit(folder)
    code, out, err, seconds = _verify(folder, "--public-key", str(keys["pub"]))
    ANSWERED[case] = seconds
    lines = err.splitlines()
    assert code == 2 and out == "" and len(lines) == 1, (code, out, err)
    assert phrase in lines[0] and "Traceback" not in err, lines[0]


def test_report_refuses_what_verify_refuses(nogo_dir, tmp_path):
    """``hil report`` reads through the same strict reader: the duplicate GO and the 1e999 bound
    are refused before anything is rendered ("≤ ∞" beside "signature HOLDS" was the symptom)."""
    for case in ("duplicate decision GO before the real one", "upper null -> 1e999"):
        folder = tmp_path / case.split()[0]
        shutil.copytree(nogo_dir, folder)
        before = (folder / "report.html").read_bytes()
        CASES[case][0](folder)
        p = subprocess.run([sys.executable, "-m", "hil", "report", str(folder), "--allow-modified"],
                           capture_output=True, text=True, timeout=HANG_S)
        assert p.returncode == 2 and len(p.stderr.splitlines()) == 1 and CASES[case][1] in p.stderr, p.stderr
        assert (folder / "report.html").read_bytes() == before


def test_the_genuine_folder_still_verifies_and_layout_is_free(nogo_dir, tmp_path):
    folder = tmp_path / "cert"
    shutil.copytree(nogo_dir, folder)
    code, out, err, _ = _verify(folder)
    assert code == 0 and out.startswith("OK ") and err == ""
    d = json.loads(_text(folder))  # re-indented, keys reversed, non-ASCII escaped: the same record
    _write(folder, json.dumps(dict(reversed(list(d.items()))), ensure_ascii=True))
    code, out, err, _ = _verify(folder)
    assert code == 0 and "2 evidence files match" in out, err


def test_answer_times(capsys):
    """Prints how long each refused case took (child start-up included), for the report."""
    if not ANSWERED:
        pytest.skip("run with the cases above")
    with capsys.disabled():
        worst = max(ANSWERED, key=ANSWERED.__getitem__)
        print(f"\nhil verify answered {len(ANSWERED)} tampered folders; slowest {ANSWERED[worst]:.2f} s ({worst})")
    assert all(s < HANG_S for s in ANSWERED.values())


# ---------------------------------------------------------------------------------------------
# the strict reader itself


@pytest.mark.parametrize(("text", "phrase"), [
    ('{"a": 1, "a": 1}', "'a' appears twice"),
    ('[{"b": {"c": 0, "c": 0}}]', "'c' appears twice"),
    ("[NaN]", "NaN is not"),
    ("[1e309]", "outside the range"),
    ("[-2e308]", "outside the range"),
    ("[4.9e-325]", "underflows"),
    (f"[{INT_LIMIT + 1}]", "outside ±(2**53 - 1)"),
    (f"[{-INT_LIMIT - 1}]", "outside ±(2**53 - 1)"),
    ('["\\udc80"]', "lone UTF-16 surrogate"),
    ('{"\\ud800": 1}', "lone UTF-16 surrogate"),
    ('"\\ud800"', "lone UTF-16 surrogate"),
    ("[" * 65 + "]" * 65, "more than 64 deep"),
    ("[" * 100_000, "more than 64 deep"),
    ('{"a": 1} x', "Extra data"),
])
def test_strict_json_refuses(text, phrase):
    with pytest.raises(StrictJsonError, match=re.escape(phrase)):
        loads(text)


def test_strict_json_keeps_what_has_one_meaning():
    deep = "[" * 63 + "]" * 63
    text = (f'{{"i": {INT_LIMIT}, "n": {-INT_LIMIT}, "z": 0.0, "m": -0.0, "e": 5e-324, '
            f'"big": 1.7976931348623157e308, "s": "\\ud834\\udd1e \\u00e9", "deep": {deep}}}')
    v = loads(text)
    assert v["i"] == 2**53 - 1 and v["n"] == -(2**53 - 1) and v["e"] == 5e-324 and v["big"] == sys.float_info.max
    assert str(v["m"]) == "-0.0" and v["s"] == "𝄞 é"
    assert v == json.loads(text)  # where the rules accept, the value is Python's own


def test_read_regular_file_refuses_fifos_devices_and_large_files(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(StrictJsonError, match="FIFO"):
        read_regular_file(fifo)  # returns: O_NONBLOCK opens without a writer, fstat refuses before a read
    with pytest.raises(StrictJsonError, match="character device"):
        read_regular_file("/dev/zero")
    big = tmp_path / "big"
    with open(big, "wb") as f:
        f.truncate(MAX_BYTES + 1)  # sparse: refused from its size, nothing read
    with pytest.raises(StrictJsonError, match="more than"):
        read_regular_file(big)
    (tmp_path / "ok").write_bytes(b"{}")
    assert read_regular_file(tmp_path / "ok") == b"{}"
