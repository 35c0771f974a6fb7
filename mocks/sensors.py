"""Sensor imperfections applied to true measurements: noise, bias, quantization, saturation, delay.

Each stage is a small object with ``__call__(value) -> value`` (arrays in, arrays out, same
shape) and ``reset()``; stateful stages (noise generator, delay line) advance by one sample per
call, so call them exactly once per control tick. Noise uses a seeded
``numpy.random.Generator`` (PCG64): the same seed gives bit-identical samples on any machine.

:class:`SensorModel` chains the stages in the physical order
``true -> delay -> + bias -> + noise -> saturation -> quantization`` (the transducer reading
is delayed in transport, offset and noisy, clipped by the ADC range, then quantized).
:class:`SensedJoints` wraps a :class:`~hil.mocks.interfaces.SimulatedJoints` handle and applies
sensor models to its readings, once per simulator tick.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Sequence

import numpy as np

from hil.errors import ModelError
from hil.lti import ArrayLike
from hil.mocks.interfaces import SimulatedJoints

logger = logging.getLogger(__name__)

Stage = Callable[[np.ndarray], np.ndarray]


class Bias:
    """Constant additive offset (same units as the measurement)."""

    def __init__(self, offset: ArrayLike) -> None:
        self.offset = np.asarray(offset, dtype=float)

    def __call__(self, value: ArrayLike) -> np.ndarray:
        return np.asarray(value, dtype=float) + self.offset

    def reset(self) -> None:
        """Stateless."""


class GaussianNoise:
    """Additive zero-mean Gaussian noise of standard deviation ``std`` from a seeded generator."""

    def __init__(self, std: ArrayLike, seed: int | None = 0) -> None:
        self.std = np.asarray(std, dtype=float)
        if np.any(self.std < 0) or not np.all(np.isfinite(self.std)):
            raise ModelError(f"noise std must be finite and >= 0, got {std!r}")
        self.seed = seed
        self.rng = np.random.default_rng(seed)

    def __call__(self, value: ArrayLike) -> np.ndarray:
        v = np.asarray(value, dtype=float)
        return v + self.std * self.rng.standard_normal(v.shape)

    def reset(self) -> None:
        """Restart the generator from its seed."""
        self.rng = np.random.default_rng(self.seed)


class Quantizer:
    """Round to the nearest multiple of ``step`` (encoder/ADC resolution); ``step = 0`` passes through.

    Ties round half to even (``numpy.round``), deterministic everywhere.
    """

    def __init__(self, step: ArrayLike) -> None:
        self.step = np.asarray(step, dtype=float)
        if np.any(self.step < 0):
            raise ModelError("quantization step must be >= 0")

    def __call__(self, value: ArrayLike) -> np.ndarray:
        v = np.asarray(value, dtype=float)
        safe = np.where(self.step > 0, self.step, 1.0)
        return np.where(self.step > 0, np.round(v / safe) * safe, v)

    def reset(self) -> None:
        """Stateless."""


class Saturation:
    """Clip to ``[low, high]`` (sensor range)."""

    def __init__(self, low: ArrayLike, high: ArrayLike) -> None:
        self.low = np.asarray(low, dtype=float)
        self.high = np.asarray(high, dtype=float)
        if np.any(self.low > self.high):
            raise ModelError("saturation low must be <= high")

    def __call__(self, value: ArrayLike) -> np.ndarray:
        return np.clip(np.asarray(value, dtype=float), self.low, self.high)

    def reset(self) -> None:
        """Stateless."""


class Delay:
    """Transport delay of ``ticks`` samples: returns the input of ``ticks`` calls ago.

    Before ``ticks`` samples have been seen it returns ``initial`` (default: the first sample,
    as a sensor that reports its first reading until fresh data arrives; pass ``0.0`` for zeros).
    """

    def __init__(self, ticks: int, initial: ArrayLike | None = None) -> None:
        if ticks < 0:
            raise ModelError("delay ticks must be >= 0")
        self.ticks = int(ticks)
        self.initial = None if initial is None else np.asarray(initial, dtype=float)
        self._buf: deque[np.ndarray] = deque()

    def __call__(self, value: ArrayLike) -> np.ndarray:
        v = np.asarray(value, dtype=float).copy()
        if self.ticks == 0:
            return v
        if not self._buf:
            fill = v if self.initial is None else np.broadcast_to(self.initial, v.shape).copy()
            self._buf.extend(fill.copy() for _ in range(self.ticks))
        self._buf.append(v)
        return self._buf.popleft()

    def reset(self) -> None:
        """Empty the delay line."""
        self._buf.clear()


class Chain:
    """Apply stages in order."""

    def __init__(self, *stages: Stage) -> None:
        self.stages: Sequence[Stage] = stages

    def __call__(self, value: ArrayLike) -> np.ndarray:
        v = np.asarray(value, dtype=float)
        for stage in self.stages:
            v = stage(v)
        return v

    def reset(self) -> None:
        for stage in self.stages:
            reset = getattr(stage, "reset", None)
            if reset is not None:
                reset()


class SensorModel(Chain):
    """Typical transducer: ``delay_ticks``, ``bias``, Gaussian ``noise_std`` (seeded), range
    ``limits = (low, high)`` and ``resolution`` (quantization step), applied in that order.
    Zero / ``None`` parameters skip the stage. Units are those of the measured quantity.
    """

    def __init__(self, *, noise_std: ArrayLike = 0.0, bias: ArrayLike = 0.0, resolution: ArrayLike = 0.0,
                 limits: tuple[ArrayLike, ArrayLike] | None = None, delay_ticks: int = 0,
                 seed: int | None = 0) -> None:
        stages: list[Stage] = []
        if delay_ticks:
            stages.append(Delay(delay_ticks))
        if np.any(np.asarray(bias) != 0):
            stages.append(Bias(bias))
        if np.any(np.asarray(noise_std) != 0):
            stages.append(GaussianNoise(noise_std, seed))
        if limits is not None:
            stages.append(Saturation(*limits))
        if np.any(np.asarray(resolution) != 0):
            stages.append(Quantizer(resolution))
        super().__init__(*stages)


class SensedJoints:
    """A SimulatedJoints wrapper whose readings pass through sensor models.

    Each reading (position, velocity, force) is sampled at most once per tick of the underlying
    handle (``handle.sample_index``, see :class:`hil.mocks.simulator.Joints`): repeated reads in
    the same tick return the same value, so noise and delay lines advance once per control
    period. Handles without ``sample_index`` are sampled on every read.
    """

    def __init__(self, handle: SimulatedJoints, *, position: Stage | None = None,
                 velocity: Stage | None = None, force: Stage | None = None) -> None:
        self.handle = handle
        self.dof = handle.dof
        self._stages = {"position": position, "velocity": velocity, "force": force}
        self._cache: dict[str, tuple[int, np.ndarray]] = {}

    def apply_effort(self, effort: np.ndarray) -> None:
        self.handle.apply_effort(effort)

    def _read(self, key: str, raw: Callable[[], np.ndarray]) -> np.ndarray:
        idx = getattr(self.handle, "sample_index", None)
        if idx is not None and key in self._cache and self._cache[key][0] == idx:
            return self._cache[key][1].copy()
        stage = self._stages[key]
        value = raw() if stage is None else stage(raw())
        if idx is not None:
            self._cache[key] = (idx, np.array(value, dtype=float))
        return np.array(value, dtype=float)

    def position(self) -> np.ndarray:
        return self._read("position", self.handle.position)

    def velocity(self) -> np.ndarray:
        return self._read("velocity", self.handle.velocity)

    def measured_force(self) -> np.ndarray:
        return self._read("force", self.handle.measured_force)

    def reset(self) -> None:
        """Reset every stage and forget cached samples."""
        self._cache.clear()
        for stage in self._stages.values():
            reset = getattr(stage, "reset", None)
            if reset is not None:
                reset()
