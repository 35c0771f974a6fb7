"""Optional Ed25519 signatures of certificates (``hil certify --sign KEY``, ``hil verify --public-key PUB``,
``hil keygen --out DIR``).

The signature covers the certificate's digest (``integrity.digest``, see :mod:`hil.certify.certificate`)
together with who signed: the signed message is the ``hil-c14n/1`` canonical JSON of ::

    {"context": "hil-certify certificate signature v1", "digest": <hex>,
     "public_key_sha256": <hex>, "signer": <name>, "signed_utc": <ISO time>}

so neither the certificate's content nor the recorded signer, key fingerprint or signing time can
change without the signature failing. Keys are PEM files: the private key PKCS#8 (unencrypted,
file mode 0600), the public key SubjectPublicKeyInfo; the fingerprint is the SHA-256 (hex) of the
raw 32-byte public key.

The ``cryptography`` package (extra ``sign``) is imported only when a key is used; without it every
entry point raises :class:`SigningError` with one line naming the extra.
"""

from __future__ import annotations

import base64
import datetime as _dt
import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.certify.certificate import Certificate, Signature, canonical_json, content_digest
from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = [
    "PRIVATE_NAME",
    "PUBLIC_NAME",
    "SigningError",
    "SigningKey",
    "VerifyKey",
    "fingerprint",
    "generate_keypair",
    "load_private_key",
    "load_public_key",
    "sign_certificate",
    "signed_message",
    "verify_signature",
]

CONTEXT = "hil-certify certificate signature v1"
PRIVATE_NAME = "hil_signing_key.pem"
PUBLIC_NAME = "hil_signing_key.pub.pem"
MISSING = "signing needs the 'cryptography' package: pip install 'hil-certify[sign]'"


class SigningError(HilError):
    """A key could not be read or written, or signing is unavailable (one-line message)."""


def _crypto() -> Any:
    """The ``cryptography`` Ed25519 and serialization modules (lazily; one line when missing)."""
    try:
        from cryptography.hazmat.primitives import serialization
        from cryptography.hazmat.primitives.asymmetric import ed25519
    except ImportError:
        raise SigningError(MISSING) from None
    return ed25519, serialization


def _raw_public(pub: Any) -> bytes:
    _, ser = _crypto()
    return pub.public_bytes(ser.Encoding.Raw, ser.PublicFormat.Raw)


def fingerprint(raw_public_key: bytes) -> str:
    """Hex SHA-256 of a raw 32-byte Ed25519 public key."""
    return hashlib.sha256(raw_public_key).hexdigest()


@dataclass(frozen=True)
class VerifyKey:
    """An Ed25519 public key read from ``path``."""

    key: Any
    path: str

    @property
    def raw(self) -> bytes:
        return _raw_public(self.key)

    @property
    def fingerprint(self) -> str:
        return fingerprint(self.raw)


@dataclass(frozen=True)
class SigningKey:
    """An Ed25519 private key read from ``path``."""

    key: Any
    path: str

    def public(self) -> VerifyKey:
        return VerifyKey(self.key.public_key(), self.path)


def _read(path: str | os.PathLike[str], what: str) -> bytes:
    p = Path(path)
    try:
        return p.read_bytes()
    except FileNotFoundError:
        raise SigningError(f"{p}: no such {what} file") from None
    except IsADirectoryError:
        raise SigningError(f"{p}: is a folder, not a {what} file") from None
    except OSError as exc:
        raise SigningError(f"{p}: cannot read: {exc.strerror or exc}") from None


def load_private_key(path: str | os.PathLike[str]) -> SigningKey:
    """Read an unencrypted Ed25519 private key (PEM, as ``hil keygen`` writes it)."""
    ed25519, ser = _crypto()
    data = _read(path, "private key")
    try:
        key = ser.load_pem_private_key(data, password=None)
    except TypeError:
        raise SigningError(f"{path}: the private key is encrypted; give an unencrypted Ed25519 key "
                           "(hil keygen writes one, readable by its owner only)") from None
    except Exception as exc:  # cryptography raises ValueError / UnsupportedAlgorithm
        if "PUBLIC KEY" in data.decode("ascii", "replace"):
            raise SigningError(f"{path}: this is a public key; --sign needs the private key") from None
        raise SigningError(f"{path}: not a PEM private key ({type(exc).__name__})") from None
    if not isinstance(key, ed25519.Ed25519PrivateKey):
        raise SigningError(f"{path}: not an Ed25519 key ({type(key).__name__.lstrip('_')})")
    return SigningKey(key, str(path))


def load_public_key(path: str | os.PathLike[str]) -> VerifyKey:
    """Read an Ed25519 public key (PEM SubjectPublicKeyInfo, as ``hil keygen`` writes it)."""
    ed25519, ser = _crypto()
    data = _read(path, "public key")
    try:
        key = ser.load_pem_public_key(data)
    except Exception as exc:  # ValueError / UnsupportedAlgorithm
        if "PRIVATE KEY" in data.decode("ascii", "replace"):
            raise SigningError(f"{path}: this is a private key; --public-key needs the public key "
                               "(keep the private key secret)") from None
        raise SigningError(f"{path}: not a PEM public key ({type(exc).__name__})") from None
    if not isinstance(key, ed25519.Ed25519PublicKey):
        raise SigningError(f"{path}: not an Ed25519 public key ({type(key).__name__.lstrip('_')})")
    return VerifyKey(key, str(path))


def generate_keypair(out_dir: str | os.PathLike[str]) -> tuple[Path, Path]:
    """Write a new Ed25519 key pair into ``out_dir`` (created if missing): the private key
    ``hil_signing_key.pem`` with mode 0600 and the public key ``hil_signing_key.pub.pem``.
    Refuses to overwrite either file. Returns (private, public) paths."""
    ed25519, ser = _crypto()
    d = Path(out_dir)
    priv_p, pub_p = d / PRIVATE_NAME, d / PUBLIC_NAME
    for p in (priv_p, pub_p):
        if p.exists() or p.is_symlink():
            raise SigningError(f"{p}: already exists; refusing to overwrite a key (choose another --out)")
    if d.exists() and not d.is_dir():
        raise SigningError(f"{d}: exists and is not a folder")
    try:
        d.mkdir(parents=True, exist_ok=True, mode=0o700)
    except OSError as exc:
        raise SigningError(f"{d}: cannot create the folder: {exc.strerror or exc}") from None
    key = ed25519.Ed25519PrivateKey.generate()
    priv = key.private_bytes(ser.Encoding.PEM, ser.PrivateFormat.PKCS8, ser.NoEncryption())
    pub = key.public_key().public_bytes(ser.Encoding.PEM, ser.PublicFormat.SubjectPublicKeyInfo)
    try:
        fd = os.open(priv_p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(priv)
        os.chmod(priv_p, 0o600)  # whatever the umask
        fd = os.open(pub_p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        with os.fdopen(fd, "wb") as f:
            f.write(pub)
    except FileExistsError as exc:
        raise SigningError(f"{exc.filename}: already exists; refusing to overwrite a key") from None
    except OSError as exc:
        raise SigningError(f"{d}: cannot write the key files: {exc.strerror or exc}") from None
    logger.info("wrote %s (private, 0600) and %s", priv_p, pub_p)
    return priv_p, pub_p


def signed_message(digest: str, public_key_sha256: str, signer: str, signed_utc: str) -> bytes:
    """The bytes an Ed25519 signature covers (see the module docstring)."""
    return canonical_json({"context": CONTEXT, "digest": digest, "public_key_sha256": public_key_sha256,
                           "signer": signer, "signed_utc": signed_utc})


def sign_certificate(cert: Certificate, key: SigningKey, signer: str = "") -> Certificate:
    """A copy of a sealed ``cert`` with ``integrity.signature`` over its digest. Raises
    :class:`SigningError` if the certificate is not sealed or its digest does not match."""
    if cert.integrity is None:
        raise SigningError("the certificate has no digest to sign (seal it first)")
    digest = content_digest(cert)
    if digest != cert.integrity.digest:
        raise SigningError("the certificate does not match its digest; refusing to sign it")
    pub = key.public()
    fp = pub.fingerprint
    when = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    sig = key.key.sign(signed_message(digest, fp, signer, when))
    signature = Signature(public_key=base64.b64encode(pub.raw).decode("ascii"), public_key_sha256=fp, signer=signer,
                          signed_utc=when, value=base64.b64encode(sig).decode("ascii"))
    return cert.model_copy(update={"integrity": cert.integrity.model_copy(update={"signature": signature})})


def verify_signature(cert: Certificate, key: VerifyKey) -> tuple[bool, str]:
    """Check ``integrity.signature`` with a trusted public key: (holds, one-line reason).

    The signature holds when it was made by ``key`` (same fingerprint) over the certificate's
    *recorded* digest; whether that digest matches the content is checked separately."""
    _crypto()
    from cryptography.exceptions import InvalidSignature

    integ = cert.integrity
    if integ is None or integ.signature is None:
        return False, "the certificate is not signed"
    s = integ.signature
    fp = key.fingerprint
    if s.public_key_sha256 != fp:
        return False, (f"signed with key {s.public_key_sha256[:16]}…, not with the given public key "
                       f"{key.path} ({fp[:16]}…)")
    try:
        sig = base64.b64decode(s.value, validate=True)
    except ValueError:
        return False, "the signature value is not base64"
    try:
        key.key.verify(sig, signed_message(integ.digest, s.public_key_sha256, s.signer, s.signed_utc))
    except InvalidSignature:
        return False, f"the signature does not verify with {key.path} (digest, signer or time changed after signing)"
    return True, f"signature holds for key {fp[:16]}… ({key.path})"
