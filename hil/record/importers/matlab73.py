"""MATLAB v7.3 ``.mat`` files: HDF5 inside, read with h5py.

MATLAB (``save -v7.3``) writes a 512-byte user block starting with ``MATLAB 7.3 MAT-file`` and then an
HDF5 file: one dataset per variable at the root, one group per struct (its fields inside), each with a
``MATLAB_class`` attribute (``double``, ``single``, ``int16``, ``logical``, ``char``, ``struct``,
``cell``, ...). MATLAB arrays are column-major, so an ``n x k`` variable is an HDF5 dataset of shape
``(k, n)``: the reader transposes every dataset that carries a ``MATLAB_class`` back to MATLAB's shape
(a column vector ``n x 1`` comes back as ``(n, 1)``). Datasets without that attribute (an HDF5 file
written by another tool and named ``.mat``) are read as stored.

Read: numeric and logical arrays (as float64 by the importer), ``char`` as text, structs as nested dicts.
Left out, with a log line: cell arrays and struct arrays (object references), complex arrays, empty
arrays (``MATLAB_empty``), and MATLAB's internal groups (``#refs#``, ``#subsystem#``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from hil.record.hdf5 import RecordError

logger = logging.getLogger(__name__)

__all__ = ["is_v73", "read_v73"]

_NUMERIC = {"double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "logical"}


def is_v73(path: Path) -> bool:
    """True when ``path`` is an HDF5 file (a MATLAB v7.3 ``.mat`` has its HDF5 superblock at byte 512)."""
    import h5py

    try:
        return bool(h5py.is_hdf5(str(path)))
    except OSError:
        return False


def _class(obj: Any) -> str | None:
    c = obj.attrs.get("MATLAB_class")
    if c is None:
        return None
    return c.decode() if isinstance(c, bytes) else str(c)


def _read_group(group: Any, prefix: str, skipped: list[str]) -> dict[str, Any]:
    import h5py

    out: dict[str, Any] = {}
    for name, obj in group.items():
        if name.startswith("#"):  # #refs#, #subsystem#: MATLAB's storage of cells and objects
            continue
        path = prefix + name
        cls = _class(obj)
        if isinstance(obj, h5py.Group):
            out[name] = _read_group(obj, path + ".", skipped)
            continue
        if obj.attrs.get("MATLAB_empty", 0) or obj.dtype.kind in ("O", "V") or obj.dtype.names:
            skipped.append(f"{path} ({cls or obj.dtype})")  # empty, cell/struct array refs, complex
            continue
        if cls == "char":
            out[name] = "".join(map(chr, np.asarray(obj[()]).T.ravel()))
            continue
        if cls is not None and cls not in _NUMERIC:
            skipped.append(f"{path} ({cls})")
            continue
        a = np.asarray(obj[()])
        out[name] = a.T if cls is not None else a  # MATLAB is column-major: back to MATLAB's shape
    return out


def read_v73(path: Path) -> dict[str, Any]:
    """The variables of a v7.3 ``.mat`` file (module docstring); raises :class:`RecordError` when the
    file is not readable HDF5."""
    import h5py

    skipped: list[str] = []
    try:
        with h5py.File(path, "r") as f:
            out = _read_group(f, "", skipped)
    except OSError as exc:
        raise RecordError(f"{path}: not a readable MATLAB v7.3 (HDF5) file ({' '.join(str(exc).split())[:160]})") \
            from None
    if skipped:
        logger.info("%s: variables not read (cell, struct array, complex or empty): %s", path, ", ".join(skipped))
    return out
