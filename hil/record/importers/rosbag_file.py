"""ROS bags (the importer of format ``rosbag``, rosbags: pure Python, no ROS install; extra ``ros``).

Reads ROS 2 bags (a folder with ``metadata.yaml`` and the storage files, sqlite3 ``.db3`` or ``.mcap``)
and ROS 1 ``.bag`` files with :class:`rosbags.highlevel.AnyReader`. Message types come from the bag
(rosbag2 stores their definitions since Iron/Humble-MCAP; ROS 1 always does), else from the standard
ROS 2 Humble types (``sensor_msgs/JointState``, ``geometry_msgs/WrenchStamped``, ``std_msgs/Float64``,
``std_msgs/Float64MultiArray``, ... every type rosbags ships).

Sources: ``/topic:field[selector]`` (:mod:`hil.record.importers.mapping`), e.g.
``motor.position=/joint_states:position[joint1]``, ``spring_ft.wrench=/ft:wrench.force.z``,
``motor.effort_cmd=/effort_cmd:data``. Time: ``header.stamp``, else the bag's receive time; several
topics at different rates onto one time base, the slower held (:mod:`hil.record.importers.stamped`).
A ROS 2 bag stored as a single ``.mcap`` file without its folder is read by the ``mcap`` importer.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hil.record.hdf5 import RecordError
from hil.record.importers.base import Entry, Sampled, lazy
from hil.record.importers.mapping import ImportMapping
from hil.record.importers.stamped import TopicInfo, inventory_rows, sample_streams

logger = logging.getLogger(__name__)

__all__ = ["RosbagImporter"]


def _reader(path: Path) -> Any:
    def load() -> Any:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        return AnyReader, get_typestore(Stores.ROS2_HUMBLE)

    any_reader, typestore = lazy("ros", "rosbags", load)
    return any_reader([path], default_typestore=typestore)


def _errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError

    return (AnyReaderError, OSError, ValueError, KeyError, EOFError)


class _Open:
    """The bag opened for reading, errors as one line naming it."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.reader = _reader(path)

    def __enter__(self) -> Any:
        try:
            self.reader.open()
        except _errors() as exc:
            raise RecordError(f"{self.path}: not a readable ROS bag ({type(exc).__name__}: "
                              f"{' '.join(str(exc).split())[:200]})") from None
        return self.reader

    def __exit__(self, *exc: object) -> None:
        try:
            self.reader.close()
        except _errors():
            pass


class RosbagImporter:
    """Format ``rosbag`` (module docstring)."""

    name = "rosbag"
    suffixes: tuple[str, ...] = (".bag", ".db3")
    extra: str | None = "ros"
    time_required = False
    resamples = True  # mapping's resample_hz (hil import --resample HZ)

    def claims(self, path: Path) -> bool:
        if path.is_dir():
            return (path / "metadata.yaml").is_file()
        return path.suffix.lower() in (".bag", ".db3")

    def _bag(self, path: Path) -> Path:
        # a rosbag2 storage file given on its own: its folder is the bag
        return path.parent if path.suffix.lower() == ".db3" and (path.parent / "metadata.yaml").is_file() else path

    def source_names(self, path: Path) -> list[str]:
        with _Open(self._bag(path)) as r:
            return sorted({c.topic for c in r.connections})

    def default_mapping(self, path: Path) -> ImportMapping | None:
        return None

    def inventory(self, path: Path) -> list[Entry]:
        infos = []
        with _Open(self._bag(path)) as r:
            for topic in sorted({c.topic for c in r.connections}):
                conns = [c for c in r.connections if c.topic == topic]
                count = sum(c.msgcount for c in conns)
                first_ns = last_ns = None
                sample = None
                for conn, ts, raw in r.messages(connections=conns):
                    if sample is None:
                        sample = self._decode(r, raw, conn)
                        first_ns = ts
                    last_ns = ts
                rate = (count - 1) / ((last_ns - first_ns) * 1e-9) if count > 1 and last_ns != first_ns \
                    and first_ns is not None and last_ns is not None else None
                infos.append(TopicInfo(topic, conns[0].msgtype, count, rate, sample))
        return inventory_rows(infos)

    def _decode(self, r: Any, raw: bytes, conn: Any) -> Any:
        try:
            return r.deserialize(raw, conn.msgtype)
        except Exception as exc:  # rosbags raises its own errors on unknown types or bad data
            raise RecordError(f"{self.path_of(conn)}: cannot decode a {conn.msgtype} message on {conn.topic} "
                              f"({type(exc).__name__}: {' '.join(str(exc).split())[:160]})") from None

    @staticmethod
    def path_of(conn: Any) -> str:
        return str(getattr(conn, "owner", "") or conn.topic)

    def read(self, path: Path, m: ImportMapping) -> Sampled:
        bag = self._bag(path)
        where = str(path)
        with _Open(bag) as r:
            topics = {c.topic for c in r.connections}
            wanted = {s.partition(":")[0].strip() for name in m.channels for s in m.sources(name)}
            missing = sorted(wanted - topics)
            if missing:
                raise RecordError(f"{where}: no topic {', '.join(missing)} in the bag (topics: "
                                  f"{', '.join(sorted(topics)) or 'none'})")
            conns = [c for c in r.connections if c.topic in wanted]

            def messages() -> Iterator[tuple[str, int, Any]]:
                for conn, ts, raw in r.messages(connections=conns):
                    yield conn.topic, ts, self._decode(r, raw, conn)

            s = sample_streams(messages(), m, where)
            s.provenance["topics"] = {c.topic: c.msgtype for c in conns}
        return s
