"""A daemon thread calling a function at a fixed rate (absolute deadlines on the monotonic clock),
for simulated devices that stream on their own (free-running mode). Lockstep runs never use it."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class PeriodicThread:
    """Call ``fn()`` every ``period`` seconds until :meth:`stop`. If it falls more than ten periods
    behind (a stalled process), it resynchronises instead of bursting to catch up."""

    def __init__(self, fn: Callable[[], object], period: float, name: str) -> None:
        self.fn = fn
        self.period = float(period)
        self.name = name
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        return self._thread is not None

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            self.fn()
            next_t += self.period
            delay = next_t - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            elif delay < -10 * self.period:
                next_t = time.monotonic()

    def stop(self, timeout: float = 2.0) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=timeout)
            self._thread = None
