"""The decimated inverse model of records, for any :class:`hil.identify.inverse_models.InverseDynamicsModel`:
regressors, the equations' left sides, held sensors, and the least-squares start.

Per record (:class:`InverseRecord`: positions of the model's coordinates, the left side of every
equation, and the ages of a held sensor) the motion is filtered (:class:`hil.identify.idim.Motion`:
Butterworth order 4 at ``f_filter = min(5 f_dyn, 0.4 fs)``), the model's columns are built, ``n_border``
samples are dropped at both ends, and every column and left side is decimated by ``r = max(round(0.8
(fs/2) / (2 f_dyn)), 1)`` (:func:`hil.identify.idim.decimate`): the IDIM-LS procedure of the EMPS
benchmark (:mod:`hil.identify.idim`), with the consistent columns of :class:`~hil.identify.idim.Motion`.
``f_dyn`` [Hz] is the dynamics bandwidth: the benchmark's 20 Hz, or half the top of the analysis band.

Left sides: an actuator force held over each period (``"input"``) is aligned with the averaged columns
(:func:`hil.identify.idim.held_force`); a sampled force (``"measured"``) is used as recorded. A force
sensor slower than the loop (a held output, :mod:`hil.identify.sensor_hold`) repeats its last value:
record sample ``k`` holds the force of sample ``k - a_k`` (``a_k`` its age), so that equation's columns
are taken at ``k - a_k`` too -- exact for any hold pattern, nothing is lost but the repeats' noise.

Held force in the point kinematics: :func:`inverse_part` with ``theta`` (``hold`` only) asks the model
for the acceleration steps of its held input (:meth:`InverseDynamicsModel.held_input`) and declares them
to the motion (:meth:`hil.identify.idim.Motion.set_held_input`).

:func:`inverse_ls` is the start of the ML fit: least squares with every equation scaled by its residual
standard deviation (two rounds), each Stribeck velocity by a bounded 1-D search (log scale, between
``1e-3`` and 1 times the joint's largest speed) with the rest solved linearly.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize

from hil.identify.errors import DataQualityError
from hil.identify.idim import F_DYN, IdimResult, Motion, decimate, held_force
from hil.identify.inverse_models import InverseDynamicsModel, Joint

logger = logging.getLogger(__name__)

__all__ = ["InversePart", "InverseProblem", "InverseRecord", "decimation_for", "inverse_ls", "inverse_part"]

#: Stribeck velocity grid (log-spaced points between the bounds) for the ML fit and the posterior
VS_GRID = 200


@dataclass
class InverseRecord:
    """One record: ``Q`` (n, n_c) positions of the model's coordinates [m or rad], ``Y`` (n, n_e) the
    left side of every equation (zeros for a ``"zero"`` equation) [N or N.m], ``ages`` per equation
    (None, or (n,) ticks since the held sensor's value was new)."""

    Q: NDArray[np.float64]
    Y: NDArray[np.float64]
    ages: Sequence[NDArray[np.int64] | None] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        self.Q = np.asarray(self.Q, float).reshape(len(self.Q), -1)
        self.Y = np.asarray(self.Y, float).reshape(len(self.Y), -1)
        if self.Q.shape[0] != self.Y.shape[0]:
            raise DataQualityError(f"positions ({self.Q.shape[0]}) and forces ({self.Y.shape[0]}) differ in length")
        if not np.all(np.isfinite(self.Q)) or not np.all(np.isfinite(self.Y)):
            raise DataQualityError("the inverse model needs finite positions and forces")


def decimation_for(fs: float, f_dyn: float | None) -> tuple[int, float, float]:
    """``(r, f_filter, f_dyn)`` for a dynamics bandwidth ``f_dyn`` [Hz] (None: the benchmark's 20 Hz)."""
    fd = float(f_dyn) if f_dyn else F_DYN
    return max(round(0.8 * (fs / 2) / (2 * fd)), 1), min(5 * fd, 0.4 * fs), fd


@dataclass
class InversePart:
    """One record's decimated inverse model: the fixed columns ``X`` (n_d, n_e, p) (Stribeck columns
    zero), the left sides ``y`` (n_d, n_e), the decimation ``r``, the motion and the per-equation sample
    selection (held sensors)."""

    motion: Motion
    X: NDArray[np.float64]
    y: NDArray[np.float64]
    r: int
    select: list[NDArray[np.int64] | None]
    kinds: tuple[str, ...]

    def column(self, col: NDArray, e: int) -> NDArray[np.float64]:
        """A full-length column of equation ``e``, selected (held sensor), cropped and decimated."""
        sel = self.select[e]
        return decimate(self.motion.crop(col if sel is None else col[sel]), self.r)


def inverse_part(model: InverseDynamicsModel, rec: InverseRecord, fs: float, *, f_dyn: float | None = None,
                 hold: bool = True, n_border: int = 50, theta: NDArray[np.float64] | None = None) -> InversePart:
    """The decimated inverse model of one record (module docstring). ``theta``: parameters at which the
    model's held-force acceleration jumps are taken (:meth:`InverseDynamicsModel.held_input`; ``hold``
    only), for its point columns and its friction velocity between samples."""
    n_e, p = len(model.equations), model.n_params
    if rec.Q.shape[1] != len(model.coordinates) or rec.Y.shape[1] != n_e:
        raise DataQualityError(f"{model.name}: {rec.Q.shape[1]} positions and {rec.Y.shape[1]} forces for "
                               f"coordinates {list(model.coordinates)} and equations "
                               f"{[e.name for e in model.equations]}")
    r, f_filter, _ = decimation_for(fs, f_dyn)
    stick = {jt.equation: jt.coordinate for jt in model.stick_joints()} if hold else {}
    motion = Motion(rec.Q, fs, f_filter, n_border, stick=tuple(stick.values()))
    for e, c in stick.items():
        motion.breakaways(c, rec.Y[:, e])
    held = model.held_input(np.asarray(theta, float), rec.Y) if hold and theta is not None else None
    if held is not None:
        motion.set_held_input(*held)
    n = motion.n
    if n - 2 * n_border < 40 * r:
        raise DataQualityError(f"IDIM: {n} samples are too few (need >= {40 * r + 2 * n_border})")
    ages = list(rec.ages) + [None] * (n_e - len(rec.ages))
    select: list[NDArray[np.int64] | None] = [
        None if a is None else np.clip(np.arange(n) - np.asarray(a, int), 0, n - 1) for a in ages]
    kinds = tuple(e.lhs for e in model.equations)
    ys = []
    for e, kind in enumerate(kinds):
        y = rec.Y[:, e]
        if kind == "input" and hold:
            y = motion.held_force(y, stick[e]) if e in stick else held_force(y)
        elif kind == "zero":
            y = np.zeros(n)
        if select[e] is None:  # filtered as the columns (a held sensor's samples are taken as recorded)
            y = motion.lowpass(y)
        ys.append(decimate(motion.crop(y), r))
    Y = np.column_stack(ys)
    part = InversePart(motion, np.zeros((Y.shape[0], n_e, p)), Y, r, select, kinds)
    full: dict[tuple[int, int], NDArray] = {}
    for k, e, col in model.columns(motion):
        full[(k, e)] = full[(k, e)] + col if (k, e) in full else col
    for (k, e), col in full.items():
        part.X[:, e, k] = part.column(col, e)
    return part


class InverseProblem:
    """The decimated inverse model of several records (stacked) for ``model``: residuals ``y - X theta``
    per record (B, n_d, n_e) for a batch of parameter vectors, the Stribeck columns interpolated on a
    log grid of ``v_s`` (:data:`VS_GRID` points between the parameter's bounds, precomputed)."""

    def __init__(self, model: InverseDynamicsModel, parts: Sequence[InversePart]) -> None:
        self.model = model
        self.parts = list(parts)
        self.strib = model.stribeck()
        vs = {iv for _, iv, _ in self.strib}
        self.lin = [i for i in range(model.n_params) if i not in vs]
        self.grids: list[NDArray] = []
        self.cols: list[list[NDArray]] = []  # per Stribeck joint, per part: (G, n_d)
        for _, iv, jt in self.strib:
            g = np.geomspace(model.lower[iv], model.upper[iv], VS_GRID)
            self.grids.append(g)
            self.cols.append([np.stack([p.column(model.stribeck_column(p.motion, jt, float(x)), jt.equation)
                                        for x in g]) for p in self.parts])

    @property
    def equations(self) -> int:
        return len(self.model.equations)

    def design(self, theta: NDArray[np.float64]) -> list[NDArray]:
        """Per record: the regressors (B, n_d, n_e, p_lin) at each parameter vector's Stribeck velocities."""
        nb = theta.shape[0]
        out = []
        for pi, part in enumerate(self.parts):
            X = part.X[:, :, self.lin]
            if not self.strib:
                out.append(np.broadcast_to(X, (nb, *X.shape)))
                continue
            Xb = np.repeat(X[None], nb, axis=0)
            for si, (i_fs, i_vs, jt) in enumerate(self.strib):
                g = self.grids[si]
                lv = np.log(np.clip(theta[:, i_vs], g[0], g[-1]))
                pos = np.interp(lv, np.log(g), np.arange(g.size))
                i0 = np.minimum(np.floor(pos).astype(int), g.size - 2)
                fr = (pos - i0)[:, None]
                c = self.cols[si][pi]
                Xb[:, :, jt.equation, self.lin.index(i_fs)] = c[i0] * (1 - fr) + c[i0 + 1] * fr
            out.append(Xb)
        return out

    def residuals(self, theta: ArrayLike) -> list[NDArray[np.float64]]:
        """Equation errors ``y - X theta`` (B, n_d, n_e) per record."""
        th = np.atleast_2d(np.asarray(theta, float))
        beta = th[:, self.lin]
        return [p.y - np.einsum("bnek,bk->bne", X, beta) for p, X in zip(self.parts, self.design(th), strict=True)]

    def stacked(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Equation errors (B, n_total, n_e), the records one after the other."""
        return np.concatenate(self.residuals(theta), axis=1)

    def omitted(self, missing: Sequence[str]) -> list[NDArray]:
        """Per record, the decimated columns (n_d, n_e, k) of the friction terms ``missing``."""
        out = []
        for p in self.parts:
            cols = self.model.omitted_columns(p.motion, missing)
            X = np.zeros((p.y.shape[0], self.equations, len(cols)))
            for j, (e, col) in enumerate(cols):
                X[:, e, j] = p.column(col, e)
            out.append(X)
        return out


def _stribeck_range(part: InversePart, jt: Joint) -> tuple[float, float]:
    vmax = float(np.max(np.abs(part.motion.crop(part.motion.velocity(jt.coordinate)))))
    return vmax * 1e-3, max(vmax, 1e-300)


def inverse_ls(model: InverseDynamicsModel, parts: Sequence[InversePart], *, rounds: int = 2) -> IdimResult:
    """The least-squares start (module docstring): an :class:`~hil.identify.idim.IdimResult` with the
    white-residual standard deviations of the scaled problem, ``residual_std`` of the first equation and
    ``residual_std_by_equation``."""
    strib = model.stribeck()
    vs_idx = {iv for _, iv, _ in strib}
    lin = [i for i in range(model.n_params) if i not in vs_idx]
    n_e = len(model.equations)
    vs = {iv: float(np.sqrt(np.prod(_stribeck_range(parts[0], jt)))) for _, iv, jt in strib}

    def system(v_s: dict[int, float]) -> tuple[NDArray, NDArray]:
        Xs, ys = [], []
        for p in parts:
            X = p.X.copy()
            for i_fs, i_vs, jt in strib:
                X[:, jt.equation, i_fs] = p.column(model.stribeck_column(p.motion, jt, v_s[i_vs]), jt.equation)
            Xs.append(X[:, :, lin])
            ys.append(p.y)
        return np.concatenate(Xs), np.concatenate(ys)

    scale = np.ones(n_e)

    def solve(v_s: dict[int, float]) -> tuple[NDArray, NDArray, NDArray]:
        X, y = system(v_s)
        Xw = (X / scale[None, :, None]).reshape(-1, len(lin))
        yw = (y / scale[None, :]).ravel()
        beta, *_ = np.linalg.lstsq(Xw, yw, rcond=None)
        return beta, Xw, (y - np.einsum("nek,k->ne", X, beta))

    for _ in range(max(rounds, 1)):
        for _, i_vs, jt in strib:
            lo, hi = _stribeck_range(parts[0], jt)

            def rss(lv: float, i_vs: int = i_vs, sc: NDArray = scale) -> float:
                e = solve({**vs, i_vs: float(np.exp(lv))})[2] / sc
                return float(np.sum(e**2))

            vs[i_vs] = float(np.exp(optimize.minimize_scalar(rss, bounds=(np.log(lo), np.log(hi)), method="bounded",
                                                             options={"xatol": 1e-3}).x))
        beta, Xw, e = solve(vs)
        scale = np.maximum(np.std(e, axis=0, ddof=1), 1e-300)
    beta, Xw, e = solve(vs)
    ew = (e / scale).ravel()
    s2 = float(np.sum(ew**2) / max(ew.size - len(lin), 1))
    cov_b = s2 * np.linalg.pinv(Xw.T @ Xw)
    theta = np.zeros(model.n_params)
    theta[lin] = beta
    std = np.full(model.n_params, np.nan)
    std[lin] = np.sqrt(np.clip(np.diag(cov_b), 0, None))
    cov = np.full((model.n_params, model.n_params), np.nan)
    cov[np.ix_(lin, lin)] = cov_b
    for iv, v in vs.items():
        theta[iv] = v
    y = np.concatenate([p.y for p in parts])
    rel = float(100 * np.linalg.norm(e) / max(float(np.linalg.norm(y)), 1e-300))
    by_eq = {eq.name: float(np.std(e[:, k], ddof=1)) for k, eq in enumerate(model.equations)}
    logger.info("inverse LS %s: %s (relative error %.2f %%)", model.names, np.round(theta, 5), rel)
    return IdimResult(model.names, theta, std, cov, parts[0].r, rel, by_eq[model.equations[0].name], int(y.shape[0]),
                      parts[0].motion.f_filter, residual_std_by_equation=by_eq)
