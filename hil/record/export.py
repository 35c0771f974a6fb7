"""Export a run record for viewers and spreadsheets: ``hil export RECORD --format mcap|csv``.

MCAP (``mcap``; extra ``formats``), JSON messages with JSON schemas, which Foxglove and PlotJuggler open:

* one topic per device, ``/<device>`` (the part of a channel name before its first ``.``; channels without
  one go to ``/record``), one message per sample: ``{"t": s, "<quantity>": value or [values]}`` (e.g.
  ``/motor`` with ``position``, ``velocity``, ``effort_cmd``); the schema (name ``hil.<device>``) gives
  each field's unit and description;
* ``/events``: every record event, ``{"t", "kind", "message"}`` plus the fields of Foxglove's
  ``foxglove.Log`` schema (``timestamp``, ``level``, ``name``, ``file``, ``line``), so its Log panel
  lists them (level ERROR for ``error``, WARNING for stops, INFO otherwise);
* ``/stop``: one message at the last sample, ``{"t", "stop_reason", "status", "samples"}``;
* ``/device_counters``: one message at the last sample, ``{"t", "counters": {device: {name: count}}}``
  (when the record has them);
* metadata ``hil.record``: format, rate_hz, scene_sha256, created_utc, the channels' units and the
  record's meta (JSON).

Each message's ``log_time`` = ``publish_time`` = the record's creation time (``created_utc``; 0 when
absent) + ``t`` in ns; ``t`` in the message is the record's float64 time itself. Values are written with
Python's shortest round-trip ``repr`` (JSON numbers), so reading them back gives the record's values bit
for bit; NaN and infinities, which JSON has no number for, are written as ``null``.

CSV: a header ``t,<channel>,...`` (a vector channel as ``name[0]``, ``name[1]``, ...: the layout
``hil import`` reads back without a mapping), one row per sample, ``%.17g`` (exact), NaN as ``nan``, and
``#`` comment lines first naming the record and each channel's unit. Events, stops and counters are not
in the CSV (use MCAP or ``hil replay``).
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hil.record.hdf5 import RecordError, RunRecord

logger = logging.getLogger(__name__)

__all__ = ["FORMATS", "device_topics", "export_csv", "export_mcap", "export_record"]

#: foxglove.Log levels
_LOG_LEVEL = {"error": 4, "safety_stop": 3, "safe_stop": 3, "watchdog": 3}


def device_topics(channels: Mapping[str, Any]) -> dict[str, dict[str, str]]:
    """Topic -> {field: channel}: channels grouped by device (module docstring)."""
    out: dict[str, dict[str, str]] = {}
    for name in channels:
        dev, dot, qty = name.partition(".")
        topic, fieldname = (f"/{dev}", qty) if dot else ("/record", name)
        out.setdefault(topic, {})[fieldname] = name
    return out


def _json_value(a: Any) -> Any:
    """A sample as JSON: float, or nested lists; non-finite -> None."""
    if np.ndim(a) == 0:
        v = float(a)
        return v if math.isfinite(v) else None
    return [_json_value(x) for x in a]


def _schema(fields: Mapping[str, str], rec: RunRecord) -> dict[str, Any]:
    props: dict[str, Any] = {"t": {"type": "number", "description": "record time [s]"}}
    for fieldname, ch in fields.items():
        shape = rec.channels[ch].shape[1:]
        desc = f"{ch} [{rec.units.get(ch) or '-'}]" + (f": {rec.descriptions[ch]}" if rec.descriptions.get(ch) else "")
        number = {"type": ["number", "null"]}
        item: dict[str, Any] = number
        for _ in shape:
            item = {"type": "array", "items": item}
        props[fieldname] = {**item, "description": desc}
    return {"type": "object", "properties": props}


def _created_ns(rec: RunRecord) -> int:
    text = rec.attrs.get("created_utc")
    if isinstance(text, bytes):
        text = text.decode()
    try:
        when = _dt.datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except (TypeError, ValueError):
        return 0
    if when.tzinfo is None:
        when = when.replace(tzinfo=_dt.UTC)
    return int(when.timestamp()) * 1_000_000_000 + when.microsecond * 1000


def export_mcap(rec: RunRecord, out: Path) -> Path:
    """Write ``rec`` as MCAP at ``out`` (module docstring); returns ``out``."""
    try:
        from mcap.writer import Writer
    except ImportError as exc:
        raise RecordError(f"MCAP export needs the 'mcap' package ({exc.name} is not installed): "
                          "pip install 'hil-certify[formats]'") from None
    base = _created_ns(rec)
    t = np.asarray(rec.t, dtype=np.float64)

    def ns(tt: float) -> int:
        return base + max(0, round(tt * 1e9))

    topics = device_topics(rec.channels)
    with out.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="hil-certify")
        chan_ids: dict[str, int] = {}
        for topic, fields in topics.items():
            sid = w.register_schema(f"hil.{topic.strip('/')}", "jsonschema",
                                    json.dumps(_schema(fields, rec)).encode())
            chan_ids[topic] = w.register_channel(topic, "json", sid)
        ev_sid = w.register_schema("foxglove.Log", "jsonschema", json.dumps({"type": "object", "properties": {
            "t": {"type": "number"}, "kind": {"type": "string"}, "message": {"type": "string"},
            "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
            "level": {"type": "integer"}, "name": {"type": "string"}, "file": {"type": "string"},
            "line": {"type": "integer"}}}).encode())
        ev_id = w.register_channel("/events", "json", ev_sid)
        stop_sid = w.register_schema("hil.Stop", "jsonschema", json.dumps({"type": "object", "properties": {
            "t": {"type": "number"}, "stop_reason": {"type": ["string", "null"]},
            "status": {"type": ["string", "null"]}, "samples": {"type": "integer"}}}).encode())
        stop_id = w.register_channel("/stop", "json", stop_sid)
        # per-sample messages, topics interleaved in time order
        arrays = {topic: [(f, rec.channels[ch]) for f, ch in fields.items()] for topic, fields in topics.items()}
        for k in range(t.size):
            tk = float(t[k])
            for topic, cols in arrays.items():
                msg = {"t": tk, **{f: _json_value(a[k]) for f, a in cols}}
                w.add_message(chan_ids[topic], log_time=ns(tk), data=json.dumps(msg).encode(), publish_time=ns(tk))
        for ev in rec.events:
            te = float(ev.get("t", 0.0))
            stamp = ns(te)
            kind = str(ev.get("kind", ""))
            msg = {"t": te, "kind": kind, "message": str(ev.get("message", "")),
                   "timestamp": {"sec": stamp // 1_000_000_000, "nsec": stamp % 1_000_000_000},
                   "level": _LOG_LEVEL.get(kind, 2), "name": kind, "file": "", "line": 0}
            w.add_message(ev_id, log_time=stamp, data=json.dumps(msg).encode(), publish_time=stamp)
        t_end = float(t[-1]) if t.size else 0.0
        w.add_message(stop_id, log_time=ns(t_end), publish_time=ns(t_end), data=json.dumps(
            {"t": t_end, "stop_reason": rec.stop_reason, "status": rec.status, "samples": int(t.size)}).encode())
        if rec.device_counters:
            c_sid = w.register_schema("hil.DeviceCounters", "jsonschema", json.dumps({"type": "object", "properties": {
                "t": {"type": "number"}, "counters": {"type": "object"}}}).encode())
            c_id = w.register_channel("/device_counters", "json", c_sid)
            w.add_message(c_id, log_time=ns(t_end), publish_time=ns(t_end),
                          data=json.dumps({"t": t_end, "counters": rec.device_counters}).encode())
        w.add_metadata("hil.record", {
            "format": "hil-record export", "source": str(rec.path), "rate_hz": repr(float(rec.rate_hz)),
            "scene_sha256": str(rec.scene_sha256), "created_utc": str(rec.attrs.get("created_utc", "")),
            "units": json.dumps(rec.units), "meta": json.dumps(rec.meta, default=str)})
        w.finish()
    logger.info("exported %s (%d samples, %d topics, %d events) -> %s", rec.path, t.size, len(topics),
                len(rec.events), out)
    return out


def export_csv(rec: RunRecord, out: Path) -> Path:
    """Write ``rec``'s channels as CSV at ``out`` (module docstring); returns ``out``."""
    header = ["t"]
    cols: list[np.ndarray] = [np.asarray(rec.t, dtype=np.float64)]
    units = []
    for name, a in rec.channels.items():
        a = np.asarray(a, dtype=np.float64)
        if a.ndim == 1:
            header.append(name)
            cols.append(a)
        else:
            flat = a.reshape(a.shape[0], -1)
            idx = list(np.ndindex(*a.shape[1:]))
            header += [f"{name}[{','.join(map(str, i))}]" for i in idx]
            cols += [flat[:, j] for j in range(flat.shape[1])]
        units.append(f"{name}={rec.units.get(name) or '-'}")
    bad = [h for h in header if "," in h.split("[")[0] or '"' in h]
    if bad:
        raise RecordError(f"{rec.path}: channel names with a comma or quote cannot be CSV columns: {bad}")
    header_text = ",".join(f'"{h}"' if "," in h else h for h in header)
    with out.open("w", encoding="utf-8") as fh:
        fh.write(f"# exported from {rec.path} (hil-record, rate {float(rec.rate_hz):.17g} Hz)\n")
        fh.write(f"# units: {'; '.join(units)}\n")
        fh.write(header_text + "\n")
        np.savetxt(fh, np.column_stack(cols), delimiter=",", fmt="%.17g")
    return out


#: format name -> exporter
FORMATS: dict[str, Callable[[RunRecord, Path], Path]] = {"mcap": export_mcap, "csv": export_csv}


def export_record(record: str | Path, out: str | Path | None, fmt: str) -> Path:
    """Export the record file ``record`` as ``fmt`` (``mcap`` or ``csv``) to ``out`` (default: the record
    with the format's suffix)."""
    if fmt not in FORMATS:
        raise RecordError(f"unknown export format {fmt!r} (formats: {', '.join(FORMATS)})")
    rec = RunRecord.open(record)
    target = Path(out) if out is not None else Path(record).with_suffix(f".{fmt}")
    return FORMATS[fmt](rec, target)
