"""Generic HDF5 files by dataset path (the importer of format ``hdf5``, h5py).

Sources are dataset paths (``/data/q``); ``/data/q[1]`` is column 1 (from 0) of a 2-D dataset. A
dataset of shape (n,) is a scalar channel, (n, k) a (k,) channel; a (k, n) dataset whose first axis does
not match the time's length is read transposed (column-major writers). The time is the dataset the
mapping names as ``t`` (``hil import --time /data/t``), else the one dataset whose name is ``t`` or
``time``. A string attribute ``units`` (or ``unit``) on a dataset is the unit the file states.

A record of the suite itself is HDF5 too (``/t``, ``/channels/<name>``): it needs no import, but can be
read this way.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from hil.record.hdf5 import RecordError
from hil.record.importers.base import Entry, Sampled, rate_of
from hil.record.importers.mapping import ImportMapping, split_index

logger = logging.getLogger(__name__)

__all__ = ["Hdf5Importer"]


def _datasets(path: Path) -> dict[str, tuple[tuple[int, ...], str, str]]:
    """Dataset path -> (shape, dtype, units attribute) of every dataset in the file."""
    import h5py

    found: dict[str, tuple[tuple[int, ...], str, str]] = {}

    def visit(name: str, obj: Any) -> None:
        if isinstance(obj, h5py.Dataset):
            u = obj.attrs.get("units", obj.attrs.get("unit", ""))
            u = u.decode() if isinstance(u, bytes) else str(u) if isinstance(u, str) else ""
            found["/" + name] = (tuple(obj.shape), str(obj.dtype), u)

    try:
        with h5py.File(path, "r") as f:
            f.visititems(visit)
    except OSError as exc:
        raise RecordError(f"{path}: not a readable HDF5 file ({' '.join(str(exc).split())[:160]})") from None
    return found


def _column(a: np.ndarray, n: int | None, name: str, where: str) -> np.ndarray:
    if a.ndim == 2 and 1 in a.shape and a.size > 1:
        a = a.reshape(-1)
    if a.ndim == 2 and n is not None and a.shape[0] != n and a.shape[1] == n:
        a = a.T
    if a.ndim not in (1, 2) or (n is not None and a.shape[0] != n):
        raise RecordError(f"{where}: dataset {name!r} has shape {a.shape}, expected ({n},) or ({n}, k)")
    return a


class Hdf5Importer:
    """Format ``hdf5`` (module docstring)."""

    name = "hdf5"
    suffixes: tuple[str, ...] = (".h5", ".hdf5", ".he5")
    extra: str | None = None
    time_required = False  # the default time is found by dataset name, not by the generic t/time rule

    def claims(self, path: Path) -> bool:
        return path.suffix.lower() in self.suffixes and not path.is_dir()

    def source_names(self, path: Path) -> list[str]:
        return sorted(_datasets(path))

    def default_mapping(self, path: Path) -> ImportMapping | None:
        return None

    def inventory(self, path: Path) -> list[Entry]:
        ds = _datasets(path)
        return [Entry(p, f"dataset {dtype}", shape[0] if shape else 1, None, shape, unit,
                      "time (default)" if p.rsplit("/", 1)[-1].lower() in ("t", "time") else "")
                for p, (shape, dtype, unit) in sorted(ds.items())]

    def _time_name(self, path: Path, m: ImportMapping, ds: dict[str, Any]) -> str:
        if m.time:
            return m.time if m.time.startswith("/") else "/" + m.time
        cands = [p for p in ds if p.rsplit("/", 1)[-1].lower() in ("t", "time")]
        if len(cands) != 1:
            why = "several candidates: " + ", ".join(cands) if cands else "no dataset named t or time"
            raise RecordError(f"{path}: name the time dataset with 'hil import --time /PATH' ({why})")
        logger.info("%s: time dataset %s (default)", path, cands[0])
        return cands[0]

    def read(self, path: Path, m: ImportMapping) -> Sampled:
        import h5py

        ds = _datasets(path)
        where = str(path)
        t_name = self._time_name(path, m, ds)
        m.time = t_name
        units: dict[str, str] = {}

        def get(f: Any, src: str, n: int | None) -> np.ndarray:
            p = src if src.startswith("/") else "/" + src
            if p in ds:
                return _column(np.asarray(f[p][()], dtype=np.float64), n, p, where)
            base, i = split_index(p)
            if i is None or base not in ds:
                raise RecordError(f"{where}: no dataset {p!r} (datasets: {', '.join(sorted(ds)) or 'none'})")
            a = _column(np.asarray(f[base][()], dtype=np.float64), n, base, where)
            if a.ndim != 2 or i >= a.shape[1]:
                raise RecordError(f"{where}: {src!r}: dataset {base!r} has shape {a.shape}, no column {i}")
            return a[:, i]

        try:
            with h5py.File(path, "r") as f:
                t = get(f, t_name, None)
                if t.ndim != 1:
                    raise RecordError(f"{where}: time dataset {t_name!r} must be a vector, got shape {t.shape}")
                data = {}
                for name in m.channels:
                    srcs = m.sources(name)
                    cols = [get(f, s, t.size) for s in srcs]
                    if len(cols) == 1:
                        data[name] = cols[0]
                    else:
                        if any(c.ndim != 1 for c in cols):
                            raise RecordError(f"{where}: channel {name!r}: each listed dataset must be a vector")
                        data[name] = np.column_stack(cols)
                    stated = {ds[s if s.startswith("/") else "/" + s][2] for s in srcs
                              if (s if s.startswith("/") else "/" + s) in ds}
                    if len(stated) == 1 and "" not in stated:
                        units[name] = stated.pop()
        except (TypeError, ValueError) as exc:
            raise RecordError(f"{where}: a mapped dataset is not numeric ({' '.join(str(exc).split())[:120]})") \
                from None
        if t.size >= 2 and np.all(np.diff(t) > 0):
            logger.debug("%s: %.6g Hz from %s", where, rate_of(t), t_name)
        return Sampled(t=t.copy(), data=data, units=units)
