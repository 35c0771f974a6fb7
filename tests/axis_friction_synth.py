"""Synthetic records of a 1-DOF axis with KNOWN friction, from the simulated twins' physics.

For calibration tests of identification with friction (bias, interval coverage, scatter against
the Cramér-Rao bound over seeds): the axis ``M q'' = u - F_0 - B q' - F_friction`` is advanced by
:class:`hil.mocks.simulator.Simulator` with :class:`hil.mocks.friction.Friction` (exact stick-slip:
Coulomb, static/Stribeck), the force ``u`` held over each period (the bench's ZOH), the position
measured by a quantized encoder (``encoder_step``) plus optional white noise, and the velocity as a
drive reports it (``estimate`` or ``difference``, hil.mocks.friction.Mechanics). Truth uses the names
of :mod:`hil.identify.friction` (``M``, ``B``, ``F_c``, ``F_s`` = the Stribeck *excess*, ``v_s``, ``F_0``).

Two outputs: :func:`axis_record` returns the arrays and the truth; :func:`write_record` stores them
as a run record (``<target>.effort_cmd``, ``.position``, ``.velocity``; the same HDF5 format a bench
writes, so ``hil.identify.api.identify_record(open_source(path), friction=...)`` and ``hil identify``
read it as they read a bench's). The excitation is a seeded random-phase multisine (a different
signal per seed) between ``f0`` and ``f1``; the defaults give an EMPS-sized axis (M 95 kg, B 200
N.s/m, F_c 20 N; 1 kHz) whose friction the inverse-dynamics estimator recovers (the built-in
``emps_axis`` scene uses the same band).

Usage (20 seeds)::

    from axis_friction_synth import AxisTruth, axis_record   # pytest puts tests/ on sys.path (as for sdea_synth)
    for seed in range(20):
        rec = axis_record(seed, AxisTruth(F_s=5.0, v_s=0.005), encoder_step=5e-8)
        res = identify_friction_arrays(rec.t, rec.u, rec.q, ("coulomb", "stribeck", "offset"))
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from hil.mocks.friction import Friction, quantize
from hil.mocks.physics import mbk_plant
from hil.mocks.simulator import Simulator

__all__ = ["AxisRecord", "AxisTruth", "axis_record", "multisine", "write_record"]


@dataclass(frozen=True)
class AxisTruth:
    """The simulated axis (linear units): ``M`` kg, ``B`` N.s/m, ``F_c`` N, ``F_s`` N (Stribeck excess at
    rest: break-away ``F_c + F_s``), ``v_s`` m/s, ``F_0`` N (constant offset, ``u = M a + ... + F_0``)."""

    M: float = 95.0
    B: float = 200.0
    F_c: float = 20.0
    F_s: float = 0.0
    v_s: float = 0.01
    F_0: float = 0.0

    def friction(self) -> Friction:
        """The twin's friction (its ``static`` is the break-away level ``F_c + F_s``)."""
        if self.F_s > 0.0:
            return Friction(self.F_c, self.F_c + self.F_s, self.v_s)
        return Friction(self.F_c)

    def as_dict(self, terms: tuple[str, ...] = ("coulomb", "offset")) -> dict[str, float]:
        """The truth of the parameters a model with friction ``terms`` has."""
        d = asdict(self)
        keep = {"M", "B"} | ({"F_c"} if {"coulomb", "stribeck"} & set(terms) else set()) \
            | ({"F_s", "v_s"} if "stribeck" in terms else set()) | ({"F_0"} if "offset" in terms else set())
        return {k: float(v) for k, v in d.items() if k in keep}


@dataclass(frozen=True)
class AxisRecord:
    """One synthetic record: time ``t`` [s], force ``u`` [N] (held over ``[t_k, t_k+1)``), measured
    position ``q`` [m] and velocity ``v`` [m/s] at ``t_k``, the true state (``q_true``, ``v_true``), the
    truth and what was added (``encoder_step`` m, ``position_std`` m)."""

    t: NDArray[np.float64]
    u: NDArray[np.float64]
    q: NDArray[np.float64]
    v: NDArray[np.float64]
    q_true: NDArray[np.float64]
    v_true: NDArray[np.float64]
    truth: AxisTruth
    encoder_step: float
    position_std: float
    dissipated: float  # energy the dry friction dissipated over the record [J] (exact)


def multisine(seed: int, n: int, fs: float, f0: float, f1: float, n_lines: int,
              amplitude: float) -> NDArray[np.float64]:
    """A random-phase multisine (seeded) of ``n_lines`` equal lines on the ``fs / n`` grid in
    ``[f0, f1]`` Hz, scaled to peak ``amplitude``."""
    rng = np.random.default_rng(seed)
    grid = np.unique(np.round(np.linspace(f0, f1, n_lines) * n / fs).astype(int))
    grid = grid[grid > 0]
    t = np.arange(n) / fs
    phases = rng.uniform(0, 2 * np.pi, grid.size)[:, None]
    x = np.sum(np.sin(2 * np.pi * np.outer(grid * fs / n, t) + phases), axis=0)
    return amplitude * x / float(np.max(np.abs(x)))


def axis_record(seed: int, truth: AxisTruth | None = None, *, fs: float = 1000.0, duration: float = 20.0,
                f0: float = 0.1, f1: float = 2.0, n_lines: int = 10, amplitude: float = 100.0,
                encoder_step: float = 5e-8, position_std: float = 0.0, velocity: str = "difference") -> AxisRecord:
    """Simulate the axis under a seeded multisine force and measure it (module docstring)."""
    tr = truth or AxisTruth()
    n = round(duration * fs)
    u = multisine(seed, n, fs, f0, f1, n_lines, amplitude)
    sim = Simulator(mbk_plant(tr.M, tr.B), 1.0 / fs, friction={"body": tr.friction()})
    h = sim.joints("body")
    xs = np.empty((n, 2))
    for k in range(n):
        xs[k] = sim.state[:2]
        h.apply_effort([u[k] - tr.F_0])  # u = M a + B v + friction + F_0
        sim.tick()
    rng = np.random.default_rng([seed, 1])
    q = quantize(xs[:, 0] + position_std * rng.standard_normal(n), encoder_step)
    if velocity == "difference":
        qq = quantize(xs[:, 0], encoder_step)
        v = np.concatenate([[0.0], np.diff(qq) * fs])
    else:
        v = xs[:, 1].copy()
    ss = sim.stick_slip
    return AxisRecord(np.arange(n) / fs, u, q, v, xs[:, 0].copy(), xs[:, 1].copy(), tr, float(encoder_step),
                      float(position_std), float(ss.dissipated.sum()) if ss is not None else 0.0)


def write_record(rec: AxisRecord, path: str | Path, target: str = "axis") -> Path:
    """Store ``rec`` as a run record with channels ``<target>.effort_cmd`` [N], ``.position`` [m],
    ``.velocity`` [m/s] (scene-less: meta carries the truth and the units)."""
    from hil.record.hdf5 import ChannelSpec, RecordWriter

    path = Path(path)
    specs = {f"{target}.effort_cmd": ChannelSpec((), "N"), f"{target}.position": ChannelSpec((), "m"),
             f"{target}.velocity": ChannelSpec((), "m/s")}
    fs = 1.0 / float(rec.t[1] - rec.t[0])
    meta = {"units": "linear", "synthetic": "tests/axis_friction_synth.py", "truth": asdict(rec.truth),
            "encoder_step": rec.encoder_step, "position_std": rec.position_std}
    with RecordWriter(path, scene_text="", scene_sha256="", meta=meta, channels=specs, rate_hz=fs) as w:
        for k in range(rec.t.size):
            w.append(float(rec.t[k]), {f"{target}.effort_cmd": rec.u[k], f"{target}.position": rec.q[k],
                                       f"{target}.velocity": rec.v[k]})
    return path
