"""Shared by the commands of ``hil``: one-line errors, NAME=VALUE flags, output folders, progress."""

from __future__ import annotations

import argparse
import contextlib
import difflib
import math
import os
import sys
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from hil.errors import (
    HilError,
)


class UsageError(HilError):
    """A command-line mistake; reported in one line with exit code 2."""

def one_line(text: object) -> str:
    """``text`` with every run of white space (newlines too) collapsed to one space."""
    return " ".join(str(text).split())

class OneLineArgumentParser(argparse.ArgumentParser):
    """An :class:`argparse.ArgumentParser` whose errors are one line on stderr,
    ``<prog>: error: <message> (see '<prog> --help')``, with exit status 2 (``SystemExit``), instead
    of the usage block followed by the message. Subparsers inherit the class."""

    def error(self, message: str) -> Any:
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see '{self.prog} --help')\n")

def parse_number(flag: str, name: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise UsageError(f"{flag} {name}={text.strip()}: {name} must be a number") from None
    if not math.isfinite(v):
        raise UsageError(f"{flag} {name}={text.strip()}: {name} must be finite")
    return v

def parse_set(items: Sequence[str], defaults: dict[str, Any] | None = None, what: str = "",
               flag: str = "--set") -> dict[str, Any]:
    """``NAME=VALUE`` items. With ``defaults``: names must be keys of it (did-you-mean otherwise);
    a name whose default is a string takes the text, every other name a finite number."""
    out: dict[str, Any] = {}
    for it in items:
        if "=" not in it:
            raise UsageError(f"{flag} expects NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        k = k.strip()
        if not k:
            raise UsageError(f"{flag} {it}: empty parameter name")
        if defaults is not None and k not in defaults:
            raise UsageError(f"{flag} {it}: {what} has no parameter {k!r}{suggest(k, list(defaults))}")
        if defaults is not None and isinstance(defaults[k], str):
            out[k] = v.strip()
        else:
            out[k] = parse_number(flag, k, v)
    return out

def suggest(name: str, known: Sequence[str]) -> str:
    close = difflib.get_close_matches(name, known, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""

#: output folders this process created (removed again when the command fails before writing a file)
CREATED: list[Path] = []

def out_dir(path: str | None, default_stem: str, overwrite: bool) -> Path:
    """:func:`hil.record.outdir.prepare_out_dir`, remembering a folder it created for clean-up on failure."""
    from hil.record.outdir import prepare_out_dir

    existed = path is not None and Path(path).exists()
    # the ancestors this call creates (e.g. runs/ for runs/<scene>-<time>): removed with it on failure
    parent = (Path(path) if path is not None else Path(default_stem)).absolute().parent
    missing = [a for a in [parent, *parent.parents] if not a.exists()]
    out = prepare_out_dir(path, default_stem=default_stem, overwrite=overwrite)
    if not existed:
        CREATED.append(missing[-1] if missing else out)
    return out

def cleanup_created() -> None:
    from hil.record.outdir import remove_if_empty

    while CREATED:
        remove_if_empty(CREATED.pop())

#: columns of a table printed where stdout is not a terminal (a pipe, a file, CI): wide enough
#: that no row of the suite's tables is cut at rich's default of 80 columns
PIPE_COLUMNS = 240


def console(stderr: bool = False) -> Any:
    """The rich Console of a command's tables: the terminal's width on a terminal, otherwise
    ``COLUMNS`` when set and :data:`PIPE_COLUMNS` if not (never the default 80 of a pipe)."""
    from rich.console import Console

    stream = sys.stderr if stderr else sys.stdout
    width = None
    if not stream.isatty():
        try:
            width = int(os.environ.get("COLUMNS", "")) or PIPE_COLUMNS
        except ValueError:
            width = PIPE_COLUMNS
    return Console(highlight=False, soft_wrap=True, width=width, stderr=stderr)


def progress_interval() -> float:
    try:
        return max(0.05, float(os.environ.get("HIL_PROGRESS_SECONDS", "5")))
    except ValueError:
        return 5.0

class StepProgress:
    """Progress of a long step on stderr. On a TTY a rich spinner with the latest message; otherwise
    a plain line ``<label>: <elapsed> s: <message>`` every ``HIL_PROGRESS_SECONDS`` (default 5) s,
    the first one only after that interval (a short step prints nothing)."""

    def __init__(self, label: str, enabled: bool = True, interval: float | None = None) -> None:
        self.label = label
        self.enabled = enabled
        self.interval = progress_interval() if interval is None else interval
        self.message = "working"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._status: Any = None
        self._t0 = time.monotonic()

    def update(self, message: str) -> None:
        self.message = message
        if self._status is not None:
            self._status.update(f"{self.label}: {message}")

    def say(self, line: str) -> None:
        """Print ``line`` on stderr, above the spinner on a terminal (never through it)."""
        if self._status is not None:
            self._status.console.print(line, highlight=False, markup=False)
        else:
            print(line, file=sys.stderr, flush=True)

    def _loop(self) -> None:
        while not self._stop.wait(self.interval):
            print(f"{self.label}: {time.monotonic() - self._t0:.0f} s: {self.message}", file=sys.stderr, flush=True)

    def __enter__(self) -> StepProgress:
        self._t0 = time.monotonic()
        if not self.enabled:
            return self
        if sys.stderr.isatty():
            from rich.console import Console

            self._status = Console(stderr=True).status(f"{self.label}: {self.message}")
            self._status.__enter__()
        else:
            self._thread = threading.Thread(target=self._loop, name="hil-progress", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._status is not None:
            self._status.__exit__(*exc)

class _BenchOpeningFilter:
    """Drops the log lines of a bench that failed while opening (``… (while the bench was opening)``):
    the command says it once, in its one-line error (nothing ran) or its result table."""

    @staticmethod
    def filter(record: Any) -> bool:
        return "(while the bench was opening)" not in record.getMessage()


@contextlib.contextmanager
def bench_opening_said_once() -> Iterator[None]:
    """While a command runs experiments: a device that cannot be opened is reported once, by the
    command (:class:`_BenchOpeningFilter` on the root logger's handlers), not also as warnings."""
    import logging

    handlers = list(logging.getLogger().handlers)
    for h in handlers:
        h.addFilter(_BenchOpeningFilter)
    try:
        yield
    finally:
        for h in handlers:
            h.removeFilter(_BenchOpeningFilter)


@contextlib.contextmanager
def numeric_guard(source: str) -> Iterator[None]:
    """Turn float overflow in the criteria (coefficients spanning too wide a range) into one
    :class:`UsageError` naming ``source`` instead of a RuntimeWarning or a traceback."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            yield
        except (FloatingPointError, OverflowError) as exc:
            raise UsageError(f"{source}: the arithmetic leaves float range ({one_line(exc)}): the coefficients "
                             "span too wide a range; rescale the units") from None
    bad = [w for w in caught if issubclass(w.category, RuntimeWarning)
           and any(k in str(w.message) for k in ("overflow", "invalid value"))]
    for w in caught:
        if w not in bad:
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    if bad:
        raise UsageError(f"{source}: the arithmetic leaves float range ({bad[0].message}): the result would not be "
                         "finite; rescale the units")

class SweepProgress(StepProgress):
    """Points done and time left: a rich bar on a TTY, otherwise a line every few seconds."""

    def __init__(self, label: str, enabled: bool = True) -> None:
        super().__init__(label, enabled=enabled and not sys.stderr.isatty())
        self._tty = enabled and sys.stderr.isatty()
        self._bar: Any = None
        self._task: Any = None
        self._t_phase = time.monotonic()
        self._last_total = -1
        self._n_phase = 0

    def update(self, done: int, total: int) -> None:  # type: ignore[override]
        if total != self._last_total:
            self._t_phase, self._last_total = time.monotonic(), total
            self._n_phase += 1
        el = time.monotonic() - self._t_phase
        left = (el / done * (total - done)) if done else float("nan")
        phase = "grid points" if self._n_phase <= 1 else "boundary segments"
        self.message = f"{done}/{total} {phase}, about {left:.0f} s left"
        if self._tty:
            if self._bar is None:
                from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

                self._bar = Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                                     TimeRemainingColumn(), transient=True)
                self._bar.start()
            if self._task is None or self._bar.tasks[-1].total != total:
                self._task = self._bar.add_task(f"{self.label} ({phase})", total=total)
            self._bar.update(self._task, completed=done)

    def __exit__(self, *exc: Any) -> None:
        if self._bar is not None:
            self._bar.stop()
        super().__exit__(*exc)


def debug_parent() -> OneLineArgumentParser:
    """The parent parser every (sub)command takes: ``--debug`` after the command name too."""
    common = OneLineArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    return common
