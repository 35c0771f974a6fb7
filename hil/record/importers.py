"""Import runs recorded by other tools (CSV, MATLAB ``.mat``) into the run-record format of :mod:`hil.record.hdf5`.

Mapping (a dict, or a YAML/JSON *sidecar* file with the same content)::

    t: time                          # time column / variable [s] (after ``scale``); default t or time
    motor.position: pos              # scalar channel <- one column
    master.position: [q1, q2]        # vector channel (2,) <- several columns
    slave.position: {columns: [q3, q4], unit: rad, description: "...", scale: 0.001}
    units: {motor.position: rad, master.position: rad}      # optional
    descriptions: {motor.position: "encoder"}               # optional
    scale: {t: 0.001, motor.position: 0.0174533}            # optional factors to SI (e.g. ms -> s)
    rate_hz: 1000                                           # optional (default 1 / median dt)
    meta: {devices: {...}}                                  # optional, merged into the record meta

Channels may also be nested under a ``channels:`` key. In ``.mat`` files a name is a variable, or
``struct.field`` inside a struct; a variable of shape (n, k) maps to a (k,) channel directly.

Without a mapping, the CSV importer looks for a sidecar next to the file (``run.yaml``, ``run.yml``,
``run.json``, or ``run.csv.yaml``/``.yml``/``.json``); failing that the time column is ``t`` or ``time``
and every other column becomes a scalar channel of that name, except ``x[0]``, ``x[1]``, ... which
form the vector channel ``x`` (the layout :meth:`RunRecord.to_identify_dict` produces). The ``.mat``
importer does the same with the variables (or with the fields of the only struct in the file).

Time must be finite and strictly increasing, and sampled on a grid: every interval must be an integer
multiple of the median interval within ``max_jitter`` (fraction of it). Missing samples (gaps) are
accepted, logged and recorded as ``import.gap`` events (the identification package diagnoses gaps);
decreasing or repeated times and off-grid (variable-step) time raise :class:`~hil.record.hdf5.RecordError`.
Imported records have an empty scene text and scene hash and close with stop reason ``imported``.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hil.inputs import read_text_file
from hil.record.hdf5 import ChannelSpec, RecordError, RecordWriter

logger = logging.getLogger(__name__)

__all__ = ["import_csv", "import_mat"]

_RESERVED = {"t", "units", "descriptions", "scale", "meta", "rate_hz", "channels"}
_VECTOR_RE = re.compile(r"^(?P<name>.+)\[(?P<i>\d+)\]$")
_MAX_GAP_EVENTS = 100


@dataclass
class _Mapping:
    """A normalized mapping: time source, channel name -> source(s), units, descriptions, scales."""

    time: str
    channels: dict[str, str | list[str]]
    units: dict[str, str] = field(default_factory=dict)
    descriptions: dict[str, str] = field(default_factory=dict)
    scale: dict[str, float] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    rate_hz: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"t": self.time, **self.channels}


def _normalize(raw: Mapping[str, Any], where: str) -> _Mapping:
    if not isinstance(raw, Mapping):
        raise RecordError(f"{where}: mapping must be a dict, got {type(raw).__name__}")
    if "t" not in raw:
        raise RecordError(f"{where}: mapping needs 't' (the time column)")
    t = raw["t"]
    if isinstance(t, Mapping):  # {column: time_ms, scale: 0.001}
        t_col, t_scale = t.get("column"), t.get("scale")
    else:
        t_col, t_scale = t, None
    if not isinstance(t_col, str):
        raise RecordError(f"{where}: 't' must name one column, got {t_col!r}")
    chans_raw = raw.get("channels")
    if chans_raw is None:
        chans_raw = {k: v for k, v in raw.items() if k not in _RESERVED}
    elif not isinstance(chans_raw, Mapping):
        raise RecordError(f"{where}: 'channels' must be a dict")
    m = _Mapping(time=t_col, channels={})
    for key in ("units", "descriptions", "scale", "meta"):
        val = raw.get(key) or {}
        if not isinstance(val, Mapping):
            raise RecordError(f"{where}: {key!r} must be a dict")
        getattr(m, key).update(val)
    if t_scale is not None:
        m.scale["t"] = t_scale
    for name, src in chans_raw.items():
        if not isinstance(name, str) or not name or "/" in name:
            raise RecordError(f"{where}: bad channel name {name!r}")
        if isinstance(src, Mapping):
            cols = src.get("columns", src.get("column"))
            if "unit" in src:
                m.units[name] = str(src["unit"])
            if "description" in src:
                m.descriptions[name] = str(src["description"])
            if "scale" in src:
                m.scale[name] = src["scale"]
            src = cols
        if isinstance(src, str):
            m.channels[name] = src
        elif isinstance(src, Sequence) and src and all(isinstance(c, str) for c in src):
            m.channels[name] = list(src)
        else:
            raise RecordError(f"{where}: channel {name!r}: source must be a column name or a list of names, "
                              f"got {src!r}")
    for key, val in m.scale.items():
        try:
            m.scale[key] = float(val)
        except (TypeError, ValueError):
            raise RecordError(f"{where}: scale of {key!r} must be a number, got {val!r}") from None
    unknown = set(m.units) - set(m.channels)
    if unknown:
        raise RecordError(f"{where}: units given for unmapped channels {sorted(unknown)}")
    if raw.get("rate_hz") is not None:
        m.rate_hz = float(raw["rate_hz"])
    return m


def _with_default_time(mapping: Mapping[str, Any], names: Sequence[str], where: str) -> Mapping[str, Any]:
    """``mapping`` with ``t`` set to the ``t``/``time`` column (case-insensitive) when it names none
    (``hil import --map ...`` without ``--time``)."""
    if not isinstance(mapping, Mapping) or "t" in mapping:
        return mapping
    lower = {n.lower(): n for n in names}
    t_col = lower.get("t") or lower.get("time")
    if t_col is None:
        what = "variable" if where.lower().endswith(".mat") else "column"
        raise RecordError(f"{where}: the mapping names no time {what} and there is no 't' or 'time' {what} "
                          f"({what}s: {', '.join(names) or 'none'}); name it with 'hil import --time NAME' "
                          "(or 't:' in the mapping)")
    logger.info("%s: time %s %r (default)", where, "variable" if where.lower().endswith(".mat") else "column", t_col)
    return {"t": t_col, **mapping}


def _load_sidecar(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    if not p.exists():
        raise RecordError(f"{p}: no such sidecar file")
    text = read_text_file(p, "sidecar file", RecordError)
    try:
        data = json.loads(text) if p.suffix.lower() == ".json" else yaml.safe_load(text)
    except (ValueError, yaml.YAMLError) as exc:
        raise RecordError(f"{p}: cannot parse the sidecar ({' '.join(str(exc).split())})") from None
    if not isinstance(data, Mapping):
        raise RecordError(f"{p}: sidecar must hold a mapping")
    return dict(data)


def _find_sidecar(path: Path) -> Path | None:
    for cand in (path.with_suffix(".yaml"), path.with_suffix(".yml"), path.with_suffix(".json"),
                 path.with_name(path.name + ".yaml"), path.with_name(path.name + ".yml"),
                 path.with_name(path.name + ".json")):
        if cand != path and cand.is_file():
            return cand
    return None


def _default_mapping(names: Sequence[str], where: str) -> _Mapping:
    """Time column t/time; ``x[i]`` columns grouped into vector channel ``x``; others scalar."""
    lower = {n.lower(): n for n in names}
    t_col = lower.get("t") or lower.get("time")
    if t_col is None:
        what = "variable" if where.lower().endswith(".mat") else "column"
        raise RecordError(f"{where}: no 't' or 'time' {what} ({what}s: {', '.join(names) or 'none'}); name the time "
                          f"{what} with 'hil import --time NAME' (channels: --map CHANNEL=NAME) or put a sidecar "
                          "mapping file next to it")
    groups: dict[str, dict[int, str]] = {}
    chans: dict[str, str | list[str]] = {}
    for n in names:
        if n == t_col:
            continue
        mt = _VECTOR_RE.match(n)
        if mt:
            groups.setdefault(mt["name"], {})[int(mt["i"])] = n
        else:
            chans[n] = n
    for base, cols in groups.items():
        if sorted(cols) == list(range(len(cols))) and base not in chans:
            chans[base] = [cols[i] for i in range(len(cols))]
        else:
            chans.update({c: c for c in cols.values()})
    return _Mapping(time=t_col, channels=chans)


def _check_time(t: np.ndarray, where: str, max_jitter: float) -> tuple[float, list[tuple[float, int]]]:
    """Median interval [s] and the gaps (time [s], samples missing); raises on bad time."""
    if t.size < 2:
        raise RecordError(f"{where}: need at least 2 samples, got {t.size}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise RecordError(f"{where}: time is not finite at row {bad[0]} ({float(t[bad[0]])!r})")
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = int(bad[0])
        what = "repeats" if dt[i] == 0 else "decreases"
        raise RecordError(f"{where}: time {what} at row {i + 1}: {float(t[i])!r} s -> {float(t[i + 1])!r} s "
                          f"({bad.size} non-increasing step(s)); sort or clean the data first")
    med = float(np.median(dt))
    ratio = dt / med
    k = np.rint(ratio)
    off = np.flatnonzero(np.abs(ratio - k) > max_jitter)
    if off.size:
        i = int(off[0])
        raise RecordError(
            f"{where}: time is not uniformly sampled: interval {dt[i]:.6g} s at row {i + 1} is "
            f"{ratio[i]:.3f} x the median interval {med:.6g} s ({off.size} off-grid interval(s), tolerance "
            f"{max_jitter:g}); resample onto a uniform grid first")
    gaps = [(float(t[i]), int(k[i]) - 1) for i in np.flatnonzero(k > 1)]
    return med, gaps


#: sample rates [Hz] a device record plausibly has; outside them the import warns (the time column is
#: probably not in seconds), it does not refuse
PLAUSIBLE_RATE_HZ = (10.0, 1.0e6)


def _write(out: str | Path, t: np.ndarray, data: dict[str, np.ndarray], m: _Mapping, src: Path, fmt: str,
           meta: Mapping[str, Any] | None, max_jitter: float) -> Path:
    where = str(src)
    t = t * m.scale.get("t", 1.0)
    med, gaps = _check_time(t, where, max_jitter)
    rate = m.rate_hz if m.rate_hz is not None else 1.0 / med
    if not PLAUSIBLE_RATE_HZ[0] <= rate <= PLAUSIBLE_RATE_HZ[1]:
        hint = (" (a time column in milliseconds? scale it to seconds: 'scale: {t: 0.001}' in the sidecar mapping)"
                if rate < PLAUSIBLE_RATE_HZ[0] else " (a time column in microseconds or ticks? scale it to seconds)")
        logger.warning("%s: the time column gives %.4g Hz, an implausible sample rate for a device record%s",
                       where, rate, hint)
    if gaps:
        logger.warning("%s: %d gap(s) in time, %d sample(s) missing in all", where, len(gaps),
                       sum(g[1] for g in gaps))
    specs = {name: ChannelSpec(tuple(a.shape[1:]), m.units.get(name, ""), m.descriptions.get(name, ""))
             for name, a in data.items()}
    digest = hashlib.sha256(src.read_bytes()).hexdigest()
    full_meta = {**m.meta, **dict(meta or {})}
    full_meta["imported_from"] = {"format": fmt, "path": str(src.resolve()), "sha256": digest,
                                  "mapping": m.as_dict(), "gaps": len(gaps)}
    out = Path(out)
    with RecordWriter(out, scene_text="", scene_sha256="", meta=full_meta, channels=specs, rate_hz=rate) as w:
        w.append_block(t, data)
        for tg, missing in gaps[:_MAX_GAP_EVENTS]:
            w.event(tg, "import.gap", f"{missing} sample(s) missing after t = {tg!r} s")
        if len(gaps) > _MAX_GAP_EVENTS:
            w.event(float(t[-1]), "import.gap", f"{len(gaps) - _MAX_GAP_EVENTS} more gap(s) not listed")
        w.close(stop_reason="imported", status="ok")
    logger.info("imported %s (%s, %d samples, %d channels) -> %s", src, fmt, t.size, len(data), out)
    return out


# ------------------------------------------------------------------------------------------------- CSV


def _read_csv(path: Path, delimiter: str | None) -> tuple[list[str], np.ndarray]:
    text = read_text_file(path, "CSV file", RecordError)
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise RecordError(f"{path}: empty CSV")
    header_line = lines[0][1]
    if delimiter is None:
        counts = {d: header_line.count(d) for d in (",", ";", "\t")}
        delimiter = max(counts, key=lambda d: counts[d]) if any(counts.values()) else ","
    header = [h.strip() for h in next(csv.reader(io.StringIO(header_line), delimiter=delimiter))]
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise RecordError(f"{path}: duplicate column names {dup}")
    rows = np.empty((len(lines) - 1, len(header)))
    reader = csv.reader((ln for _, ln in lines[1:]), delimiter=delimiter)
    for r, cells in enumerate(reader):
        lineno = lines[r + 1][0]
        if len(cells) != len(header):
            raise RecordError(f"{path}:{lineno}: {len(cells)} fields, header has {len(header)}")
        for c, cell in enumerate(cells):
            cell = cell.strip()
            if not cell or cell.lower() in ("nan", "na", "null"):
                rows[r, c] = np.nan
                continue
            try:
                rows[r, c] = float(cell)
            except ValueError:
                raise RecordError(f"{path}:{lineno}: column {header[c]!r}: {cell!r} is not a number") from None
    return header, rows


def import_csv(
    path: str | Path,
    out: str | Path,
    *,
    mapping: Mapping[str, Any] | None = None,
    sidecar: str | Path | None = None,
    meta: Mapping[str, Any] | None = None,
    delimiter: str | None = None,
    max_jitter: float = 0.1,
) -> Path:
    """Convert a CSV run (header row, one sample per row) into a run record at ``out``; return ``out``.

    ``mapping`` (or the ``sidecar`` YAML/JSON file with the same content, or one found next to the CSV)
    names the time column and the columns of each channel (module docstring). ``meta`` is merged into
    the record meta. ``delimiter``: ``,`` ``;`` or tab (guessed from the header by default).
    ``max_jitter``: tolerated deviation of a time interval from a multiple of the median interval
    (fraction of it)."""
    src = Path(path)
    if src.is_dir():
        raise RecordError(f"{src}: is a folder, not a CSV file")
    if not src.is_file():
        raise RecordError(f"{src}: no such file")
    header, rows = _read_csv(src, delimiter)
    m = _resolve_mapping(src, mapping, sidecar, header)
    col = {h: i for i, h in enumerate(header)}

    def get(name: str, channel: str) -> np.ndarray:
        if name not in col:
            raise RecordError(f"{src}: channel {channel!r}: no column {name!r} (columns: {', '.join(header)})")
        return rows[:, col[name]]

    t = get(m.time, "t").copy()
    data = {}
    for name, cols in m.channels.items():
        a = get(cols, name) if isinstance(cols, str) else np.column_stack([get(c, name) for c in cols])
        data[name] = a * m.scale.get(name, 1.0)
    return _write(out, t, data, m, src, "csv", meta, max_jitter)


def _resolve_mapping(src: Path, mapping: Mapping[str, Any] | None, sidecar: str | Path | None,
                     names: Sequence[str]) -> _Mapping:
    if mapping is not None and sidecar is not None:
        raise RecordError(f"{src}: give mapping or sidecar, not both")
    if mapping is not None:
        return _normalize(_with_default_time(mapping, names, str(src)), f"{src}: mapping")
    if sidecar is None:
        sidecar = _find_sidecar(src)
        if sidecar is not None:
            logger.info("%s: using sidecar %s", src, sidecar)
    if sidecar is not None:
        return _normalize(_load_sidecar(sidecar), str(sidecar))
    return _default_mapping(names, str(src))


# ------------------------------------------------------------------------------------------------- MAT


def _mat_get(variables: Mapping[str, Any], name: str, where: str) -> Any:
    obj: Any = variables
    for part in name.split("."):
        if not isinstance(obj, Mapping) or part not in obj:
            raise RecordError(f"{where}: no variable {name!r} (variables: {', '.join(_mat_names(variables))})")
        obj = obj[part]
    return obj


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


def import_mat(
    path: str | Path,
    out: str | Path,
    *,
    mapping: Mapping[str, Any] | None = None,
    meta: Mapping[str, Any] | None = None,
    max_jitter: float = 0.1,
) -> Path:
    """Convert a MATLAB ``.mat`` (v4-v7.2, read with :func:`scipy.io.loadmat`) run into a record at ``out``.

    ``mapping``: as for :func:`import_csv`, naming variables or ``struct.field``; without one, a sidecar
    next to the file, else the variables (or the fields of the only struct) with ``t``/``time`` as time."""
    from scipy.io import loadmat  # lazy: scipy.io only for .mat files

    src = Path(path)
    if src.is_dir():
        raise RecordError(f"{src}: is a folder, not a .mat file")
    if not src.is_file():
        raise RecordError(f"{src}: no such file")
    try:
        raw = loadmat(src, simplify_cells=True)
    except NotImplementedError as exc:  # v7.3 files are HDF5
        raise RecordError(f"{src}: MATLAB v7.3 files are not supported; save with -v7 ({exc})") from None
    except PermissionError:
        raise RecordError(f"{src}: cannot read the .mat file (permission denied)") from None
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError, EOFError, struct.error ... on garbage
        raise RecordError(f"{src}: not a readable .mat file ({type(exc).__name__}: "
                          f"{' '.join(str(exc).split())[:200]})") from None
    variables = {k: v for k, v in raw.items() if not k.startswith("__")}
    where = str(src)
    if mapping is None:
        side = _find_sidecar(src)
        if side is not None:
            m = _normalize(_load_sidecar(side), str(side))
        else:
            top = variables
            if len(variables) == 1 and isinstance(next(iter(variables.values())), Mapping):
                top = next(iter(variables.values()))
            m = _default_mapping([k for k, v in top.items() if not isinstance(v, Mapping)], where)
            if top is not variables:
                prefix = next(iter(variables)) + "."
                m.time = prefix + m.time
                m.channels = {k: (prefix + v if isinstance(v, str) else [prefix + c for c in v])
                              for k, v in m.channels.items()}
    else:
        m = _normalize(_with_default_time(mapping, _mat_names(variables), where), f"{where}: mapping")
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
        data[name] = a * m.scale.get(name, 1.0)
    return _write(out, t.copy(), data, m, src, "mat", meta, max_jitter)
