"""``static_hold``: hold a target and record the statistics of the measurements (noise levels,
offsets) in constant memory."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, model_validator
from pydantic_core import PydanticCustomError

from hil.errors import SceneError
from hil.experiments.base import Excitation, ExperimentConfig, _Base, _check_target, _get, _row_blocks
from hil.schema import (
    DofList,
    Effort,
    Name,
    SceneView,
    Seconds,
    SecondsOrZero,
)


class StaticHoldExperiment(ExperimentConfig):
    """Constant ``effort`` (N or N.m; one value, or one per DOF) on ``target``'s ``dofs`` for
    ``duration`` s; statistics after ``settle`` s; ``variant``: plant configuration of a simulated
    SDEA (``locked`` | ``free`` output; recorded) (see :class:`StaticHold`)."""

    type: Literal["static_hold"]
    target: Name
    dofs: DofList | None = None
    effort: Effort | Annotated[list[Effort], Field(min_length=1)]
    duration: Seconds
    settle: SecondsOrZero = 0.0
    variant: Literal["locked", "free"] | None = None

    def check_scene(self, scene: SceneView, path: str) -> None:
        _check_target(self, scene, path)

    @model_validator(mode="after")
    def _settle(self) -> StaticHoldExperiment:
        if self.settle >= self.duration:
            raise PydanticCustomError("settle", "settle ({s} s) must be shorter than duration ({d} s)",
                                      {"s": self.settle, "d": self.duration, "key": "settle"})
        return self


class StaticHold(_Base[StaticHoldExperiment]):
    """Step ``effort`` (N or N.m; scalar or per DOF) on ``target``'s ``dofs``, hold for
    ``duration`` s; after ``settle`` s report the static stiffness ``K = ΔF/Δx`` per DOF (ΔF the
    effort step, Δx the mean position after settling minus the position at the start, i.e. what
    the device + its controller + its environment oppose to a constant force)."""

    kind = "static_hold"

    def __init__(self, cfg: StaticHoldExperiment, rate_hz: float) -> None:
        super().__init__(cfg, rate_hz)
        self.target = cfg.target
        self.duration = cfg.duration
        self.settle = cfg.settle
        self.effort_cfg = np.atleast_1d(np.asarray(cfg.effort, dtype=float))
        self.dofs_cfg = cfg.dofs
        self.sel = [0] if cfg.dofs is None else list(cfg.dofs)
        self.target_dof = max(self.sel) + 1
        self.variant = cfg.variant
        self._resolve_effort()

    def _resolve_effort(self) -> None:
        e = self.effort_cfg
        if e.size == 1:
            e = np.full(len(self.sel), float(e[0]))
        if e.size != len(self.sel):
            raise SceneError(f"{self.f('effort')}: {e.size} values for {len(self.sel)} DOF")
        self.effort = e

    def check(self, scene: Any) -> None:
        dev, sel = self._check_target(scene, self.target, self.dofs_cfg)
        self.sel = sel
        self.target_dof = int(_get(dev, "dof", 1))
        self._resolve_effort()
        self._check_effort(scene, float(np.max(np.abs(self.effort))), "effort")

    def excitation(self, k: int, t: float, meas: Mapping[str, Any]) -> Excitation:
        e = np.zeros(self.target_dof)
        if 0 <= k < round(self.duration * self.rate_hz):
            e[self.sel] = self.effort
        return Excitation(effort={self.target: e})

    def finish(self, data: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict:
        """Stiffness from the settled window, in one pass over blocks of rows (bounded memory: the
        channels may be h5py datasets of the record); mean, std and drift (least-squares slope)
        from merged per-block moments (Chan et al.), equal to the two-pass values to rounding."""
        try:
            t_all = data["t"]
            x_all = data[f"{self.target}.position"]
        except KeyError as exc:
            raise SceneError(f"{self.where}: record lacks channel {exc.args[0]!r}") from exc
        n_all = int(np.shape(t_all)[0])
        if n_all < 2:
            raise SceneError(f"{self.where}: no samples after settle = {self.settle} s")
        x0 = np.asarray(x_all[0], dtype=float).reshape(-1)[self.sel]
        mom = _Moments()
        for i, tb in _row_blocks(t_all, n_all):
            xb = np.asarray(x_all[i:i + tb.shape[0]], dtype=float).reshape(tb.shape[0], -1)[:, self.sel]
            win = tb >= self.settle
            if np.any(win):
                mom.add(tb[win], xb[win])
        if mom.n == 0:
            raise SceneError(f"{self.where}: no samples after settle = {self.settle} s")
        xm = mom.mean_x
        dx = xm - x0
        with np.errstate(divide="ignore", invalid="ignore"):
            K = np.where(np.abs(dx) > 0, self.effort / dx, np.inf)
        res: dict[str, Any] = {"type": "static_hold", "target": self.target, "dofs": list(self.sel),
                               "effort": self.effort.tolist(), "x0": x0.tolist(), "x_mean": xm.tolist(),
                               "dx": dx.tolist(), "x_std": np.sqrt(np.maximum(mom.m2_x, 0.0) / mom.n).tolist(),
                               "stiffness": [float(k) for k in K], "settle": self.settle, "variant": self.variant,
                               "n_samples": int(mom.n)}
        # drift over the averaging window: a still-moving position means settle was too short
        if mom.n > 2 and mom.m2_t > 0:
            res["drift_per_s"] = np.atleast_1d(mom.c_tx / mom.m2_t).tolist()
        return res


class _Moments:
    """Count, means, centred sums of squares of ``t`` and ``x`` (per column) and their centred cross
    sum, merged block by block (Chan, Golub & LeVeque's pairwise update)."""

    def __init__(self) -> None:
        self.n = 0
        self.mean_t = 0.0
        self.m2_t = 0.0
        self.mean_x: np.ndarray = np.zeros(0)
        self.m2_x: np.ndarray = np.zeros(0)
        self.c_tx: np.ndarray = np.zeros(0)

    def add(self, t: np.ndarray, x: np.ndarray) -> None:
        nb = t.shape[0]
        mt, mx = float(np.mean(t)), np.mean(x, axis=0)
        dt_, dx_ = t - mt, x - mx
        m2t, m2x, ctx = float(dt_ @ dt_), np.sum(dx_ ** 2, axis=0), dt_ @ dx_
        if self.n == 0:
            self.n, self.mean_t, self.m2_t, self.mean_x, self.m2_x, self.c_tx = nb, mt, m2t, mx, m2x, ctx
            return
        na, n = self.n, self.n + nb
        d_t, d_x = mt - self.mean_t, mx - self.mean_x
        f = na * nb / n
        self.m2_t += m2t + d_t * d_t * f
        self.m2_x = self.m2_x + m2x + d_x * d_x * f
        self.c_tx = self.c_tx + ctx + d_t * d_x * f
        self.mean_t += d_t * nb / n
        self.mean_x = self.mean_x + d_x * nb / n
        self.n = n
