"""CSV / TXT / TSV tables: a header row, one sample per row (the importer of format ``csv``).

The delimiter (``,`` ``;`` or tab) is guessed from the header; ``#`` lines and blank lines are skipped;
empty cells and ``nan``/``na``/``null`` read as NaN. Sources are column names. Without a mapping, the
time column is ``t`` or ``time`` and every other column becomes a channel of its name (``x[0]``,
``x[1]``, ... form the vector channel ``x``).
"""

from __future__ import annotations

import csv
import io
import logging
from pathlib import Path

import numpy as np

from hil.inputs import read_text_file
from hil.record.hdf5 import RecordError
from hil.record.importers.base import Entry, Sampled, rate_of
from hil.record.importers.mapping import ImportMapping, default_mapping

logger = logging.getLogger(__name__)

__all__ = ["CsvImporter"]


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


class CsvImporter:
    """Format ``csv`` (module docstring). ``delimiter``: ``,`` ``;`` or tab (None: guessed)."""

    name = "csv"
    suffixes: tuple[str, ...] = (".csv", ".txt", ".tsv")
    extra: str | None = None
    time_required = True

    def __init__(self, delimiter: str | None = None) -> None:
        self.delimiter = delimiter
        self._cache: tuple[tuple[str, float, str | None], tuple[list[str], np.ndarray]] | None = None

    def _load(self, path: Path) -> tuple[list[str], np.ndarray]:
        key = (str(path.resolve()), path.stat().st_mtime, self.delimiter)
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, _read_csv(path, self.delimiter))
        return self._cache[1]

    def claims(self, path: Path) -> bool:
        return path.suffix.lower() in self.suffixes and not path.is_dir()

    def source_names(self, path: Path) -> list[str]:
        return self._load(path)[0]

    def default_mapping(self, path: Path) -> ImportMapping:
        return default_mapping(self.source_names(path), str(path), "column")

    def inventory(self, path: Path) -> list[Entry]:
        header, rows = self._load(path)
        lower = {h.lower(): i for i, h in enumerate(header)}
        it = lower.get("t", lower.get("time"))
        rate = None
        if it is not None and rows.shape[0] >= 2 and np.all(np.diff(rows[:, it]) > 0):
            rate = rate_of(rows[:, it])
        return [Entry(h, "column", rows.shape[0], rate, note="time (default)" if i == it else "")
                for i, h in enumerate(header)]

    def read(self, path: Path, m: ImportMapping) -> Sampled:
        header, rows = self._load(path)
        col = {h: i for i, h in enumerate(header)}

        def get(name: str, channel: str) -> np.ndarray:
            if name not in col:
                raise RecordError(f"{path}: channel {channel!r}: no column {name!r} (columns: {', '.join(header)})")
            return rows[:, col[name]]

        t = get(m.time, "t").copy()
        data = {}
        for name, cols in m.channels.items():
            data[name] = get(cols, name) if isinstance(cols, str) else np.column_stack([get(c, name) for c in cols])
        return Sampled(t=t, data=data)
