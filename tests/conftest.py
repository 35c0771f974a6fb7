"""Suite-wide test configuration.

Tests marked ``slow`` (calibration over many datasets, long sweeps) are skipped unless the ``-m``
expression mentions ``slow``: ``pytest`` runs the fast suite, ``pytest -m "slow or not slow"``
(what CI runs) runs everything, ``pytest -m slow`` only the slow checks.

Timeouts (pytest-timeout) are hang guards, never a measure of speed: each test's ``timeout`` marker
is the time it needs on an idle 2-core machine with margin, and is multiplied here by
``simtime.TIMEOUT_SCALE``, so that the suite passes on a loaded box (a CI runner: two CPU-bound processes
beside the two test workers make every test about four times slower). The default for unmarked
tests (``timeout`` in pyproject.toml) is already scaled.
"""

from __future__ import annotations

import pytest
from simtime import TIMEOUT_SCALE


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        marker = item.get_closest_marker("timeout")
        if marker is not None and marker.args:
            item.add_marker(pytest.mark.timeout(float(marker.args[0]) * TIMEOUT_SCALE), append=False)
    if "slow" in (config.getoption("-m") or ""):
        return
    skip = pytest.mark.skip(reason="slow: run with -m 'slow or not slow'")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


# ---------------------------------------------------------------------------------------------
# leaks: a test must not leave threads, pseudo-terminals or virtual CAN channels behind

#: threads a library keeps for the life of the process by design (not owned by any test)
_LONG_LIVED_THREADS = ("asyncio_", "ThreadPoolExecutor-", "IO loop", "Profile", "TCP-Executor", "Dask-Offload",
                       "AsyncProcess", "QueueFeederThread")
#: how long (s) the leak check lets threads that are ending finish (it returns as soon as they did:
#: a bound for a loaded machine, not a pace)
_LEAK_GRACE_S = 30.0


def _own_threads() -> dict[int, str]:
    import threading

    return {t.ident or 0: t.name for t in threading.enumerate()
            if t is not threading.main_thread() and t.is_alive() and not t.name.startswith(_LONG_LIVED_THREADS)}


def _pty_fds() -> set[str]:
    import os

    out = set()
    try:
        for fd in os.listdir("/proc/self/fd"):
            try:
                target = os.readlink(f"/proc/self/fd/{fd}")
            except OSError:
                continue
            if target == "/dev/ptmx" or target.startswith("/dev/pts/"):
                out.add(f"{fd}->{target}")
    except OSError:  # no /proc (not Linux): the pty check is off
        pass
    return out


def _can_channels() -> set[str]:
    try:
        from can.interfaces import virtual
    except ImportError:
        return set()
    return {str(k) for k, v in getattr(virtual, "channels", {}).items() if v}


@pytest.fixture(autouse=True)
def _no_leaks(request: pytest.FixtureRequest):
    """Fail a test that leaves a thread running, a pty open or a virtual CAN channel with a bus
    attached (after a short grace period for threads that are already stopping)."""
    import time

    before_t, before_p, before_c = _own_threads(), _pty_fds(), _can_channels()
    yield
    if request.node.get_closest_marker("leaks_ok"):
        return
    deadline = time.monotonic() + _LEAK_GRACE_S
    while True:
        threads = {i: n for i, n in _own_threads().items() if i not in before_t}
        ptys = _pty_fds() - before_p
        chans = _can_channels() - before_c
        if not (threads or ptys or chans) or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    problems = []
    if threads:
        problems.append(f"threads still running: {sorted(threads.values())}")
    if ptys:
        problems.append(f"pseudo-terminals left open: {sorted(ptys)}")
    if chans:
        problems.append(f"virtual CAN channels still attached: {sorted(chans)}")
    if problems:
        pytest.fail("leak: " + "; ".join(problems), pytrace=False)
