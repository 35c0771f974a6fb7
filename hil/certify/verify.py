"""``hil verify DIR``: is this certificate what ``hil certify`` wrote, and do its files still match?

The certificate is read strictly (:mod:`hil.certify.strict_json`: a bounded regular file, no
duplicate member, only finite numbers, bounded depth), then three checks, in this order, each
answered in the one output line:

1. **digest** -- ``integrity.digest`` against the SHA-256 of the certificate's canonical content
   (``hil-c14n/1``, :func:`hil.certify.certificate.content_digest`): any edited value (a decision changed
   from NO-GO to GO, a measurement, a reason, an evidence hash) or a removed digest fails;
2. **signature** (with ``--public-key PUB``) -- ``integrity.signature`` was made by that key over
   the recorded digest (:func:`hil.certify.signing.verify_signature`; needs the ``sign`` extra); an
   unsigned certificate fails;
3. **evidence** -- only when 1 and 2 hold (the evidence list of a modified certificate is not
   followed): every file in ``evidence`` (run records, the scene text) is a regular file inside the
   certificate's folder, reached without a symbolic link, with the recorded size and SHA-256, and
   every run record in ``records/`` is listed. No read blocks (FIFOs and devices are refused from
   ``lstat``, before any open) and none goes past the recorded size.

``hil verify`` (hil.cli.main) exits 0 with one line ``OK …`` (:func:`ok_summary`) on stdout, or 2 with one
line on stderr naming what does not match. :func:`check_certificate` is the library form (``hil
report`` uses it to refuse or mark a modified certificate); :func:`file_evidence` hashes a file for
the certificate (``hil.certify.pipeline``).
"""

from __future__ import annotations

import hashlib
import logging
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from hil.certify.certificate import Certificate, Evidence, content_digest
from hil.certify.signing import verify_signature
from hil.certify.strict_json import file_kind
from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["IntegrityStatus", "VerifyError", "check_certificate", "check_evidence", "file_evidence", "file_sha256",
           "ok_summary"]

MODIFIED = "MODIFIED: NOT A VALID CERTIFICATE"
_CHUNK = 1 << 20
#: the folder of run records inside a certificate folder
RECORDS = "records"


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


def _evidence_parts(path: str) -> list[str] | str:
    """The components of an evidence path, or why it is not a plain relative POSIX path inside the
    folder (absolute, ``..``, ``.``, empty components, backslashes, NUL)."""
    if not path:
        return "is empty"
    if path.startswith("/"):
        return "is absolute (paths are relative to the certificate folder)"
    if "\\" in path or "\0" in path:
        return "holds a backslash or NUL (a POSIX path relative to the certificate folder is expected)"
    parts = path.split("/")
    if any(p in ("", ".", "..") for p in parts):
        return "leaves the certificate folder or is not normalized ('..', '.' or '//'): evidence must lie inside it"
    return parts


def _open_evidence(base_fd: int, parts: list[str]) -> int:
    """A descriptor of the regular file ``parts`` under ``base_fd``, reached without following any
    symbolic link and without opening anything that is not a folder or a regular file (a FIFO, a
    device node or a socket is refused from ``lstat``, before any open). Raises ``_Refused``."""
    fds: list[int] = []
    cur = base_fd
    try:
        for i, name in enumerate(parts):
            last = i == len(parts) - 1
            try:
                st = os.stat(name, dir_fd=cur, follow_symlinks=False)
            except FileNotFoundError:
                raise _Refused("is missing") from None
            except NotADirectoryError:
                raise _Refused(f"is missing ({'/'.join(parts[:i])} is not a folder)") from None
            where = "" if last else f" ({'/'.join(parts[:i + 1])})"
            if stat.S_ISLNK(st.st_mode):
                raise _Refused(f"is reached through a symbolic link{where}: evidence must be regular files inside "
                               "the certificate folder")
            if last and not stat.S_ISREG(st.st_mode):
                raise _Refused(f"is {file_kind(st.st_mode)}, not a regular file")
            if not last and not stat.S_ISDIR(st.st_mode):
                raise _Refused(f"is missing ({'/'.join(parts[:i + 1])} is not a folder)")
            flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK | os.O_NOCTTY
            fd = os.open(name, flags | (0 if last else os.O_DIRECTORY), dir_fd=cur)
            fds.append(fd)
            now = os.fstat(fd)
            if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino) or (last and not stat.S_ISREG(now.st_mode)):
                raise _Refused("was replaced while it was opened")
            cur = fd
        return fds.pop()
    except OSError as exc:
        raise _Refused(f"cannot be read: {exc.strerror or exc}") from None
    finally:
        for fd in fds:
            os.close(fd)


class _Refused(Exception):
    """Why one evidence file cannot be checked (a phrase: 'is missing', 'is a FIFO ...')."""


def _hash_fd(fd: int, size: int) -> tuple[str, int]:
    """SHA-256 of at most ``size`` + 1 bytes of ``fd`` and how many were read (bounded even if the
    file grows while it is read)."""
    h = hashlib.sha256()
    n = 0
    while n <= size:
        chunk = os.read(fd, min(_CHUNK, size + 1 - n))
        if not chunk:
            break
        h.update(chunk)
        n += len(chunk)
    return h.hexdigest(), n


def check_evidence(cert: Certificate, folder: str | os.PathLike[str]) -> list[str]:
    """One problem per evidence file that is missing, differs, or is not a regular file inside
    ``folder``, plus run records in ``folder/records`` the evidence does not list (empty when all
    match).

    Nothing outside ``folder`` is opened, no symbolic link is followed, nothing but folders and
    regular files is opened, and no file is read past its recorded size + 1 byte (a size that
    differs from the recorded one is reported from ``fstat`` without reading): a FIFO, a device
    or a link to one answers at once."""
    problems: list[str] = []
    try:
        base_fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError as exc:
        return [f"the certificate folder {folder} cannot be read: {exc.strerror or exc}"]
    seen: set[str] = set()
    try:
        for ev in cert.evidence:
            parts = _evidence_parts(ev.path)
            if isinstance(parts, str):
                problems.append(f"{ev.role} {ev.path!r}: the path {parts}")
                continue
            if ev.path in seen:
                problems.append(f"{ev.role} {ev.path} is listed twice in the evidence")
                continue
            seen.add(ev.path)
            try:
                fd = _open_evidence(base_fd, parts)
            except _Refused as why:
                problems.append(f"{ev.role} {ev.path} {why}")
                continue
            try:
                size = os.fstat(fd).st_size
                if size != ev.bytes:
                    problems.append(f"{ev.role} {ev.path} changed ({ev.bytes} -> {size} bytes)")
                    continue
                digest, n = _hash_fd(fd, ev.bytes)
            except OSError as exc:
                problems.append(f"{ev.role} {ev.path} cannot be read: {exc.strerror or exc}")
                continue
            finally:
                os.close(fd)
            if digest != ev.sha256 or n != ev.bytes:
                sizes = f", {ev.bytes} -> {n} bytes" if n != ev.bytes else ""
                problems.append(f"{ev.role} {ev.path} changed (sha256 {ev.sha256[:12]}… recorded, "
                                f"{digest[:12]}… now{sizes})")
            if ev.role == "scene" and ev.sha256 != cert.scene.sha256:
                problems.append(f"scene {ev.path}: its recorded sha256 differs from scene.sha256")
        problems += _unlisted_records(base_fd, seen)
    finally:
        os.close(base_fd)
    return problems


def _unlisted_records(base_fd: int, listed: set[str]) -> list[str]:
    """Run records (``records/*.h5``) in the folder that the evidence does not list: a record left
    from another certificate, or one an edit removed from the evidence."""
    try:
        st = os.stat(RECORDS, dir_fd=base_fd, follow_symlinks=False)
    except OSError:
        return []
    if not stat.S_ISDIR(st.st_mode):  # a link or a file named records: the listed entries say so
        return []
    fd = os.open(RECORDS, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=base_fd)
    try:
        names = sorted(os.listdir(fd))
    finally:
        os.close(fd)
    extra = [f"{RECORDS}/{n}" for n in names if n.endswith(".h5") and f"{RECORDS}/{n}" not in listed]
    return [f"record {p} is in the folder but not in the evidence" for p in extra]


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
    evidence_skipped: str = ""

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
        if self.evidence_skipped and out:
            out.append(self.evidence_skipped)
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
    """Check the digest; the signature too when ``public_key`` (a :class:`hil.certify.signing.VerifyKey`)
    is given (an unsigned certificate then fails); the evidence files in ``folder`` too when it is
    given, but only once the digest and any checked signature hold: the evidence list of a
    certificate that is not what was sealed is not followed (``evidence_skipped`` says why).
    ``verified_with`` names the key in the report (default: its file)."""
    integ = cert.integrity
    st = IntegrityStatus(recorded_digest=None if integ is None else integ.digest,
                         computed_digest=content_digest(cert), n_evidence=len(cert.evidence))
    sig = None if integ is None else integ.signature
    if sig is not None:
        st.signer, st.key_fingerprint, st.signed_utc = sig.signer, sig.public_key_sha256, sig.signed_utc
        st.signature = "unchecked"
    if public_key is not None:
        if sig is None:
            ok, detail = False, "the certificate is not signed"
        else:
            ok, detail = verify_signature(cert, public_key)
        st.signature = "valid" if ok else "invalid"
        st.signature_detail = detail
        st.verified_with = verified_with or f"public key {public_key.path}"
    if folder is not None:
        if st.digest_ok and st.signature != "invalid":
            st.evidence_checked = True
            st.evidence_problems = check_evidence(cert, folder)
        else:
            st.evidence_skipped = "evidence files not checked: the certificate itself does not hold"
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
