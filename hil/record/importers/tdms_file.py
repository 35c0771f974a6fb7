"""LabVIEW TDMS files (the importer of format ``tdms``, npTDMS; extra ``formats``).

Sources are ``group/channel`` (``Untitled/Voltage 0``; LabVIEW's ``'group'/'channel'`` path is accepted
too). Time: a channel the mapping names as ``t`` (``hil import --time Group/Time``), else each channel's
waveform timing, ``wf_start_offset + k * wf_increment`` [s]. Channels at different ``wf_increment``
are put onto the fastest one's times, the slower held (:func:`hil.record.importers.base.align`). The
channel property ``unit_string`` is the unit the file states; ``wf_start_time`` (absolute start) goes
into the record's ``imported_from``.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

import numpy as np

from hil.record.hdf5 import RecordError
from hil.record.importers.base import Entry, Sampled, Stream, align, lazy
from hil.record.importers.mapping import ImportMapping

logger = logging.getLogger(__name__)

__all__ = ["TdmsImporter"]

_QUOTED = re.compile(r"^/?'(?P<g>(?:[^']|'')*)'/'(?P<c>(?:[^']|'')*)'$")


def _read(path: Path) -> Any:
    nptdms = lazy("formats", "npTDMS", lambda: __import__("nptdms"))
    try:
        return nptdms.TdmsFile.read(str(path))
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise RecordError(f"{path}: not a readable TDMS file ({type(exc).__name__}: "
                          f"{' '.join(str(exc).split())[:160]})") from None


def _channels(f: Any) -> dict[str, Any]:
    return {f"{g.name}/{c.name}": c for g in f.groups() for c in g.channels()}


def _lookup(chans: dict[str, Any], src: str, where: str) -> Any:
    if src in chans:
        return chans[src]
    q = _QUOTED.match(src.strip())
    if q:
        key = f"{q['g'].replace(chr(39) * 2, chr(39))}/{q['c'].replace(chr(39) * 2, chr(39))}"
        if key in chans:
            return chans[key]
    raise RecordError(f"{where}: no channel {src!r} (group/channel: {', '.join(chans) or 'none'})")


def _unit(ch: Any) -> str:
    u = ch.properties.get("unit_string", "")
    return str(u) if u is not None else ""


def _waveform_time(ch: Any) -> np.ndarray | None:
    props = ch.properties
    if "wf_increment" not in props:
        return None
    inc = float(props["wf_increment"])
    off = float(props.get("wf_start_offset", 0.0))
    return off + inc * np.arange(len(ch), dtype=np.float64)


class TdmsImporter:
    """Format ``tdms`` (module docstring)."""

    name = "tdms"
    suffixes: tuple[str, ...] = (".tdms",)
    extra: str | None = "formats"
    time_required = False
    resamples = True  # mapping's resample_hz (hil import --resample HZ)

    def claims(self, path: Path) -> bool:
        return path.suffix.lower() == ".tdms" and not path.is_dir()

    def source_names(self, path: Path) -> list[str]:
        return list(_channels(_read(path)))

    def default_mapping(self, path: Path) -> ImportMapping | None:
        return None

    def inventory(self, path: Path) -> list[Entry]:
        out = []
        for key, ch in _channels(_read(path)).items():
            props = ch.properties
            rate = 1.0 / float(props["wf_increment"]) if props.get("wf_increment") else None
            note = f"wf_start_time {props['wf_start_time']}" if "wf_start_time" in props else ""
            out.append(Entry(key, f"channel {ch.dtype}", len(ch), rate, (len(ch),), _unit(ch), note))
        return out

    def read(self, path: Path, m: ImportMapping) -> Sampled:
        where = str(path)
        chans = _channels(_read(path))
        units: dict[str, str] = {}
        start_times: dict[str, str] = {}

        def values(name: str) -> tuple[np.ndarray, list[Any]]:
            objs = [_lookup(chans, s, where) for s in m.sources(name)]
            try:
                cols = [np.asarray(o[:], dtype=np.float64) for o in objs]
            except (TypeError, ValueError):
                raise RecordError(f"{where}: channel {name!r}: a source is not numeric") from None
            if len({c.size for c in cols}) != 1:
                raise RecordError(f"{where}: channel {name!r}: its sources have different lengths "
                                  f"{[c.size for c in cols]}")
            stated = {_unit(o) for o in objs}
            if len(stated) == 1 and "" not in stated:
                units[name] = stated.pop()
            for o in objs:
                if "wf_start_time" in o.properties:
                    start_times[name] = str(o.properties["wf_start_time"])
            return (cols[0] if len(cols) == 1 else np.column_stack(cols)), objs

        if m.time:
            t = np.asarray(_lookup(chans, m.time, where)[:], dtype=np.float64)
            data = {}
            for name in m.channels:
                a, _ = values(name)
                if a.shape[0] != t.size:
                    raise RecordError(f"{where}: channel {name!r} has {a.shape[0]} samples, the time channel "
                                      f"{m.time!r} {t.size}")
                data[name] = a
            return Sampled(t=t, data=data, units=units, provenance={"time_source": m.time})
        streams = {}
        for name in m.channels:
            a, objs = values(name)
            times = [_waveform_time(o) for o in objs]
            if times[0] is None:
                raise RecordError(f"{where}: channel {name!r}: {m.sources(name)[0]!r} has no waveform timing "
                                  "(wf_increment): name the time channel with 'hil import --time GROUP/CHANNEL'")
            if any(tt is None or not np.array_equal(tt, times[0]) for tt in times[1:]):
                raise RecordError(f"{where}: channel {name!r}: its sources have different waveform timing")
            streams[name] = Stream(times[0], a, origin=m.sources(name)[0])
        s = align(streams, None, where, m.resample_hz)
        s.units = units
        s.provenance.update(time_source="waveform timing (wf_start_offset + k wf_increment)")
        if start_times:
            s.provenance["wf_start_time"] = start_times
        return s
