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

* :func:`stage_out_dir` -- a folder written *as a unit* (``hil certify``'s certificate folder):
  everything is written into a new sibling ``<name>.incomplete-<6 hex>`` and moved into place by
  :meth:`StagedFolder.commit`, so the folder at ``path`` is at every instant either the old one or
  the complete new one (see the class docstring). With ``overwrite`` the old folder is replaced
  *as a whole*; it may hold only the names the command itself writes (``owned``), so a folder of
  other files is never swept away.

A path under a regular file, an existing regular file where a folder is wanted, or a place without
write permission raises :class:`OutputPathError` (a :class:`~hil.errors.HilError`) with a one-line
message naming the path; never a bare ``FileNotFoundError`` / ``FileExistsError``.
"""

from __future__ import annotations

import contextlib
import ctypes
import datetime as _dt
import errno
import logging
import os
import secrets
import shutil
import signal
import stat
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["OutputPathError", "StagedFolder", "check_out_dir", "check_out_file", "default_out_dir", "prepare_out_dir",
           "prepare_out_file", "remove_if_empty", "stage_out_dir"]


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


# ---------------------------------------------------------------------------------------------
# a folder written as a unit


_RENAME_EXCHANGE = 2  # linux/fs.h
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap the two paths in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``). False when the
    system or the file system does not offer it (the caller then renames in two steps)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(a), None, str(b))


def _discard(p: Path) -> None:
    """Remove a replaced folder (symbolic links inside are removed, never followed)."""
    shutil.rmtree(p, ignore_errors=True)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP recorded instead of handled for the block, then re-raised (in
    the order received) under the handlers that were in place. Main thread only; elsewhere a no-op."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got: list[int] = []
    sigs = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP]
    old = {s: signal.signal(s, lambda n, f: got.append(n)) for s in sigs}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)
        for n in dict.fromkeys(got):
            signal.raise_signal(n)


def _sibling(final: Path, tag: str) -> Path:
    return final.with_name(f"{final.name}.{tag}-{secrets.token_hex(3)}")


def _holds_files(p: Path) -> bool:
    try:
        return any(not q.is_dir() or q.is_symlink() for q in p.rglob("*"))
    except OSError:
        return True


class StagedFolder:
    """A folder built under a temporary sibling name and moved into place as a unit.

    ``path`` (``<final>.incomplete-<hex>``, new and empty) is where everything is written; nothing
    is written at ``final`` itself, so a link planted there is never followed. :meth:`commit` moves
    the staged folder to ``final``: a plain rename when ``final`` does not exist, else an atomic
    exchange of the two (``renameat2(RENAME_EXCHANGE)``) followed by the removal of the old one,
    which then sits at the staging name. Where the exchange is not offered the old folder is first
    renamed to ``<final>.replaced-<hex>`` (between the two renames ``final`` does not exist; the old
    folder is still whole under that name). A process killed at any point therefore leaves at
    ``final`` the old folder or the complete new one, and at most an ``.incomplete-`` or
    ``.replaced-`` sibling beside it.

    :meth:`abandon` (the command failed or was stopped): a staged folder holding no file is
    removed; one holding files (records of an interrupted run) becomes ``final`` when there is no
    old folder, and otherwise stays beside it under its ``.incomplete-`` name (returned, so the
    message can name it)."""

    def __init__(self, final: Path, path: Path) -> None:
        self.final = final
        self.path = path
        self.done = False

    def commit(self) -> Path:
        """Move the staged folder to ``final`` (class docstring); returns ``final``. Signals are held
        during the renames (their handlers run right after)."""
        final = self.final
        old: Path | None = None
        with _signals_held():
            try:
                st = os.lstat(final)
            except FileNotFoundError:
                st = None
            try:
                if st is None:
                    os.rename(self.path, final)
                elif not stat.S_ISDIR(st.st_mode):
                    raise OutputPathError(f"{final}: was replaced by a file or link while the folder was "
                                          f"written; the new folder is {self.path}")
                elif _exchange(self.path, final):
                    old = _sibling(final, "replaced")
                    os.rename(self.path, old)  # the old folder, named for what it is until removed
                else:
                    old = _sibling(final, "replaced")
                    os.rename(final, old)
                    os.rename(self.path, final)
            except OSError as exc:
                raise OutputPathError(f"{final}: cannot move the new folder into place ({exc.strerror or exc}); "
                                      f"it is complete in {self.path}") from None
            self.done = True
        if old is not None:
            _discard(old)
        logger.debug("%s moved into place as %s", self.path, final)
        return final

    def abandon(self) -> Path | None:
        """After a failure: where the partial results are (``final``, the staged folder) or None
        when there were none (class docstring)."""
        if self.done or not self.path.is_dir():
            return None
        self.done = True
        if not _holds_files(self.path):
            _discard(self.path)
            return None
        if not os.path.lexists(self.final):
            try:
                os.rename(self.path, self.final)
                return self.final
            except OSError:
                pass
        return self.path


def stage_out_dir(path: str | Path | None, *, default_stem: str, overwrite: bool = False,
                  owned: Iterable[str] = ()) -> StagedFolder:
    """Check the output folder and create its staging sibling (:class:`StagedFolder`).

    ``path`` None: a new name ``<default_stem>-<UTC time>-<6 hex>``. An explicit ``path`` that is a
    symbolic link, or exists and is not a folder, is refused; a non-empty folder is refused unless
    ``overwrite``, and then also when it holds a name not in ``owned`` (the names the command writes
    there), so ``--overwrite`` replaces an earlier result of the same command and nothing else."""
    if path is None:
        final = default_out_dir(default_stem)
        _check_creatable(final, "folder")
    else:
        final = Path(path)
        if final.is_symlink():
            raise OutputPathError(f"{final}: is a symbolic link; give the folder itself (the output folder is "
                                  "replaced as a whole, never written through a link)")
        check_out_dir(final, overwrite=overwrite)
        if final.is_dir() and overwrite:
            allowed = set(owned)
            foreign = sorted(q.name for q in final.iterdir() if q.name not in allowed)
            if foreign:
                raise OutputPathError(f"{final}: holds {foreign[0]!r}, which this command does not write; "
                                      "--overwrite replaces the folder as a whole: move that away or choose "
                                      "another --out")
    try:
        final.absolute().parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"{final}: cannot create the folder ({exc.strerror or exc})") from None
    for _ in range(20):
        staging = _sibling(final, "incomplete")
        try:
            staging.mkdir()
        except FileExistsError:
            continue
        except OSError as exc:
            raise OutputPathError(f"{final}: cannot create the folder ({exc.strerror or exc})") from None
        logger.debug("output folder %s staged in %s", final, staging)
        return StagedFolder(final, staging)
    raise OutputPathError(f"{final}: cannot find a free staging name")  # pragma: no cover
