"""``hil verify DIR``: is this certificate what ``hil certify`` wrote, and do its files still match?

Three checks, each answered in the one output line:

1. **digest** -- ``integrity.digest`` against the SHA-256 of the certificate's canonical content
   (``hil-c14n/1``, :func:`hil.certify.certificate.content_digest`): any edited value (a decision changed
   from NO-GO to GO, a measurement, a reason, an evidence hash) or a removed digest fails;
2. **evidence** -- every file in ``evidence`` (run records, the scene text), relative to the
   certificate's folder, is present with the recorded size and SHA-256;
3. **signature** (with ``--public-key PUB``) -- ``integrity.signature`` was made by that key over
   the recorded digest (:func:`hil.certify.signing.verify_signature`; needs the ``sign`` extra).

``hil verify`` (hil.cli.main) exits 0 with one line ``OK …`` (:func:`ok_summary`) on stdout, or 2 with one
line on stderr naming what does not match. :func:`check_certificate` is the library form (``hil
report`` uses it to refuse or mark a modified certificate); :func:`file_evidence` hashes a file for
the certificate (``hil.certify.pipeline``).
"""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from hil.certify.certificate import Certificate, Evidence, content_digest
from hil.certify.signing import verify_signature
from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["IntegrityStatus", "VerifyError", "check_certificate", "check_evidence", "file_evidence", "file_sha256",
           "ok_summary"]

MODIFIED = "MODIFIED: NOT A VALID CERTIFICATE"
_CHUNK = 1 << 20


class VerifyError(HilError):
    """Bad input to ``hil verify`` (one-line message)."""


def file_sha256(path: str | os.PathLike[str]) -> tuple[str, int]:
    """(hex SHA-256, size in bytes) of a file, read in 1 MiB chunks."""
    h = hashlib.sha256()
    n = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
            n += len(chunk)
    return h.hexdigest(), n


def file_evidence(folder: str | os.PathLike[str], path: str | os.PathLike[str],
                  role: Literal["record", "scene"]) -> Evidence:
    """An evidence entry for ``path`` (a closed file), its path relative to ``folder`` (POSIX)."""
    p = Path(path)
    digest, size = file_sha256(p)
    rel = Path(os.path.relpath(p.resolve(), Path(folder).resolve())).as_posix()
    return Evidence(path=rel, sha256=digest, bytes=size, role=role)


def check_evidence(cert: Certificate, folder: str | os.PathLike[str]) -> list[str]:
    """One problem per evidence file that is missing or differs (empty when all match)."""
    base = Path(folder)
    problems: list[str] = []
    for ev in cert.evidence:
        if Path(ev.path).is_absolute():
            problems.append(f"evidence path {ev.path} is absolute (paths are relative to the certificate folder)")
            continue
        p = base / ev.path
        try:
            digest, size = file_sha256(p)
        except FileNotFoundError:
            problems.append(f"{ev.role} {ev.path} is missing")
            continue
        except IsADirectoryError:
            problems.append(f"{ev.role} {ev.path} is a folder, not a file")
            continue
        except OSError as exc:
            problems.append(f"{ev.role} {ev.path} cannot be read: {exc.strerror or exc}")
            continue
        if digest != ev.sha256 or size != ev.bytes:
            sizes = f", {ev.bytes} -> {size} bytes" if size != ev.bytes else ""
            problems.append(f"{ev.role} {ev.path} changed (sha256 {ev.sha256[:12]}… recorded, "
                            f"{digest[:12]}… now{sizes})")
        if ev.role == "scene" and ev.sha256 != cert.scene.sha256:
            problems.append(f"scene {ev.path}: its recorded sha256 differs from scene.sha256")
    return problems


@dataclass
class IntegrityStatus:
    """What a certificate's integrity checks found (digest always; evidence and signature when asked)."""

    recorded_digest: str | None
    computed_digest: str
    evidence_checked: bool = False
    evidence_problems: list[str] = field(default_factory=list)
    n_evidence: int = 0
    signature: Literal["absent", "unchecked", "valid", "invalid"] = "absent"
    signature_detail: str = ""
    signer: str = ""
    key_fingerprint: str = ""
    signed_utc: str = ""
    verified_with: str = ""

    @property
    def digest_ok(self) -> bool:
        return self.recorded_digest is not None and self.recorded_digest == self.computed_digest

    @property
    def valid(self) -> bool:
        """The digest matches, no evidence file differs, and no checked signature failed."""
        return self.digest_ok and not self.evidence_problems and self.signature != "invalid"

    def digest_problem(self) -> str:
        if self.recorded_digest is None:
            return "no digest: the certificate has no integrity block, so its content cannot be checked"
        if not self.digest_ok:
            return (f"digest mismatch: the content no longer matches its recorded digest "
                    f"(recorded {self.recorded_digest[:16]}…, content {self.computed_digest[:16]}…)")
        return ""

    def problems(self) -> list[str]:
        out = [p for p in [self.digest_problem()] if p]
        out += self.evidence_problems
        if self.signature == "invalid":
            out.append(f"signature: {self.signature_detail}")
        return out

    def reason(self) -> str:
        """All problems in one line ('' when valid)."""
        return "; ".join(self.problems())

    def signature_text(self) -> str:
        """A sentence on who signed and whether the signature holds (for reports)."""
        if self.signature == "absent":
            return "not signed (hil certify --sign KEY signs the digest with an Ed25519 key)"
        who = f"signed by {self.signer}" if self.signer else "signed (no signer name given)"
        who += f" with Ed25519 key {self.key_fingerprint} on {self.signed_utc}"
        if self.signature == "valid":
            return f"{who}: the signature HOLDS (checked with {self.verified_with})"
        if self.signature == "invalid":
            return f"{who}: the signature DOES NOT HOLD ({self.signature_detail})"
        return f"{who}: the signature was not checked (give the signer's public key: hil verify DIR --public-key PUB)"


def check_certificate(cert: Certificate, folder: str | os.PathLike[str] | None = None,
                      public_key: Any = None, *, verified_with: str | None = None) -> IntegrityStatus:
    """Check the digest; the evidence files too when ``folder`` is given; the signature too when
    ``public_key`` (a :class:`hil.certify.signing.VerifyKey`) is given. ``verified_with`` names the key in
    the report (default: its file)."""
    integ = cert.integrity
    st = IntegrityStatus(recorded_digest=None if integ is None else integ.digest,
                         computed_digest=content_digest(cert), n_evidence=len(cert.evidence))
    if folder is not None:
        st.evidence_checked = True
        st.evidence_problems = check_evidence(cert, folder)
    sig = None if integ is None else integ.signature
    if sig is not None:
        st.signer, st.key_fingerprint, st.signed_utc = sig.signer, sig.public_key_sha256, sig.signed_utc
        st.signature = "unchecked"
    if public_key is not None:
        ok, detail = verify_signature(cert, public_key)
        st.signature = "valid" if ok else "invalid"
        st.signature_detail = detail
        st.verified_with = verified_with or f"public key {public_key.path}"
    return st


def ok_summary(st: IntegrityStatus) -> str:
    """The ``OK`` line's account of a valid certificate: digest, evidence files, signature."""
    parts = [f"digest {st.computed_digest[:16]}… matches",
             f"{st.n_evidence} evidence file{'s match' if st.n_evidence != 1 else ' matches'}"]
    if st.signature == "valid":
        parts.append(f"signature holds ({'signer ' + st.signer + ', ' if st.signer else ''}"
                     f"key {st.key_fingerprint[:16]}…)")
    elif st.signature == "unchecked":
        parts.append(f"signed{' by ' + st.signer if st.signer else ''} (key {st.key_fingerprint[:16]}…), "
                     "signature not checked: give --public-key PUB")
    else:
        parts.append("not signed")
    return ", ".join(parts)
