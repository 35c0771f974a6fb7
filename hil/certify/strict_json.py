"""Reading a certificate's JSON text so that every text has exactly one meaning (docs/INTEGRITY.md,
"Reading a certificate").

The digest (``hil-c14n/1``, :mod:`hil.certify.certificate`) is computed from the *validated* record,
so it protects a certificate only if every reader derives the same record from the same text. JSON
as RFC 8259 allows leaves that room: duplicate member names (Python keeps the last, other readers
the first), literals outside the double range (``1e999`` reads as infinity here, as ``null`` in the
canonical form), ``NaN`` / ``Infinity`` tokens (not JSON, accepted by Python), lone UTF-16
surrogates. A certificate is therefore read as I-JSON (RFC 7493) and a little stricter:

* no member name twice in one object (:class:`StrictJsonError` names it);
* numbers: no ``NaN`` / ``Infinity`` / ``-Infinity``; a number with a fraction or exponent must be
  a finite double that does not underflow to zero (``1e999``, ``1e-999`` refused); an integer must
  lie in ±(2**53 − 1), where every double reader reads it exactly;
* strings (member names included) are Unicode scalar values: no lone surrogate;
* at most :data:`MAX_DEPTH` nested arrays/objects and :data:`MAX_BYTES` bytes (a text of 100 000
  ``[`` is refused in one line: the parser stops at the interpreter's recursion limit, and the
  parsed value is walked without recursion);
* the file is opened without blocking and must be a regular file (a FIFO, ``/dev/zero`` or a
  terminal is refused before any read), and at most :data:`MAX_BYTES` + 1 bytes are read.

:func:`read_regular_file` is that bounded read; :func:`loads` the parse. Both raise
:class:`StrictJsonError` (a :class:`~hil.errors.HilError`, exit 2) with a one-line message; callers
prefix the file's path.
"""

from __future__ import annotations

import logging
import math
import os
import re
import stat
from pathlib import Path
from typing import Any

from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["INT_LIMIT", "MAX_BYTES", "MAX_DEPTH", "StrictJsonError", "file_kind", "loads", "read_regular_file"]

#: largest certificate text read, in bytes (the built-in scenes' certificates are 50-400 kB)
MAX_BYTES = 16 * 2**20
#: deepest nesting of arrays and objects accepted (a certificate nests about 8 deep)
MAX_DEPTH = 64
#: largest integer magnitude (I-JSON, RFC 7493 section 2.2: exact in every IEEE double reader)
INT_LIMIT = 2**53 - 1

_NONZERO_DIGIT = re.compile(r"[1-9]")


class StrictJsonError(HilError, ValueError):
    """A text or file that is not a certificate's strict JSON (one-line message, no path)."""


def file_kind(mode: int) -> str:
    """What a ``st_mode`` names, in words ("a FIFO", "a character device", ...)."""
    for test, word in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISLNK, "a symbolic link")):
        if test(mode):
            return word
    return "not a regular file"


def read_regular_file(path: str | os.PathLike[str], limit: int = MAX_BYTES) -> bytes:
    """The bytes of ``path``, which must be a regular file of at most ``limit`` bytes.

    Opened with ``O_NONBLOCK | O_NOCTTY`` (opening a FIFO does not wait for a writer, a terminal
    does not become the controlling one), checked with ``fstat`` before the first read, and read
    to at most ``limit`` + 1 bytes (a file that grows while it is read is still bounded). Raises
    :class:`StrictJsonError` for anything else; ``FileNotFoundError`` / ``PermissionError`` pass
    through for the caller's wording."""
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
    fd = os.open(path, flags)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise StrictJsonError(f"is {file_kind(st.st_mode)}, not a regular file")
        if st.st_size > limit:
            raise StrictJsonError(f"is {st.st_size} bytes, more than the {limit} a certificate may have")
        chunks: list[bytes] = []
        n = 0
        while n <= limit:
            chunk = os.read(fd, min(1 << 20, limit + 1 - n))
            if not chunk:
                break
            chunks.append(chunk)
            n += len(chunk)
        if n > limit:
            raise StrictJsonError(f"grew past {limit} bytes while it was read")
        return b"".join(chunks)
    finally:
        os.close(fd)


def _no_constant(token: str) -> Any:
    raise StrictJsonError(f"{token} is not a JSON number (a certificate holds only finite numbers)")


def _float(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise StrictJsonError(f"number {_short(text)} is outside the range of a double")
    if v == 0.0 and _NONZERO_DIGIT.search(text.split("e")[0].split("E")[0]):
        raise StrictJsonError(f"number {_short(text)} underflows to zero")
    return v


def _int(text: str) -> int:
    if len(text.lstrip("-")) > 16 or abs(int(text)) > INT_LIMIT:
        raise StrictJsonError(f"integer {_short(text)} is outside ±(2**53 - 1), where every reader reads it exactly")
    return int(text)


def _short(text: str) -> str:
    return text if len(text) <= 24 else f"{text[:20]}…({len(text)} characters)"


def _check_str(s: str) -> None:
    try:
        s.encode("utf-8")
    except UnicodeEncodeError:
        raise StrictJsonError(f"string {s[:24]!r} holds a lone UTF-16 surrogate (not a Unicode character)") from None


def _pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise StrictJsonError(f"member {k!r} appears twice in one object (readers disagree on which counts)")
        _check_str(k)
        if isinstance(v, str):
            _check_str(v)
        out[k] = v
    return out


def _walk(value: Any, max_depth: int) -> None:
    """Depth of nesting and the strings inside arrays (object members are checked as they are
    parsed), without recursion."""
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        v, d = stack.pop()
        if d > max_depth:
            raise StrictJsonError(f"nests arrays/objects more than {max_depth} deep (the most a certificate may)")
        items = v if isinstance(v, list) else v.values()
        for x in items:
            if isinstance(x, list | dict):
                stack.append((x, d + 1))
            elif isinstance(x, str) and isinstance(v, list):
                _check_str(x)


def loads(text: str, *, max_depth: int = MAX_DEPTH) -> Any:
    """Parse ``text`` under the rules of the module docstring; :class:`StrictJsonError` otherwise
    (``json.JSONDecodeError`` wording, with line and column, for text that is not JSON at all).

    The depth is bounded twice: the parser itself stops at the interpreter's recursion limit
    (``RecursionError``, turned into the same one-line error), and the parsed value is walked
    without recursion before anything else reads it."""
    import json

    if len(text) > MAX_BYTES:
        raise StrictJsonError(f"is {len(text)} characters, more than the {MAX_BYTES} a certificate may have")
    try:
        value = json.loads(text, object_pairs_hook=_pairs, parse_constant=_no_constant, parse_float=_float,
                           parse_int=_int)
    except json.JSONDecodeError as exc:
        raise StrictJsonError(f"not valid JSON: line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except RecursionError:
        raise StrictJsonError(f"nests arrays/objects more than {max_depth} deep (the most a certificate may)") from None
    if isinstance(value, str):
        _check_str(value)
    elif isinstance(value, list | dict):
        _walk(value, max_depth)
    return value


def read_json_file(path: str | os.PathLike[str], *, what: str = "certificate") -> Any:
    """:func:`read_regular_file` + UTF-8 (a BOM dropped) + :func:`loads`, errors prefixed with the path."""
    p = Path(path)
    try:
        raw = read_regular_file(p)
        if b"\x00" in raw:
            raise StrictJsonError(f"binary data (NUL bytes), not a text {what}")
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise StrictJsonError(f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start})") from None
        return loads(text)
    except StrictJsonError as exc:
        raise StrictJsonError(f"{p}: {exc}") from None
    except FileNotFoundError:
        raise StrictJsonError(f"{p}: no such file") from None
    except OSError as exc:
        raise StrictJsonError(f"{p}: cannot read the {what}: {exc.strerror or exc}") from None
