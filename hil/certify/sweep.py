"""Stability maps: the verdict, the margin and (optionally) P(stable) over a grid of one to three
parameters of a built-in network model, with the stability boundary refined by bisection.

``hil sweep --model sdea --grid b22=0.05:0.3:26 --grid k22=100:600:26 --criterion passivity``

Definitions (also in docs/guide/certification.md, "Stability maps"):

* **grid point**: one assignment of the swept parameters (``NAME=LO:HI:N`` gives N values from LO
  to HI inclusive, evenly spaced; ``NAME=log:LO:HI:N`` evenly spaced in log). The other model
  parameters take the model's defaults or ``--set`` values.
* **verdict** per point: the exact verdict of :func:`hil.stability.criteria.check` (``stable``,
  ``marginal``, ``potentially_unstable``, ``not_applicable``), stored as the integer code of
  :data:`VERDICT_CODES`; ``margin`` is that result's normalized margin (dimensionless, defined in
  docs/VERDICTS.md) and ``worst_frequency`` its frequency [rad/s].
* **boundary point**: between two neighbouring grid points (along one axis, the others fixed)
  of which exactly one is ``stable``, the crossing is bracketed by bisection on that axis with
  exact verdicts until the bracket is narrower than ``boundary_tol`` × the axis' grid step. The
  stored point is the bracket's midpoint; ``bracket`` holds its ends (the stable end first). With
  two or more crossings between two neighbours bisection finds one of them.
* **P(stable)** per point (``posterior=``): the fraction of posterior draws (the swept parameters
  replaced by the point's values) whose network is stable. The draws are a fixed subset of the
  stored posterior chosen by a seed derived from the sweep's content, so every executor and every
  number of workers computes the same numbers.

Work is cut into tasks of ``chunk`` points (and one task per boundary segment). Each task's result
is stored in a content-addressed cache (the SHA-256 of the model, the criterion, the fixed
parameters, the task's points and the package version): an interrupted sweep, run again, only
computes what is missing. Executors come from :data:`EXECUTORS` (``serial``, ``process`` — a local
process pool, the default — and ``dask``, the distributed scheduler, extra ``dask``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import re
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.certify.executors import (
    EXECUTORS,
    DaskExecutor,
    Executor,
    ExecutorLost,
    ProcessExecutor,
    SerialExecutor,
    SweepError,
    make_executor,
)
from hil.errors import HilError

logger = logging.getLogger(__name__)

# the executors (hil.certify.executors) are re-exported: ``from hil.certify.sweep import DaskExecutor`` etc.
__all__ = [
    "EXECUTORS",
    "VERDICT_CODES",
    "DaskExecutor",
    "Executor",
    "ExecutorLost",
    "GridAxis",
    "ProcessExecutor",
    "SerialExecutor",
    "SweepError",
    "SweepResult",
    "SweepSpec",
    "evaluate_points",
    "load_sweep",
    "make_executor",
    "parse_grid",
    "run_sweep",
    "save_sweep",
]

#: integer codes of the verdicts in the stored table (-1: not computed)
VERDICT_CODES: dict[str, int] = {"stable": 0, "marginal": 1, "potentially_unstable": 2, "not_applicable": 3}
VERDICT_NAMES = {v: k for k, v in VERDICT_CODES.items()}
SWEEP_FORMAT = 1
MAX_POINTS = 2_000_000


@dataclass(frozen=True)
class GridAxis:
    """One swept parameter: ``n`` values from ``lo`` to ``hi`` inclusive (log-spaced if ``log``)."""

    name: str
    lo: float
    hi: float
    n: int
    log: bool = False

    @property
    def values(self) -> np.ndarray:
        if self.n == 1:
            return np.array([self.lo])
        if self.log:
            return np.geomspace(self.lo, self.hi, self.n)
        return np.linspace(self.lo, self.hi, self.n)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "lo": self.lo, "hi": self.hi, "n": self.n, "log": self.log}


_GRID = re.compile(r"^(?P<name>[A-Za-z_][A-Za-z0-9_]*)=(?P<log>log:)?(?P<lo>[^:]+):(?P<hi>[^:]+):(?P<n>[^:]+)$")


def parse_grid(text: str) -> GridAxis:
    """``NAME=LO:HI:N`` or ``NAME=log:LO:HI:N`` → :class:`GridAxis`; :class:`SweepError` otherwise."""
    m = _GRID.match(text.strip())
    if not m:
        raise SweepError(f"--grid {text!r}: expected NAME=LO:HI:N (or NAME=log:LO:HI:N), e.g. k22=100:600:51")
    try:
        lo, hi = float(m["lo"]), float(m["hi"])
        n = int(m["n"])
    except ValueError:
        raise SweepError(f"--grid {text!r}: LO and HI must be numbers and N an integer") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise SweepError(f"--grid {text!r}: LO and HI must be finite")
    if n < 1:
        raise SweepError(f"--grid {text!r}: N must be at least 1")
    if n > 1 and not lo < hi:
        raise SweepError(f"--grid {text!r}: LO must be below HI")
    log_ = bool(m["log"])
    if log_ and lo <= 0:
        raise SweepError(f"--grid {text!r}: a log axis needs LO > 0")
    return GridAxis(m["name"], lo, hi, n, log_)


@dataclass
class SweepSpec:
    """What to compute: a built-in model (``hil stability --list-models``), its fixed parameters, the
    swept axes (1-3), the criterion (default: the model's), optional posterior draws for P(stable)."""

    model: str
    axes: list[GridAxis]
    params: dict[str, Any] = field(default_factory=dict)
    criterion: str | None = None
    refine: bool = True
    boundary_tol: float = 1e-4
    posterior: dict[str, np.ndarray] | None = None
    n_draws: int = 200
    chunk: int = 64
    #: parameters taken from a scene (``from_scene``): passed to the builder as they are
    scene_params: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_scene(cls, scene: Any, axes: list[GridAxis], params: Mapping[str, Any] | None = None,
                   criterion: str | None = None, **kw: Any) -> SweepSpec:
        """A sweep of a scene's certification network: its model, the fixed parameters its
        controller and simulation imply (:func:`hil.certify.pipeline.model_params_from_scene`), ``params``
        on top, and its criterion unless ``criterion`` is given."""
        from hil.certify.pipeline import model_params_from_scene

        cert = scene.certification
        sp = {k: v for k, v in model_params_from_scene(scene).items() if k not in {a.name for a in axes}}
        crit = criterion or (None if cert.criterion == "auto" else cert.criterion)
        return cls(cert.model, axes, dict(params or {}), crit, scene_params=sp, **kw)

    def validate(self) -> None:
        from hil.models import get_model, model_names

        if not 1 <= len(self.axes) <= 3:
            raise SweepError(f"give one to three --grid axes, got {len(self.axes)}")
        try:
            m = get_model(self.model)
        except KeyError:
            raise SweepError(f"--model {self.model}: unknown model; known: {', '.join(model_names())}") from None
        names = [a.name for a in self.axes]
        if len(set(names)) != len(names):
            raise SweepError(f"--grid: a parameter is swept twice ({', '.join(names)})")
        for a in self.axes:
            if a.name in self.params:
                raise SweepError(f"--grid {a.name}: also fixed with --set; drop one")
            gains = self.scene_params.get(m.table) if m.table is not None else None
            if isinstance(gains, Mapping) and a.name in gains:
                continue  # a gain of the scene's controller table
            if m.defaults and a.name not in m.defaults:
                raise SweepError(f"--grid {a.name}: model {self.model} has no parameter {a.name!r}; "
                                 f"known: {', '.join(sorted(m.defaults))}")
            if isinstance(m.defaults.get(a.name), str):
                raise SweepError(f"--grid {a.name}: a named choice cannot be swept over numbers")
        try:
            m.check_params(dict(self.params))
        except HilError as exc:
            raise SweepError(f"--set: {exc}") from None
        n = math.prod(a.n for a in self.axes)
        if n > MAX_POINTS:
            raise SweepError(f"{n} grid points exceed the limit of {MAX_POINTS}; use fewer points and refinement")
        if not 0 < self.boundary_tol < 1:
            raise SweepError("--boundary-tol must lie in (0, 1) (a fraction of the grid step)")
        if self.chunk < 1:
            raise SweepError("--chunk must be at least 1")
        if self.posterior is not None:
            if self.n_draws < 1:
                raise SweepError("--draws must be at least 1")
            unknown = [k for k in self.posterior if m.defaults and k not in m.defaults]
            if unknown:
                raise SweepError(f"the posterior has parameters the model {self.model} does not take: "
                                 f"{', '.join(unknown)}")

    @property
    def fixed(self) -> dict[str, Any]:
        """Every fixed parameter: the scene's, then ``params`` on top."""
        return {**self.scene_params, **self.params}

    @property
    def criterion_name(self) -> str:
        from hil.models import get_model

        return self.criterion or get_model(self.model).criterion

    def identity(self) -> dict[str, Any]:
        """The content that fixes every number of the sweep (hashed for the cache and the seeds)."""
        post = None
        if self.posterior is not None:
            h = hashlib.sha256()
            for k in sorted(self.posterior):
                h.update(k.encode())
                h.update(np.ascontiguousarray(self.posterior[k], dtype=float).tobytes())
            post = {"sha256": h.hexdigest(), "n_draws": self.n_draws}
        fixed = self.fixed
        return {"format": SWEEP_FORMAT, "model": self.model, "criterion": self.criterion_name,
                "params": {k: fixed[k] for k in sorted(fixed)}, "posterior": post,
                "version": _version()}


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("hil-certify")
    except Exception:  # pragma: no cover - not installed (source tree)
        return "0"


def _digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":"), default=repr).encode()).hexdigest()


# ---------------------------------------------------------------------------------------------
# the work of one task (module level: picklable for process pools and dask)


def _draw_subset(posterior: Mapping[str, np.ndarray], n: int, seed_text: str) -> dict[str, np.ndarray]:
    """``n`` draws of the posterior without replacement (all when it has fewer), chosen by a seed
    derived from ``seed_text`` (the sweep's content), so every executor uses the same ones."""
    total = len(next(iter(posterior.values())))
    rng = np.random.default_rng(int(_digest(["draws", seed_text])[:16], 16))
    idx = np.sort(rng.choice(total, size=min(n, total), replace=False))
    return {k: np.asarray(v, dtype=float)[idx] for k, v in posterior.items()}


def build_network(model: str, params: Mapping[str, Any]) -> Any:
    """The network of a built-in model: :func:`hil.certify.pipeline.build_network` (which also takes a
    scene's gain table, with swept gains given at the top level)."""
    from hil.certify.pipeline import build_network as build

    return build(model, params)


def _p_stable(model: str, criterion: str, params: Mapping[str, Any], draws: Mapping[str, np.ndarray]) -> float:
    from hil.models import get_model

    n = len(next(iter(draws.values())))
    batch = get_model(model).vectorized(criterion)
    if batch is not None:
        fixed = {k: float(v) for k, v in params.items()}
        d = {k: v for k, v in draws.items() if k not in fixed}
        if not d:
            d = {next(iter(fixed)): np.full(n, next(iter(fixed.values())))}
        res = batch(d, fixed=fixed)  # verdicts only (no band: it is not used here)
        return float(np.mean(res["passive"]))
    from hil.stability.criteria import check

    ok = 0
    for i in range(n):
        p = {**{k: float(v[i]) for k, v in draws.items()}, **params}
        ok += check(build_network(model, p), criterion).verdict == "stable"
    return ok / n


def evaluate_points(model: str, criterion: str, params: Mapping[str, Any], names: Sequence[str],
                    points: np.ndarray, draws: Mapping[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Exact verdict, margin and worst frequency (and P(stable) over ``draws``) at each row of
    ``points`` (shape (n, len(names))). A network the model cannot build counts as
    ``not_applicable`` with a NaN margin (the message is logged)."""
    from hil.stability.criteria import check

    n = points.shape[0]
    verdict = np.full(n, -1, dtype=np.int8)
    margin = np.full(n, np.nan)
    wf = np.full(n, np.nan)
    pst = np.full(n, np.nan)
    for i in range(n):
        p = {**params, **{k: float(points[i, j]) for j, k in enumerate(names)}}
        try:
            r = check(build_network(model, p), criterion)
        except HilError as exc:
            logger.info("sweep point %s: %s", p, exc)
            verdict[i] = VERDICT_CODES["not_applicable"]
            continue
        verdict[i] = VERDICT_CODES[str(r.verdict)]
        margin[i] = float(r.margin)
        wf[i] = np.nan if r.worst_frequency is None else float(r.worst_frequency)
        if draws is not None:
            pst[i] = _p_stable(model, criterion, p, draws)
    return {"verdict": verdict, "margin": margin, "worst_frequency": wf, "p_stable": pst}


def _is_stable(model: str, criterion: str, params: Mapping[str, Any]) -> bool:
    from hil.stability.criteria import check

    try:
        return check(build_network(model, params), criterion).verdict == "stable"
    except HilError:
        return False


def bisect_boundary(model: str, criterion: str, params: Mapping[str, Any], name: str, a: float, b: float,
                    a_stable: bool, tol: float) -> tuple[float, float, int]:
    """Bisect between ``a`` and ``b`` on parameter ``name`` (``a``'s verdict class is ``a_stable``, b's
    the other) until ``|b - a| ≤ tol``. Returns (stable end, unstable end, exact verdicts used)."""
    lo, hi = a, b  # lo keeps a's class
    n = 0
    while abs(hi - lo) > tol:
        mid = 0.5 * (lo + hi)
        n += 1
        if _is_stable(model, criterion, {**params, name: mid}) == a_stable:
            lo = mid
        else:
            hi = mid
    return (lo, hi, n) if a_stable else (hi, lo, n)


def _task(kind: str, payload: dict[str, Any]) -> dict[str, Any]:
    """One unit of work (runs in a worker)."""
    if kind == "points":
        return evaluate_points(payload["model"], payload["criterion"], payload["params"], payload["names"],
                               np.asarray(payload["points"], dtype=float), payload.get("draws"))
    if kind == "segment":
        s, u, n = bisect_boundary(payload["model"], payload["criterion"], payload["params"], payload["name"],
                                  payload["a"], payload["b"], payload["a_stable"], payload["tol"])
        return {"stable_end": s, "unstable_end": u, "evaluations": n}
    raise ValueError(kind)


# ---------------------------------------------------------------------------------------------
# the cache (content-addressed, one small file per task)


class TaskCache:
    """One ``.npz`` per task under ``root``, named by the SHA-256 of the task's content. Files are
    written to a temporary name and renamed, so an interrupted write never leaves a half file."""

    def __init__(self, root: str | Path | None) -> None:
        self.root = None if root is None else Path(root)
        self.hits = 0
        if self.root is not None:
            try:
                self.root.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise SweepError(f"--cache {self.root}: cannot create: {exc.strerror or exc}") from None

    def _path(self, key: str) -> Path:
        assert self.root is not None
        return self.root / f"{key}.npz"

    def get(self, key: str) -> dict[str, Any] | None:
        if self.root is None:
            return None
        p = self._path(key)
        if not p.exists():
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                out = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:  # a damaged file is recomputed, never trusted
            logger.warning("sweep cache %s unreadable (%s): recomputing", p, exc)
            return None
        self.hits += 1
        return {k: (v.item() if v.shape == () else v) for k, v in out.items()}

    def put(self, key: str, value: Mapping[str, Any]) -> None:
        if self.root is None:
            return
        p = self._path(key)
        tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
        try:
            with open(tmp, "wb") as fh:
                arrays: dict[str, Any] = {k: np.asarray(v) for k, v in value.items()}
                np.savez(fh, **arrays)
            os.replace(tmp, p)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            logger.warning("sweep cache %s not written (%s)", p, exc)


# ---------------------------------------------------------------------------------------------
# the sweep


@dataclass
class SweepResult:
    """The table of a sweep. ``verdict``, ``margin``, ``worst_frequency``, ``p_stable`` have the
    grid's shape (axis order as given); ``boundary`` holds the refined crossings (``points`` (n, d),
    ``axis`` (n,) the index of the bisected axis, ``bracket`` (n, 2): stable end, unstable end)."""

    spec: dict[str, Any]
    axes: list[GridAxis]
    verdict: np.ndarray
    margin: np.ndarray
    worst_frequency: np.ndarray
    p_stable: np.ndarray | None
    boundary: dict[str, np.ndarray]
    evaluations: int
    timings: dict[str, float]
    cache_hits: int = 0

    @property
    def names(self) -> list[str]:
        return [a.name for a in self.axes]

    def boundary_curve(self, axis: int | str = -1, where: Mapping[str, float] | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
        """The crossings found along ``axis`` (default the last) as a curve over the first other
        axis, sorted (e.g. k22_max(b22)). With three axes, ``where`` fixes the third one
        (``{"alpha": 0.9}``; default its first value). With several crossings per line, all are kept."""
        ax = self.names.index(axis) if isinstance(axis, str) else axis % len(self.axes)
        if len(self.axes) == 1:
            raise SweepError("a boundary curve needs two or three swept parameters")
        others = [i for i in range(len(self.axes)) if i != ax]
        sel = self.boundary["axis"] == ax
        pts = self.boundary["points"][sel]
        if len(others) == 2:
            third = others[1]
            name = self.names[third]
            value = (where or {}).get(name, float(self.axes[third].values[0]))
            pts = pts[np.isclose(pts[:, third], value, rtol=1e-12, atol=0)]
        other = others[0]
        order = np.lexsort((pts[:, ax], pts[:, other]))
        return pts[order, other], pts[order, ax]


def _grid_points(axes: Sequence[GridAxis]) -> np.ndarray:
    mesh = np.meshgrid(*[a.values for a in axes], indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


def _run_tasks(executor: Executor, cache: TaskCache, tasks: list[tuple[str, dict[str, Any]]], keys: list[str],
               on_done: Callable[[int, dict[str, Any]], None], progress: Callable[[int, int], None] | None,
               should_stop: Callable[[], None] | None, weights: Sequence[int] | None = None) -> None:
    """Cached tasks first, then the rest on ``executor``; ``progress(done, total)`` counts
    ``weights`` (grid points per task; default 1 per task)."""
    w = list(weights) if weights is not None else [1] * len(keys)
    total = sum(w)
    todo = []
    done = 0
    for i, k in enumerate(keys):
        hit = cache.get(k)
        if hit is not None:
            on_done(i, hit)
            done += w[i]
        else:
            todo.append(i)
    if progress:
        progress(done, total)
    if not todo:
        return
    for j, res in executor.map_unordered(_task, [tasks[i] for i in todo]):
        i = todo[j]
        cache.put(keys[i], res)
        on_done(i, res)
        done += w[i]
        if progress:
            progress(done, total)
        if should_stop is not None:
            should_stop()  # raises (e.g. hil.bench.stopflag.StopRequested) to end the sweep here


def run_sweep(spec: SweepSpec, executor: Executor | None = None, cache_dir: str | Path | None = None,
              progress: Callable[[int, int], None] | None = None,
              should_stop: Callable[[], None] | None = None) -> SweepResult:
    """Evaluate the grid, then (``spec.refine``) bisect every stable/unstable neighbour pair.

    ``progress(done, total)`` is called after every task (grid points, then boundary segments); ``should_stop()`` is
    called between tasks and ends the sweep by raising (e.g. ``hil.bench.stopflag.STOP.check``); every
    task finished by then is in the cache."""
    spec.validate()
    executor = executor or SerialExecutor()
    cache = TaskCache(cache_dir)
    ident = spec.identity()
    crit = spec.criterion_name
    names = [a.name for a in spec.axes]
    shape = tuple(a.n for a in spec.axes)
    pts = _grid_points(spec.axes)
    draws = None if spec.posterior is None else _draw_subset(spec.posterior, spec.n_draws, _digest(ident))
    t0 = time.perf_counter()
    tasks: list[tuple[str, dict[str, Any]]] = []
    keys: list[str] = []
    spans: list[tuple[int, int]] = []
    for s in range(0, len(pts), spec.chunk):
        chunk = pts[s:s + spec.chunk]
        payload: dict[str, Any] = {"model": spec.model, "criterion": crit, "params": spec.fixed, "names": names,
                   "points": chunk, "draws": draws}
        tasks.append(("points", payload))
        keys.append(_digest([ident, "points", names, chunk.tolist()]))
        spans.append((s, s + len(chunk)))
    n = len(pts)
    verdict = np.full(n, -1, dtype=np.int8)
    margin = np.full(n, np.nan)
    wf = np.full(n, np.nan)
    pst = np.full(n, np.nan)

    def grid_done(i: int, r: dict[str, Any]) -> None:
        a, b = spans[i]
        verdict[a:b] = r["verdict"]
        margin[a:b] = r["margin"]
        wf[a:b] = r["worst_frequency"]
        pst[a:b] = r["p_stable"]

    _run_tasks(executor, cache, tasks, keys, grid_done, progress, should_stop, [b - a for a, b in spans])
    t_grid = time.perf_counter() - t0
    V = verdict.reshape(shape)
    boundary: dict[str, np.ndarray] = {"points": np.zeros((0, len(names))), "axis": np.zeros(0, dtype=np.int64),
                                       "bracket": np.zeros((0, 2))}
    evaluations = n
    if spec.refine:
        seg_tasks: list[tuple[str, dict[str, Any]]] = []
        seg_keys: list[str] = []
        seg_meta: list[tuple[int, dict[str, float]]] = []
        stable = VERDICT_CODES["stable"] == V
        unstable = VERDICT_CODES["potentially_unstable"] == V
        for ax, a in enumerate(spec.axes):
            if a.n < 2:
                continue
            vals = a.values
            s_lo = np.take(stable, np.arange(a.n - 1), axis=ax)
            s_hi = np.take(stable, np.arange(1, a.n), axis=ax)
            u_lo = np.take(unstable, np.arange(a.n - 1), axis=ax)
            u_hi = np.take(unstable, np.arange(1, a.n), axis=ax)
            cross = (s_lo & u_hi) | (u_lo & s_hi)
            for idx in zip(*np.nonzero(cross), strict=True):
                i = int(idx[ax])
                step = abs(vals[i + 1] - vals[i])
                point = {names[d]: float(spec.axes[d].values[idx[d]]) for d in range(len(names)) if d != ax}
                seg = {"model": spec.model, "criterion": crit, "params": {**spec.fixed, **point}, "name": a.name,
                       "a": float(vals[i]), "b": float(vals[i + 1]), "a_stable": bool(s_lo[idx]),
                       "tol": spec.boundary_tol * step}
                seg_tasks.append(("segment", seg))
                seg_keys.append(_digest([ident, "segment", seg["params"], a.name, seg["a"], seg["b"], seg["tol"]]))
                seg_meta.append((ax, point))
        results: list[dict[str, Any] | None] = [None] * len(seg_tasks)

        def seg_done(i: int, r: dict[str, Any]) -> None:
            results[i] = r

        _run_tasks(executor, cache, seg_tasks, seg_keys, seg_done, progress, should_stop)
        rows: list[list[float]] = []
        axis_of: list[int] = []
        brackets: list[tuple[float, float]] = []
        for (ax, point), r in zip(seg_meta, results, strict=True):
            assert r is not None
            s_end, u_end = float(r["stable_end"]), float(r["unstable_end"])
            row = [point.get(nm, 0.5 * (s_end + u_end)) for nm in names]
            rows.append(row)
            axis_of.append(ax)
            brackets.append((s_end, u_end))
            evaluations += int(r["evaluations"])
        if rows:
            boundary = {"points": np.array(rows, dtype=float), "axis": np.array(axis_of, dtype=np.int64),
                        "bracket": np.array(brackets, dtype=float)}
    timings = {"grid_s": t_grid, "refine_s": time.perf_counter() - t0 - t_grid, "total_s": time.perf_counter() - t0}
    return SweepResult(spec=ident | {"axes": [a.to_dict() for a in spec.axes], "refine": spec.refine,
                                     "boundary_tol": spec.boundary_tol, "chunk": spec.chunk},
                       axes=list(spec.axes), verdict=V, margin=margin.reshape(shape),
                       worst_frequency=wf.reshape(shape),
                       p_stable=None if spec.posterior is None else pst.reshape(shape),
                       boundary=boundary, evaluations=evaluations, timings=timings, cache_hits=cache.hits)


# ---------------------------------------------------------------------------------------------
# output


def save_sweep(res: SweepResult, path: str | Path) -> Path:
    """Write the table as HDF5: ``/axes/<name>`` values, ``verdict`` (int8 codes, attribute
    ``codes``), ``margin`` (1), ``worst_frequency`` (rad/s), ``p_stable`` (1, if computed),
    ``/boundary/{points,axis,bracket}``, and the spec as JSON in the ``spec`` attribute."""
    import h5py

    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs["spec"] = json.dumps(res.spec, sort_keys=True, default=repr)
        f.attrs["axis_order"] = json.dumps(res.names)
        g = f.create_group("axes")
        for a in res.axes:
            g.create_dataset(a.name, data=a.values)
        d = f.create_dataset("verdict", data=res.verdict)
        d.attrs["codes"] = json.dumps(VERDICT_CODES)
        f.create_dataset("margin", data=res.margin).attrs["unit"] = "1"
        f.create_dataset("worst_frequency", data=res.worst_frequency).attrs["unit"] = "rad/s"
        if res.p_stable is not None:
            f.create_dataset("p_stable", data=res.p_stable).attrs["unit"] = "1"
        b = f.create_group("boundary")
        for k, v in res.boundary.items():
            b.create_dataset(k, data=v)
        f.attrs["evaluations"] = res.evaluations
    os.replace(tmp, path)
    return path


def load_sweep(path: str | Path) -> dict[str, Any]:
    """The arrays of a file written by :func:`save_sweep` (``axes`` as name → values)."""
    import h5py

    with h5py.File(path, "r") as f:
        order = json.loads(f.attrs["axis_order"])
        out: dict[str, Any] = {"spec": json.loads(f.attrs["spec"]), "axes": {n: f["axes"][n][()] for n in order},
                               "verdict": f["verdict"][()], "margin": f["margin"][()],
                               "worst_frequency": f["worst_frequency"][()],
                               "boundary": {k: f["boundary"][k][()] for k in f["boundary"]}}
        out["p_stable"] = f["p_stable"][()] if "p_stable" in f else None
    return out


def plot_sweep(res: SweepResult, path: str | Path, required: float | None = None) -> Path:
    """Heat map of the margin (1 axis: a line) with the verdict boundary drawn (grey: not stable);
    with P(stable), a second panel and the contour where it crosses ``required``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = res.names
    panels = 2 if res.p_stable is not None else 1
    fig, axs = plt.subplots(1, panels, figsize=(6.2 * panels, 4.6), squeeze=False)
    ax = axs[0, 0]
    crit = res.spec.get("criterion")
    if len(res.axes) == 1:
        x = res.axes[0].values
        ax.plot(x, res.margin, "k.-", lw=1)
        ax.axhline(0, color="grey", lw=0.8)
        for p in res.boundary["points"][:, 0]:
            ax.axvline(p, color="C3", ls="--", lw=1)
        ax.set_xlabel(_label(names[0], res))
        ax.set_ylabel("normalized margin [1]")
    else:
        from matplotlib.colors import BoundaryNorm, ListedColormap

        x, y = res.axes[0].values, res.axes[1].values
        V = res.verdict if len(res.axes) == 2 else res.verdict[..., 0]
        cmap = ListedColormap(["#7fc97f", "#fdc086", "#f0027f", "#bbbbbb"])  # stable, marginal, unstable, n/a
        mesh = ax.pcolormesh(x, y, V.T, shading="nearest", cmap=cmap, norm=BoundaryNorm([-0.5, 0.5, 1.5, 2.5, 3.5], 4))
        cb = fig.colorbar(mesh, ax=ax, ticks=[0, 1, 2, 3])
        cb.ax.set_yticklabels(["stable", "marginal", "potentially\nunstable", "not\napplicable"])
        b = res.boundary
        if len(b["points"]):
            first = np.ones(len(b["points"]), dtype=bool) if len(res.axes) == 2 else \
                np.isclose(b["points"][:, 2], res.axes[2].values[0], rtol=1e-12, atol=0)
            ax.plot(b["points"][first, 0], b["points"][first, 1], "k.", ms=3, label="refined boundary points")
            if len(res.axes) == 2 and np.any(b["axis"] == 1):
                bx, by = res.boundary_curve(1)
                ax.plot(bx, by, "k-", lw=1.4, label=f"{names[1]} at the boundary")
            elif len(res.axes) == 3 and np.any(b["axis"] == 1):
                for j, v in enumerate(res.axes[2].values[:8]):
                    bx, by = res.boundary_curve(1, {names[2]: float(v)})
                    ax.plot(bx, by, "-", color=f"C{j}", lw=1.4, label=f"{names[1]} at the boundary, {names[2]} = {v:g}")
            ax.legend(loc="best", fontsize=8)
        ax.set_xlabel(_label(names[0], res))
        ax.set_ylabel(_label(names[1], res))
        if res.axes[0].log:
            ax.set_xscale("log")
        if res.axes[1].log:
            ax.set_yscale("log")
        if len(res.axes) == 3:
            ax.text(0.01, 0.01, f"colours and points: {names[2]} = {res.axes[2].values[0]:g}", transform=ax.transAxes,
                    fontsize=8)
    ax.set_title(f"{res.spec.get('model')}: {crit} ", fontsize=10)
    if res.p_stable is not None:
        ax2 = axs[0, 1]
        if len(res.axes) == 1:
            ax2.plot(res.axes[0].values, res.p_stable, "b.-")
            if required is not None:
                ax2.axhline(required, color="C3", ls="--", label=f"required {required:g}")
                ax2.legend(fontsize=8)
            ax2.set_xlabel(names[0])
            ax2.set_ylabel("P(stable) [1]")
        else:
            P = res.p_stable if len(res.axes) == 2 else res.p_stable[..., 0]
            x, y = res.axes[0].values, res.axes[1].values
            mesh = ax2.pcolormesh(x, y, P.T, shading="nearest", cmap="viridis", vmin=0, vmax=1)
            fig.colorbar(mesh, ax=ax2, label="P(stable) [1]")
            if required is not None and np.nanmin(P) < required < np.nanmax(P):
                ax2.contour(x, y, P.T, levels=[required], colors="r")
            ax2.set_xlabel(names[0])
            ax2.set_ylabel(names[1])
        ax2.set_title("P(stable) over the posterior" + (f" (red: {required:g})" if required else ""), fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _label(name: str, res: SweepResult) -> str:
    """An axis label: the parameter with its unit where the model declares one."""
    from hil.models import get_model

    try:
        unit = get_model(str(res.spec.get("model"))).units.get(name)
    except KeyError:
        unit = None
    return f"{name} [{unit}]" if unit else name


def posterior_from_record(path: str, name: str | None = None, network_model: str | None = None
                          ) -> dict[str, np.ndarray]:
    """Posterior draws (parameter name → array) of a stored identification (``hil identify`` /
    ``hil certify`` records): the sampled parameters and the identification model's derived ones
    (e.g. the entries of M, B, K of an MBK model sampled as Cholesky factors), kept where the
    network ``network_model`` takes them. :class:`SweepError` if none can be read or none match."""
    from hil.identify.api import load_identification
    from hil.identify.models import make_model

    try:
        ident = load_identification(path, name)
    except HilError as exc:
        raise SweepError(f"--posterior {path}: {exc}") from None
    samples = np.asarray(ident["samples"], dtype=float)
    summary = ident["summary"] if isinstance(ident["summary"], Mapping) else {}
    names = summary.get("sample_names") or list(summary.get("parameters") or [])
    if samples.ndim != 2 or samples.shape[1] < len(names) or not names:
        raise SweepError(f"--posterior {path}: samples of shape {samples.shape} do not match parameters {names}")
    out = {n: samples[:, i] for i, n in enumerate(names)}
    try:
        out.update({k: np.asarray(v, dtype=float) for k, (v, _u) in
                    make_model(str(summary.get("model"))).derived(samples[:, : len(names)]).items()})
    except HilError as exc:
        logger.info("posterior %s: no derived parameters (%s)", path, exc)
    if network_model is not None:
        from hil.models import get_model

        takes = set(get_model(network_model).defaults)
        out = {k: v for k, v in out.items() if k in takes}
        if not out:
            raise SweepError(f"--posterior {path}: none of its parameters ({', '.join(names)}) is a parameter of "
                             f"the model {network_model}")
    return out


def iter_table(res: SweepResult) -> Iterable[dict[str, Any]]:
    """Every grid point as a row (for ``--json`` and tests)."""
    pts = _grid_points(res.axes)
    V, M, W = res.verdict.ravel(), res.margin.ravel(), res.worst_frequency.ravel()
    P = None if res.p_stable is None else res.p_stable.ravel()
    for i, p in enumerate(pts):
        row: dict[str, Any] = {n: float(p[j]) for j, n in enumerate(res.names)}
        row |= {"verdict": VERDICT_NAMES.get(int(V[i]), "not_computed"), "margin": float(M[i]),
                "worst_frequency": float(W[i])}
        if P is not None:
            row["p_stable"] = float(P[i])
        yield row
