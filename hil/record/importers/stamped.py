"""Messages with time stamps (ROS bags, MCAP): fields by path, stamps, streams per channel, the topic list.

Shared by :mod:`hil.record.importers.rosbag_file` and :mod:`hil.record.importers.mcap_file`. A decoded
message is a rosbags dataclass, an ``mcap_ros2`` object or a JSON dict; a field path walks attributes or
keys (``wrench.force.z``). A selector ``[i]`` takes element i of an array; ``[name]`` takes the element
at the index of ``name`` in the ``name`` list next to the array (``sensor_msgs/JointState``: position,
velocity and effort by joint name, looked up per message, so a bag whose joint order changes is read
correctly).

Time of a message: its ``header.stamp`` (``sec`` + ``nanosec``, or ROS 1 / JSON ``nsec``) when the topic's
messages carry one that is not zero, else the time the message was logged (the bag's receive time, MCAP
``log_time``). The record's t = 0 is the earliest stamp of the mapped topics; the absolute start is kept
in ``imported_from.t0_ns`` (ns since the Unix epoch, or of whatever clock the bag used).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.record.hdf5 import RecordError
from hil.record.importers.base import Entry, Sampled, Stream, align
from hil.record.importers.mapping import FieldRef, ImportMapping, parse_field

logger = logging.getLogger(__name__)

__all__ = ["TopicInfo", "children", "get_field", "inventory_rows", "sample_streams", "stamp_ns"]

#: leaf fields listed per message by ``--list`` at most (a big message lists its first ones)
MAX_FIELDS = 60


def children(obj: Any) -> list[tuple[str, Any]]:
    """The named fields of a decoded message (dict, dataclass or object with ``__slots__``)."""
    if isinstance(obj, Mapping):
        return [(str(k), v) for k, v in obj.items()]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return [(f.name, getattr(obj, f.name)) for f in dataclasses.fields(obj) if not f.name.startswith("_")]
    slots = getattr(type(obj), "__slots__", None)
    if slots:
        return [(s, getattr(obj, s)) for s in slots if not s.startswith("_") and hasattr(obj, s)]
    return []


def _child(obj: Any, name: str) -> Any:
    if isinstance(obj, Mapping):
        if name in obj:
            return obj[name]
        raise KeyError(name)
    if dataclasses.is_dataclass(obj) or getattr(type(obj), "__slots__", None) or hasattr(obj, "__dict__"):
        if name.startswith("_") or not hasattr(obj, name):
            raise KeyError(name)
        return getattr(obj, name)
    raise KeyError(name)


def stamp_ns(msg: Any) -> int | None:
    """``header.stamp`` in ns, or None (no header, or a zero stamp)."""
    try:
        st = _child(_child(msg, "header"), "stamp")
        sec = int(_child(st, "sec"))
        try:
            ns = int(_child(st, "nanosec"))
        except KeyError:
            ns = int(_child(st, "nsec"))
    except (KeyError, TypeError, ValueError):
        return None
    v = sec * 1_000_000_000 + ns
    return v or None


def get_field(msg: Any, ref: FieldRef, where: str) -> Any:
    """The value at ``ref`` in ``msg`` (float or 1-D float array); one line naming the source when the
    field, the index or the joint name is not there."""
    parent: Any = None
    obj = msg
    try:
        for part in ref.path:
            parent, obj = obj, _child(obj, part)
    except KeyError as exc:  # obj: the message or field that lacks it
        have = ", ".join(n for n, _ in children(obj)) or "none"
        raise RecordError(f"{where}: {ref}: no field {exc.args[0]!r} (fields there: {have})") from None
    if ref.selector is not None:
        if isinstance(ref.selector, int):
            i = ref.selector
        else:
            try:
                names = list(_child(parent, "name"))
            except KeyError:
                raise RecordError(f"{where}: {ref}: selects by name, but the message has no 'name' list "
                                  "next to the field (use an index [i])") from None
            if ref.selector not in names:
                raise RecordError(f"{where}: {ref}: no joint {ref.selector!r} (names: {', '.join(map(str, names))})")
            i = names.index(ref.selector)
        try:
            obj = obj[i]
        except (IndexError, TypeError, KeyError):
            raise RecordError(f"{where}: {ref}: no element {ref.selector!r} (the field has "
                              f"{len(obj) if hasattr(obj, '__len__') else 'no'} elements)") from None
    try:
        return float(obj) if np.ndim(obj) == 0 else np.asarray(obj, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise RecordError(f"{where}: {ref}: not a number ({type(obj).__name__})") from None


@dataclass
class TopicInfo:
    """A topic as ``--list`` shows it: message type, count, rate [Hz] of its log times, one message."""

    topic: str
    msgtype: str
    count: int
    rate_hz: float | None = None
    sample: Any = None
    extra: dict[str, Any] = field(default_factory=dict)


def _leaves(obj: Any, prefix: str, out: list[tuple[str, Any]], depth: int = 0) -> None:
    if len(out) >= MAX_FIELDS or depth > 8:
        return
    for name, v in children(obj):
        path = f"{prefix}.{name}" if prefix else name
        if isinstance(v, (bool, int, float, np.integer, np.floating)):
            out.append((path, v))
        elif isinstance(v, (list, tuple, np.ndarray)) and len(v) and all(
                isinstance(x, (bool, int, float, np.integer, np.floating)) for x in list(v)[:8]):
            out.append((path, np.asarray(v)))
        elif children(v):
            _leaves(v, path, out, depth + 1)


def inventory_rows(topics: Iterable[TopicInfo]) -> list[Entry]:
    """``--list`` rows: per topic, its numeric fields as sources (joint names spelled out)."""
    rows = []
    for ti in topics:
        rows.append(Entry(ti.topic, ti.msgtype, ti.count, ti.rate_hz,
                          note="stamped (header.stamp)" if ti.sample is not None and stamp_ns(ti.sample)
                          else "log time"))
        if ti.sample is None:
            continue
        leaves: list[tuple[str, Any]] = []
        _leaves(ti.sample, "", leaves)
        names: list[str] = []
        try:
            names = [str(n) for n in _child(ti.sample, "name")]
        except (KeyError, TypeError):
            names = []
        for path, v in leaves:
            if path.startswith("header.") or path == "name":
                continue
            if isinstance(v, np.ndarray):
                if names and v.size == len(names) and "." not in path:
                    rows += [Entry(f"{ti.topic}:{path}[{n}]", "  field", ti.count, ti.rate_hz) for n in names]
                else:
                    rows.append(Entry(f"{ti.topic}:{path}", "  field (array)", ti.count, ti.rate_hz, (v.size,),
                                      note=f"[0]..[{v.size - 1}] for one element" if v.size > 1 else ""))
            else:
                rows.append(Entry(f"{ti.topic}:{path}", "  field", ti.count, ti.rate_hz))
    return rows


def sample_streams(messages: Iterable[tuple[str, int, Any]], m: ImportMapping, where: str) -> Sampled:
    """The mapped channels of ``messages`` ((topic, log time [ns], decoded message), in any order) on
    one time base (:func:`hil.record.importers.base.align`; the base is ``m.time`` when it names a topic,
    else the fastest topic)."""
    refs = {name: [parse_field(s, where) for s in m.sources(name)] for name in m.channels}
    by_topic: dict[str, list[tuple[str, int, FieldRef]]] = {}
    for name, rs in refs.items():
        for k, r in enumerate(rs):
            by_topic.setdefault(r.topic, []).append((name, k, r))
    if m.time and m.time not in by_topic:
        raise RecordError(f"{where}: t: {m.time!r} is not a mapped topic (topics: {', '.join(sorted(by_topic))})")
    times: dict[str, list[int]] = {tp: [] for tp in by_topic}
    stamped: dict[str, bool | None] = dict.fromkeys(by_topic)
    vals: dict[tuple[str, int], list[Any]] = {(n, k): [] for n, rs in refs.items() for k in range(len(rs))}
    for topic, log_ns, msg in messages:
        wanted = by_topic.get(topic)
        if wanted is None:
            continue
        st = stamp_ns(msg)
        if stamped[topic] is None:
            stamped[topic] = st is not None
        times[topic].append(st if stamped[topic] and st is not None else int(log_ns))
        for name, k, r in wanted:
            vals[(name, k)].append(get_field(msg, r, where))
    empty = sorted(tp for tp, ts in times.items() if not ts)
    if empty:
        raise RecordError(f"{where}: no message on {', '.join(empty)}")
    t0 = min(min(ts) for ts in times.values())
    streams: dict[str, Stream] = {}
    topic_t: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for tp, ts in times.items():
        ns = np.asarray(ts, dtype=np.int64) - t0
        order = np.argsort(ns, kind="stable")  # header stamps may arrive out of order
        topic_t[tp] = (ns[order].astype(np.float64) * 1e-9, order)
    for name, rs in refs.items():
        cols = []
        for k, r in enumerate(rs):
            order = topic_t[r.topic][1]
            v = vals[(name, k)]
            try:
                a = np.asarray(v, dtype=np.float64)
            except ValueError:
                raise RecordError(f"{where}: channel {name!r}: {r} changes length between messages") from None
            cols.append(a[order])
        if len({r.topic for r in rs}) != 1:
            raise RecordError(f"{where}: channel {name!r}: its sources are on different topics "
                              f"({', '.join(sorted({r.topic for r in rs}))}); map one channel per topic")
        values = cols[0] if len(cols) == 1 else np.column_stack(cols)
        streams[name] = Stream(topic_t[rs[0].topic][0], values, origin=rs[0].topic)
    s = align(streams, m.time or None, where, m.resample_hz)
    s.provenance.update(t0_ns=int(t0), time_stamps={tp: ("header.stamp" if stamped[tp] else "log time")
                                                    for tp in sorted(times)})
    return s
