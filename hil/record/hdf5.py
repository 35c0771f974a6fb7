"""Run records: every sample streamed to HDF5 as it is taken, readable even after ``kill -9``.

Writer: :class:`RecordWriter` (context manager; this module). Reader: :class:`~hil.record.reader.RunRecord`
(:mod:`hil.record.reader`). The format's constants, errors, channel spec and JSON encoding:
:mod:`hil.record.format`. CLI: :func:`~hil.record.replay.replay` (``hil replay RECORD [--json]``,
:mod:`hil.record.replay`). All are importable from here. Importers of other tools' runs:
:mod:`hil.record.importers`.

File layout (format ``hil-record``, ``format_version`` 2; all values SI, time in seconds)::

    /                         root attributes:
        format                "hil-record"
        format_version        2 (1: /status and /results were groups written at close; still read)
        created_utc           ISO 8601 UTC time the file was created
        software.hil|numpy|scipy|h5py|hdf5|python   versions (strings)
        seed                  meta["seed"] when it is an integer (absent otherwise)
        rate_hz               nominal sample rate [Hz]
        scene_sha256          SHA-256 of the scene as given by the scene loader ("" for imports)
        flush_every_s         flush period in run time [s]; flush_samples = round(rate_hz * flush_every_s)
        meta                  JSON object: the run's meta (device identities, experiment list, ...)
    /scene                    scalar UTF-8 string dataset: the exact scene YAML text
    /t                        float64 (n,), resizable, chunked, fill NaN: sample times [s], strictly increasing
    /channels/<name>          float64 (n, *shape), resizable along axis 0, fill NaN; attrs unit, description
    /events                   uint8 (m,), resizable: UTF-8 JSON lines {"t": s, "kind": str, "message": str}
    /results                  uint8, resizable: UTF-8 JSON lines {"experiment", "results", "arrays"}, one per
                              set_results (the last per experiment counts); numpy arrays in "results" are
                              {"__dataset__": key} and "arrays"[key] = [offset, nbytes] in /results_npy
    /results_npy              uint8, resizable: the arrays in .npy format, back to back
    /device_counters          uint8, resizable: UTF-8 JSON lines {"t": s, "counters": {device: {name: int}}},
                              one per set_device_counters (the last counts)
    /status                   uint8 (1024,), fixed: all zeros until close() overwrites it in place with one
                              JSON line {stop_reason, status, closed_utc, samples}, zero padded.
                              Zeros => the run never closed (killed, power loss): the samples up to the
                              last flush are still there

Crash safety. Every object is created, and the file flushed, before SWMR mode is switched on; after
that the writer only appends to the datasets above (resize + write) and overwrites ``/status`` in
place, so nothing is ever created, reopened or re-laid out: a SIGKILL at any moment -- also inside
:meth:`RecordWriter.close` -- leaves a file that SWMR-reads with every sample up to the last flush.
Samples are buffered in memory and written in blocks of ``flush_samples`` samples (or when
``flush_every_s`` of run time ``t`` has passed since the first buffered sample, whichever comes
first), each block followed by ``f.flush()``. Channels are written before ``/t``; the reader keeps
``min(len)`` over all of them, then the longest prefix of finite, strictly increasing times, so a
kill in the middle of a flush never yields a half-written sample. The writer tracks the rows and
bytes the file holds and writes each block at those absolute positions, so a block is never
written twice (an interrupted write that is retried lands on the same rows).

Background writing (``RecordWriter(background=True)``, used by the realtime runner): the same
blocks are written, in the same order and to the same positions, by a writer thread instead of
the appending thread; ``append`` only copies the sample into a preallocated block. During the run
every h5py call on the file is made by that thread. The blocks not yet written are bounded
(``max_pending_blocks``): a writer that falls behind further is a :class:`RecordLagError` (the
samples are kept and written by ``close``), never unbounded memory or a silent loss. A kill loses
at most the blocks not yet written; a write error in the thread fails the writer as above and is
raised by the next call (see :class:`RecordWriter`).

Writer process (``background="process"``, the realtime runner's default): as above, but the blocks
are preallocated in shared memory (``multiprocessing.shared_memory``) and every h5py call is made
by a writer process (``python -c``, connected by a socket), to which the writer thread hands each
block's index and waits for the answer. The appending process closes its own handle once the
layout is written; the writer process opens the file for SWMR writing in one call, writes the
blocks, the status and closes it. The loop's process then never waits for the interpreter lock
held by h5py (a block costs milliseconds of HDF5 CPU, all of it under that lock). The guarantees
are the same: same file contents; a write error there (full disk, file-size limit, EIO) is the
caller's failed writer with the same one-line reason; a writer process that dies or does not
answer is a write error that leaves the file as a kill does.

Signals. While a block (and the whole of ``close()``) is written, the Python handlers of SIGINT,
SIGTERM, SIGHUP, SIGQUIT, SIGUSR1/2 and SIGALRM are deferred (swapped for a handler that notes the
signal; re-delivered afterwards), so a handler that raises never runs between a resize and its
write, and the writer's bookkeeping is updated in the same protected section.

Full disk. Before each block, the writer reserves the block's size plus one chunk per dataset and a
margin past HDF5's end of file (``posix_fallocate``). A full disk or a file-size limit then fails
there, before HDF5 writes anything: the writer raises :class:`RecordWriteError` (one line), stays
failed (every later call raises it again, nothing more is written except the ``/status``, whose
space exists since creation), and the file keeps every sample flushed before. Without the reserve,
HDF5 would update its superblock to point past what it could write, and the whole file would be
unreadable. ``planned_samples`` checks the free space and ``RLIMIT_FSIZE`` before the file is made.

Reading. :meth:`RunRecord.open` checks the HDF5 signature and the superblock's end-of-file address
against the file size before HDF5 sees the file (HDF5 skips that check in SWMR-read mode, and then
retries each failed metadata checksum 100 times with back-off: minutes, deaf to Ctrl-C, on a
truncated file), opens read-only without file locking, uses SWMR-read only for files whose
superblock says "open for SWMR write" (killed or live writers, no ``h5clear`` needed), and caps the
metadata read attempts to 8. A truncated, empty or garbage file, or a directory, is a one-line
:class:`RecordError` naming it.

All channel values are stored as float64 (booleans and counters too), so a channel missing from one
:meth:`RecordWriter.append` call is NaN in that sample.
"""

from __future__ import annotations

import atexit
import contextlib
import datetime as _dt
import errno
import hashlib
import io
import logging
import math
import os
import platform
import queue
import shutil
import signal
import tempfile
import threading
import weakref
from collections.abc import Callable, Iterable, Iterator, Mapping
from importlib import metadata as _metadata
from pathlib import Path
from types import TracebackType
from typing import Any

import h5py
import numpy as np

from hil import __version__
from hil.record.format import (
    _BYTE_LOGS,
    _MAX_CHUNK_BYTES,
    _MIN_CHUNK_ROWS,
    _STATUS_BYTES,
    FORMAT,
    FORMAT_VERSION,
    ChannelSpec,
    RecordError,
    RecordWriteError,
    _check_name,
    _one_line,
    _probe_hdf5,
    _split_arrays,
    _to_json,
)
from hil.record.reader import LATENESS_BINS_S, RunRecord, lateness_distribution
from hil.record.replay import replay

logger = logging.getLogger(__name__)

# the format's names, the reader and replay are re-exported: ``from hil.record.hdf5 import RunRecord`` etc.
__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "LATENESS_BINS_S",
    "ChannelSpec",
    "RecordError",
    "RecordLagError",
    "RecordWriteError",
    "RecordWriter",
    "RunRecord",
    "lateness_distribution",
    "replay",
    "store_identification",
]

#: extra file space reserved before every block [bytes] (HDF5 metadata: chunk index, object headers)
_RESERVE_MARGIN = 1 << 16

#: asynchronous signals held while a block is written: their handlers run after the write
_HELD_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGUSR1", "SIGUSR2",
                                                      "SIGALRM") if hasattr(signal, n))

#: tests only: called as ``hook(point, writer)`` at "flushed", "close", "close:flushed", "close:status"
_TEST_HOOK: Callable[[str, RecordWriter], None] | None = None


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """Defer the asynchronous signals' Python handlers until the block is done.

    Python runs signal handlers in the main thread between two bytecodes, whichever thread the
    signal hit (bus threads do not block it), so ``pthread_sigmask`` alone cannot keep a handler out
    of a write. In the main thread, each held signal's handler is swapped for one that only notes
    the signal; on exit the handlers are restored and every noted signal is re-delivered to its own
    handler (``SIG_DFL``: the signal is re-raised, so e.g. a SIGTERM still ends the process, after
    the block). In other threads nothing is needed: no handler runs there."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    saved: dict[int, Any] = {}

    def note(signum: int, frame: Any) -> None:
        caught.append(signum)

    try:
        for sig in _HELD_SIGNALS:
            current = signal.getsignal(sig)
            if current is None or current == signal.SIG_IGN:  # installed outside Python / ignored: leave it
                continue
            saved[sig] = signal.signal(sig, note)
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
        for signum in caught:
            handler = saved.get(signum)
            if callable(handler):
                handler(signum, None)
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), signum)



def _mib(n: float) -> str:
    return f"{n / (1 << 20):.1f} MiB"


def _fsize_limit() -> int | None:
    """The process's soft file-size limit [bytes] (``RLIMIT_FSIZE``), None when unlimited."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    return None if soft == resource.RLIM_INFINITY else int(soft)


# --------------------------------------------------------------------------------------------- helpers


def _utc_now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def _software_versions() -> dict[str, str]:
    """Versions of the packages that shape a record's numbers (no heavy imports: read from metadata)."""
    out = {"hil": __version__, "numpy": np.__version__, "h5py": h5py.version.version,
           "hdf5": h5py.version.hdf5_version, "python": platform.python_version()}
    try:
        out["scipy"] = _metadata.version("scipy")
    except _metadata.PackageNotFoundError:  # pragma: no cover - scipy is a dependency
        out["scipy"] = "not installed"
    return out


# ---------------------------------------------------------------------------------------------- writer


def _write_rows(ds: Any, start: int, data: np.ndarray) -> None:
    """Grow ``ds`` along axis 0 to ``start + len(data)`` rows and write ``data`` there, with h5py's
    low-level calls: the same file contents as ``ds.resize(...); ds[start:] = data``, at a tenth of
    the cost per call (no high-level selection machinery), which matters because the realtime loop
    flushes from within a tick (issue 17)."""
    arr = np.ascontiguousarray(data)
    m = arr.shape[0]
    dsid = ds.id
    dsid.set_extent((start + m, *ds.shape[1:]))
    fspace = dsid.get_space()
    fspace.select_hyperslab((start,) + (0,) * (arr.ndim - 1), arr.shape)
    dsid.write(h5py.h5s.create_simple(arr.shape), fspace, arr)


#: background writers whose thread is running: stopped at interpreter exit (see :func:`_stop_writers_at_exit`)
_LIVE_WRITERS: weakref.WeakSet[RecordWriter] = weakref.WeakSet()


@atexit.register
def _stop_writers_at_exit() -> None:
    """A writer never closed (an exception escaped its owner): let its thread finish the queued
    blocks and exit before the interpreter finalizes. A daemon thread left inside h5py while the
    interpreter shuts down would hold h5py's lock forever (the finalizer's h5py calls would hang)."""
    for w in list(_LIVE_WRITERS):
        with contextlib.suppress(Exception):
            w._stop_writer()
        with contextlib.suppress(Exception):
            w._end_process()


class _Block:
    """One preallocated block of samples: ``t`` (n,) and ``cols[name]`` (n, *shape), NaN filled.
    ``buf`` (with ``index``): the block is the ``index``-th of :func:`_block_bytes` bytes in that
    buffer (the writer process's shared memory), else its own arrays."""

    __slots__ = ("cols", "index", "t")

    def __init__(self, n: int, specs: Mapping[str, ChannelSpec], buf: Any = None, index: int = -1,
                 fill: bool = True) -> None:
        self.index = index
        if buf is None:
            self.t = np.full(n, np.nan)
            self.cols = {k: np.full((n, *s.shape), np.nan) for k, s in specs.items()}
            return
        off = index * _block_bytes(n, specs)
        self.t = np.ndarray((n,), dtype=np.float64, buffer=buf, offset=off)
        off += 8 * n
        self.cols = {}
        for k, s in specs.items():
            self.cols[k] = np.ndarray((n, *s.shape), dtype=np.float64, buffer=buf, offset=off)
            off += 8 * n * math.prod(s.shape)
        if fill:  # the owner NaN-fills; the writer process only reads
            self.t[:] = np.nan
            for c in self.cols.values():
                c[...] = np.nan


def _writer_process_entry(fd: int) -> None:  # pragma: no cover - runs in the writer process
    """``python -c`` entry of the writer process: the connection is the inherited socket ``fd``; the
    first message carries :func:`_writer_process_main`'s arguments."""
    import sys
    from multiprocessing.connection import Connection

    try:
        conn = Connection(fd)
        args = conn.recv()
        _writer_process_main(conn, *args)
    except BaseException as exc:  # e.g. the creator died during start-up and its shared memory is gone
        with contextlib.suppress(Exception):  # stderr is a file the creator reads, never a terminal
            sys.stderr.write(f"hil record writer process: {type(exc).__name__}: {exc}\n")
        os._exit(1)


def _writer_process_main(conn: Any, path: str, shm_name: str, n: int, shapes: Mapping[str, tuple[int, ...]],
                         nblocks: int) -> None:  # pragma: no cover - runs in the writer process (tested through it)
    """The record writer process (``RecordWriter(background="process")``): opens the record for
    SWMR writing (after its creator closed it: one writer per file), then answers the creator's
    calls on ``conn`` one at a time -- ``("ready",)``, ``("commit", block index or None, m, t, block,
    logs, rows, sizes, reserve)`` (a block in the shared memory ``shm_name`` or sent), ``("status",
    bytes)``, ``("close",)`` -- with ``("ok", value)`` or ``("err", what, reason, broken)``. The end
    of ``conn`` (its creator died) closes the file as it is (the status says "not closed"). Ignores
    SIGINT: a Ctrl-C reaches the whole process group, and the loop's process decides the stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from multiprocessing import resource_tracker, shared_memory

    shm = shared_memory.SharedMemory(name=shm_name)
    with contextlib.suppress(Exception):  # the creator owns (and unlinks) it: not this process's tracker
        resource_tracker.unregister(shm._name, "shared_memory")  # type: ignore[attr-defined]
    specs = {k: ChannelSpec(tuple(v), "") for k, v in shapes.items()}
    blocks = [_Block(n, specs, shm.buf, i, fill=False) for i in range(nblocks)]
    f: Any = None
    open_err: str | None = None
    try:
        fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
        fapl.set_libver_bounds(h5py.h5f.LIBVER_LATEST, h5py.h5f.LIBVER_LATEST)
        f = h5py.File(h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDWR | h5py.h5f.ACC_SWMR_WRITE, fapl=fapl))
    except Exception as exc:
        open_err = _exc_reason(exc)
    dsets: dict[str, Any] = {}
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            kind = msg[0]
            try:
                if open_err is not None:
                    raise _WriteFailed("opening the record in the writer process", open_err, False)
                out: Any = None
                if kind == "commit":
                    _, idx, m, t, block, logs, rows, sizes, reserve = msg
                    _reserve_in(f, reserve)
                    if idx is not None:
                        b = blocks[idx]
                        t, block = b.t[:m], {k: c[:m] for k, c in b.cols.items()}
                    out = _write_block(f, dsets, rows, sizes, t, block, logs)
                elif kind == "status":
                    try:
                        f["status"][:] = msg[1]
                        f.flush()
                    except Exception as exc:
                        raise _WriteFailed("writing the status", _exc_reason(exc), True) from exc
                elif kind == "close":
                    ff, f = f, None
                    ff.close()
                    conn.send(("ok", None))
                    break
                conn.send(("ok", out))
            except _WriteFailed as exc:
                conn.send(("err", exc.what, exc.reason, exc.broken))
    finally:
        if f is not None:
            with contextlib.suppress(Exception):
                f.close()
        del blocks
        with contextlib.suppress(Exception):
            shm.close()


def _block_bytes(n: int, specs: Mapping[str, ChannelSpec]) -> int:
    """Bytes of one block of ``n`` samples in shared memory: ``t`` and every channel, float64."""
    return 8 * n * (1 + sum(math.prod(s.shape) for s in specs.values()))


def _exc_reason(exc: BaseException) -> str:
    """A write failure's reason as the writer reports it (``strerror (errno N)`` for OS errors)."""
    return (f"{exc.strerror or exc} (errno {exc.errno})" if isinstance(exc, OSError) and exc.errno
            else _one_line(exc))


class _WriteFailed(Exception):
    """A block write failed: ``what`` failed because of ``reason``; ``broken``: HDF5 may have written
    part of it (nothing more may be written)."""

    def __init__(self, what: str, reason: str, broken: bool) -> None:
        super().__init__(f"{what}: {reason}")
        self.what, self.reason, self.broken = what, reason, broken


def _reserve_in(f: Any, nbytes: int) -> None:
    """``posix_fallocate`` ``nbytes`` past HDF5's end of ``f`` (see :meth:`RecordWriter._reserve`);
    raises :class:`_WriteFailed` (not broken: nothing was written) when the disk cannot hold them."""
    if not hasattr(os, "posix_fallocate"):  # pragma: no cover - not POSIX
        return
    try:
        fid = f.id
        os.posix_fallocate(fid.get_vfd_handle(), fid.get_filesize(), int(nbytes))
    except OSError as exc:
        if exc.errno in (errno.EINVAL, errno.EOPNOTSUPP):  # pragma: no cover - e.g. some network file systems
            return
        raise _WriteFailed(f"reserving {_mib(nbytes)} of disk", _exc_reason(exc), False) from None


def _write_block(f: Any, dsets: dict[str, Any], rows: int, sizes: dict[str, int], t: np.ndarray | None,
                 block: Mapping[str, np.ndarray] | None, logs: Mapping[str, list[bytes]]) -> tuple[int, dict[str, int]]:
    """Write one block into the open file ``f`` at row ``rows`` (channels first, ``/t`` last: t's
    length commits the samples), then every byte log at ``sizes``, then flush. Returns the new
    ``(rows, sizes)``; raises :class:`_WriteFailed` (broken) on any HDF5 / OS failure. ``dsets``
    caches the datasets (h5py's name lookup costs as much as the write)."""
    sizes = dict(sizes)
    try:
        m = 0 if t is None else t.shape[0]
        if t is not None and block is not None and m:
            g = f["channels"]
            for name, data in block.items():
                ds = dsets.get(name)
                if ds is None:
                    ds = dsets[name] = g[name]
                _write_rows(ds, rows, data)
            if "/t" not in dsets:
                dsets["/t"] = f["t"]
            _write_rows(dsets["/t"], rows, t)
            rows += m
        for name, chunks in logs.items():
            data = np.frombuffer(b"".join(chunks), dtype=np.uint8)
            ds = f[name]
            n0 = sizes[name]
            ds.resize((n0 + data.size,))
            ds[n0:] = data
            sizes[name] = n0 + data.size
        f.flush()
    except Exception as exc:  # OSError (EFBIG, ENOSPC, EIO), RuntimeError from HDF5
        raise _WriteFailed("write", _exc_reason(exc), True) from exc
    return rows, sizes


class RecordLagError(RecordWriteError):
    """The background writer fell behind: every preallocated block is waiting to be written. The
    samples taken so far are kept (in memory) and written by :meth:`RecordWriter.close`."""


class RecordWriter:
    """Stream one run to an HDF5 file (layout and crash-safety guarantees in the module docstring).

    ``path``: output file; an existing file is refused (:class:`RecordError`) unless
    ``overwrite=True``. ``scene_text``: the exact scene YAML; ``scene_sha256``: its hash as computed
    by the scene loader. ``meta``: JSON-serializable run metadata (device identities, seed, ...).
    ``channels``: name -> :class:`ChannelSpec`. ``rate_hz``: nominal sample rate [Hz].
    ``flush_every_s``: flush period in run time [s]. ``planned_samples``: when given, the free disk
    space (and the process's file-size limit) is checked against the run's estimated size before
    anything is created (:meth:`check_space`).

    Errors: bad input raises :class:`RecordError`; a failed write (disk full, file-size limit, IO
    error) raises :class:`RecordWriteError` with a one-line reason, after which the writer is
    *failed*: every further call raises that error again without touching the file, and
    :meth:`close` only releases the file. What was flushed before the failure stays readable.

    Use as a context manager; an exception inside the ``with`` closes the record with
    ``status="error"`` and the exception's message as stop reason, then propagates.

    ``background="process"``: the same, with the h5py calls in a writer process fed through shared
    memory (see the module docstring); ``"thread"`` is ``True``.

    Background writing (``background=True``): :meth:`append` only copies
    the sample into the current preallocated block; a full block (or one older than
    ``flush_every_s``) is handed, with the queued events/results/counters, to a writer thread that
    writes it and flushes the file -- the same blocks, positions and file contents as the
    synchronous mode, so the guarantees above hold (a kill loses at most the blocks not yet
    written: at most ``max_pending_blocks + 1`` blocks). During the run *every* h5py call on the
    file happens in the writer thread; the caller's thread touches the file only while no block is
    in flight (after :meth:`flush` has waited for the writer, and in :meth:`close` after the writer
    thread has exited). The pool holds ``max_pending_blocks`` free blocks besides the current one,
    so memory is bounded: when the current block is full and none is free, :meth:`append` raises
    :class:`RecordLagError` (nothing is lost: the samples stay in memory and :meth:`close` writes
    them). A write error in the writer thread makes the writer *failed* (as above) and is raised by
    the next :meth:`append` / :meth:`event` / :meth:`flush` (the loop's next tick: a safe stop with
    the reason). :meth:`flush` waits (at most ``writer_timeout_s`` [s]) until everything handed over
    is on disk; :meth:`close` flushes, then joins the writer thread (bounded the same way; signals
    held, like the rest of close). A writer that does not finish in time is left alone (the file is
    not touched again from the caller's thread: what was flushed is on disk, as after a kill) and
    :meth:`close` raises :class:`RecordWriteError`.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        scene_text: str,
        scene_sha256: str,
        meta: Mapping[str, Any],
        channels: Mapping[str, ChannelSpec],
        rate_hz: float,
        flush_every_s: float = 0.1,
        overwrite: bool = False,
        planned_samples: int | None = None,
        background: bool | str = False,
        max_pending_blocks: int = 4,
        writer_timeout_s: float = 10.0,
    ) -> None:
        self.path = Path(path)
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise RecordError(f"rate_hz must be positive and finite, got {rate_hz!r}")
        if not (math.isfinite(flush_every_s) and flush_every_s > 0):
            raise RecordError(f"flush_every_s must be positive and finite, got {flush_every_s!r}")
        if int(max_pending_blocks) < 1:
            raise RecordError(f"max_pending_blocks must be >= 1, got {max_pending_blocks!r}")
        if not (math.isfinite(writer_timeout_s) and writer_timeout_s > 0):
            raise RecordError(f"writer_timeout_s must be positive and finite, got {writer_timeout_s!r}")
        self.rate_hz = float(rate_hz)
        self.flush_every_s = float(flush_every_s)
        if background not in (False, True, "thread", "process"):
            raise RecordError(f"background must be False, True, 'thread' or 'process', got {background!r}")
        #: blocks are written by a writer thread (see the class docstring), not by append()
        self.background = bool(background)
        #: ... and, ``background="process"``, the h5py calls by a writer process (no GIL shared with the loop)
        self.process = background == "process"
        self._proc: Any = None
        self._conn: Any = None
        self._shm: Any = None
        self._proc_err: Any = None
        #: why the writer process was lost (it died, or did not answer and was killed), else None
        self._proc_lost: str | None = None
        #: file offset of /status's bytes (contiguous, allocated at creation): written directly when
        #: the writer process that held the file is lost
        self._status_offset: int | None = None
        self._call_lock = threading.Lock()
        self.max_pending_blocks = int(max_pending_blocks)
        self.writer_timeout_s = float(writer_timeout_s)
        #: samples per flush (the buffer size)
        self.flush_samples = max(1, round(self.rate_hz * self.flush_every_s))
        self.specs: dict[str, ChannelSpec] = {}
        for name, spec in channels.items():
            _check_name(name, "channel")
            if not isinstance(spec, ChannelSpec):
                raise RecordError(f"channel {name!r}: expected a ChannelSpec, got {type(spec).__name__}")
            self.specs[name] = spec
        self._shapes = {name: tuple(spec.shape) for name, spec in self.specs.items()}
        self._scalar_ok = {name for name, shp in self._shapes.items() if math.prod(shp) == 1}
        self.meta = dict(meta)
        meta_json = _to_json(self.meta, "meta")
        if hashlib.sha256(scene_text.encode()).hexdigest() != scene_sha256 and scene_text:
            logger.info("scene_sha256 %s is not the SHA-256 of scene_text (stored as given)", scene_sha256[:12])

        n = self.flush_samples
        self._cur = _Block(n, self.specs)
        self._t_buf = self._cur.t
        self._buf = self._cur.cols
        self._nbuf = 0
        #: background mode: the free preallocated blocks (the writer puts written ones back) and the
        #: jobs for the writer thread: (block or None, rows, byte logs, samples after it), a
        #: threading.Event to set once everything before it is written, or None (exit)
        self._free: queue.SimpleQueue[_Block] = queue.SimpleQueue()
        self._jobs: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._writer_stuck = False
        #: bytes of each byte log handed to a write so far (the file's size once they are written)
        self._queued_bytes: dict[str, int] = dict.fromkeys(_BYTE_LOGS, 0)
        self._events: list[bytes] = []
        #: JSON-lines / byte logs waiting for the next flush: dataset name -> chunks
        self._pending: dict[str, list[bytes]] = {}
        self._results_set: set[str] = set()
        #: what the file holds (committed by a successful write): rows of /t and the channels,
        #: bytes of every byte-log dataset. Writes go to these absolute positions, so a write is
        #: never applied twice.
        self._rows = 0
        self._bytes: dict[str, int] = dict.fromkeys(_BYTE_LOGS, 0)
        self._t_last = -math.inf
        self._t_first_buffered = math.nan
        #: samples appended so far / samples written and flushed to the file
        self.samples = 0
        self.samples_flushed = 0
        self.flushes = 0
        self.closed = False
        #: the write error that made this writer fail (None while healthy)
        self.failure: RecordWriteError | None = None
        self._hdf5_broken = False
        self.stop_reason: str | None = None
        self.status: str | None = None
        self._dsets: dict[str, Any] = {}  # the sample datasets (and "/t"), looked up once (see _commit)

        if self.path.is_dir():
            raise RecordError(f"{self.path}: is a directory")
        if self.path.exists() and not overwrite:
            raise RecordError(f"{self.path}: a record already exists; refusing to overwrite it")
        if planned_samples is not None:
            self.check_space(planned_samples)
        try:
            self._f = h5py.File(self.path, "w", libver="latest")
        except OSError as exc:
            raise RecordError(f"{self.path}: cannot create record: {_one_line(exc)}") from None
        try:
            with _signals_held():
                self._create_layout(scene_text, scene_sha256, meta_json)
                self._f.flush()
                self._f.swmr_mode = True
                offset = self._f["status"].id.get_offset()
                self._status_offset = None if offset is None else int(offset)
        except BaseException as exc:
            with contextlib.suppress(Exception):
                self._f.close()
            if isinstance(exc, OSError | RuntimeError):
                raise RecordWriteError(f"{self.path}: cannot create record: {_one_line(exc)}") from None
            raise
        if self.process:
            self._start_process()
        if self.background:
            if self._shm is None:
                for _ in range(self.max_pending_blocks):
                    self._free.put(_Block(n, self.specs))
            self._thread = threading.Thread(target=self._writer_main, name=f"hil-record-writer {self.path.name}",
                                            daemon=True)
            self._thread.start()
            _LIVE_WRITERS.add(self)
        logger.debug("record %s: %d channels, %d samples per flush%s", self.path, len(self.specs), n,
                     f", written by a writer thread (at most {self.max_pending_blocks} blocks queued)"
                     if self.background else "")

    # -- disk space
    def bytes_per_sample(self) -> int:
        """Bytes one sample takes in the file: 8 for ``/t`` plus 8 per channel value (float64)."""
        return 8 * (1 + sum(math.prod(s.shape) for s in self.specs.values()))

    def estimated_bytes(self, samples: int) -> int:
        """Estimated file size [bytes] for ``samples`` samples: raw data plus a margin for chunk
        indexes, partial chunks, events and results (x1.25 + 1 MiB + one chunk per channel)."""
        raw = self.bytes_per_sample() * int(samples)
        chunk = 8 * max(self.flush_samples, _MIN_CHUNK_ROWS) * (1 + len(self.specs))
        return int(raw * 1.25) + (1 << 20) + chunk

    def check_space(self, samples: int) -> None:
        """Raise :class:`RecordError` (with the numbers) when the disk holding ``path`` or the
        process's file-size limit (``RLIMIT_FSIZE``) cannot hold a record of ``samples`` samples."""
        samples = int(samples)
        if samples < 0:
            raise RecordError(f"planned_samples must be >= 0, got {samples}")
        need = self.estimated_bytes(samples)
        parent = self.path.parent if str(self.path.parent) else Path(".")
        try:
            free = shutil.disk_usage(parent).free
        except OSError as exc:
            raise RecordError(f"{self.path}: cannot check free space in {parent}: {_one_line(exc)}") from None
        if need > free:
            raise RecordError(f"{self.path}: not enough disk space for {samples} samples: need about "
                              f"{_mib(need)} ({self.bytes_per_sample()} B/sample + margin), {_mib(free)} free "
                              f"in {parent}")
        limit = _fsize_limit()
        if limit is not None and need > limit:
            raise RecordError(f"{self.path}: the file-size limit (ulimit -f) {_mib(limit)} is below the "
                              f"{_mib(need)} needed for {samples} samples")

    def _create_layout(self, scene_text: str, scene_sha256: str, meta_json: str) -> None:
        f = self._f
        a = f.attrs
        a["format"] = FORMAT
        a["format_version"] = FORMAT_VERSION
        a["created_utc"] = _utc_now()
        for k, v in _software_versions().items():
            a[f"software.{k}"] = v
        seed = self.meta.get("seed")
        if isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            a["seed"] = int(seed)
        a["rate_hz"] = self.rate_hz
        a["scene_sha256"] = scene_sha256
        a["flush_every_s"] = self.flush_every_s
        a["flush_samples"] = self.flush_samples
        a["meta"] = meta_json
        f.create_dataset("scene", data=scene_text, dtype=h5py.string_dtype("utf-8"))
        rows = self.flush_samples
        chunk = max(rows, _MIN_CHUNK_ROWS)
        t = f.create_dataset("t", shape=(0,), maxshape=(None,), chunks=(chunk,), dtype="f8", fillvalue=np.nan)
        t.attrs["unit"] = "s"
        g = f.create_group("channels", track_order=True)
        for name, spec in self.specs.items():
            width = int(np.prod(spec.shape)) if spec.shape else 1
            crows = max(1, min(chunk, _MAX_CHUNK_BYTES // (8 * width)))
            ds = g.create_dataset(name, shape=(0, *spec.shape), maxshape=(None, *spec.shape),
                                  chunks=(crows, *spec.shape), dtype="f8", fillvalue=np.nan)
            ds.attrs["unit"] = spec.unit
            ds.attrs["description"] = spec.description
        for name, (chunk_bytes, encoding) in _BYTE_LOGS.items():
            ds = f.create_dataset(name, shape=(0,), maxshape=(None,), chunks=(chunk_bytes,), dtype="u1")
            ds.attrs["encoding"] = encoding
        # written (all zeros = "not closed") now, overwritten in place by close(): no allocation later
        st = f.create_dataset("status", data=np.zeros(_STATUS_BYTES, dtype=np.uint8))
        st.attrs["encoding"] = "utf-8 JSON line {stop_reason, status, closed_utc, samples}, zero padded"
        self._chunk_bytes = 8 * max(rows, _MIN_CHUNK_ROWS) + sum(
            8 * math.prod(ds.chunks) for ds in g.values()) + sum(c for c, _ in _BYTE_LOGS.values())

    # -- context manager
    def __enter__(self) -> RecordWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self.closed:
            return
        if exc is None:
            self.close()
        else:
            reason = _one_line(exc) or type(exc).__name__
            try:
                self.close(stop_reason=reason, status="error")
            except Exception as close_exc:  # never mask the original exception
                if close_exc is exc:  # the write failure that is propagating anyway
                    return
                logger.error("record %s: close after %s failed: %s", self.path, exc_type.__name__ if exc_type
                             else "error", _one_line(close_exc))

    # -- writing
    def _check_open(self) -> None:
        if self.failure is not None:
            raise self.failure
        if self.closed:
            raise RecordError(f"{self.path}: record is closed")

    def _coerce(self, name: str, value: Any, lead: tuple[int, ...] = ()) -> np.ndarray:
        spec = self.specs.get(name)
        if spec is None:
            raise RecordError(f"unknown channel {name!r} (declared: {', '.join(self.specs) or 'none'})")
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise RecordError(f"channel {name!r}: value is not numeric ({exc})") from None
        want = (*lead, *spec.shape)
        if arr.shape != want:
            # Accept differences in singleton dimensions only (a float for a (1,) channel, (1, 2) for (2,)).
            core = arr.shape[len(lead):] if arr.shape[: len(lead)] == lead else None
            if core is None or arr.size != math.prod(want) or \
                    tuple(d for d in core if d != 1) != tuple(d for d in spec.shape if d != 1):
                raise RecordError(f"channel {name!r}: expected shape {spec.shape}, got {arr.shape[len(lead):]}"
                                  if lead else f"channel {name!r}: expected shape {spec.shape}, got {arr.shape}")
            arr = arr.reshape(want)
        return arr

    def _fast_coerce(self, values: Mapping[str, Any]) -> list[tuple[str, Any]] | None:
        """The per-tick fast path of :meth:`append`: every value already is a numeric array of its
        channel's exact shape, or a float for a one-value channel (what the runner's rows hold), so it
        can be stored as is (the buffer's assignment converts exactly as ``_coerce`` would). None
        when any value needs :meth:`_coerce` (conversion, singleton reshaping, or an error to name)."""
        shapes = self._shapes
        out = []
        for name, v in values.items():
            shp = shapes.get(name)
            tv = type(v)
            if shp is None:
                return None
            if tv is np.ndarray:
                if v.shape != shp or v.dtype.kind not in "fiub":
                    return None
            elif tv is float or tv is np.float64:
                if name not in self._scalar_ok:
                    return None
            else:
                return None
            out.append((name, v))
        return out

    def append(self, t: float, values: Mapping[str, np.ndarray | float]) -> None:
        """Append one sample at run time ``t`` [s] (strictly increasing). Channels missing from ``values``
        are NaN; an undeclared channel or a wrong shape raises :class:`RecordError` naming the channel."""
        self._check_open()
        t = float(t)
        if not (math.isfinite(t) and t > self._t_last):
            raise RecordError(f"sample time {t!r} s is not finite or not after the previous one ({self._t_last} s)")
        coerced = self._fast_coerce(values)
        if coerced is None:
            coerced = [(name, self._coerce(name, v)) for name, v in values.items()]
        if self._nbuf >= self.flush_samples:  # background: a full block no writer could take yet
            self._hand_over()
        i = self._nbuf
        if len(coerced) != len(self._buf):
            given = {name for name, _ in coerced}
            for name, buf in self._buf.items():
                if name not in given:
                    buf[i] = np.nan
        for name, arr in coerced:
            self._buf[name][i] = arr
        self._t_buf[i] = t
        if i == 0:
            self._t_first_buffered = t
        self._nbuf = i + 1
        self._t_last = t
        self.samples += 1
        if self._nbuf >= self.flush_samples or t - self._t_first_buffered >= self.flush_every_s:
            if self.background:
                self._hand_over()
            else:
                self.flush()

    def append_block(self, t: np.ndarray, values: Mapping[str, np.ndarray]) -> None:
        """Append many samples at once: ``t`` (m,) [s] strictly increasing, ``values[name]`` (m, *shape).

        Written (and flushed) directly, after any buffered samples. Used by the importers."""
        self._check_open()
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        m = t.size
        if m == 0:
            return
        if not np.all(np.isfinite(t)):
            raise RecordError("sample times must be finite")
        if t[0] <= self._t_last or np.any(np.diff(t) <= 0):
            raise RecordError("sample times must be strictly increasing")
        coerced = {name: self._coerce(name, v, (m,)) for name, v in values.items()}
        self.flush()  # background: waits for the writer, so this thread may write (nothing in flight)
        block = {name: coerced.get(name, np.full((m, *spec.shape), np.nan)) for name, spec in self.specs.items()}

        def done() -> None:
            self._t_last = float(t[-1])
            self.samples += m
            self.samples_flushed = self.samples

        self._commit(t, block, self._take_logs(), done)

    def event(self, t: float, kind: str, message: str) -> None:
        """Record an event at run time ``t`` [s] (written with the next flush)."""
        self._check_open()
        line = _to_json({"t": float(t), "kind": str(kind), "message": str(message)}, "event") + "\n"
        self._events.append(line.encode())
        logger.debug("record event t=%.6f %s: %s", t, kind, message)

    def set_results(self, experiment: str, results: Mapping[str, Any]) -> None:
        """Store an experiment's results (JSON-serializable; numpy arrays are stored in ``.npy``
        form in ``/results_npy``). Written and flushed at once, so results survive a later kill.
        Setting the same experiment twice replaces the earlier results."""
        self._check_open()
        _check_name(experiment, "experiment")
        if not isinstance(results, Mapping):
            raise RecordError(f"results of {experiment!r} must be a mapping, got {type(results).__name__}")
        arrays: dict[str, np.ndarray] = {}
        doc = _split_arrays(results, (), arrays)
        _to_json(doc, f"results of {experiment!r}")  # validate before anything is queued
        if experiment in self._results_set:
            logger.warning("record %s: results of %r replaced", self.path, experiment)
        self._results_set.add(experiment)
        blobs = []
        offset = self._queued_bytes["results_npy"] + sum(len(b) for b in self._pending.get("results_npy", []))
        index: dict[str, list[int]] = {}
        for key, arr in arrays.items():
            bio = io.BytesIO()
            np.save(bio, np.asarray(arr), allow_pickle=False)
            blob = bio.getvalue()
            index[key] = [offset, len(blob)]
            offset += len(blob)
            blobs.append(blob)
        line = _to_json({"experiment": experiment, "results": doc, "arrays": index}, "results") + "\n"
        self._pending.setdefault("results_npy", []).extend(blobs)
        self._pending.setdefault("results", []).append(line.encode())
        self.flush()

    def set_device_counters(self, counters: Mapping[str, Mapping[str, int]]) -> None:
        """Store per-device fault counters, e.g. ``{"odrive0": {"crc_errors": 0, "resyncs": 1,
        "dropped": 3, "late": 0, "stale": 2, "retries": 5}}`` (any integer keys). Each call
        records a snapshot (the last one counts; read back as :attr:`RunRecord.device_counters`);
        written with the next flush. Raises :class:`RecordError` for a non-integer count."""
        self._check_open()
        if not isinstance(counters, Mapping):
            raise RecordError(f"device counters must be a mapping, got {type(counters).__name__}")
        snap: dict[str, dict[str, int]] = {}
        for dev, cs in counters.items():
            _check_name(str(dev), "device")
            if not isinstance(cs, Mapping):
                raise RecordError(f"device {dev!r}: counters must be a mapping, got {type(cs).__name__}")
            row: dict[str, int] = {}
            for k, v in cs.items():
                if isinstance(v, bool) or not isinstance(v, int | np.integer):
                    raise RecordError(f"device {dev!r}: counter {k!r} must be an integer, got {v!r}")
                row[str(k)] = int(v)
            snap[str(dev)] = row
        line = _to_json({"t": None if self._t_last == -math.inf else self._t_last, "counters": snap},
                        "device counters") + "\n"
        self._pending.setdefault("device_counters", []).append(line.encode())

    def _reserve(self, nbytes: int) -> None:
        """Make sure the file can grow by ``nbytes`` before HDF5 writes anything (``posix_fallocate``
        past HDF5's end of file): a full disk or a file-size limit then fails *here*, with the file
        untouched and consistent, instead of in the middle of a block (HDF5 would have updated its
        superblock to point past what it could write, making even the earlier samples unreadable).
        HDF5 trims the unused reserve when it flushes or closes."""
        try:
            _reserve_in(self._f, nbytes)
        except _WriteFailed as exc:
            raise self._fail_reason(exc.reason, exc.what) from None

    def _fail(self, exc: BaseException, what: str) -> RecordWriteError:
        return self._fail_reason(_exc_reason(exc), what)

    def _fail_reason(self, reason: str, what: str) -> RecordWriteError:
        err = RecordWriteError(f"{self.path}: {what} failed: {reason}; the {self.samples_flushed} samples "
                               "flushed before are kept")
        self.failure = err
        logger.error("%s", err)
        return err

    def _take_logs(self) -> dict[str, list[bytes]]:
        """The byte-log chunks waiting for the next block (events, results, counters), taken out of
        the writer's queue (counted in ``_queued_bytes``, so results offsets stay exact)."""
        logs = {k: v for k, v in ((k, self._pending.pop(k, None)) for k in _BYTE_LOGS) if v}
        if self._events:
            logs["events"] = [*logs.get("events", []), *self._events]
            self._events = []
        for name, chunks in logs.items():
            self._queued_bytes[name] += sum(len(c) for c in chunks)
        return logs

    def _commit(self, t: np.ndarray | None, block: Mapping[str, np.ndarray] | _Block | None,
                logs: Mapping[str, list[bytes]], on_commit: Callable[[], None] | None = None) -> None:
        """Write one block (samples, then every byte log) at the positions the file is known to hold,
        flush the file, then update the writer's state (and run ``on_commit``). Signals are held for
        all of it, so a handler (which may raise) runs only after the block and the state that says
        it is written are both done: a block is never written twice nor half. Any write failure makes
        the writer failed (a failed write is never re-applied)."""
        m = 0 if t is None else t.shape[0]
        need = 2 * (m * self.bytes_per_sample() + sum(len(c) for cs in logs.values() for c in cs))
        reserve = need + self._chunk_bytes + _RESERVE_MARGIN
        if self._proc is None:
            self._reserve(reserve)
        err: RecordWriteError | None = None
        with _signals_held():
            try:
                if self._proc is not None:  # the writer process: the block by index in shared memory, or sent
                    shm_block = block if isinstance(block, _Block) else None
                    rows, sizes = self._call("commit", shm_block.index if shm_block is not None else None, m,
                                             None if shm_block is not None else t,
                                             None if shm_block is not None else block, logs, self._rows,
                                             dict(self._bytes), reserve, timeout=self.writer_timeout_s)
                else:
                    assert not isinstance(block, _Block)
                    rows, sizes = _write_block(self._f, self._dsets, self._rows, self._bytes, t, block, logs)
            except _WriteFailed as exc:
                self._hdf5_broken = self._hdf5_broken or exc.broken  # HDF5 may be mid-block: write nothing more
                err = self._fail_reason(exc.reason, exc.what)
            else:
                self._rows = rows
                self._bytes = sizes
                self.flushes += 1
                if on_commit is not None:
                    on_commit()
        if err is not None:
            raise err
        if _TEST_HOOK is not None:
            _TEST_HOOK("flushed", self)

    def flush(self) -> None:
        """Write the buffered samples, events, results and counters to the file and flush it (readers
        see them). Raises :class:`RecordWriteError` when the write fails."""
        if self.closed:
            return
        if self.failure is not None:
            raise self.failure
        if self.background:
            self._hand_over(wait=True)
            self._wait_written()
            return
        k = self._nbuf

        def done() -> None:
            self._nbuf = 0
            self.samples_flushed = self.samples

        self._commit(self._t_buf[:k], {name: buf[:k] for name, buf in self._buf.items()}, self._take_logs(), done)

    # -- background writer
    def _hand_over(self, wait: bool = False) -> None:
        """Background mode: queue the current block (and the byte logs) for the writer thread and
        continue in a free block. No free block: :class:`RecordLagError` (``wait``: wait for one, at
        most ``writer_timeout_s``)."""
        k = self._nbuf
        block: _Block | None = None
        if k:
            try:
                nxt = self._free.get(timeout=self.writer_timeout_s) if wait else self._free.get_nowait()
            except queue.Empty:
                if self.failure is not None:
                    raise self.failure from None
                lag = self.max_pending_blocks
                err = RecordLagError(
                    f"{self.path}: the record writer fell behind: {lag} blocks ({lag * self.flush_samples} samples, "
                    f"{lag * self.flush_every_s:g} s) wait to be written; the {self.samples} samples taken are kept "
                    "and written at close")
                logger.error("%s", err)
                raise err from None
            block, self._cur = self._cur, nxt
            self._t_buf, self._buf, self._nbuf = nxt.t, nxt.cols, 0
        logs = self._take_logs()
        if block is None and not logs:
            return
        self._jobs.put((block, k, logs, self.samples))

    def _wait_written(self) -> None:
        """Background mode: wait (at most ``writer_timeout_s``) until every job handed over is
        written; then raise the writer's failure, if any."""
        done = threading.Event()
        self._jobs.put(done)
        if not done.wait(self.writer_timeout_s):
            self._writer_stuck = True
            err = self._fail(TimeoutError(f"the writer thread did not finish within {self.writer_timeout_s:g} s"),
                             "background write")
            raise err
        if self.failure is not None:
            raise self.failure

    def _writer_main(self) -> None:
        """The writer thread: write each queued block (the only thread calling h5py during the run),
        put the block back in the free pool. After a failure, queued blocks are dropped (the writer
        is failed: nothing more is written) and the failure waits for the caller's next call."""
        while True:
            job = self._jobs.get()
            if job is None:
                return
            if isinstance(job, threading.Event):
                job.set()
                continue
            block, k, logs, samples_after = job
            try:
                if self.failure is None:
                    def done(n: int = samples_after) -> None:
                        self.samples_flushed = n

                    if block is None:
                        self._commit(None, None, logs, done)
                    elif self._proc is not None:  # the process reads the block from shared memory
                        self._commit(block.t[:k], block, logs, done)
                    else:
                        self._commit(block.t[:k], {name: c[:k] for name, c in block.cols.items()}, logs, done)
            except RecordWriteError:
                pass  # self.failure is set: the caller raises it at its next call
            except BaseException as exc:  # never lose a writer failure silently
                if self.failure is None:
                    self._fail(exc, "background write")
            finally:
                if block is not None:
                    self._free.put(block)

    def set_writer_scheduling(self, priority: int, cpus: Iterable[int] | None = None,
                              process_priority: int | None = None) -> str | None:
        """Background mode: give the writer thread SCHED_FIFO ``priority`` (Linux) and, when ``cpus``
        is given (non-empty), pin it to those CPUs. The realtime runner uses one below its loop's and
        the CPUs the loop does not run on: the writer then is not preempted by ordinary processes
        while it holds the interpreter lock the loop waits for (priority inversion), the loop still
        preempts it, and its writes run beside the loop instead of in the loop CPU's idle time.
        Returns None on success, else a one-line reason (what failed is left unchanged).
        ``background="process"``: the same for the writer process (the h5py calls), with
        ``process_priority`` when given (it shares no interpreter lock with the loop, so it may run
        below other realtime work on its CPUs, e.g. the simulated devices), and the thread that
        hands it the blocks."""
        th = self._thread
        if th is None or th.native_id is None:
            return "no writer thread"
        if not hasattr(os, "sched_setscheduler"):  # pragma: no cover - not Linux
            return "SCHED_FIFO not available on this platform"
        why: list[str] = []
        cpu_set = set(cpus or ())
        targets = [("writer thread", th.native_id, int(priority))]
        if self._proc is not None and self._proc.pid is not None:
            targets.append(("writer process", self._proc.pid,
                            int(priority if process_priority is None else process_priority)))
        for who, tid, prio in targets:
            if cpu_set:
                try:
                    os.sched_setaffinity(tid, cpu_set)
                except OSError as exc:
                    why.append(f"{who} affinity {sorted(cpu_set)} not permitted: {exc.strerror or exc}")
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(prio))
            except OSError as exc:
                why.append(f"{who} SCHED_FIFO {prio} not permitted: {exc.strerror or exc}")
        return "; ".join(why) or None

    # -- the writer process (background="process")
    def _start_process(self) -> None:
        """Hand the file to a writer process: preallocate the blocks in shared memory, close this
        process's handle, start the process (``spawn``) and wait until it holds the file."""
        import socket
        import subprocess
        import sys
        from multiprocessing import shared_memory
        from multiprocessing.connection import Connection

        n, nb = self.flush_samples, self.max_pending_blocks + 1
        try:
            self._f.close()  # one writer per file: from now on only the writer process opens it
            self._shm = shared_memory.SharedMemory(create=True, size=max(1, _block_bytes(n, self.specs) * nb))
            blocks = [_Block(n, self.specs, self._shm.buf, i) for i in range(nb)]
            self._cur = blocks[0]
            self._t_buf, self._buf = self._cur.t, self._cur.cols
            for b in blocks[1:]:
                self._free.put(b)
            # a fresh interpreter (never fork a process with running threads; no re-import of __main__)
            mine, theirs = socket.socketpair()
            try:
                code = ("import sys; from hil.record.hdf5 import _writer_process_entry; "
                        "_writer_process_entry(int(sys.argv[1]))")
                # its stdout/stderr are never the caller's (a frozen writer must not hold a CI job's
                # pipes); what it says on stderr lands in a file read when it fails
                self._proc_err = tempfile.TemporaryFile()  # noqa: SIM115 (closed with the process)
                self._proc = subprocess.Popen([sys.executable, "-c", code, str(theirs.fileno())],
                                              pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL,
                                              stdout=subprocess.DEVNULL, stderr=self._proc_err,
                                              start_new_session=True)  # Ctrl-C reaches the loop's process only
            finally:
                theirs.close()
            self._conn = Connection(mine.detach())
            shapes = {k: tuple(v.shape) for k, v in self.specs.items()}
            self._conn.send((str(self.path), self._shm.name, n, shapes, nb))
            self._call("ready", timeout=max(self.writer_timeout_s, 60.0))  # the process imports numpy and h5py
        except BaseException as exc:
            self._end_process(graceful=False)
            if isinstance(exc, _WriteFailed):
                raise RecordWriteError(f"{self.path}: cannot create record: {exc.what}: {exc.reason}") from None
            if isinstance(exc, Exception):
                raise RecordWriteError(f"{self.path}: cannot start the record writer process: "
                                       f"{_one_line(exc)}") from None
            raise

    def _call(self, kind: str, *args: Any, timeout: float | None = None) -> Any:
        """One call to the writer process (see :func:`_writer_process_main`); its value, or
        :class:`_WriteFailed` (a process that ended or does not answer within ``timeout``: broken,
        the file is left as a kill leaves it)."""
        with self._call_lock:
            if self._proc_lost is not None:
                raise _WriteFailed("the record writer process", self._proc_lost, True)
            try:
                self._conn.send((kind, *args))
                if timeout is not None and not self._conn.poll(timeout):
                    raise TimeoutError(f"no answer within {timeout:g} s")
                reply = self._conn.recv()
            except (EOFError, OSError, TimeoutError) as exc:
                if isinstance(exc, TimeoutError):  # frozen (SIGSTOP) or stuck: it must not outlive its use
                    why = f"did not answer within {timeout:g} s and was killed"
                    self._kill_process()
                else:
                    why = self._how_it_ended(exc)
                self._proc_lost = why
                raise _WriteFailed("the record writer process", why, True) from None
        if reply[0] == "ok":
            return reply[1]
        raise _WriteFailed(reply[1], reply[2], reply[3])

    def _kill_process(self) -> None:
        """SIGKILL the writer process (it also ends a stopped one) and reap it."""
        import subprocess

        proc = self._proc
        if proc is None:
            return
        with contextlib.suppress(OSError):
            proc.kill()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(5.0)

    def _how_it_ended(self, exc: BaseException) -> str:
        """One phrase on a writer process whose connection failed: its exit (signal or code) and the
        last line it wrote on stderr."""
        import subprocess

        proc, code = self._proc, None
        if proc is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                code = proc.wait(2.0)
        if code is None:
            self._kill_process()
            return f"stopped answering ({_one_line(exc) or type(exc).__name__}) and was killed"
        if code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            why = f"was killed by {name}"
        else:
            why = f"ended with exit code {code}"
        said = self._process_said()
        return f"{why}{': ' + said if said else ''}"

    def _process_said(self) -> str:
        """The last line the writer process wrote on its stderr (a file), at most 200 characters."""
        err = self._proc_err
        if err is None:
            return ""
        try:
            err.seek(0)
            lines = err.read()[-4096:].decode("utf-8", "replace").strip().splitlines()
        except (OSError, ValueError):
            return ""
        return _one_line(lines[-1])[:200] if lines else ""

    def _end_process(self, graceful: bool = True) -> None:
        """Close the file in the writer process (``graceful``, bounded by ``writer_timeout_s``) and
        let it end; release the shared memory's name. A stuck process is left to finish alone."""
        proc, conn = self._proc, self._conn
        if graceful and conn is not None and proc is not None and self._proc_lost is None:
            with contextlib.suppress(_WriteFailed):
                self._call("close", timeout=self.writer_timeout_s)
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.close()
        if proc is not None:
            import subprocess

            try:
                proc.wait(self.writer_timeout_s if graceful and self._proc_lost is None else 2.0)
            except subprocess.TimeoutExpired:  # a process that does not end: never left running
                self._kill_process()
        if self._shm is not None:
            with contextlib.suppress(Exception):
                self._shm.unlink()
        if self._proc_err is not None:
            with contextlib.suppress(OSError):
                self._proc_err.close()
            self._proc_err = None
        self._conn = None

    def _stop_writer(self) -> bool:
        """Background mode: let the writer thread finish what is queued and exit (at most
        ``writer_timeout_s``). False when it is still running (stuck in a write)."""
        th = self._thread
        if th is None:
            return True
        self._jobs.put(None)
        th.join(self.writer_timeout_s)
        if th.is_alive():
            self._writer_stuck = True
            return False
        self._thread = None
        return True

    def close(self, stop_reason: str = "completed", status: str = "ok") -> None:
        """Flush, write the final ``/status`` (stop reason, status) in place and flush again, then
        close the file. Idempotent.

        After a write failure (or when this last flush fails) the status records ``"error"`` with the
        failure as stop reason when the file is still consistent (the failure was caught before HDF5
        wrote anything, e.g. a full disk), the file is released, and the failure is raised
        (:class:`RecordWriteError`, once: a second close is a no-op)."""
        if self.closed:
            return
        if _TEST_HOOK is not None:
            _TEST_HOOK("close", self)
        with _signals_held():  # a handler runs once the file is closed, never between its steps
            self._close(stop_reason, status)

    def _close(self, stop_reason: str, status: str) -> None:
        failure = self.failure
        try:
            if failure is None:
                try:
                    self.flush()
                except RecordWriteError as exc:
                    failure = exc
            stopped = self._stop_writer()
            if isinstance(failure, RecordLagError) and self.failure is not None:
                failure = self.failure  # the writer failed meanwhile (e.g. a lost process): the real reason
            if not stopped or self._writer_stuck:
                # a thread may still be inside h5py: the file is not touched again (left as a kill leaves it)
                failure = failure or self._fail(TimeoutError(
                    f"the writer thread did not finish within {self.writer_timeout_s:g} s"), "background write")
            if _TEST_HOOK is not None:
                _TEST_HOOK("close:flushed", self)
            if self._proc_lost is None and not self._hdf5_broken and not self._writer_stuck:
                if failure is not None and status == "ok":
                    stop_reason, status = str(failure), "error"
                self._write_status(str(stop_reason), str(status))
                if _TEST_HOOK is not None:
                    _TEST_HOOK("close:status", self)
        except RecordWriteError as exc:
            failure = failure or exc
        finally:
            self.closed = True
            try:
                if self._proc is not None:
                    self._end_process()
                elif not self._writer_stuck:
                    self._f.close()
            except Exception as exc:  # the samples flushed before are on disk; the handle is gone
                if failure is None:
                    failure = self._fail(exc, "close")
            if self._proc_lost is not None:  # nothing holds the file now: the reason goes into it
                self._write_lost_status(str(stop_reason), "error" if status == "ok" else str(status))
        if failure is not None:
            raise failure
        self._trim()
        logger.info("record %s closed: %d samples, %s (%s)", self.path, self.samples, self.status, self.stop_reason)

    def _trim(self) -> None:
        """Cut the unused disk reserve (zeros past HDF5's end of file) off the closed file."""
        with contextlib.suppress(OSError, RecordError):
            swmr, end = _probe_hdf5(self.path)
            if not swmr and end is not None and self.path.stat().st_size > end:
                os.truncate(self.path, end)

    @staticmethod
    def _status_bytes(stop_reason: str, status: str, samples: int) -> tuple[np.ndarray, dict[str, Any]]:
        """The ``/status`` bytes: one JSON line, zero padded to ``_STATUS_BYTES`` (a very long
        reason is shortened so the line stays valid JSON), and the document."""
        doc: dict[str, Any] = {"stop_reason": stop_reason, "status": status, "closed_utc": _utc_now(),
                               "samples": samples}
        raw = (_to_json(doc, "status") + "\n").encode()
        if len(raw) > _STATUS_BYTES:
            doc["stop_reason"] = stop_reason[: max(0, len(stop_reason) - (len(raw) - _STATUS_BYTES) - 8)] + "..."
            raw = (_to_json(doc, "status") + "\n").encode()
        buf = np.zeros(_STATUS_BYTES, dtype=np.uint8)
        buf[: len(raw)] = np.frombuffer(raw[:_STATUS_BYTES], dtype=np.uint8)
        return buf, doc

    def _write_lost_status(self, stop_reason: str, status: str) -> None:
        """The writer process was lost (killed, died, or frozen and killed): nothing holds the file,
        whose HDF5 state is what that process last flushed. Its ``/status`` bytes (contiguous, at a
        fixed offset since creation, outside HDF5's metadata) are written directly with the reason,
        saying that the record holds the samples of the last flushed block and how many taken after
        it are not in it. Failures are logged (the record then reads as not closed, as before)."""
        lost = self.samples - self.samples_flushed
        note = (f"record writer process {self._proc_lost}: the record holds the {self.samples_flushed} samples "
                f"of its last flushed block" + (f"; the {lost} samples taken after it are not in it" if lost else ""))
        reason = note if not stop_reason or stop_reason == "completed" else f"{stop_reason}; {note}"
        buf, doc = self._status_bytes(reason, status, self.samples_flushed)
        if self._status_offset is None:
            logger.error("record %s: %s (no /status offset: not written into the record)", self.path, reason)
            return
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
            try:
                os.pwrite(fd, buf.tobytes(), self._status_offset)
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as exc:
            logger.error("record %s: the stop reason could not be written into it (%s): %s", self.path,
                         _one_line(exc), reason)
            return
        self.stop_reason, self.status = doc["stop_reason"], status
        logger.error("record %s: %s", self.path, reason)

    def _write_status(self, stop_reason: str, status: str) -> None:
        """Overwrite the fixed ``/status`` bytes with one JSON line (zero padded) and flush. The space
        was allocated at creation, so this cannot run out of disk."""
        buf, doc = self._status_bytes(stop_reason, status, self.samples)
        err: RecordWriteError | None = None
        with _signals_held():
            try:
                if self._proc is not None:
                    self._call("status", buf, timeout=self.writer_timeout_s)
                else:
                    self._f["status"][:] = buf
                    self._f.flush()
            except _WriteFailed as exc:
                self._hdf5_broken = True
                err = self._fail_reason(exc.reason, exc.what)
            except Exception as exc:
                self._hdf5_broken = True
                err = self._fail(exc, "writing the status")
            else:
                self.stop_reason, self.status = doc["stop_reason"], status
        if err is not None:
            raise err


# ---------------------------------------------------------------------------------------------- reader


# ---------------------------------------------------------------------------------------- identification


def store_identification(path: str | Path, name: str, samples: Any, summary: Mapping[str, Any]) -> None:
    """Write an identification result into a closed record as ``/identification/<name>`` (replacing
    an earlier one of that name); the run's own groups are not touched.

    Layout: group attrs ``format`` ("hil-identification"), ``format_version`` 1, ``created_utc``;
    dataset ``samples`` float64 (n_samples, n_params) -- posterior draws in physical units, with the
    attr ``columns`` (JSON list, from ``summary["sample_names"]`` when given); dataset ``summary`` --
    a UTF-8 JSON string of ``summary`` (per-parameter summary, convergence diagnostics, ...).
    Raises :class:`RecordError` when the file cannot be opened for writing (e.g. a record whose
    writer is still running).
    """
    _check_name(name, "identification")
    arr = np.asarray(samples, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise RecordError(f"identification {name!r}: samples must be (n, p), got shape {arr.shape}")
    text = _to_json(dict(summary), f"identification {name!r} summary")
    try:
        with h5py.File(path, "r+") as f:
            if f.attrs.get("format") not in (FORMAT, FORMAT.encode()):
                raise RecordError(f"{path}: not a {FORMAT} file")
            root = f.require_group("identification")
            if name in root:
                del root[name]
            g = root.create_group(name)
            g.attrs["format"] = "hil-identification"
            g.attrs["format_version"] = 1
            g.attrs["created_utc"] = _utc_now()
            ds = g.create_dataset("samples", data=arr, chunks=True, compression="gzip", shuffle=True)
            cols = summary.get("sample_names")
            ds.attrs["columns"] = _to_json(list(cols) if cols is not None else [], "columns")
            g.create_dataset("summary", data=text, dtype=h5py.string_dtype("utf-8"))
    except OSError as exc:
        raise RecordError(f"{path}: cannot write the identification: {exc}") from None

