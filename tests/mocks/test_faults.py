"""The shared fault-injection plan: semantics and determinism."""

from __future__ import annotations

from collections import Counter

import pytest

from hil.mocks.faults import ByteStreamFaults, FaultInjector, FaultPlan


def _decisions(inj: FaultInjector, n: int = 200) -> list:
    out = []
    for t in range(n):
        out.append(
            (inj.should_drop(t), inj.should_corrupt(t), inj.is_late(), inj.should_repeat_stale(), inj.garbage())
        )
    return out


PLAN = FaultPlan(drop_prob=0.2, corrupt_prob=0.1, late_prob=0.1, stale_prob=0.1, garbage_prob=0.1)


def test_same_seed_same_decisions():
    assert _decisions(FaultInjector(PLAN, seed=7)) == _decisions(FaultInjector(PLAN, seed=7))


def test_different_seed_differs():
    assert _decisions(FaultInjector(PLAN, seed=7)) != _decisions(FaultInjector(PLAN, seed=8))


def test_streams_are_independent():
    a = FaultInjector(FaultPlan(drop_prob=0.3), seed=1)
    b = FaultInjector(FaultPlan(drop_prob=0.3, corrupt_prob=0.5), seed=1)
    da, db = [], []
    for t in range(100):
        da.append(a.should_drop(t))
        db.append(b.should_drop(t))
        b.maybe_corrupt(b"abc", t)
    assert da == db


def test_null_plan_injects_nothing():
    inj = FaultInjector(seed=0)
    assert FaultPlan().is_null
    assert not any(any(x) for x in _decisions(inj, 50))
    assert inj.error_code(10) == 0 and not inj.is_disconnected(10)
    assert not inj.injected


def test_rates_roughly_match():
    inj = FaultInjector(FaultPlan(drop_prob=0.25), seed=0)
    n = sum(inj.should_drop() for _ in range(4000))
    assert 850 < n < 1150
    assert inj.injected["drop"] == n


def test_scheduled_ticks():
    inj = FaultInjector(FaultPlan(drop_ticks=[3], corrupt_ticks={5}), seed=0)
    assert [inj.should_drop(t) for t in range(6)] == [False, False, False, True, False, False]
    assert [inj.should_corrupt(t) for t in range(6)] == [False] * 5 + [True]


def test_corrupt_always_changes_one_byte():
    inj = FaultInjector(seed=3)
    data = bytes(range(37))
    for _ in range(100):
        out = inj.corrupt(data, start=1)
        diff = [i for i in range(len(data)) if out[i] != data[i]]
        assert len(diff) == 1 and diff[0] >= 1
    assert inj.corrupt(b"", 0) == b""


def test_error_code_window_and_disconnect_window():
    inj = FaultInjector(FaultPlan(error_code=0x20, error_at_tick=5, error_until_tick=8,
                                  disconnect_at_tick=10, reconnect_at_tick=12))
    assert [inj.error_code(t) for t in range(4, 9)] == [0, 0x20, 0x20, 0x20, 0]
    assert [inj.is_disconnected(t) for t in range(9, 13)] == [False, True, True, False]
    forever = FaultInjector(FaultPlan(disconnect_at_tick=1))
    assert forever.is_disconnected(10**6)


def test_garbage_length_bounds():
    inj = FaultInjector(FaultPlan(garbage_prob=1.0, garbage_len=5), seed=0)
    lens = {len(inj.garbage()) for _ in range(200)}
    assert lens <= set(range(1, 6)) and len(lens) > 1


def test_plan_validation_and_from_dict():
    with pytest.raises(ValueError):
        FaultPlan(drop_prob=1.5)
    with pytest.raises(ValueError, match="unknown fault plan keys"):
        FaultPlan.from_dict({"dorp_prob": 0.1})
    p = FaultPlan.from_dict({"drop_prob": 0.1, "drop_ticks": [1, 2]})
    assert p.drop_ticks == frozenset({1, 2})
    assert FaultPlan.from_dict(None) == FaultPlan()


def test_byte_stream_faults_order_and_counts():
    """Drop, late (held and sent after the next frame), stale repeat and corruption past the header."""
    stats: Counter[str] = Counter()
    sent = ByteStreamFaults(FaultInjector(FaultPlan(drop_ticks=frozenset({2}))), stats)
    assert sent.bytes_to_send(b"A", 1) == b"A"
    assert sent.bytes_to_send(b"B", 2) is None and stats["dropped"] == 1
    assert sent.bytes_to_send(b"C", 3) == b"C"

    late = ByteStreamFaults(FaultInjector(FaultPlan(late_prob=1.0)), Counter())
    assert late.bytes_to_send(b"A", 1) is None  # held back
    assert late.bytes_to_send(b"B", 2) == b"BA"  # sent after the next frame, which is not held
    assert late.stats["late"] == 1

    stale = ByteStreamFaults(FaultInjector(FaultPlan(stale_prob=1.0)), Counter())
    assert stale.bytes_to_send(b"A", 1) == b"A"  # nothing to repeat yet
    assert stale.bytes_to_send(b"B", 2) == b"A" and stale.stats["stale"] == 1

    frame = bytes(range(10))
    bad = ByteStreamFaults(FaultInjector(FaultPlan(corrupt_ticks=frozenset({1}))), Counter(), corrupt_start=2)
    out = bad.bytes_to_send(frame, 1)
    diff = [i for i in range(10) if out[i] != frame[i]]
    assert len(diff) == 1 and diff[0] >= 2 and bad.stats["corrupted"] == 1


def test_scheduled_stale_window_and_draws_unchanged():
    from hil.mocks.faults import FaultInjector, FaultPlan

    inj = FaultInjector(FaultPlan(stale_at_tick=3, stale_until_tick=5), seed=1)
    assert [inj.should_repeat_stale(t) for t in range(7)] == [False, False, False, True, True, False, False]
    assert inj.injected["stale"] == 2
    forever = FaultInjector(FaultPlan(stale_at_tick=2), seed=1)
    assert [forever.is_stale_scheduled(t) for t in (1, 2, 10**6)] == [False, True, True]


def test_bounded_log_keeps_the_newest_entries():
    from hil.mocks.faults import BoundedLog

    log = BoundedLog(maxlen=3)
    for k in range(10):
        log.append(k)
    assert log == [7, 8, 9] and log.total == 10
