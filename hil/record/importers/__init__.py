"""Import runs recorded by other tools into the run-record format of :mod:`hil.record.hdf5`.

One importer per format (:mod:`hil.record.importers.base`: the protocol and the registry; more from the
entry-point group ``hil_certify.importers``):

==========  ===============================================  ==========================  ========
format      files                                            module                      extra
==========  ===============================================  ==========================  ========
``csv``     ``.csv``, ``.txt``, ``.tsv``                     :mod:`.table`               --
``mat``     MATLAB ``.mat`` v4-v7.2, and v7.3 (HDF5)          :mod:`.matlab`              --
``hdf5``    HDF5 by dataset path (``.h5``, ``.hdf5``)        :mod:`.hdf5_file`           --
``tdms``    LabVIEW TDMS (``.tdms``)                         :mod:`.tdms_file`           formats
``rosbag``  ROS 2 bags (folder: sqlite3 or MCAP storage),    :mod:`.rosbag_file`         ros
            ROS 1 ``.bag``
``mcap``    MCAP files with JSON or ROS 2 schemas            :mod:`.mcap_file`           formats
==========  ===============================================  ==========================  ========

Mapping (a dict, or a YAML/JSON *sidecar* file with the same content)::

    t: time                          # time column / variable / dataset [s]; bags, MCAP: the time-base topic
    motor.position: pos              # scalar channel <- one source
    master.position: [q1, q2]        # vector channel (2,) <- several sources
    slave.position: {columns: [q3, q4], unit: rad, description: "...", scale: 0.001}
    units: {motor.position: mm, t: ms}                      # optional: the unit of the values in the file
    descriptions: {motor.position: "encoder"}               # optional
    scale: {motor.effort_cmd: 35.15}                        # optional factors (e.g. N per V of a drive input)
    rate_hz: 1000                                           # optional (default 1 / median dt)
    meta: {devices: {...}}                                  # optional, merged into the record meta

How each format names a source (``/joint_states:position[joint1]`` for a bag): :mod:`.mapping`.
``hil import FILE --list`` (:func:`describe`) lists what a file holds.

A channel's value in the record is the file's value x ``scale`` x the factor from its unit to SI, and the
record states the SI unit (:mod:`hil.record.importers.units`: ``mm`` -> ``m``, ``deg`` -> ``rad``,
``ms`` -> ``s``; an unknown unit is refused). Without a unit in the mapping, a unit the file states
(TDMS ``unit_string``, an HDF5 ``units`` attribute) is used. ``hil import --scale NAME=FACTOR`` and
``--unit NAME=UNIT`` (``scale=`` / ``units=``) apply on top of whichever mapping is used. A sample rate
outside :data:`~hil.record.importers.base.PLAUSIBLE_RATE_HZ` from the time is warned about (time in ms
read as seconds).

Channels may also be nested under a ``channels:`` key. Without a mapping, a sidecar next to the file is
used (``run.yaml``, ``run.yml``, ``run.json``, or ``run.csv.yaml``/``.yml``/``.json``); failing that, CSV
and ``.mat`` files use their ``t``/``time`` column or variable and every other one as a channel of its name
(``x[0]``, ``x[1]``, ... form the vector channel ``x``: the layout :meth:`RunRecord.to_identify_dict`
produces). The other formats need a mapping.

Time must be finite and strictly increasing, and sampled on a grid: every interval must be an integer
multiple of the median interval within ``max_jitter`` (fraction of it). Missing samples (gaps) are
accepted, logged and recorded as ``import.gap`` events (the identification package diagnoses gaps);
decreasing or repeated times and off-grid (variable-step) time raise :class:`~hil.record.hdf5.RecordError`.
Sources at several rates are put onto one time base (:func:`hil.record.importers.base.align`; the
slower ones held, and named in the record's ``held_channels``). Imported records have an empty scene
text and scene hash and close with stop reason ``imported``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hil.record.hdf5 import RecordError
from hil.record.importers.base import (
    PLAUSIBLE_RATE_HZ,
    Entry,
    Importer,
    importer_for,
    importers,
    register,
    write_record,
)
from hil.record.importers.mapping import ImportMapping, find_sidecar, load_sidecar, normalize, with_default_time

logger = logging.getLogger(__name__)

__all__ = ["PLAUSIBLE_RATE_HZ", "Entry", "Importer", "describe", "import_csv", "import_file", "import_mat",
           "importer_for", "importers", "register"]


def _register_builtin() -> None:
    from hil.record.importers.hdf5_file import Hdf5Importer
    from hil.record.importers.matlab import MatImporter
    from hil.record.importers.mcap_file import McapImporter
    from hil.record.importers.rosbag_file import RosbagImporter
    from hil.record.importers.table import CsvImporter
    from hil.record.importers.tdms_file import TdmsImporter

    for imp in (CsvImporter(), MatImporter(), Hdf5Importer(), TdmsImporter(), RosbagImporter(), McapImporter()):
        register(imp)


_register_builtin()


def _check_input(src: Path, imp: Importer) -> None:
    if not src.exists():
        raise RecordError(f"{src}: no such file")
    if src.is_dir() and imp.name != "rosbag":
        raise RecordError(f"{src}: is a folder, not a {imp.name} file")


def resolve_mapping(src: Path, imp: Importer, mapping: Mapping[str, Any] | None, sidecar: str | Path | None,
                    scale: Mapping[str, float] | None = None, units: Mapping[str, str] | None = None
                    ) -> ImportMapping:
    """The mapping of an import: ``mapping`` (``--map``), else the ``sidecar`` (or one found next to the
    file), else the importer's default; then ``scale``/``units`` on top."""
    where = str(src)
    if mapping is not None and sidecar is not None:
        raise RecordError(f"{src}: give mapping or sidecar, not both")
    if mapping is not None:
        if imp.time_required:
            what = "variable" if imp.name == "mat" else "column"
            mapping = with_default_time(mapping, imp.source_names(src), where, what)
        m = normalize(mapping, f"{where}: mapping", time_required=imp.time_required)
    else:
        side = Path(sidecar) if sidecar is not None else (find_sidecar(src) if src.is_file() else None)
        if side is not None:
            if sidecar is None:
                logger.info("%s: using sidecar %s", src, side)
            m = normalize(load_sidecar(side), str(side), time_required=imp.time_required)
        else:
            dm = imp.default_mapping(src)
            if dm is None:
                raise RecordError(f"{src}: name the channels to import: hil import {src.name} --map CHANNEL=SOURCE "
                                  f"(hil import {src.name} --list shows the sources)")
            m = dm
    m.override(scale, units, where)
    if m.resample_hz is not None and not getattr(imp, "resamples", False):
        raise RecordError(f"{src}: resampling (--resample, resample_hz) applies to time-stamped formats (ROS bags, "
                          f"MCAP, TDMS), not to {imp.name}")
    return m


def import_file(
    path: str | Path,
    out: str | Path,
    *,
    mapping: Mapping[str, Any] | None = None,
    sidecar: str | Path | None = None,
    meta: Mapping[str, Any] | None = None,
    max_jitter: float = 0.1,
    scale: Mapping[str, float] | None = None,
    units: Mapping[str, str] | None = None,
    fmt: str | None = None,
    importer: Importer | None = None,
    resample_hz: float | None = None,
) -> Path:
    """Convert a run recorded by another tool into a run record at ``out``; return ``out``.

    The format comes from the file (:func:`importer_for`; ``fmt`` names it, ``importer`` gives one).
    ``mapping`` / ``sidecar``: module docstring; ``scale`` / ``units`` (channel or ``t`` -> factor /
    the file's unit) apply on top of the mapping. ``meta`` is merged into the record meta.
    ``max_jitter``: tolerated deviation of a time interval from a multiple of the median interval
    (fraction of it). ``resample_hz``: bags, MCAP, TDMS: every channel onto a uniform grid at this rate
    (:func:`hil.record.importers.base.align`), for time stamps that jitter more than ``max_jitter``."""
    src = Path(path)
    imp = importer or importer_for(src, fmt)
    _check_input(src, imp)
    m = resolve_mapping(src, imp, mapping, sidecar, scale, units)
    if resample_hz is not None:
        if not (0 < resample_hz < float("inf")):
            raise RecordError(f"{src}: --resample must be a positive number of Hz, got {resample_hz!r}")
        if not getattr(imp, "resamples", False):
            raise RecordError(f"{src}: resampling (--resample) applies to time-stamped formats (ROS bags, MCAP, "
                              f"TDMS), not to {imp.name}")
        m.resample_hz = float(resample_hz)
    sampled = imp.read(src, m)
    fmt_name = str(getattr(imp, "format_of", lambda _p: imp.name)(src))
    return write_record(out, sampled, m, src, fmt_name, meta, max_jitter)


def import_csv(path: str | Path, out: str | Path, *, delimiter: str | None = None, **kw: Any) -> Path:
    """:func:`import_file` of a CSV / TXT / TSV table (``delimiter``: ``,`` ``;`` or tab; None: guessed
    from the header)."""
    from hil.record.importers.table import CsvImporter

    src = Path(path)
    if src.is_dir():
        raise RecordError(f"{src}: is a folder, not a CSV file")
    return import_file(path, out, importer=CsvImporter(delimiter), **kw)


def import_mat(path: str | Path, out: str | Path, **kw: Any) -> Path:
    """:func:`import_file` of a MATLAB ``.mat`` file (v4-v7.2 with scipy, v7.3 with h5py)."""
    from hil.record.importers.matlab import MatImporter

    src = Path(path)
    if src.is_dir():
        raise RecordError(f"{src}: is a folder, not a .mat file")
    return import_file(path, out, importer=MatImporter(), **kw)


def describe(path: str | Path, fmt: str | None = None) -> tuple[str, list[Entry]]:
    """The format of ``path`` and what it holds (:class:`Entry` rows): ``hil import FILE --list``."""
    src = Path(path)
    imp = importer_for(src, fmt)
    _check_input(src, imp)
    return str(getattr(imp, "format_of", lambda _p: imp.name)(src)), imp.inventory(src)
