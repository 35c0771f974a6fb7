"""Reading run records: :class:`RunRecord` (also a record whose writer was killed or is still
writing: SWMR read) and the lateness view of ``hil replay`` (:func:`lateness_distribution`). The
file layout and the reading rules are documented in :mod:`hil.record.hdf5`."""

from __future__ import annotations

import functools
import io
import json
import logging
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hil.record.format import (
    _BYTE_LOGS,
    FORMAT,
    FORMAT_VERSION,
    RecordError,
    _indexed,
    _join_arrays,
    _json_lines,
    _one_line,
    _open_h5_read,
    _probe_hdf5,
)

logger = logging.getLogger(__name__)

__all__ = ["LATENESS_BINS_S", "RunRecord", "lateness_distribution"]


def _attr_str(v: Any) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def _check_lengths(p: Path, lengths: Mapping[str, int], closed: bool, attrs: Mapping[str, Any]) -> None:
    """Every channel is as long as the time column: exactly in a closed record; in a record whose
    writer was killed (SWMR), within the rows of two flushes (a flush cut short is read up to its
    shortest dataset). A channel cut short beyond that -- a damaged or edited record -- is refused in
    one line, never silently truncated to (e.g. half its length)."""
    nt = lengths["t"]
    rate = float(attrs.get("rate_hz", math.nan))
    every = float(attrs.get("flush_every_s", 0.1) or 0.1)
    slack = 0 if closed else (2 * max(1, round(rate * every)) if math.isfinite(rate) and rate > 0 else nt)
    for name, n in lengths.items():
        if abs(n - nt) > slack:
            state = "closed" if closed else "unclosed"
            raise RecordError(f"{p}: channel {name} has {n} samples but the time column {nt}: a damaged or "
                              f"altered record ({state}; at most {slack} may differ)")


@dataclass
class RunRecord:
    """A run record loaded into memory. ``stop_reason``/``status`` are None when the run never closed."""

    path: Path
    meta: dict[str, Any]
    scene_text: str
    scene_sha256: str
    stop_reason: str | None
    status: str | None
    t: np.ndarray
    channels: dict[str, np.ndarray]
    units: dict[str, str]
    events: list[dict[str, Any]]
    results: dict[str, Any]
    descriptions: dict[str, str] = field(default_factory=dict)
    rate_hz: float = math.nan
    attrs: dict[str, Any] = field(default_factory=dict)
    #: per-device fault counters, the writer's last snapshot: device -> counter -> count
    device_counters: dict[str, dict[str, int]] = field(default_factory=dict)

    @property
    def closed(self) -> bool:
        """True when the writer closed the record (False: killed / still running)."""
        return self.status is not None

    @classmethod
    def open(cls, path: str | Path) -> RunRecord:
        """Read a record (also one whose writer was killed, or is still writing: SWMR read).

        Fails fast with a one-line :class:`RecordError` naming the file for a missing, empty,
        truncated or non-HDF5 file, a directory, or a file that is not a run record."""
        p = Path(path)
        if p.is_dir():
            raise RecordError(f"{p}: is a directory, not a run record")
        if not p.is_file():
            raise RecordError(f"{p}: no such file")
        swmr, _ = _probe_hdf5(p)
        try:
            f = _open_h5_read(p, swmr)  # swmr: a file left "open for SWMR write" (killed or live writer)
        except (OSError, RuntimeError, ValueError) as exc:
            raise RecordError(f"{p}: not a readable HDF5 file ({_one_line(exc)})") from None
        try:
            with f:
                return cls._load(p, f)
        except RecordError:
            raise
        except (OSError, RuntimeError, KeyError, ValueError, TypeError, IndexError, AttributeError) as exc:
            raise RecordError(f"{p}: malformed run record ({_one_line(exc)})") from None

    @classmethod
    def _load(cls, p: Path, f: h5py.File) -> RunRecord:
        attrs = {k: (_attr_str(v) if isinstance(v, bytes | str) else v) for k, v in f.attrs.items()}
        if attrs.get("format") != FORMAT:
            raise RecordError(f"{p}: not a {FORMAT} file (format attribute {attrs.get('format')!r})")
        if int(attrs.get("format_version", 0)) > FORMAT_VERSION:
            raise RecordError(f"{p}: format_version {attrs['format_version']} is newer than this reader")
        g = f["channels"]
        names = list(g)
        if f.swmr_mode:
            for name in ("t", *(n for n in _BYTE_LOGS if isinstance(f.get(n), h5py.Dataset))):
                f[name].refresh()
            for name in names:
                g[name].refresh()
        lengths = {"t": f["t"].shape[0], **{k: g[k].shape[0] for k in names}}
        n = min(lengths.values())
        t = np.array(f["t"][:n])
        # keep the longest prefix of finite, strictly increasing times: a flush cut short (kill, full
        # disk) may leave rows whose time was never written (NaN fill, or zeros past the end of file)
        ok = np.isfinite(t)
        ok[1:] &= np.diff(t) > 0
        bad = np.flatnonzero(~ok)
        if bad.size:
            n = int(bad[0])
            t = t[:n]
        channels = {k: np.array(g[k][:n]) for k in names}
        units = {k: _attr_str(g[k].attrs.get("unit", "")) for k in names}
        descr = {k: _attr_str(g[k].attrs.get("description", "")) for k in names}
        events = _json_lines(bytes(f["events"][:]), p, "event")

        results: dict[str, Any] = {}
        stop_reason = status = None
        counters: dict[str, dict[str, int]] = {}
        if isinstance(f.get("results"), h5py.Group):  # format_version 1: a group per experiment
            for exp, rg in f["results"].items():
                results[exp] = _join_arrays(json.loads(_attr_str(rg.attrs["json"])), rg.__getitem__)
        elif isinstance(f.get("results"), h5py.Dataset):
            npy = f["results_npy"]

            def array(ref: Any) -> np.ndarray:
                off, size = int(ref[0]), int(ref[1])
                return np.load(io.BytesIO(bytes(npy[off:off + size])), allow_pickle=False)

            for line in _json_lines(bytes(f["results"][:]), p, "results"):
                index: dict[str, Any] = line.get("arrays", {})
                get = functools.partial(_indexed, array, index)
                results[str(line["experiment"])] = _join_arrays(line["results"], get)
        if isinstance(f.get("status"), h5py.Group):  # format_version 1
            stop_reason = _attr_str(f["status"].attrs["stop_reason"])
            status = _attr_str(f["status"].attrs["status"])
        elif isinstance(f.get("status"), h5py.Dataset):
            lines = [x for x in _json_lines(bytes(f["status"][:]), p, "status") if "status" in x]
            if lines:
                stop_reason, status = str(lines[-1].get("stop_reason")), str(lines[-1]["status"])
        if isinstance(f.get("device_counters"), h5py.Dataset):
            snaps = [x for x in _json_lines(bytes(f["device_counters"][:]), p, "device counters")
                     if isinstance(x.get("counters"), dict)]
            if snaps:
                counters = {str(d): {str(k): int(v) for k, v in cs.items()}
                            for d, cs in snaps[-1]["counters"].items()}
        _check_lengths(p, lengths, status is not None, attrs)
        scene = f["scene"][()]
        return cls(
            path=p,
            meta=json.loads(attrs.get("meta", "{}")),
            scene_text=_attr_str(scene),
            scene_sha256=str(attrs.get("scene_sha256", "")),
            stop_reason=stop_reason,
            status=status,
            t=t,
            channels=channels,
            units=units,
            events=events,
            results=results,
            descriptions=descr,
            rate_hz=float(attrs.get("rate_hz", math.nan)),
            attrs=attrs,
            device_counters=counters,
        )

    # -- derived views
    def summary(self) -> dict[str, Any]:
        """Duration [s], samples, measured rate [Hz], per-channel unit/shape/min/max/mean (NaN-aware;
        per column for vector channels), stop reason/status, events, experiments and, when the
        ``loop.overrun`` / ``loop.latency`` / ``loop.late`` channels exist, loop timing statistics
        (``loop.late``: tick start after its deadline [s]; ``late_over_period`` counts ticks later than
        one period); ``device_counters``: the per-device fault counters (see
        :meth:`RecordWriter.set_device_counters`); ``lateness``: :func:`lateness_distribution` of
        ``loop.late`` for realtime records (p50/p99/max, overruns, histogram)."""
        n = self.t.size
        duration = float(self.t[-1] - self.t[0]) if n > 1 else 0.0
        chans: dict[str, Any] = {}
        for name, a in self.channels.items():
            flat = a.reshape(n, int(np.prod(a.shape[1:], dtype=int)))
            if n:
                with np.errstate(all="ignore"), warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
                    mn, mx, mean = np.nanmin(flat, axis=0), np.nanmax(flat, axis=0), np.nanmean(flat, axis=0)
            else:
                mn = mx = mean = np.full(flat.shape[1], np.nan)
            scalar = a.ndim == 1
            conv = (lambda v: float(v[0])) if scalar else (lambda v: [float(x) for x in v])
            chans[name] = {
                "unit": self.units.get(name, ""),
                "shape": list(a.shape[1:]),
                "min": conv(mn), "max": conv(mx), "mean": conv(mean),
                "nan": int(np.count_nonzero(np.isnan(a))),
            }
        out: dict[str, Any] = {
            "path": str(self.path),
            "closed": self.closed,
            "status": self.status,
            "stop_reason": self.stop_reason,
            "samples": int(n),
            "duration_s": duration,
            "t_start_s": float(self.t[0]) if n else None,
            "t_end_s": float(self.t[-1]) if n else None,
            "rate_hz": self.rate_hz,
            "measured_rate_hz": (n - 1) / duration if duration > 0 else None,
            "scene_sha256": self.scene_sha256,
            "created_utc": self.attrs.get("created_utc"),
            "channels": chans,
            "events": len(self.events),
            "event_kinds": dict(sorted(_count(e.get("kind", "") for e in self.events).items())),
            "experiments": sorted(self.results),
            "device_counters": {d: dict(c) for d, c in self.device_counters.items()},
        }
        loop: dict[str, Any] = {}
        if "loop.overrun" in self.channels:
            ov = self.channels["loop.overrun"].reshape(n, -1)[:, 0] if n else np.zeros(0)
            hit = np.nan_to_num(ov) > 0
            loop["overrun_samples"] = int(np.count_nonzero(hit))
            loop["overrun_total"] = float(np.nansum(ov)) if n else 0.0
            loop["overrun_fraction"] = float(np.count_nonzero(hit) / n) if n else 0.0
        if "loop.latency" in self.channels and n:
            lat = self.channels["loop.latency"].reshape(n, -1)[:, 0]
            lat = lat[np.isfinite(lat)]
            if lat.size:
                loop["latency_unit"] = self.units.get("loop.latency", "")
                loop["latency_mean"] = float(np.mean(lat))
                loop["latency_p50"] = float(np.percentile(lat, 50))
                loop["latency_p99"] = float(np.percentile(lat, 99))
                loop["latency_max"] = float(np.max(lat))
        if "loop.late" in self.channels and n:  # the runner's tick lateness [s] (realtime mode)
            late = self.channels["loop.late"].reshape(n, -1)[:, 0]
            late = late[np.isfinite(late)]
            if late.size:
                dt = 1.0 / self.rate_hz if self.rate_hz > 0 else math.inf
                loop["late_mean_s"] = float(np.mean(late))
                loop["late_p99_s"] = float(np.percentile(late, 99))
                loop["late_max_s"] = float(np.max(late))
                loop["late_over_period"] = int(np.count_nonzero(late > dt))
                if self.meta.get("mode") == "realtime" or np.any(late > 0):
                    out["lateness"] = lateness_distribution(late, self.rate_hz)
        if loop:
            out["loop"] = loop
        return out

    def to_identify_dict(self, *, meta: Mapping[str, Any] | None = None,
                         t_range: tuple[float, float] | None = None) -> dict[str, Any]:
        """``{"t", "signals", "meta"}`` for :func:`hil.identify.api.identify_record`.

        Vector channels are split into 1-D signals ``name[0]``, ``name[1]``, ... (``name[i,j]`` for
        matrices). ``meta`` entries override the record's meta; ``t_range`` = (t0, t1) [s] keeps
        t0 <= t <= t1 (e.g. one experiment of a multi-experiment run)."""
        keep = slice(None) if t_range is None else (self.t >= t_range[0]) & (self.t <= t_range[1])
        signals: dict[str, np.ndarray] = {}
        for name, a in self.channels.items():
            a = a[keep]
            if a.ndim == 1:
                signals[name] = a
                continue
            for idx in np.ndindex(*a.shape[1:]):
                signals[f"{name}[{','.join(map(str, idx))}]"] = np.ascontiguousarray(a[(slice(None), *idx)])
        m = dict(self.meta)
        m.setdefault("rate_hz", self.rate_hz)
        m["channel_units"] = dict(self.units)
        if meta:
            m.update(meta)
        return {"t": self.t[keep], "signals": signals, "meta": m}


#: upper edges [s] of the lateness histogram of ``hil replay`` (the last bin is open)
LATENESS_BINS_S = (1e-5, 1e-4, 1e-3, 1e-2)


def lateness_distribution(late_s: np.ndarray, rate_hz: float) -> dict[str, Any]:
    """The distribution of per-tick lateness ``late_s`` [s] (the ``loop.late`` channel): ``ticks``,
    ``p50_s`` / ``p99_s`` (``numpy.percentile``, linear interpolation), ``max_s``, ``overruns`` (ticks
    later than one period ``1 / rate_hz``), ``overrun_fraction`` (overruns / ticks) and ``histogram``:
    ``[[label, count], ...]`` over :data:`LATENESS_BINS_S` (bin i holds edge[i-1] < late <= edge[i])."""
    a = np.asarray(late_s, dtype=float).reshape(-1)
    a = a[np.isfinite(a)]
    dt = 1.0 / rate_hz if rate_hz > 0 else math.inf
    if a.size == 0:
        return {"ticks": 0, "p50_s": None, "p99_s": None, "max_s": None, "overruns": 0, "overrun_fraction": 0.0,
                "histogram": []}
    edges = np.asarray(LATENESS_BINS_S)
    counts = np.bincount(np.searchsorted(edges, a, side="left"), minlength=edges.size + 1)
    names = [f"≤ {_fmt_s(edges[0])}"] + [f"{_fmt_s(lo)} – {_fmt_s(hi)}" for lo, hi in pairwise(edges)]
    names.append(f"> {_fmt_s(edges[-1])}")
    over = int(np.count_nonzero(a > dt))
    return {"ticks": int(a.size), "p50_s": float(np.percentile(a, 50)), "p99_s": float(np.percentile(a, 99)),
            "max_s": float(a.max()), "overruns": over, "overrun_fraction": over / a.size,
            "histogram": [[n, int(c)] for n, c in zip(names, counts, strict=True)]}


def _fmt_s(x: float) -> str:
    return f"{x * 1e6:g} µs" if x < 1e-3 else f"{x * 1e3:g} ms"


def _count(items: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for k in items:
        out[k] = out.get(k, 0) + 1
    return out


