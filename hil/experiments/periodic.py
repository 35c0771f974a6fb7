"""Periodic effort signals on one actuator: ``chirp`` and ``multisine`` (schemas and
implementations). Effort in N or N.m, frequencies Hz."""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Any, Literal, TypeVar

import numpy as np
from pydantic import Field, model_validator
from pydantic_core import PydanticCustomError

from hil.errors import SceneError
from hil.experiments.base import (
    Excitation,
    ExperimentConfig,
    _band_ok,
    _Base,
    _check_target,
    _devices,
    _get,
    _row_blocks,
)
from hil.experiments.signals import chirp_signal, crest_factor, multisine_lines, raised_cosine_fade, schroeder_phases
from hil.schema import (
    DampNonneg,
    DofList,
    EffortNonneg,
    Hz,
    Name,
    SceneView,
    Seconds,
    SecondsOrZero,
    Seed,
    StiffPos,
    StrictModel,
)

logger = logging.getLogger(__name__)


class ServoCfg(StrictModel):
    """The experiment's own position servo for ``excite: motion``: ``kp`` (N/m or N.m/rad, > 0)
    and ``kv`` (N.s/m or N.m.s/rad, >= 0); its effort is added to the controller's."""

    kp: StiffPos
    kv: DampNonneg = 0.0


class _PeriodicConfig(ExperimentConfig):
    """Fields of the periodic effort signals (chirp, multisine) on one actuator."""

    f0: Hz
    f1: Hz
    duration: Seconds
    amplitude: EffortNonneg
    target: Name
    dofs: DofList | None = None
    excite: Literal["effort", "motion"] = "effort"
    servo: ServoCfg | None = None
    periods: int = Field(default=1, ge=1)
    variant: Literal["locked", "free"] | None = None

    def check_scene(self, scene: SceneView, path: str) -> None:
        _check_target(self, scene, path)

    @model_validator(mode="after")
    def _band_and_servo(self) -> _PeriodicConfig:
        _band_ok(self.f0, self.f1)
        if self.excite == "motion" and self.servo is None:
            raise PydanticCustomError("servo", "excite: motion needs servo (kp in N/m, kv in N.s/m)", {"key": "servo"})
        return self


class ChirpExperiment(_PeriodicConfig):
    """Swept sine from ``f0`` to ``f1`` (Hz) of ``amplitude`` (N or N.m; m or rad with ``excite:
    motion``) on ``target``'s ``dofs`` (see :class:`Chirp`)."""

    type: Literal["chirp"]
    sweep: Literal["log", "linear"] = "log"
    fade: SecondsOrZero = 0.0
    periodic: bool = False
    simultaneous: bool = False


class MultisineExperiment(_PeriodicConfig):
    """Sum of ``n_lines`` sines per DOF between ``f0`` and ``f1`` (Hz), peak ``amplitude`` (N or
    N.m) on ``target``'s ``dofs`` (see :class:`Multisine`)."""

    type: Literal["multisine"]
    n_lines: int = Field(default=64, ge=1)
    simultaneous: bool = True
    spacing: Literal["linear", "log"] = "linear"
    seed: Seed | None = None


P = TypeVar("P", bound=_PeriodicConfig)


class _PeriodicEffort(_Base[P]):
    """Shared machinery: per-DOF periodic sample arrays played on ``target``, sequentially (one
    DOF after the other, each for ``block`` samples) or simultaneously."""

    wave: np.ndarray
    wave_rate: np.ndarray
    simultaneous: bool

    def __init__(self, cfg: P, rate_hz: float, *, periodic: bool) -> None:
        super().__init__(cfg, rate_hz)
        self.f0, self.f1 = cfg.f0, cfg.f1
        self.amplitude = cfg.amplitude
        self.variant = cfg.variant
        self._setup_periods(cfg.duration, periodic, cfg.periods)
        self.excite = cfg.excite
        self.kp = cfg.servo.kp if cfg.servo is not None else 0.0
        self.kv = cfg.servo.kv if cfg.servo is not None else 0.0
        self._x_start: np.ndarray | None = None
        self.target = cfg.target
        self.dofs_cfg = cfg.dofs
        self.sel = [0] if cfg.dofs is None else list(cfg.dofs)
        self.target_dof = max(self.sel) + 1
        self.checked = False

    def _setup_periods(self, duration: float, periodic: bool, periods: int) -> None:
        self.periods = periods if periodic else 1
        n_block = round(duration * self.rate_hz)
        self.n_period = max(1, n_block // self.periods)
        if self.n_period * self.periods != n_block:
            logger.info("%s: duration %.6g s rounded to %d periods of %d samples", self.name, duration,
                        self.periods, self.n_period)
        self.n_block = self.n_period * self.periods
        self.period = self.n_period / self.rate_hz

    def _layout(self, n_dofs: int, simultaneous: bool) -> None:
        self.simultaneous = simultaneous
        self.n_blocks = 1 if simultaneous or n_dofs == 1 else n_dofs
        self.duration = self.n_blocks * self.n_block / self.rate_hz

    def _value(self, k: int) -> np.ndarray:
        """Effort per selected DOF at tick k (zeros after the end)."""
        return self._sample(self.wave, k)

    def _value_rate(self, k: int) -> np.ndarray:
        """Time derivative of the excitation per selected DOF at tick k (units/s)."""
        return self._sample(self.wave_rate, k)

    def _sample(self, table: np.ndarray, k: int) -> np.ndarray:
        """Row of a per-DOF periodic table at tick k, laid out in blocks; zeros outside."""
        out = np.zeros(len(self.sel))
        block, i = divmod(k, self.n_block)
        if k < 0 or block >= self.n_blocks:
            return out
        j = i % self.n_period
        if self.n_blocks == 1:
            out[:] = table[:, j]
        else:
            out[block] = table[block, j]
        return out

    def segments(self) -> list[dict[str, Any]]:
        """Time windows of the blocks: which DOFs are excited when (s)."""
        if self.n_blocks == 1:
            return [{"dofs": list(self.sel), "t_start": 0.0, "t_end": self.duration}]
        T = self.n_block / self.rate_hz
        return [{"dofs": [d], "t_start": b * T, "t_end": (b + 1) * T} for b, d in enumerate(self.sel)]

    def excitation(self, k: int, t: float, meas: Mapping[str, Any]) -> Excitation:
        u = self._value(k)
        if self.excite == "motion":
            s = meas.get(self.target) if meas is not None else None
            if s is None:
                return Excitation()
            pos = np.asarray(s.position, dtype=float).reshape(-1)[self.sel]
            vel = np.asarray(s.velocity, dtype=float).reshape(-1)[self.sel]
            if self._x_start is None or k == 0:
                self._x_start = pos.copy()
            rd = self._value_rate(k)
            u = self.kp * (self._x_start + u - pos) + self.kv * (rd - vel)
        eff = np.zeros(self.target_dof)
        eff[self.sel] = u
        return Excitation(effort={self.target: eff})

    def _finish_rate(self) -> None:
        """Derivative of the periodic waves (for motion references), central differences."""
        w = self.wave
        self.wave_rate = (np.roll(w, -1, axis=1) - np.roll(w, 1, axis=1)) * (0.5 * self.rate_hz)
        if self.periods == 1:  # not periodic: one-sided at the ends
            self.wave_rate[:, 0] = (w[:, 1] - w[:, 0]) * self.rate_hz if w.shape[1] > 1 else 0.0
            self.wave_rate[:, -1] = (w[:, -1] - w[:, -2]) * self.rate_hz if w.shape[1] > 1 else 0.0

    def _check_common(self, scene: Any) -> None:
        self._check_band(self.f0, self.f1)
        dev, sel = self._check_target(scene, self.target, self.dofs_cfg)
        if sel != self.sel:
            raise SceneError(f"{self.f('dofs')}: resolved {sel}, built for {self.sel}")
        if int(_get(dev, "dof", 1)) != self.target_dof:
            self.target_dof = int(_get(dev, "dof", 1))
        peak = float(np.max(np.abs(self.wave))) if self.wave.size else 0.0
        if self.excite == "motion":
            stalled = self.kp * peak + self.kv * float(np.max(np.abs(self.wave_rate)))
            self._check_effort(scene, stalled, "amplitude")
            lims = _get(_get(scene, "safety"), "position_limits")
            if lims is not None and peak > 0.5 * (float(lims[1]) - float(lims[0])):
                raise SceneError(f"{self.f('amplitude')}: motion amplitude {peak:g} exceeds half the position range")
        else:
            self._check_effort(scene, peak, "amplitude")
        self.checked = True

    def check(self, scene: Any) -> None:
        """Validate against the scene (module doc). When ``dofs`` is omitted, all of the
        target's DOFs are excited: the signals are rebuilt for the scene's DOF count."""
        devs = _devices(scene)
        dev = devs.get(self.target)
        if self.dofs_cfg is None and dev is not None and int(_get(dev, "dof", 1)) != len(self.sel):
            self.sel = list(range(int(_get(dev, "dof", 1))))
            self.target_dof = len(self.sel)
            self._build()
        self._check_common(scene)

    def _build(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError


class Chirp(_PeriodicEffort[ChirpExperiment]):
    """Swept sine on ``target``'s ``dofs``.

    Fields: ``f0``, ``f1`` (Hz), ``duration`` (s, per DOF block), ``amplitude`` (N or N.m; m or rad
    with ``excite: motion``), ``sweep`` (log | linear), ``fade`` (s, raised cosine in and out),
    ``periodic`` + ``periods`` (``periods`` identical sweeps of ``duration/periods`` s, rounded to
    whole samples), ``simultaneous`` (all DOFs at once with the same sweep; default false: one DOF
    after the other, each for ``duration``), ``excite`` (effort | motion: a position reference
    ``x(0) + r(t)`` tracked by the experiment's own servo ``servo: {kp, kv}`` added to the
    controller effort), ``variant`` (locked | free; recorded, the scene decides the physics).

    Fade and periodicity: the fade is applied to *every period* (each period starts and ends at
    zero), so all periods are identical sample for sample and a Welch segment of exactly one
    period (rectangular window, no overlap) after the first (transient) period gives an unbiased
    H1 estimate. Without fade a periodic sweep jumps back from its end phase to 0 at each period
    boundary (broadband but periodic; harmless for H1).
    """

    kind = "chirp"

    def __init__(self, cfg: ChirpExperiment, rate_hz: float) -> None:
        super().__init__(cfg, rate_hz, periodic=cfg.periodic)
        self.fade = cfg.fade
        self.sweep = cfg.sweep
        self.periodic = cfg.periodic
        if 2 * round(self.fade * self.rate_hz) > self.n_period:
            raise SceneError(f"{self.f('fade')}: {self.fade} s in and out exceeds the period {self.period:g} s")
        self._build()
        if self.periodic and self.f0 < 1.0 / self.period:
            logger.warning("%s: f0 = %g Hz is below the frequency resolution 1/period = %g Hz", self.name, self.f0,
                           1.0 / self.period)

    def _build(self) -> None:
        x, self.f_inst = chirp_signal(self.n_period, self.rate_hz, self.f0, self.f1, self.sweep)
        win = raised_cosine_fade(self.n_period, round(self.fade * self.rate_hz))
        one = self.amplitude * win * x
        self.wave = np.tile(one, (len(self.sel), 1))
        self._layout(len(self.sel), self.cfg.simultaneous)
        self._finish_rate()

    def finish(self, data: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict:
        """Identification hints: band, period (Welch segment), ``skip`` (one period of transient),
        blocks per DOF, and the RMS of the recorded excitation per DOF."""
        res: dict[str, Any] = {
            "type": "chirp", "band": [self.f0, self.f1], "sweep": self.sweep, "fs": self.rate_hz,
            "period": self.period, "periods": self.periods, "nperseg": self.n_period,
            "skip": self.period if self.periods > 1 else 0.0, "fade": self.fade, "target": self.target,
            "dofs": list(self.sel), "simultaneous": self.simultaneous, "excite": self.excite,
            "variant": self.variant, "segments": self.segments(), "periodic": self.periodic,
        }
        exc = data.get(f"{self.target}.excitation")
        n = int(np.shape(exc)[0]) if exc is not None and np.ndim(exc) else 0
        if n:
            sq: np.ndarray | None = None
            for _, blk in _row_blocks(exc, n):  # in blocks: the channel may be an h5py dataset of a long run
                part = np.sum(blk ** 2, axis=0)
                sq = part if sq is None else sq + part
            assert sq is not None
            res["excitation_rms"] = [float(np.sqrt(sq[i] / n)) for i in self.sel if i < sq.size]
        return res


class Multisine(_PeriodicEffort[MultisineExperiment]):
    """Periodic multisine with Schroeder phases, for MIMO identification in one experiment.

    Fields: ``f0``, ``f1`` (Hz), ``n_lines`` (lines per DOF), ``duration`` (s), ``periods``,
    ``amplitude`` (peak per DOF, N or N.m), ``target``, ``dofs``, ``simultaneous`` (default true:
    all DOFs at once on *zippered* lines -- DOF j gets every n-th line of one grid, so every line
    carries exactly one input and the MIMO FRF separates line by line; false: one DOF after the
    other on the same lines), ``spacing`` (linear | log), ``seed`` (recorded; phases are
    deterministic), ``variant``, ``excite``/``servo`` as for :class:`Chirp`.

    Lines are harmonics ``h / P`` of the period ``P = duration/periods`` in ``[f0, f1]``; each
    DOF's lines get Schroeder phases (low crest factor for equally spaced lines) and the sum is
    scaled so that its peak over a period equals ``amplitude``.
    """

    kind = "multisine"

    def __init__(self, cfg: MultisineExperiment, rate_hz: float) -> None:
        super().__init__(cfg, rate_hz, periodic=True)
        self.n_lines = cfg.n_lines
        self.spacing = cfg.spacing
        self.seed = cfg.seed
        self._build()

    def _build(self) -> None:
        simultaneous = self.cfg.simultaneous
        n_in = len(self.sel) if simultaneous else 1
        df = 1.0 / self.period
        kmin, kmax = math.ceil(self.f0 / df - 1e-9), math.floor(self.f1 / df + 1e-9)
        try:
            grid = multisine_lines(kmin, kmax, self.n_lines * n_in, self.spacing)
        except ValueError as exc:
            raise SceneError(f"{self.f('n_lines')}: {self.n_lines} lines x {n_in} DOF on the {df:g} Hz grid of "
                             f"[{self.f0}, {self.f1}] Hz: {exc}; lengthen the period or reduce n_lines") from exc
        if kmax >= self.n_period / 2:
            raise SceneError(f"{self.f('f1')}: above Nyquist")
        self.lines = [grid[j::n_in] for j in range(n_in)]  # harmonic indices per input (zipper)
        ph = schroeder_phases(self.n_lines)
        i = np.arange(self.n_period)
        waves = []
        for h in self.lines:
            x = np.sum(np.cos(2 * np.pi * np.outer(h, i) / self.n_period + ph[: h.size, None]), axis=0)
            peak = float(np.max(np.abs(x)))
            waves.append(self.amplitude * x / peak if peak > 0 else x)
        self.wave = np.array(waves if simultaneous else waves * len(self.sel))
        self._layout(len(self.sel), simultaneous)
        self._finish_rate()

    def line_frequencies(self) -> list[list[float]]:
        """Excited frequencies (Hz) per input (per DOF when simultaneous)."""
        return [list(np.asarray(h, dtype=float) / self.period) for h in self.lines]

    def finish(self, data: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict:
        return {"type": "multisine", "band": [self.f0, self.f1], "fs": self.rate_hz, "period": self.period,
                "periods": self.periods, "nperseg": self.n_period, "skip": self.period if self.periods > 1 else 0.0,
                "target": self.target, "dofs": list(self.sel), "simultaneous": self.simultaneous,
                "lines_hz": self.line_frequencies(), "crest_factor": [crest_factor(w) for w in self.wave],
                "segments": self.segments(), "variant": self.variant, "seed": self.seed, "excite": self.excite}
