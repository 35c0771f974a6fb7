"""Stop requests as a flag, handled at safe points (never an exception raised from a signal handler).

One process-wide :data:`STOP` (:class:`StopRequest`). While it is installed (``with STOP.install():``,
re-entrant; the bench installs it from the moment it starts opening until every device is closed,
the runner for a whole ``run()``), SIGINT, SIGTERM and SIGHUP only *record* the request:

* the first signal sets the flag with its reason (``"signal: SIGTERM"``, ``"signal: SIGINT"``, ...)
  and status (``"interrupted"`` for SIGINT, ``"safety_stop"`` for SIGTERM/SIGHUP);
* the fixed-rate loop calls :meth:`StopRequest.check` once per tick (a safe point): it raises
  :class:`StopRequested` (a :class:`hil.errors.SafetyStop`) there, so the usual safe stop runs;
  the runner also checks before starting each experiment, so a stop ends the whole run;
* inside :meth:`StopRequest.critical` (the safe stop: zero effort to every actuator) further signals
  are only counted, never acted on. A *third* signal ends the process once the safe stop is done
  (at once if it is done already), a *second* one received after the safe stop completed ends it
  at once: one line on stderr, then the signal's default action (every actuator has been sent zero
  effort already). Escape hatch: a fifth signal ends the process even if no safe stop could run
  (a bench stuck before its next safe point).

Nothing here raises into arbitrary code: handlers only set attributes and, when the process must
end, re-deliver the signal with its default disposition. Handlers can only be installed in the
main thread; elsewhere :meth:`install` is a no-op (the flag still works with :meth:`request`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
from collections.abc import Iterator
from typing import Any

from hil.errors import SafetyStop

logger = logging.getLogger(__name__)

__all__ = ["STOP", "SignalInterrupt", "StopRequest", "StopRequested", "signals_interrupt"]

#: Signals received before any safe stop that end the process anyway (a bench stuck before its
#: next safe point; the safe stop itself is bounded and never cut short).
_ESCAPE = 5

#: Signals turned into stop requests, and the run status each one gives.
SIGNALS: dict[str, str] = {"SIGINT": "interrupted", "SIGTERM": "safety_stop", "SIGHUP": "safety_stop"}


class StopRequested(SafetyStop):
    """Raised at a safe point once a stop was requested. ``status``: ``interrupted`` | ``safety_stop``."""

    def __init__(self, reason: str, status: str = "safety_stop") -> None:
        super().__init__(reason)
        self.status = status


class StopRequest:
    """A process-wide stop flag fed by signals (see the module docstring).

    Attributes: ``requested`` (bool), ``reason`` (str or None, e.g. ``"signal: SIGTERM"``),
    ``status`` (``"interrupted"`` | ``"safety_stop"`` or None), ``signum`` (first signal or None),
    ``count`` (signals received since the flag was last reset), ``in_critical`` (inside a safe stop),
    ``safe_stops`` (safe stops completed after the first signal).
    """

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._depth = 0
        self._old: dict[int, Any] = {}
        self.reset()

    # -- state ------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Clear the flag (a new run starts)."""
        self.requested = False
        self.reason: str | None = None
        self.status: str | None = None
        self.signum: int | None = None
        self.count = 0
        self.in_critical = 0
        self.safe_stops = 0

    def request(self, reason: str, status: str = "safety_stop") -> None:
        """Request a stop (the first request's reason and status are kept)."""
        if not self.requested:
            self.requested, self.reason, self.status = True, str(reason), str(status)
            logger.warning("stop requested: %s", reason)

    def check(self) -> None:
        """At a safe point: raise :class:`StopRequested` when a stop was requested."""
        if self.requested:
            raise StopRequested(self.reason or "stop requested", self.status or "safety_stop")

    @property
    def installed(self) -> bool:
        """True while the signal handlers are installed."""
        return bool(self._old)

    # -- handlers ---------------------------------------------------------------------------------
    def _handler(self, signum: int, frame: Any) -> None:  # runs between bytecodes of the main thread
        if self._depth == 0:  # left installed by a release outside the main thread: behave as before
            if signum == signal.SIGINT:
                raise KeyboardInterrupt
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        self.count += 1
        name = signal.Signals(signum).name
        if self.signum is None:
            self.signum = signum
        if not self.requested:
            self.requested, self.reason = True, f"signal: {name}"
            self.status = SIGNALS.get(name, "safety_stop")
            return
        if self.in_critical:
            return  # the safe stop runs to its end (bounded); critical() decides when it is left
        if (self.count >= 2 and self.safe_stops > 0) or self.count >= _ESCAPE:
            self._force_exit(signum)
        # a third signal before the safe stop: acted on when the safe stop is done (critical())

    def _force_exit(self, signum: int) -> None:
        """End the process by ``signum``'s default action (after a completed safe stop, or on the
        third signal)."""
        with contextlib.suppress(OSError):
            os.write(2, f"hil: {signal.Signals(signum).name} received again: exiting now "
                        f"(safe stop {'done' if self.safe_stops else 'NOT completed'})\n".encode())
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)

    def _acquire(self) -> None:
        with self._lock:
            if self._depth == 0:
                self.reset()
                if not self._old and threading.current_thread() is threading.main_thread():
                    for name in SIGNALS:
                        sig = getattr(signal, name, None)
                        if sig is None:  # pragma: no cover - SIGHUP on Windows
                            continue
                        self._old[sig] = signal.signal(sig, self._handler)
            self._depth += 1

    def _release(self) -> None:
        with self._lock:
            self._depth = max(0, self._depth - 1)
            # handlers can only be changed in the main thread (a bench closed by the garbage
            # collector elsewhere leaves them installed; _handler then acts as the default would)
            if self._depth == 0 and self._old and threading.current_thread() is threading.main_thread():
                for sig, old in self._old.items():
                    with contextlib.suppress(ValueError, TypeError):
                        signal.signal(sig, old if old is not None else signal.SIG_DFL)
                self._old.clear()

    @contextlib.contextmanager
    def install(self) -> Iterator[StopRequest]:
        """Install the handlers for the block (re-entrant: only the outermost block installs and
        restores them; entering the outermost block clears the flag)."""
        self._acquire()
        try:
            yield self
        finally:
            self._release()

    def acquire(self) -> None:
        """Non-context form of :meth:`install` (paired with :meth:`release`; used by the bench)."""
        self._acquire()

    def release(self) -> None:
        """End one :meth:`acquire` (the outermost restores the previous handlers)."""
        self._release()

    @contextlib.contextmanager
    def critical(self) -> Iterator[None]:
        """A block no signal may cut short (the safe stop). On leaving it, a third signal received
        meanwhile ends the process; later ones follow :meth:`_handler`'s rules."""
        self.in_critical += 1
        try:
            yield
        finally:
            self.in_critical -= 1
            if not self.in_critical and self.count > 0:
                self.safe_stops += 1
                if self.count >= 3 and self.installed and self.signum is not None:
                    self._force_exit(self.signum)


#: The process-wide stop request.
STOP = StopRequest()


class SignalInterrupt(KeyboardInterrupt):
    """SIGTERM or SIGHUP received where no device is open (the computing stages of ``hil certify``),
    raised the way Python raises ``KeyboardInterrupt`` for SIGINT, so whatever already handles a
    Ctrl-C cleanly handles it too. ``signame`` is the signal's name; the command turns it into a
    :class:`StopRequested` (exit 20) once it has put its output in order."""

    def __init__(self, signame: str) -> None:
        super().__init__(f"signal: {signame}")
        self.signame = signame


@contextlib.contextmanager
def signals_interrupt() -> Iterator[None]:
    """For the block: SIGTERM and SIGHUP raise :class:`SignalInterrupt` (SIGINT keeps Python's
    ``KeyboardInterrupt``). A bench opened inside installs :data:`STOP` over these handlers and
    restores them when it closes, so at the bench a signal is still only a flag handled at a safe
    point. Main thread only (elsewhere a no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def raise_it(signum: int, frame: Any) -> None:
        raise SignalInterrupt(signal.Signals(signum).name)

    old = {}
    for name in ("SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None:
            old[sig] = signal.signal(sig, raise_it)
    try:
        yield
    finally:
        for sig, prev in old.items():
            signal.signal(sig, prev if prev is not None else signal.SIG_DFL)
