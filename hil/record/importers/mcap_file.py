"""MCAP files with JSON or ROS 2 schemas (the importer of format ``mcap``; ``mcap``, ``mcap-ros2-support``;
extra ``formats``).

Messages encoded ``json`` (schema ``jsonschema``, as Foxglove writes them and as ``hil export --format
mcap`` does) are read with :func:`json.loads`; ``cdr`` messages (schema ``ros2msg``/``ros2idl``: a ROS 2 bag
in MCAP storage, or a file written by ros2 tooling) with the ROS 2 decoder of ``mcap-ros2-support``, from
the schema stored in the file. Sources, time and several rates: as for ROS bags
(:mod:`hil.record.importers.rosbag_file`, :mod:`hil.record.importers.stamped`): ``header.stamp`` when the
messages carry one, else ``log_time``.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from hil.record.hdf5 import RecordError
from hil.record.importers.base import Entry, Sampled, lazy
from hil.record.importers.mapping import ImportMapping
from hil.record.importers.stamped import TopicInfo, inventory_rows, sample_streams

logger = logging.getLogger(__name__)

__all__ = ["McapImporter"]


def _make_reader(fh: Any) -> Any:
    def load() -> Any:
        from mcap.reader import make_reader

        return make_reader

    return lazy("formats", "mcap", load)(fh)


class _Decoders:
    """Decoder per channel: JSON, or the ROS 2 CDR decoder of its schema."""

    def __init__(self, where: str) -> None:
        self.where = where
        self._by_channel: dict[int, Callable[[bytes], Any]] = {}
        self._ros2: Any = None

    def __call__(self, schema: Any, channel: Any) -> Callable[[bytes], Any]:
        dec = self._by_channel.get(channel.id)
        if dec is not None:
            return dec
        enc = channel.message_encoding
        if enc == "json":
            def dec(data: bytes) -> Any:
                return json.loads(data)
        elif enc == "cdr":
            if self._ros2 is None:
                def load() -> Any:
                    from mcap_ros2.decoder import DecoderFactory

                    return DecoderFactory()

                self._ros2 = lazy("formats", "mcap-ros2-support", load)
            made = self._ros2.decoder_for(enc, schema)
            if made is None:
                raise RecordError(f"{self.where}: {channel.topic}: cannot decode CDR with schema encoding "
                                  f"{getattr(schema, 'encoding', None)!r}")
            dec = made
        else:
            raise RecordError(f"{self.where}: {channel.topic}: message encoding {enc!r} is not read "
                              "(json and cdr are)")
        self._by_channel[channel.id] = dec
        return dec


class McapImporter:
    """Format ``mcap`` (module docstring)."""

    name = "mcap"
    suffixes: tuple[str, ...] = (".mcap",)
    extra: str | None = "formats"
    time_required = False
    resamples = True  # mapping's resample_hz (hil import --resample HZ)

    def claims(self, path: Path) -> bool:
        return path.suffix.lower() == ".mcap" and not path.is_dir()

    def _summary(self, path: Path) -> Any:
        with path.open("rb") as fh:
            try:
                summary = _make_reader(fh).get_summary()
            except RecordError:
                raise
            except Exception as exc:  # mcap raises its own errors (InvalidMagic, EndOfFile, ...)
                raise RecordError(f"{path}: not a readable MCAP file ({type(exc).__name__}: "
                                  f"{' '.join(str(exc).split())[:160]})") from None
        if summary is None:
            raise RecordError(f"{path}: the MCAP file has no summary section (not finished?)")
        return summary

    def source_names(self, path: Path) -> list[str]:
        return sorted({c.topic for c in self._summary(path).channels.values()})

    def default_mapping(self, path: Path) -> ImportMapping | None:
        return None

    def _messages(self, path: Path, topics: list[str] | None) -> Iterator[tuple[Any, Any, Any]]:
        with path.open("rb") as fh:
            reader = _make_reader(fh)
            try:
                yield from reader.iter_messages(topics=topics, log_time_order=True)
            except RecordError:
                raise
            except Exception as exc:
                raise RecordError(f"{path}: not a readable MCAP file ({type(exc).__name__}: "
                                  f"{' '.join(str(exc).split())[:160]})") from None

    def inventory(self, path: Path) -> list[Entry]:
        summary = self._summary(path)
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        decoders = _Decoders(str(path))
        infos = []
        for topic in sorted({c.topic for c in summary.channels.values()}):
            chans = [c for c in summary.channels.values() if c.topic == topic]
            count = sum(counts.get(c.id, 0) for c in chans)
            first = last = None
            sample = None
            schema_name = ""
            for schema, channel, message in self._messages(path, [topic]):
                if sample is None:
                    sample = decoders(schema, channel)(message.data)
                    first = message.log_time
                    schema_name = schema.name if schema is not None else channel.message_encoding
                last = message.log_time
            rate = (count - 1) / ((last - first) * 1e-9) if count > 1 and first is not None and last is not None \
                and last != first else None
            infos.append(TopicInfo(topic, schema_name, count, rate, sample))
        return inventory_rows(infos)

    def read(self, path: Path, m: ImportMapping) -> Sampled:
        where = str(path)
        summary = self._summary(path)
        topics = {c.topic for c in summary.channels.values()}
        wanted = sorted({s.partition(":")[0].strip() for name in m.channels for s in m.sources(name)})
        missing = [t for t in wanted if t not in topics]
        if missing:
            raise RecordError(f"{where}: no topic {', '.join(missing)} in the file (topics: "
                              f"{', '.join(sorted(topics)) or 'none'})")
        decoders = _Decoders(where)

        def messages() -> Iterator[tuple[str, int, Any]]:
            for schema, channel, message in self._messages(path, wanted):
                yield channel.topic, message.log_time, decoders(schema, channel)(message.data)

        s = sample_streams(messages(), m, where)
        s.provenance["topics"] = {c.topic: (summary.schemas[c.schema_id].name if c.schema_id in summary.schemas
                                            else c.message_encoding)
                                  for c in summary.channels.values() if c.topic in wanted}
        return s
