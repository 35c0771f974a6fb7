"""Regenerate the figures of the documentation (docs/img/) from the code, and record what they show.

    python docs/make_figures.py            # rewrites docs/img/*.png and docs/img/figures.json

* ``certificate_go_page1.png`` / ``certificate_nogo_page1.png``: page 1 of the PDF certificate of
  ``hil certify`` (the default scene ``sdea_bench``: GO) and ``hil certify bilateral_2dof_B`` (NO-GO),
  rasterized by poppler's ``pdftoppm`` at 60 dpi;
* ``sweep_sdea.png``: the map of ``hil sweep --model sdea --grid b22=0.01:0.21:41 --grid k22=50:450:41``.

``figures.json`` holds, per image, its SHA-256 and what it shows as text: page 1 of each
certificate (``pdftotext``, without the lines that change on every run: creation time, digests,
software versions) and the sweep's boundary (``boundary.csv``). ``tests/test_doc_figures.py`` checks
that the committed images are the ones recorded there and (slow) that the code still gives the same
text: a figure showing β = 70.06 when the code gives 68.02 fails it.

Needs the ``report`` extra and poppler-utils (``pdftoppm``, ``pdftotext``). Not imported by the package.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
IMG = ROOT / "docs" / "img"
CERTIFICATES = {"certificate_go_page1.png": "sdea_bench", "certificate_nogo_page1.png": "bilateral_2dof_B"}
SWEEP_ARGS = ["--model", "sdea", "--grid", "b22=0.01:0.21:41", "--grid", "k22=50:450:41"]
#: page-1 lines that change on every run (time, digests) or with the installed libraries
VOLATILE = ("created", "digest", "sha256", "numpy", "python 3")


def _tool(name: str) -> str:
    exe = shutil.which(name)
    if exe is None:
        raise SystemExit(f"{name} is not installed (apt-get install poppler-utils)")
    return exe


def page1_text(pdf: Path) -> str:
    """Page 1 of a certificate as text, one line per line, without the volatile lines."""
    text = subprocess.run([_tool("pdftotext"), "-layout", "-f", "1", "-l", "1", str(pdf), "-"], capture_output=True,
                          text=True, check=True, timeout=120).stdout
    lines = [" ".join(ln.split()) for ln in text.splitlines()]
    return "\n".join(ln for ln in lines if ln and not any(v in ln for v in VOLATILE))


def certificate(scene: str, work: Path) -> tuple[Path, str]:
    """Certify a built-in scene as ``hil certify SCENE`` does (its default seed): the PDF and page 1's text."""
    from hil.certify.pipeline import certify_scene
    from hil.report.render import build_reports
    from hil.scene.spec import load_scene

    out = work / scene
    cert = certify_scene(load_scene(scene), out)
    files = build_reports(cert, out)
    return Path(files["pdf"]), page1_text(Path(files["pdf"]))


def sweep(work: Path) -> tuple[Path, str]:
    """The sweep's map and its boundary (the CSV text)."""
    from hil.cli.main import main

    out = work / "sweep"
    code = main(["sweep", *SWEEP_ARGS, "--out", str(out), "--no-cache"])
    if code != 0:
        raise SystemExit(f"hil sweep exited {code}")
    return out / "sweep.png", (out / "boundary.csv").read_text(encoding="utf-8")


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def platform_fingerprint() -> dict[str, Any]:
    """What the figures' numbers depend on besides the code: numpy and scipy versions, the CPU
    architecture, the C library and the SIMD targets numpy dispatches to. Elsewhere, last-bit
    differences in BLAS and libm change emcee's accept/reject steps, so the posterior draws (and the
    numbers derived from them, e.g. β) move by their Monte Carlo error."""
    import platform

    import numpy as np
    import scipy

    try:
        simd = np.__config__.show(mode="dicts")["SIMD Extensions"]["found"]  # type: ignore[call-arg, index]
    except Exception:
        from numpy._core._multiarray_umath import __cpu_features__  # type: ignore[import-not-found]

        simd = sorted(k for k, v in __cpu_features__.items() if v)
    return {"numpy": np.__version__, "scipy": scipy.__version__, "machine": platform.machine(),
            "libc": " ".join(platform.libc_ver()), "numpy_simd": list(simd)}


def make(img: Path = IMG) -> dict[str, Any]:
    """Write the images into ``img`` and return the record (also written as ``figures.json``)."""
    img.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {"generated_by": "python docs/make_figures.py", "platform": platform_fingerprint(),
                              "images": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name, scene in CERTIFICATES.items():
            pdf, text = certificate(scene, work)
            stem = work / f"{scene}-page"
            subprocess.run([_tool("pdftoppm"), "-png", "-r", "60", "-f", "1", "-l", "1", "-singlefile", str(pdf),
                            str(stem)], check=True, timeout=120)
            shutil.copyfile(stem.with_suffix(".png"), img / name)
            record["images"][name] = {"shows": f"page 1 of hil certify {scene}", "sha256": _sha(img / name),
                                      "text": text}
        png, boundary = sweep(work)
        shutil.copyfile(png, img / "sweep_sdea.png")
        record["images"]["sweep_sdea.png"] = {"shows": "hil sweep " + " ".join(SWEEP_ARGS),
                                              "sha256": _sha(img / "sweep_sdea.png"), "text": boundary}
    (img / "figures.json").write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    return record


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    make()
    print("wrote", ", ".join(str(IMG / n) for n in [*CERTIFICATES, "sweep_sdea.png", "figures.json"]))
