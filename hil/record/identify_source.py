"""The suite's run records (:mod:`hil.record.hdf5`, :mod:`hil.record.importers`) as identification sources.

:mod:`hil.identify` reads records only through its interface :class:`hil.identify.source.RecordSource`
and file backends (:class:`hil.identify.source.RecordBackend`); this module is the backend of the
suite's own HDF5 run records (``.h5``; ``.csv`` and ``.mat`` imported into a temporary record with the
importers' defaults). It is registered in the entry-point group ``hil.identify.record_backends``
(pyproject.toml) and on import. The record's scene text is parsed here (:mod:`hil.scene.spec`), so the
identification side never imports the scene schema.
"""

from __future__ import annotations

import logging
import tempfile
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import HilError, SceneError
from hil.identify.errors import ModelSpecError
from hil.identify.source import register_backend
from hil.record.hdf5 import RecordError, RunRecord, store_identification

logger = logging.getLogger(__name__)

__all__ = ["BACKEND", "RunRecordSource", "open_source", "scene_of_record"]


def scene_of_record(rec: Any) -> Any:
    """The validated :class:`hil.scene.spec.Scene` stored in a record, or None (imported records have no
    scene text; an unreadable scene is logged and ignored)."""
    text = getattr(rec, "scene_text", "") or ""
    if not text.strip():
        return None
    import yaml  # type: ignore[import-untyped]  # PyYAML ships no stubs (types-PyYAML is not a dependency)

    from hil.scene.spec import scene_from_dict

    try:
        return scene_from_dict(yaml.safe_load(text), label="record scene", source_text=text)
    except (SceneError, yaml.YAMLError) as exc:
        logger.warning("the record's scene cannot be parsed (%s): inferring from channel names only", exc)
        return None


@dataclass
class RunRecordSource:
    """A :class:`hil.record.hdf5.RunRecord` with its scene parsed: a :class:`hil.identify.source.RecordSource`."""

    record: RunRecord
    scene: Any

    @property
    def path(self) -> Any:
        return self.record.path

    @property
    def t(self) -> NDArray[np.float64]:
        return np.asarray(self.record.t, float)

    @property
    def rate_hz(self) -> float:
        return float(self.record.rate_hz)

    @property
    def meta(self) -> Mapping[str, Any]:
        return self.record.meta

    @property
    def results(self) -> Mapping[str, Any]:
        return self.record.results

    @property
    def scene_sha256(self) -> str:
        return str(self.record.scene_sha256)

    def to_identify_dict(self) -> dict[str, Any]:
        return self.record.to_identify_dict()


def open_source(path_or_record: str | Path | RunRecord) -> RunRecordSource:
    """A record file (``.h5``, ``.csv``, ``.mat``) or an open :class:`RunRecord` as an identification
    source. Raises :class:`RecordError` (one line naming the file) when the file cannot be read."""
    if isinstance(path_or_record, RunRecord):
        return RunRecordSource(path_or_record, scene_of_record(path_or_record))
    p = Path(path_or_record)
    suffix = p.suffix.lower()
    if suffix not in (".csv", ".mat"):
        rec = RunRecord.open(p)  # raises RecordError naming the file
        return RunRecordSource(rec, scene_of_record(rec))
    try:  # an unreadable file is one line naming it, never a traceback
        from hil.record.importers import import_csv, import_mat

        with tempfile.TemporaryDirectory(prefix="hil-identify-") as tmp:
            out = Path(tmp) / (p.stem + ".h5")
            (import_csv if suffix == ".csv" else import_mat)(p, out)
            rec = RunRecord.open(out)
    except HilError:
        raise
    except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:  # UnicodeDecodeError is a ValueError
        raise RecordError(f"{p}: not a readable {suffix} record ({' '.join(str(exc).split())[:200]})") from None
    except Exception as exc:  # scipy's MatReadError derives from Exception only
        if type(exc).__name__ != "MatReadError":
            raise
        raise RecordError(f"{p}: not a readable .mat file ({' '.join(str(exc).split())[:200]})") from None
    return RunRecordSource(rec, scene_of_record(rec))


class _Backend:
    """:class:`hil.identify.source.RecordBackend` of the suite's run records."""

    #: "*": also every suffix no other backend claims (``RunRecord.open`` says what the file is not)
    suffixes = (".h5", ".hdf5", ".csv", ".mat", "*")
    error = RecordError

    def open(self, path: Path) -> RunRecordSource:
        return open_source(path)

    def adapt(self, obj: Any) -> RunRecordSource | None:
        return open_source(obj) if isinstance(obj, RunRecord) else None

    def store(self, path: str | Path, name: str, samples: NDArray[np.float64], summary: Mapping[str, Any]) -> None:
        store_identification(path, name, samples, summary)

    def import_to(self, src: str | Path, out: str | Path, *, overwrite: bool = False) -> Path:
        from hil.record.importers import import_csv, import_mat
        from hil.record.outdir import check_out_file

        s = Path(src)
        if not s.is_file():
            raise ModelSpecError(f"{s}: no such file")
        check_out_file(str(out), overwrite=overwrite)
        return Path((import_csv if s.suffix.lower() == ".csv" else import_mat)(s, out))


#: the backend instance (the entry point's target)
BACKEND = _Backend()
register_backend(BACKEND)
