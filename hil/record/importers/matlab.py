"""MATLAB ``.mat`` files (the importer of format ``mat``): v4-v7.2 read with :func:`scipy.io.loadmat`,
v7.3 (HDF5 inside) with h5py (:mod:`hil.record.importers.matlab73`).

Sources are variables or ``struct.field``; a variable of shape (n, k) maps to a (k,) channel directly
and ``q[1]`` names its column 1 (from 0). Without a mapping, the time is the variable ``t`` or ``time``
and every other numeric variable of the same length is a channel (scalars such as gains and text are
left out); a file holding a single struct is read as its fields.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hil.record.hdf5 import RecordError
from hil.record.importers.base import Entry, Sampled, rate_of
from hil.record.importers.mapping import ImportMapping, default_mapping, split_index

logger = logging.getLogger(__name__)

__all__ = ["MatImporter", "read_mat"]


def _get_literal(variables: Mapping[str, Any], name: str, where: str) -> Any:
    obj: Any = variables
    for part in name.split("."):
        if not isinstance(obj, Mapping) or part not in obj:
            raise RecordError(f"{where}: no variable {name!r} (variables: {', '.join(_mat_names(variables))})")
        obj = obj[part]
    return obj


def _mat_get(variables: Mapping[str, Any], name: str, where: str) -> Any:
    """Variable or ``struct.field`` ``name``; ``q[i]``: column i of q when no variable is named so."""
    try:
        return _get_literal(variables, name, where)
    except RecordError:
        base, i = split_index(name)
        if i is None:
            raise
        a = np.asarray(_get_literal(variables, base, where), dtype=np.float64)
        cols = _as_columns(a, None, base, where)
        if cols.ndim != 2 or i >= cols.shape[1]:
            raise RecordError(f"{where}: {name!r}: variable {base!r} has shape {a.shape}, no column {i}") from None
        return cols[:, i]


def _mat_names(variables: Mapping[str, Any], prefix: str = "") -> list[str]:
    out = []
    for k, v in variables.items():
        if isinstance(v, Mapping):
            out += _mat_names(v, f"{prefix}{k}.")
        else:
            out.append(prefix + k)
    return out


def _as_columns(value: Any, n: int | None, name: str, where: str) -> np.ndarray:
    """A variable as (n,) or (n, k) float array (MATLAB row vectors and (k, n) matrices transposed)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise RecordError(f"{where}: variable {name!r} is not numeric") from None
    if a.ndim == 2 and 1 in a.shape:
        a = a.reshape(-1)
    if a.ndim == 2 and n is not None and a.shape[0] != n and a.shape[1] == n:
        a = a.T
    if a.ndim not in (1, 2) or (n is not None and a.shape[0] != n):
        raise RecordError(f"{where}: variable {name!r} has shape {a.shape}, expected ({n},) or ({n}, k)")
    return a



def read_mat(src: Path) -> tuple[dict[str, Any], str]:
    """The variables of a ``.mat`` file (structs as nested dicts) and its format: ``mat`` (v4-v7.2) or
    ``mat-v7.3`` (HDF5)."""
    from hil.record.importers.matlab73 import is_v73, read_v73

    if is_v73(src):
        return read_v73(src), "mat-v7.3"
    from scipy.io import loadmat  # lazy: scipy.io only for .mat files

    try:
        raw = loadmat(src, simplify_cells=True)
    except NotImplementedError as exc:  # an HDF5 .mat that h5py did not recognize
        raise RecordError(f"{src}: not a readable .mat file ({exc})") from None
    except PermissionError:
        raise RecordError(f"{src}: cannot read the .mat file (permission denied)") from None
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError, EOFError, struct.error ... on garbage
        raise RecordError(f"{src}: not a readable .mat file ({type(exc).__name__}: "
                          f"{' '.join(str(exc).split())[:200]})") from None
    return {k: v for k, v in raw.items() if not k.startswith("__")}, "mat"


def _numeric_vectors(top: Mapping[str, Any], n: int | None) -> list[str]:
    """Names of the variables of ``top`` that can be channels (numeric with ``n`` rows, or any numeric
    array with more than one element when ``n`` is None); scalars and text are left out."""
    out = []
    for k, v in top.items():
        if isinstance(v, (Mapping, str)):
            continue
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if a.size > 1 and (n is None or n in a.shape):
            out.append(k)
    return out


class MatImporter:
    """Format ``mat`` (module docstring)."""

    name = "mat"
    suffixes: tuple[str, ...] = (".mat",)
    extra: str | None = None
    time_required = True

    def __init__(self) -> None:
        self._cache: tuple[tuple[str, float], tuple[dict[str, Any], str]] | None = None

    def _load(self, path: Path) -> tuple[dict[str, Any], str]:
        key = (str(path.resolve()), path.stat().st_mtime)
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, read_mat(path))
        return self._cache[1]

    def claims(self, path: Path) -> bool:
        return path.suffix.lower() == ".mat" and not path.is_dir()

    def format_of(self, path: Path) -> str:
        return self._load(path)[1]

    def source_names(self, path: Path) -> list[str]:
        return _mat_names(self._load(path)[0])

    def default_mapping(self, path: Path) -> ImportMapping:
        variables = self._load(path)[0]
        where = str(path)
        top = variables
        if len(variables) == 1 and isinstance(next(iter(variables.values())), Mapping):
            top = next(iter(variables.values()))
        names = [k for k, v in top.items() if not isinstance(v, Mapping)]
        m = default_mapping(names, where, "variable")
        n = _as_columns(top[m.time], None, m.time, where).size
        keep = set(_numeric_vectors(top, n))
        dropped = [k for k, v in m.channels.items() if isinstance(v, str) and v not in keep]
        if dropped:
            logger.info("%s: not channels (scalars, text or another length): %s", where, ", ".join(dropped))
            m.channels = {k: v for k, v in m.channels.items() if k not in dropped}
        if top is not variables:
            prefix = next(iter(variables)) + "."
            m.time = prefix + m.time
            m.channels = {k: (prefix + v if isinstance(v, str) else [prefix + c for c in v])
                          for k, v in m.channels.items()}
        return m

    def inventory(self, path: Path) -> list[Entry]:
        variables = self._load(path)[0]
        out = []
        lower = {n.lower(): n for n in _mat_names(variables)}
        t_name = lower.get("t") or lower.get("time")
        rate = None
        if t_name is not None:
            try:
                tt = _as_columns(_mat_get(variables, t_name, str(path)), None, t_name, str(path))
                rate = rate_of(tt) if tt.ndim == 1 and np.all(np.diff(tt) > 0) else None
            except RecordError:
                rate = None
        for name in _mat_names(variables):
            v = _get_literal(variables, name, str(path))
            if isinstance(v, str):
                out.append(Entry(name, "text", note=repr(v[:40])))
                continue
            try:
                a = np.asarray(v, dtype=np.float64)
            except (TypeError, ValueError):
                out.append(Entry(name, "other"))
                continue
            rows = max(a.shape) if a.ndim else 1
            note = "time (default)" if name == t_name else ("scalar " + repr(float(a)) if a.size == 1 else "")
            out.append(Entry(name, "variable", rows, rate if a.size > 1 else None, tuple(a.shape), note=note))
        return out

    def read(self, path: Path, m: ImportMapping) -> Sampled:
        variables = self._load(path)[0]
        where = str(path)
        t = _as_columns(_mat_get(variables, m.time, where), None, m.time, where)
        if t.ndim != 1:
            raise RecordError(f"{where}: time variable {m.time!r} must be a vector, got shape {t.shape}")
        n = t.size
        data = {}
        for name, srcs in m.channels.items():
            if isinstance(srcs, str):
                a = _as_columns(_mat_get(variables, srcs, where), n, srcs, where)
            else:
                cols = [_as_columns(_mat_get(variables, s, where), n, s, where) for s in srcs]
                if any(c.ndim != 1 for c in cols):
                    raise RecordError(f"{where}: channel {name!r}: each listed variable must be a vector")
                a = np.column_stack(cols)
            data[name] = a
        return Sampled(t=t.copy(), data=data)
