"""Benchmark: the reports of a certificate, each figure drawn once (issue 26, item 3).

For a stored certificate (``certificate.json``; default: a fresh ``hil certify --no-experiments``
of the default scene's plant known from its priors, which draws every figure but the FRFs), CPU time
of:

* **one draw** -- what ``hil certify`` / ``hil report`` do now: the PDF draws each figure on its
  page and the HTML shows those drawings (:func:`hil.report.render.build_reports`);
* **two draws** -- the former way, in the same run: ``render_html`` drawing its own PNG figures,
  then ``render_pdf`` drawing them again as vectors;
* **ERROR** -- the same certificate marked ERROR (its reports are short: no figures).

Run: ``python benchmarks/bench_reports.py [CERTIFICATE_DIR] [--repeat N]``. Not a test; prints a table
(CPU seconds, best of N, and the ratio to the two-draw baseline of the same run).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from hil.report.render import build_reports, load_certificate, render_html, render_pdf


def _cpu(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.process_time()
        fn()
        best = min(best, time.process_time() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("certificate", nargs="?", help="a certificate folder (default: certify sdea_bench's priors)")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if args.certificate:
            cert = load_certificate(args.certificate)
        else:
            import yaml

            from hil.certify.pipeline import certify_scene
            from hil.scene.spec import load_scene, scene_from_dict

            d = yaml.safe_load(load_scene("sdea_bench").source_text)
            d["experiments"] = []
            c = d["certification"]
            c.pop("identify")
            c["uncertain"] = {"M": {"value": 6.399e-4, "rel_std": 0.05}, "B": {"value": 0.169, "rel_std": 0.1}}
            cert = certify_scene(scene_from_dict(d, label="sdea_priors"), work / "c", run_experiments=False)
        n_fig = len(cert.plots)

        def one() -> None:
            build_reports(cert, work / "one")

        def two() -> None:
            render_html(cert, work / "two" / "report.html")
            render_pdf(cert, work / "two" / "report.pdf")

        error = cert.model_copy(update={"decision": "ERROR", "integrity": None})

        def short() -> None:
            build_reports(error, work / "error")

        base = _cpu(two, args.repeat)
        rows = [("two draws (before)", base), ("one draw (build_reports)", _cpu(one, args.repeat)),
                ("ERROR certificate", _cpu(short, args.repeat))]
    print(f"Reports of {cert.scene.name} ({n_fig} figures): CPU seconds, best of {args.repeat}")
    print(f"{'path':28s} {'CPU [s]':>8s} {'ratio':>7s}")
    for name, t in rows:
        print(f"{name:28s} {t:8.2f} {t / base:7.2f}")


if __name__ == "__main__":
    main()
