"""The run record's format, shared by its writer (:mod:`hil.record.hdf5`) and its reader
(:mod:`hil.record.reader`): the format name and version, the byte-log datasets, the errors, the channel
specification, the JSON encoding of results (numeric arrays stored apart) and the check of an HDF5 file
before HDF5 opens it. The file layout is documented in :mod:`hil.record.hdf5`."""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import functools
import json
import logging
import math
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["FORMAT", "FORMAT_VERSION", "ChannelSpec", "RecordError", "RecordWriteError"]

FORMAT = "hil-record"
FORMAT_VERSION = 2
_DATASET_KEY = "__dataset__"
_MAX_CHUNK_BYTES = 1 << 20  # 1 MiB per HDF5 chunk at most
_MIN_CHUNK_ROWS = 1024


class RecordError(HilError):
    """A run record cannot be written or read (bad channel, shape, time, file, ...)."""


class RecordWriteError(RecordError):
    """Writing a record failed (disk full, file-size limit, IO error). The message is one line; the
    samples flushed before the failure stay readable."""


#: byte-log datasets (uint8, resizable) -> (chunk bytes, ``encoding`` attribute). All are created
#: with the file, so nothing is ever created after SWMR mode is on; each is appended to only.
_BYTE_LOGS: dict[str, tuple[int, str]] = {
    "events": (4096, "utf-8 JSON lines"),
    "results": (4096, "utf-8 JSON lines {experiment, results, arrays}"),
    "results_npy": (8192, "concatenated .npy arrays; offsets in /results"),
    "device_counters": (1024, "utf-8 JSON lines {t, counters}"),
}
#: size of the fixed ``/status`` dataset [bytes]: written in place at close, so closing never grows the file
_STATUS_BYTES = 1024
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"

def _one_line(exc: BaseException | str) -> str:
    """An exception's message on one line (HDF5 messages can span several)."""
    text = str(exc) if not isinstance(exc, str) else exc
    text = " ".join(text.split())
    return text[:300] + ("..." if len(text) > 300 else "")

def _probe_hdf5(p: Path) -> tuple[bool, int | None]:
    """Check that ``p`` looks like a complete HDF5 file before HDF5 sees it. Returns (swmr, end):
    ``swmr`` True when its superblock says it is (or was, for a killed writer) open for SWMR
    writing; ``end`` the end-of-file address it stores [bytes] (None when undefined).

    Why: HDF5 refuses a truncated file in normal read mode, but in SWMR-read mode (needed for a
    record whose writer was killed) it skips that check and retries every metadata read that fails
    its checksum (100 attempts with back-off, inside the C library: minutes, deaf to Ctrl-C). So the
    stored end-of-file address is compared with the real size here, and SWMR mode is used only for
    files flagged for it."""
    try:
        size = p.stat().st_size
        with p.open("rb") as fh:
            head = fh.read(96)
    except OSError as exc:
        raise RecordError(f"{p}: cannot read: {_one_line(exc.strerror or exc)}") from None
    if size == 0:
        raise RecordError(f"{p}: empty file, not a run record")
    if head[:8] != _HDF5_SIGNATURE:
        raise RecordError(f"{p}: not an HDF5 file (no HDF5 signature at the start)")
    if len(head) < 48:
        raise RecordError(f"{p}: truncated HDF5 file ({size} bytes, shorter than its superblock)")
    version = head[8]
    if version in (0, 1):
        osize, flags_at = head[13], None
        base_at = 24 + (4 if version == 1 else 0)
        eof_at = base_at + 2 * osize
    elif version in (2, 3):
        osize, flags_at = head[9], 11
        base_at = 12
        eof_at = base_at + 2 * osize
    else:
        raise RecordError(f"{p}: unknown HDF5 superblock version {version}")
    if osize not in (2, 4, 8) or len(head) < eof_at + osize:
        raise RecordError(f"{p}: malformed HDF5 superblock (size of offsets {osize})")
    base = int.from_bytes(head[base_at:base_at + osize], "little")
    eof = int.from_bytes(head[eof_at:eof_at + osize], "little")
    undefined = (1 << (8 * osize)) - 1
    end = None if undefined in (eof, base) else base + eof
    if end is not None and size < end:
        raise RecordError(f"{p}: truncated HDF5 file ({size} bytes, its superblock says {end})")
    return flags_at is not None and version == 3 and bool(head[flags_at] & 0b101), end


#: metadata read attempts in SWMR-read mode (HDF5's default is 100, each failed checksum retried with a
#: back-off, so a damaged killed file takes minutes per object; a live writer needs only a few)
_SWMR_READ_ATTEMPTS = 8


@functools.cache
def _hdf5_library() -> Any:
    """The libhdf5 that h5py is linked to (ctypes handle), or None when it cannot be located (then
    HDF5's default number of read attempts applies)."""
    candidates: list[str] = []
    with contextlib.suppress(OSError):  # Linux: the copy already mapped into this process (h5py wheels)
        for line in Path("/proc/self/maps").read_text().splitlines():
            name = line.rsplit(" ", 1)[-1]
            if re.search(r"/libhdf5(-[0-9a-f]+)?\.so", name) and name not in candidates:
                candidates.append(name)
    # no ctypes.util.find_library fallback: another copy of libhdf5 than h5py's would not know its ids
    for name in candidates:
        try:
            lib = ctypes.CDLL(name)
            fn = lib.H5Pset_metadata_read_attempts
        except (OSError, AttributeError):
            continue
        fn.argtypes = [ctypes.c_int64, ctypes.c_uint]
        fn.restype = ctypes.c_int
        return lib
    return None


def _open_h5_read(p: Path, swmr: bool) -> h5py.File:
    """Open ``p`` read-only without file locking (a reader never waits for, nor blocks, a writer);
    in SWMR-read mode with at most :data:`_SWMR_READ_ATTEMPTS` metadata read attempts."""
    if not swmr:
        return h5py.File(p, "r", locking=False)
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_libver_bounds(h5py.h5f.LIBVER_LATEST, h5py.h5f.LIBVER_LATEST)
    fapl.set_file_locking(False, True)
    fapl.set_fclose_degree(h5py.h5f.CLOSE_STRONG)
    lib = _hdf5_library()
    if lib is None or lib.H5Pset_metadata_read_attempts(fapl.id, _SWMR_READ_ATTEMPTS) < 0:
        logger.debug("cannot limit HDF5 metadata read attempts (libhdf5 not found)")
    fid = h5py.h5f.open(os.fsencode(p), h5py.h5f.ACC_RDONLY | h5py.h5f.ACC_SWMR_READ, fapl=fapl)
    return h5py.File(fid)


def _json_lines(raw: bytes, p: Path, what: str) -> list[dict[str, Any]]:
    """The JSON objects of a UTF-8 JSON-lines log; an incomplete last line (a killed writer) is skipped."""
    out = []
    for line in raw.decode("utf-8", errors="replace").splitlines():
        if not line.strip("\x00 "):
            continue
        try:
            obj = json.loads(line)
        except json.JSONDecodeError:
            logger.warning("%s: skipped an unreadable %s line %r", p, what, line[:80])
            continue
        if isinstance(obj, dict):
            out.append(obj)
    return out


@dataclass(frozen=True)
class ChannelSpec:
    """One recorded channel: per-sample ``shape`` (``()`` for a scalar), SI ``unit``, free ``description``."""

    shape: tuple[int, ...]
    unit: str
    description: str = ""

    def __post_init__(self) -> None:
        shape = tuple(int(d) for d in self.shape)
        if any(d < 1 for d in shape):
            raise RecordError(f"channel shape {self.shape} must have positive dimensions")
        object.__setattr__(self, "shape", shape)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, set | frozenset):
        return sorted(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def _to_json(obj: Any, what: str) -> str:
    try:
        return json.dumps(obj, default=_json_default, ensure_ascii=False)
    except (TypeError, ValueError) as exc:
        raise RecordError(f"{what} is not JSON-serializable: {exc}") from None


def _check_name(name: str, what: str) -> str:
    if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
        raise RecordError(f"{what} name {name!r} must be a non-empty string without '/'")
    return name


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _jsonable(obj: Any) -> Any:
    """Replace non-finite floats by None (strict JSON for ``--json``)."""
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float):
        return _finite_or_none(obj)
    return obj


def _split_arrays(obj: Any, path: tuple[str, ...], arrays: dict[str, np.ndarray]) -> Any:
    """JSON-able copy of ``obj``; numeric numpy arrays (and complex numbers) go to ``arrays`` by path."""
    if not isinstance(obj, Mapping | np.ndarray) and callable(getattr(obj, "to_dict", None)):
        obj = obj.to_dict()  # result objects that know their dict form
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {str(k): _split_arrays(v, (*path, str(k)), arrays) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_split_arrays(v, (*path, str(i)), arrays) for i, v in enumerate(obj)]
    if isinstance(obj, complex | np.complexfloating) or (
        isinstance(obj, np.ndarray) and obj.dtype.kind in "biufc" and (obj.ndim > 0 or obj.dtype.kind == "c")
    ):
        parts = [re.sub(r"[/.]", "_", p) or "_" for p in path] or ["_"]
        key = "/".join(parts)
        base, i = key, 1
        while key in arrays or any(k.startswith(key + "/") or key.startswith(k + "/") for k in arrays):
            key, i = f"{base}~{i}", i + 1
        arrays[key] = np.asarray(obj)
        return {_DATASET_KEY: key}
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if obj is None or isinstance(obj, bool | int | float | str):
        return obj
    if isinstance(obj, Path):
        return str(obj)
    raise RecordError(f"result {'/'.join(path) or '<root>'}: {type(obj).__name__} is not JSON-serializable")


def _indexed(array: Callable[[Any], Any], index: Mapping[str, Any], key: str) -> Any:
    """``array(index[key])`` (a ``get`` for :func:`_join_arrays`)."""
    return array(index[key])


def _join_arrays(obj: Any, get: Callable[[str], Any]) -> Any:
    """Inverse of :func:`_split_arrays`: ``get(key)`` returns the array stored under ``key``."""
    if isinstance(obj, dict):
        if set(obj) == {_DATASET_KEY}:
            arr = get(obj[_DATASET_KEY])
            return arr[()] if isinstance(arr, h5py.Dataset) else arr
        return {k: _join_arrays(v, get) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_join_arrays(v, get) for v in obj]
    return obj


