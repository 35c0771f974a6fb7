"""SimPoint.apply_uniform (a CAN drive's per-tick torque without an array) has the effect of
apply_effort(np.full(dof, value)): the same efforts reach the body's handle, the same writes are
skipped, and a reset of the handle makes the next write go through."""

from __future__ import annotations

import numpy as np

from hil.bench.runtime import SimPoint, _BodyDrive


class _Handle:
    """A body's Joints handle that records every effort applied to it."""

    def __init__(self, dof: int) -> None:
        self.dof = dof
        self.resets = 0
        self.applied: list[list[float]] = []

    def apply_effort(self, effort: np.ndarray) -> None:
        self.applied.append(np.asarray(effort, dtype=float).tolist())


class _Sim:
    step_count = 0
    dt = 5e-4


def _point(handle: _Handle) -> SimPoint:
    return SimPoint(_Sim(), _BodyDrive(handle), [1, 2], lambda: np.zeros(2))


def test_apply_uniform_equals_apply_effort_of_full() -> None:
    seq = [0.0, 0.0, 0.25, 0.25, -1.5, 3, 3.0, "reset", 3.0, -0.0, 0.0]
    ha, hb = _Handle(3), _Handle(3)
    pa, pb = _point(ha), _point(hb)
    for v in seq:
        if v == "reset":
            ha.resets += 1
            hb.resets += 1
            continue
        pa.apply_effort(np.full(pa.dof, v))
        pb.apply_uniform(float(v))
    assert ha.applied == hb.applied
    # writes of an unchanged value were skipped (6 writes for 10 calls), the reset forced one (3.0
    # twice); -0.0 then 0.0 compare equal, so the second is skipped on both paths alike
    assert len(hb.applied) == 6
    assert hb.applied[3] == hb.applied[4] == [0.0, 3.0, 3.0]
    assert [np.signbit(v) for v in hb.applied[-1]] == [False, True, True]
