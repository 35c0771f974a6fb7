"""The mapping of an import: which source of the file becomes which channel of the record, with scale and unit.

A mapping is a dict (``hil import --time/--map/--scale/--unit``, or a YAML/JSON sidecar file with the
same content; the keys are described in :mod:`hil.record.importers`). Each channel names one source or a
list of sources (a vector channel). A source is written in the file's own words:

=================  ==========================================================================================
format             source
=================  ==========================================================================================
CSV / TXT / TSV    a column name (``pos``); ``x[0]`` is the column of that name
MATLAB ``.mat``    a variable or ``struct.field`` (``qm``, ``run.q1``); ``q[1]``: column 1 (from 0) of q
HDF5               a dataset path (``/data/q``); ``/data/q[1]``: column 1 of a 2-D dataset
LabVIEW TDMS       ``group/channel`` (``Untitled/Voltage 0``)
ROS bags, MCAP     ``/topic:field`` with a dotted field path (``/wrench:wrench.force.z``, ``/cmd:data``) and
                   an optional selector at its end: ``[i]`` an element of an array (``/array:data[2]``),
                   ``[name]`` the element of that joint in a ``sensor_msgs/JointState``
                   (``/joint_states:position[joint1]``)
=================  ==========================================================================================

:func:`parse_field` splits the ``/topic:field[selector]`` form.
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hil.inputs import read_text_file
from hil.record.hdf5 import RecordError

logger = logging.getLogger(__name__)

__all__ = ["FieldRef", "ImportMapping", "default_mapping", "find_sidecar", "load_sidecar", "normalize",
           "parse_field"]

_RESERVED = {"t", "units", "descriptions", "scale", "meta", "rate_hz", "resample_hz", "channels"}
_VECTOR_RE = re.compile(r"^(?P<name>.+)\[(?P<i>\d+)\]$")
_FIELD_RE = re.compile(r"^(?P<path>[^\[\]]+?)(?:\[(?P<sel>[^\[\]]+)\])?$")


@dataclass
class ImportMapping:
    """A normalized mapping: time source (``""``: the format's own time), channel name -> source(s),
    units of the file's values, descriptions, scales, extra meta and a declared rate."""

    time: str
    channels: dict[str, str | list[str]]
    units: dict[str, str] = field(default_factory=dict)
    descriptions: dict[str, str] = field(default_factory=dict)
    scale: dict[str, float] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    rate_hz: float | None = None
    #: time-stamped formats (bags, MCAP, TDMS): put every channel onto a uniform grid at this rate [Hz]
    resample_hz: float | None = None

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"t": self.time, **self.channels}
        if self.scale:
            out["scale"] = dict(self.scale)
        if self.units:
            out["units"] = dict(self.units)
        if self.resample_hz is not None:
            out["resample_hz"] = self.resample_hz
        return out

    def sources(self, name: str) -> list[str]:
        """The sources of channel ``name`` as a list (one for a scalar channel)."""
        src = self.channels[name]
        return [src] if isinstance(src, str) else list(src)

    def override(self, scale: Mapping[str, float] | None, units: Mapping[str, str] | None, where: str) -> None:
        """Apply ``hil import --scale/--unit`` on top of the mapping (sidecar, default or ``--map``):
        each name must be ``t`` or a mapped channel."""
        for flag, names in (("--scale", scale or {}), ("--unit", units or {})):
            for name in names:
                if name != "t" and name not in self.channels:
                    raise RecordError(f"{where}: {flag} {name}: no such channel in the mapping "
                                      f"(channels: {', '.join(sorted(self.channels)) or 'none'}, and t)")
        self.scale.update(scale or {})
        self.units.update(units or {})


def normalize(raw: Mapping[str, Any], where: str, *, time_required: bool = True) -> ImportMapping:
    """The :class:`ImportMapping` of a mapping dict; ``time_required=False`` for formats that carry their
    own time (bags, MCAP, TDMS waveforms): then ``t`` may be left out (``""``)."""
    if not isinstance(raw, Mapping):
        raise RecordError(f"{where}: mapping must be a dict, got {type(raw).__name__}")
    if "t" not in raw and time_required:
        raise RecordError(f"{where}: mapping needs 't' (the time column)")
    t = raw.get("t", "")
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
    m = ImportMapping(time=t_col, channels={})
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
            cols = src.get("columns", src.get("column", src.get("sources", src.get("source"))))
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
    unknown = set(m.units) - set(m.channels) - {"t"}
    if unknown:
        raise RecordError(f"{where}: units given for unmapped channels {sorted(unknown)}")
    for key in ("rate_hz", "resample_hz"):
        if raw.get(key) is not None:
            try:
                val = float(raw[key])
            except (TypeError, ValueError):
                raise RecordError(f"{where}: {key} must be a number, got {raw[key]!r}") from None
            if not (val > 0 and val < float("inf")):
                raise RecordError(f"{where}: {key} must be a positive number of Hz, got {raw[key]!r}")
            setattr(m, key, val)
    return m


def with_default_time(mapping: Mapping[str, Any], names: Sequence[str], where: str, what: str) -> Mapping[str, Any]:
    """``mapping`` with ``t`` set to the ``t``/``time`` column (case-insensitive) when it names none
    (``hil import --map ...`` without ``--time``). ``what``: "column" or "variable" (for the message)."""
    if not isinstance(mapping, Mapping) or "t" in mapping:
        return mapping
    lower = {n.lower(): n for n in names}
    t_col = lower.get("t") or lower.get("time")
    if t_col is None:
        raise RecordError(f"{where}: the mapping names no time {what} and there is no 't' or 'time' {what} "
                          f"({what}s: {', '.join(names) or 'none'}); name it with 'hil import --time NAME' "
                          "(or 't:' in the mapping)")
    logger.info("%s: time %s %r (default)", where, what, t_col)
    return {"t": t_col, **mapping}


def load_sidecar(path: str | Path) -> dict[str, Any]:
    """The mapping dict of a YAML or JSON sidecar file (one line naming the file when unreadable)."""
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


def find_sidecar(path: Path) -> Path | None:
    """``run.yaml``/``.yml``/``.json`` or ``run.csv.yaml``/... next to ``path``, or None."""
    for cand in (path.with_suffix(".yaml"), path.with_suffix(".yml"), path.with_suffix(".json"),
                 path.with_name(path.name + ".yaml"), path.with_name(path.name + ".yml"),
                 path.with_name(path.name + ".json")):
        if cand != path and cand.is_file():
            return cand
    return None


def default_mapping(names: Sequence[str], where: str, what: str) -> ImportMapping:
    """Time column t/time; ``x[i]`` columns grouped into vector channel ``x``; others scalar."""
    lower = {n.lower(): n for n in names}
    t_col = lower.get("t") or lower.get("time")
    if t_col is None:
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
    return ImportMapping(time=t_col, channels=chans)


@dataclass(frozen=True)
class FieldRef:
    """``/topic:path[selector]``: a topic, a dotted field path and an optional selector (an index
    ``int`` or a joint name ``str``)."""

    topic: str
    path: tuple[str, ...]
    selector: int | str | None = None

    def __str__(self) -> str:
        sel = "" if self.selector is None else f"[{self.selector}]"
        return f"{self.topic}:{'.'.join(self.path)}{sel}"


def parse_field(text: str, where: str) -> FieldRef:
    """A ``/topic:field.path[selector]`` source (module docstring); one line naming it when malformed."""
    topic, sep, rest = text.strip().partition(":")
    m = _FIELD_RE.match(rest.strip()) if sep else None
    if not topic or m is None:
        raise RecordError(f"{where}: source {text!r}: expected /topic:field (e.g. /joint_states:position[joint1], "
                          "/wrench:wrench.force.z, /cmd:data)")
    path = tuple(p for p in m["path"].strip().split("."))
    if any(not p for p in path):
        raise RecordError(f"{where}: source {text!r}: empty field name in {m['path']!r}")
    sel_text = m["sel"]
    selector: int | str | None = None
    if sel_text is not None:
        sel_text = sel_text.strip()
        selector = int(sel_text) if re.fullmatch(r"\d+", sel_text) else sel_text
    return FieldRef(topic.strip(), path, selector)


def split_index(name: str) -> tuple[str, int | None]:
    """``q[1]`` -> ``("q", 1)``; any other name -> ``(name, None)``."""
    mt = _VECTOR_RE.match(name)
    return (mt["name"], int(mt["i"])) if mt else (name, None)
