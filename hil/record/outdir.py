"""Output folders and files that never overwrite by accident.

Every command that writes results (``hil run``, ``hil certify``, ``hil import``, ``hil identify
--out``, ``hil report --out``) gets its output place from here:

* :func:`prepare_out_dir` -- a folder. Without an explicit path it makes a new one named
  ``<default_stem>-<UTC time>-<6 hex digits>`` (e.g. ``runs/sdea_bench-20260101T120000Z-3fa9c1``), so
  two runs started in the same second never share a folder. An explicit path that exists and is
  not empty is refused unless ``overwrite`` is given (then files of the same name are replaced;
  nothing else in the folder is deleted).
* :func:`prepare_out_file` -- one file (an imported record): an existing file is refused unless
  ``overwrite``.
* :func:`check_out_dir` / :func:`check_out_file` -- the same checks without creating anything, so
  a command can validate every input before it touches the disk.

A path under a regular file, an existing regular file where a folder is wanted, or a place without
write permission raises :class:`OutputPathError` (a :class:`~hil.errors.HilError`) with a one-line
message naming the path; never a bare ``FileNotFoundError`` / ``FileExistsError``.
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
import secrets
from pathlib import Path

from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["OutputPathError", "check_out_dir", "check_out_file", "default_out_dir", "prepare_out_dir",
           "prepare_out_file", "remove_if_empty"]


class OutputPathError(HilError):
    """An output folder or file cannot be used (exists, under a file, not writable)."""


def default_out_dir(default_stem: str | Path) -> Path:
    """``<default_stem>-<UTC time, seconds>-<6 random hex digits>`` (not created)."""
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    return Path(f"{default_stem}-{stamp}-{secrets.token_hex(3)}")


def _nearest_existing(p: Path) -> Path:
    q = p.absolute()
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


def _check_creatable(p: Path, what: str) -> None:
    """``p`` does not exist: its nearest existing ancestor must be a writable folder."""
    anc = _nearest_existing(p)
    if not anc.is_dir():
        raise OutputPathError(f"{p}: cannot create the {what}: {anc} is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise OutputPathError(f"{p}: cannot create the {what}: no write permission in {anc}")


def check_out_dir(path: str | Path, *, overwrite: bool = False) -> Path:
    """Check that ``path`` can be used as a fresh output folder; create nothing. Returns the path."""
    p = Path(path)
    if p.is_dir():
        try:
            nonempty = any(p.iterdir())
        except OSError as exc:
            raise OutputPathError(f"{p}: cannot read the folder ({exc.strerror or exc})") from None
        if nonempty and not overwrite:
            raise OutputPathError(f"{p}: exists and is not empty; use --overwrite to replace its files "
                                  "or choose another --out")
        if not os.access(p, os.W_OK | os.X_OK):
            raise OutputPathError(f"{p}: no write permission")
        return p
    if p.exists() or p.is_symlink():
        raise OutputPathError(f"{p}: exists and is not a folder")
    _check_creatable(p, "folder")
    return p


def _mkdir(p: Path, exist_ok: bool) -> None:
    try:
        p.mkdir(parents=True, exist_ok=exist_ok)
    except FileExistsError:
        raise
    except OSError as exc:
        raise OutputPathError(f"{p}: cannot create the folder ({exc.strerror or exc})") from None


def prepare_out_dir(path: str | Path | None, *, default_stem: str, overwrite: bool = False) -> Path:
    """Create and return the output folder (see the module docstring).

    ``path`` None: a new folder ``<default_stem>-<UTC time>-<6 hex>``; an explicit ``path`` must not
    exist, or be an empty folder, or ``overwrite`` must be set. Raises :class:`OutputPathError`."""
    if path is None:
        for _ in range(20):
            p = default_out_dir(default_stem)
            _check_creatable(p, "folder")
            try:
                _mkdir(p, exist_ok=False)
            except FileExistsError:
                continue
            logger.debug("output folder %s", p)
            return p
        raise OutputPathError(f"{default_stem}: cannot find a free output folder name")  # pragma: no cover
    p = check_out_dir(path, overwrite=overwrite)
    try:
        _mkdir(p, exist_ok=True)
    except FileExistsError:  # created as a file between the check and here
        raise OutputPathError(f"{p}: exists and is not a folder") from None
    return p


def check_out_file(path: str | Path, *, overwrite: bool = False) -> Path:
    """Check that a file can be written at ``path`` without replacing one (unless ``overwrite``)."""
    p = Path(path)
    if p.is_dir():
        raise OutputPathError(f"{p}: is a folder; give a file name")
    if p.exists():
        if not overwrite:
            raise OutputPathError(f"{p}: exists; use --overwrite to replace it or choose another --out")
        if not os.access(p, os.W_OK):
            raise OutputPathError(f"{p}: no write permission")
        return p
    _check_creatable(p, "file")
    return p


def prepare_out_file(path: str | Path, *, overwrite: bool = False) -> Path:
    """Check ``path`` (:func:`check_out_file`) and create its parent folders; returns the path."""
    p = check_out_file(path, overwrite=overwrite)
    if not p.parent.is_dir():
        try:
            _mkdir(p.parent, exist_ok=True)
        except FileExistsError:
            raise OutputPathError(f"{p}: cannot create the file: {p.parent} is not a folder") from None
    return p


def remove_if_empty(path: str | Path) -> bool:
    """Remove ``path`` and its sub-folders when they hold no file (a command that failed before
    writing anything leaves nothing behind). Returns True when removed."""
    p = Path(path)
    if not p.is_dir():
        return False
    try:
        inside = list(p.rglob("*"))
    except OSError:
        return False
    if any(not q.is_dir() or q.is_symlink() for q in inside):
        return False
    for sub in sorted(inside, key=lambda q: len(q.parts), reverse=True):
        try:
            sub.rmdir()
        except OSError:
            return False
    try:
        p.rmdir()
    except OSError:
        return False
    return True
