"""EMPS benchmark: error against the published values and CPU time, per method (not a test).

Run: ``python benchmarks/bench_emps.py [DATA_DIR]`` (default ``../shared/data/emps`` next to the
repository; the two .mat files of the EMPS benchmark, Janot, Gautier, Brunot 2019). Prints, for
DATA_EMPS.mat (force = gtau * vir, position qm, 1 kHz), one row per method:

* ``IDIM-LS``: the benchmark's own estimator (:func:`hil.identify.idim.idim_ls`), white-residual sd;
* ``IDIM-ML``: :func:`hil.identify.inverse_ml.fit_inverse_ml` (LS with the held-force alignment,
  sandwich sd);
* ``IDIM-ML + emcee``: the same with the emcee posterior (:func:`hil.identify.api.identify_record`,
  ``friction=("coulomb", "offset")``), posterior medians and sd;
* ``linear OE``: the viscous-only member, for the error a linear model makes.

Columns: M [kg], B [N.s/m], F_c [N], F_0 [N] (sd in brackets), the relative error of M, B, F_c
against the published IDIM-LS estimates [%], the absolute error of F_0 [N], and the CPU time
(``time.process_time``: this process's CPU seconds, robust to other load on the machine) [s] with
its ratio to the IDIM-LS row measured in the same run. The machine's load average is printed too.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

PUBLISHED = {"M": 95.1089, "B": 203.5034, "F_c": 20.3935, "F_0": -3.1648}


def main() -> int:
    import scipy.io as sio

    from hil.identify.api import identify_record
    from hil.identify.idim import idim_ls
    from hil.identify.inverse_ml import fit_inverse_ml

    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared" / "data" / "emps"
    if not (root / "DATA_EMPS.mat").is_file():
        root = Path("/work/shared/data/emps")
    d = sio.loadmat(root / "DATA_EMPS.mat")
    q, vir, g = d["qm"].ravel(), d["vir"].ravel(), float(d["gtau"].ravel()[0])
    u = g * vir
    t = np.arange(q.size) * 1e-3
    rows = []

    c0 = time.process_time()
    r = idim_ls(q, u, 1000.0, ("coulomb", "offset"))
    rows.append(("IDIM-LS (benchmark)", dict(zip(r.names, r.theta, strict=True)),
                 dict(zip(r.names, r.std, strict=True)), time.process_time() - c0))
    c0 = time.process_time()
    f = fit_inverse_ml([(q, u)], 1000.0, ("coulomb", "offset"))
    rows.append(("IDIM-ML (sandwich sd)", dict(zip(f.model.names, f.theta, strict=True)),
                 dict(zip(f.model.names, np.sqrt(np.diag(f.cov_theta)), strict=True)), time.process_time() - c0))
    c0 = time.process_time()
    rec = {"t": t, "signals": {"qm": q, "force": u}, "meta": {"inputs": ["force"], "outputs": {"position": "qm"}}}
    res = identify_record(rec, seed=0, model="mbk", friction=("coulomb", "offset"))
    s = res.summary()
    rows.append((f"IDIM-ML + emcee ({res.posterior.diagnostics.n_steps} steps)", {k: v["median"] for k, v in s.items()},
                 {k: v["std"] for k, v in s.items()}, time.process_time() - c0))
    c0 = time.process_time()
    lin = fit_inverse_ml([(q, u)], 1000.0, ())
    rows.append(("linear (viscous only)", dict(zip(lin.model.names, lin.theta, strict=True)),
                 dict(zip(lin.model.names, np.sqrt(np.diag(lin.cov_theta)), strict=True)), time.process_time() - c0))

    print(f"EMPS (DATA_EMPS.mat, {q.size} samples at 1 kHz); load average {os.getloadavg()[0]:.2f} "
          f"on {os.cpu_count()} CPUs")
    print(f"{'method':<32} {'M [kg]':>16} {'B [N.s/m]':>18} {'F_c [N]':>16} {'F_0 [N]':>16} "
          f"{'dM %':>6} {'dB %':>6} {'dFc %':>6} {'dF0 N':>6} {'CPU s':>6} {'ratio':>6}")
    base = rows[0][3]
    for name, est, sd, cpu in rows:
        cells = [f"{est[k]:8.3f} ({sd[k]:.3f})" if k in est else f"{'-':>16}" for k in ("M", "B", "F_c", "F_0")]
        err = [100 * (est[k] / PUBLISHED[k] - 1) if k in est else float("nan") for k in ("M", "B", "F_c")]
        e0 = est["F_0"] - PUBLISHED["F_0"] if "F_0" in est else float("nan")
        print(f"{name:<32} {cells[0]:>16} {cells[1]:>18} {cells[2]:>16} {cells[3]:>16} "
              f"{err[0]:6.2f} {err[1]:6.2f} {err[2]:6.2f} {e0:6.3f} {cpu:6.2f} {cpu / base:6.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
