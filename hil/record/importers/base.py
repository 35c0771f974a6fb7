"""What every importer shares: the :class:`Importer` protocol, the registry, the time checks, the
conversion to SI, several rates onto one time base, and writing the record.

An importer reads one format. It is an object with

* ``name`` (the format: ``csv``, ``mat``, ``hdf5``, ``tdms``, ``rosbag``, ``mcap``), ``suffixes`` and
  ``extra`` (the pip extra it needs, or None);
* ``claims(path)``: whether it reads this file or folder (suffix, or a look inside);
* ``time_required``: whether a mapping must name the time (``t``); formats with their own time
  stamps (bags, MCAP, TDMS waveforms) take it from the file;
* ``default_mapping(path)``: the mapping used when none is given (or None: the user must map);
* ``inventory(path)``: what the file holds, as :class:`Entry` rows (``hil import FILE --list``);
* ``read(path, mapping)``: a :class:`Sampled` -- time and the mapped channels in the file's units.

Importers are registered with :func:`register` (the built-in ones on import of
:mod:`hil.record.importers`) and from the entry-point group ``hil_certify.importers`` (an importer object
or a class taking no arguments; :func:`hil.plugins.load_group`), read on first use. An entry point may
replace a built-in format of the same name.

Several rates onto one time base (:func:`align`): each channel's stream has its own times; the record's
time is one stream's (the base: the fastest, or the one the mapping names as ``t``), every other channel
takes at each base time its latest sample at or before it (zero-order hold, as a sample-and-hold sensor
read by a faster loop), and leading base times before every channel has a sample are dropped. A
channel in which a stream sample is reused for several record samples (a stream slower than the base,
or jittering against it) is *held*: listed in the record's meta ``held_channels`` and described in
``imported_from.resampling`` (its source, rate, the fraction of repeated samples, the method), so the
identification treats it as a held output (:mod:`hil.identify.sensor_hold`). With ``resample_hz``
(``hil import --resample HZ``) the time base is a uniform grid instead and every channel is held onto it.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from hil.record.hdf5 import ChannelSpec, RecordError, RecordWriter
from hil.record.importers.mapping import ImportMapping
from hil.record.importers.units import to_si

logger = logging.getLogger(__name__)

__all__ = [ "PLAUSIBLE_RATE_HZ", "Entry", "Importer", "Sampled", "Stream", "align",
           "check_time", "importer_for", "importers", "missing_extra", "register", "write_record"]

_MAX_GAP_EVENTS = 100
#: sample rates [Hz] outside which an imported record's time column is probably not in seconds (bench
#: loops run at 100 Hz to tens of kHz; a 1 kHz log with its time in ms reads as 1 Hz): a warning
PLAUSIBLE_RATE_HZ = (20.0, 1e6)


@dataclass
class Entry:
    """One row of ``hil import FILE --list``: a source the mapping can name."""

    source: str  # as written in a mapping (column, variable, dataset path, group/channel, /topic:field)
    kind: str  # what it is: column, variable, dataset, channel, sensor_msgs/msg/JointState, ...
    samples: int | None = None
    rate_hz: float | None = None
    shape: tuple[int, ...] = ()
    unit: str = ""
    note: str = ""


@dataclass
class Stream:
    """One channel's samples on its own times [s] (before the mapping's scale/unit): ``values`` (n,)
    or (n, k). ``origin``: where it came from (topic, group), for the record's resampling note."""

    t: np.ndarray
    values: np.ndarray
    origin: str = ""


@dataclass
class Sampled:
    """What an importer read: time ``t`` (n,) and each mapped channel (n,) or (n, k), in the file's
    units; ``units``: units the file itself states (used when the mapping gives none);
    ``resampling``: channel -> how it was put onto ``t``; ``provenance``: format details for the
    record's ``imported_from`` (time source, topics, start time)."""

    t: np.ndarray
    data: dict[str, np.ndarray]
    units: dict[str, str] = field(default_factory=dict)
    resampling: dict[str, dict[str, Any]] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class Importer(Protocol):
    """One file format (module docstring)."""

    name: str
    suffixes: tuple[str, ...]
    extra: str | None
    time_required: bool

    def claims(self, path: Path) -> bool: ...

    def default_mapping(self, path: Path) -> ImportMapping | None: ...

    def source_names(self, path: Path) -> list[str]: ...

    def inventory(self, path: Path) -> list[Entry]: ...

    def read(self, path: Path, mapping: ImportMapping) -> Sampled: ...


_REGISTRY: dict[str, Importer] = {}


def register(importer: Importer) -> Importer:
    """Add (or replace) the importer of ``importer.name``; returns it."""
    _REGISTRY[importer.name] = importer
    return importer


def _load_entry_points() -> None:
    from hil.plugins import load_group

    def add(obj: Any) -> None:  # an importer class passes the protocol check itself: instantiate it
        register(obj() if isinstance(obj, type) else obj)

    load_group("importers", Importer, add)  # once per process; a broken entry point is logged, skipped


def importers() -> dict[str, Importer]:
    """Every registered importer by format name (built-in and entry points)."""
    _load_entry_points()
    return dict(_REGISTRY)


def importer_for(path: Path, fmt: str | None = None) -> Importer:
    """The importer of ``path`` (or of format ``fmt``); one line naming the formats when none reads it."""
    regs = importers()
    if fmt is not None:
        if fmt not in regs:
            raise RecordError(f"unknown format {fmt!r} (formats: {', '.join(sorted(regs))})")
        return regs[fmt]
    for imp in regs.values():
        if imp.claims(path):
            return imp
    known = sorted({s for imp in regs.values() for s in imp.suffixes})
    raise RecordError(f"{path}: not a format hil import reads (suffixes: {', '.join(known)}; a ROS 2 bag is "
                      "a folder with metadata.yaml)")


def missing_extra(extra: str, package: str, exc: ImportError) -> RecordError:
    """The one-line error of an importer whose extra is not installed."""
    return RecordError(f"reading this format needs {package} ({exc.name or 'missing'} is not installed): "
                       f"pip install 'hil-certify[{extra}]'")


# ------------------------------------------------------------------------------------------- time, units


def check_time(t: np.ndarray, where: str, max_jitter: float,
               fix: str = "resample onto a uniform grid first") -> tuple[float, list[tuple[float, int]]]:
    """Median interval [s] and the gaps (time [s], samples missing); raises on bad time (``fix``: what the
    message advises for off-grid time)."""
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
            f"{max_jitter:g}); {fix}")
    gaps = [(float(t[i]), int(k[i]) - 1) for i in np.flatnonzero(k > 1)]
    return med, gaps


def _unit(m: ImportMapping, file_units: Mapping[str, str], name: str, where: str,
          default: str = "") -> tuple[float, str]:
    """The factor to SI and SI unit of channel ``name``: the mapping's unit (strict), else the unit the
    file states (an unknown one is kept as written, with a warning), else ``default``."""
    if name in m.units:
        try:
            return to_si(str(m.units[name]))
        except RecordError as exc:
            raise RecordError(f"{where}: {name}: {exc}") from None
    stated = file_units.get(name, default)
    try:
        return to_si(stated)
    except RecordError as exc:
        logger.warning("%s: %s: the file's unit %r is kept as written (%s)", where, name, stated, exc)
        return 1.0, stated


def to_si_values(s: Sampled, m: ImportMapping, where: str) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, str]]:
    """Time [s] and channels in SI: file values x ``scale`` x the unit's factor to SI; the SI unit of
    each channel (:mod:`hil.record.importers.units`)."""
    factor, si = _unit(m, {}, "t", where, default="s")
    if si != "s":
        raise RecordError(f"{where}: t: unit {m.units['t']!r} is not a unit of time")
    t = s.t * (m.scale.get("t", 1.0) * factor)
    out: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    for name, a in s.data.items():
        factor, units[name] = _unit(m, s.units, name, where)
        gain = m.scale.get(name, 1.0) * factor
        out[name] = a * gain if gain != 1.0 else a
    return t, out, units


def check_rate(rate: float, where: str) -> None:
    """Warn when the sample rate taken from the time is outside :data:`PLAUSIBLE_RATE_HZ` (a time
    column in ms read as seconds makes a 1 kHz record a 1 Hz one)."""
    lo, hi = PLAUSIBLE_RATE_HZ
    if not lo <= rate <= hi:
        logger.warning("%s: the time column gives a sample rate of %.6g Hz, implausible for a bench record "
                       "(%g Hz to %g Hz): if the time is not in seconds, give its unit (hil import --unit t=ms, "
                       "or 'units: {t: ms}' in the mapping)", where, rate, lo, hi)


# ------------------------------------------------------------------------------------- one time base


def rate_of(t: np.ndarray) -> float:
    """1 / median interval [Hz] of increasing times ``t`` [s] (nan for fewer than 2)."""
    return float(1.0 / np.median(np.diff(t))) if t.size >= 2 else float("nan")


def align(streams: Mapping[str, Stream], base: str | None, where: str, resample_hz: float | None = None) -> Sampled:
    """Every stream onto one time base (module docstring). ``base``: the ``origin`` of the stream whose
    times become the record's (None: the fastest). ``resample_hz``: instead, a uniform grid at that rate
    from the first time every stream has a sample to the earliest last sample, every stream held onto it
    (for stamps that jitter too much for one stream's times to be the record's). Returns the
    :class:`Sampled` with ``resampling`` filled for every channel not of the base."""
    if not streams:
        raise RecordError(f"{where}: no channel mapped")
    for name, s in streams.items():
        if s.t.size < 2:
            raise RecordError(f"{where}: channel {name!r} ({s.origin}): {s.t.size} sample(s), need at least 2")
    rates = {name: rate_of(s.t) for name, s in streams.items()}
    if resample_hz is not None:
        return _onto_grid(streams, rates, resample_hz, where)
    if base is None:
        base_name = max(streams, key=lambda n: (rates[n], streams[n].t.size))
    else:
        named = [n for n, s in streams.items() if s.origin == base]
        if not named:
            raise RecordError(f"{where}: time base {base!r} is not the source of a mapped channel (sources: "
                              f"{', '.join(sorted({s.origin for s in streams.values()}))})")
        base_name = named[0]
    base_origin = streams[base_name].origin
    tb = streams[base_name].t
    idx: dict[str, np.ndarray] = {}
    start = 0
    for name, s in streams.items():
        if s.t.size == tb.size and np.array_equal(s.t, tb):  # already on the base's times
            continue
        if np.any(np.diff(s.t) < 0):
            raise RecordError(f"{where}: channel {name!r} ({s.origin}): time stamps decrease")
        i = np.searchsorted(s.t, tb, side="right") - 1
        first = int(np.searchsorted(i, 0, side="left"))  # i is non-decreasing: first base time with a sample
        if first >= tb.size:
            raise RecordError(f"{where}: channel {name!r} ({s.origin}) has no sample at or before the last time "
                              f"of the time base {base_origin}")
        start = max(start, first)
        idx[name] = i
    t = tb[start:]
    data: dict[str, np.ndarray] = {}
    resampling: dict[str, dict[str, Any]] = {}
    for name, s in streams.items():
        if name not in idx:
            data[name] = s.values[start:]
            continue
        data[name] = s.values[idx[name][start:]]
        resampling[name] = {"source": s.origin, "source_rate_hz": rates[name], **_repeats(idx[name][start:]),
                            "method": "zero-order hold: the latest sample at or before each time of the base"}
    if start:
        logger.info("%s: %d leading sample(s) of %s dropped (before every channel had a value)", where, start,
                    base_origin)
    prov = {"time_base": {"source": base_origin, "rate_hz": rates[base_name], "dropped_leading": start}}
    return Sampled(t=t, data=data, resampling=resampling, provenance=prov)


def _repeats(i: np.ndarray) -> dict[str, Any]:
    """``held`` (some record sample repeats the one before it: the stream's sample was reused) and
    ``repeated_fraction`` (of the record's samples) for the source indices ``i`` of a held stream."""
    frac = float(np.mean(i[1:] == i[:-1])) if i.size > 1 else 0.0
    return {"held": frac > 0.0, "repeated_fraction": frac}


def _onto_grid(streams: Mapping[str, Stream], rates: Mapping[str, float], rate_hz: float, where: str) -> Sampled:
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise RecordError(f"{where}: resample rate must be a positive number of Hz, got {rate_hz!r}")
    t0 = max(float(s.t[0]) for s in streams.values())
    t1 = min(float(s.t[-1]) for s in streams.values())
    n = int(np.floor((t1 - t0) * rate_hz + 1e-9)) + 1
    if n < 2:
        raise RecordError(f"{where}: the streams overlap for {max(t1 - t0, 0.0):.6g} s: nothing to resample")
    grid = t0 + np.arange(n) / rate_hz
    data: dict[str, np.ndarray] = {}
    resampling: dict[str, dict[str, Any]] = {}
    for name, s in streams.items():
        if np.any(np.diff(s.t) < 0):
            raise RecordError(f"{where}: channel {name!r} ({s.origin}): time stamps decrease")
        i = np.searchsorted(s.t, grid, side="right") - 1
        data[name] = s.values[i]
        resampling[name] = {"source": s.origin, "source_rate_hz": rates[name], **_repeats(i),
                            "method": f"zero-order hold onto a uniform {rate_hz:g} Hz grid (--resample)"}
    prov = {"time_base": {"source": f"uniform grid {rate_hz:g} Hz", "rate_hz": float(rate_hz), "dropped_leading": 0}}
    return Sampled(t=grid, data=data, resampling=resampling, provenance=prov)


# ------------------------------------------------------------------------------------------------ write


def file_digest(path: Path) -> str:
    """SHA-256 of a file, or of a folder's files (sorted relative paths and contents: a ROS 2 bag)."""
    h = hashlib.sha256()
    if path.is_dir():
        for p in sorted(q for q in path.rglob("*") if q.is_file()):
            h.update(str(p.relative_to(path)).encode() + b"\0")
            h.update(hashlib.sha256(p.read_bytes()).digest())
        return h.hexdigest()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_record(out: str | Path, s: Sampled, m: ImportMapping, src: Path, fmt: str,
                 meta: Mapping[str, Any] | None, max_jitter: float) -> Path:
    """Check the time, convert to SI and write the run record at ``out`` (module docstring)."""
    where = str(src)
    t, data, units = to_si_values(s, m, where)
    fix = ("resample onto a uniform grid: hil import --resample HZ" if s.provenance.get("time_base") else
           "resample onto a uniform grid first")
    med, gaps = check_time(t, where, max_jitter, fix)
    rate = m.rate_hz if m.rate_hz is not None else 1.0 / med
    if m.rate_hz is None:
        check_rate(rate, where)
    if gaps:
        logger.warning("%s: %d gap(s) in time, %d sample(s) missing in all", where, len(gaps),
                       sum(g[1] for g in gaps))
    specs = {name: ChannelSpec(tuple(a.shape[1:]), units[name], m.descriptions.get(name, ""))
             for name, a in data.items()}
    full_meta = {**m.meta, **dict(meta or {})}
    full_meta["imported_from"] = {"format": fmt, "path": str(src.resolve()), "sha256": file_digest(src),
                                  "mapping": m.as_dict(), "gaps": len(gaps), **s.provenance}
    if s.resampling:
        full_meta["imported_from"]["resampling"] = s.resampling
        held = sorted(n for n, r in s.resampling.items() if r.get("held"))
        if held:
            full_meta["held_channels"] = held
            logger.info("%s: held (slower than the time base, zero-order hold): %s", where, ", ".join(held))
    with RecordWriter(Path(out), scene_text="", scene_sha256="", meta=full_meta, channels=specs, rate_hz=rate) as w:
        w.append_block(t, data)
        for tg, missing in gaps[:_MAX_GAP_EVENTS]:
            w.event(tg, "import.gap", f"{missing} sample(s) missing after t = {tg!r} s")
        if len(gaps) > _MAX_GAP_EVENTS:
            w.event(float(t[-1]), "import.gap", f"{len(gaps) - _MAX_GAP_EVENTS} more gap(s) not listed")
        w.close(stop_reason="imported", status="ok")
    logger.info("imported %s (%s, %d samples, %d channels) -> %s", src, fmt, t.size, len(data), out)
    return Path(out)


def lazy(extra: str, package: str, load: Callable[[], Any]) -> Any:
    """``load()`` (an import of an extra's package), or the one-line :func:`missing_extra` error."""
    try:
        return load()
    except ImportError as exc:
        raise missing_extra(extra, package, exc) from None
