"""Malformed inputs of every kind through ``hil.cli.main.main``: each one exits 2 with exactly one stderr
line naming the offending file or flag, and no traceback (issue 9, item 3).

The table lists (id, files to write, argv, strings the message must contain). File contents are
bytes or text; ``{d}`` in argv is the test's folder. Cases that need no hardware run in-process
with capsys; none of them runs an experiment (they are refused before anything starts).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from malformed_helpers import assert_one_line_error, run_cli

NET_OK = "type: impedance\nmatrix: [[{num: [1.0, 2.0], den: [1.0, 0.0]}]]\n"
CSV_OK = "t,v\n0.000,1\n0.001,2\n0.002,3\n0.003,4\n"
RANDOM = bytes(np.random.default_rng(7).integers(0, 256, 400, dtype=np.uint8))


def net(matrix: str, extra: str = "type: impedance\n") -> str:
    return f"{extra}matrix: {matrix}\n"


# (id, {file name: content}, argv, must_contain)
CASES: list[tuple[str, dict[str, str | bytes], list[str], list[str]]] = [
    # ---- network files: hil stability FILE
    ("net-not-utf8", {"n.yaml": b"type: impedance\nname: caf\xe9\n"}, ["stability", "{d}/n.yaml"], ["n.yaml", "UTF-8"]),
    ("net-binary", {"n.yaml": RANDOM}, ["stability", "{d}/n.yaml"], ["n.yaml", "binary"]),
    ("net-directory", {"n.yaml/x": "1"}, ["stability", "{d}/n.yaml"], ["n.yaml", "folder"]),
    ("net-missing", {}, ["stability", "{d}/missing.yaml"], ["missing.yaml", "no such file"]),
    ("net-empty", {"n.yaml": ""}, ["stability", "{d}/n.yaml"], ["n.yaml"]),
    ("net-top-list", {"n.yaml": "- 1\n- 2\n"}, ["stability", "{d}/n.yaml"], ["n.yaml", "mapping"]),
    ("net-bad-yaml", {"n.yaml": "type: [impedance\nmatrix: 1\n"}, ["stability", "{d}/n.yaml"], ["n.yaml", "YAML"]),
    ("net-bad-json", {"n.json": '{"type": "impedance", "matrix": [[{"num": [1]}]'}, ["stability", "{d}/n.json"],
     ["n.json", "JSON"]),
    ("net-string-coef", {"n.yaml": net("[[{num: ['1', '2']}]]")}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "matrix[0][0].num", "'1'"]),
    ("net-bool-coef", {"n.yaml": net("[[{num: [true, false]}]]")}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "matrix[0][0].num", "True"]),
    ("net-1e308", {"n.yaml": net("[[{num: [1e308, 1.0], den: [1.0, 0.0]}]]")}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "too large"]),
    ("net-huge-int-json", {"n.json": '{"matrix": [[{"num": [1' + "0" * 400 + ', 1]}]]}'},
     ["stability", "{d}/n.json"], ["n.json", "too large"]),
    ("net-nan", {"n.yaml": net("[[{num: [.nan, 1.0]}]]")}, ["stability", "{d}/n.yaml"], ["n.yaml", "finite"]),
    ("net-inf", {"n.yaml": net("[[{num: [1.0], den: [-.inf, 1.0]}]]")}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "matrix[0][0].den"]),
    ("net-wide-range", {"n.yaml": net("[[{num: [1e90, 1e-90], den: [1e-90, 1e90]}, {num: [1e90]}], "
                                      "[{num: [1e-90, 1e90, 3]}, {num: [1e90, 1], den: [1e-90, 3]}]]")},
     ["stability", "{d}/n.yaml"], ["n.yaml", "rescale"]),
    ("net-empty-matrix", {"n.yaml": net("[]")}, ["stability", "{d}/n.yaml"], ["n.yaml", "matrix"]),
    ("net-not-square", {"n.yaml": net("[[{num: [1]}, {num: [1]}]]")}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "square"]),
    ("net-zero-den", {"n.yaml": net("[[{num: [1], den: [0, 0]}]]")}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "den"]),
    ("net-empty-num", {"n.yaml": net("[[{num: [], den: [1]}]]")}, ["stability", "{d}/n.yaml"], ["n.yaml", "num"]),
    ("net-missing-num", {"n.yaml": net("[[{den: [1]}]]")}, ["stability", "{d}/n.yaml"], ["n.yaml", "num"]),
    ("net-num-string", {"n.yaml": net("[[{num: '1 2'}]]")}, ["stability", "{d}/n.yaml"], ["n.yaml", "num"]),
    ("net-typo-key", {"n.yaml": "type: impedance\nmatrx: [[{num: [1]}]]\n"}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "unknown key 'matrx'", "did you mean 'matrix'"]),
    ("net-typo-entry-key", {"n.yaml": net("[[{num: [1], dem: [1]}]]")}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "'dem'", "'den'"]),
    ("net-bad-type", {"n.yaml": net("[[{num: [1]}]]", "type: impedence\n")}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "type"]),
    ("net-bad-criterion", {"n.yaml": net("[[{num: [1]}]]", "criterion: stable\n")}, ["stability", "{d}/n.yaml"],
     ["n.yaml", "criterion"]),
    ("net-duplicate-key", {"n.yaml": "type: impedance\ntype: admittance\nmatrix: [[{num: [1]}]]\n"},
     ["stability", "{d}/n.yaml"], ["n.yaml", "duplicate key 'type'"]),
    ("net-bad-ports", {"n.yaml": net("[[{num: [1]}, {num: [0]}], [{num: [0]}, {num: [1]}]]",
                                     "type: impedance\nports: [1, 5]\n")}, ["stability", "{d}/n.yaml"], ["n.yaml"]),
    ("net-with-set", {"n.yaml": NET_OK}, ["stability", "{d}/n.yaml", "--set", "M=1"], ["--set"]),
    # ---- built-in models and flags: hil stability --model
    ("model-set-not-number", {}, ["stability", "--model", "sdea", "--set", "M=abc"], ["--set M=abc", "number"]),
    ("model-set-inf", {}, ["stability", "--model", "sdea", "--set", "M=inf"], ["--set M=inf", "finite"]),
    ("model-set-negative-mass", {}, ["stability", "--model", "sdea", "--set", "M=-1"], ["--model sdea", "M"]),
    ("model-set-no-equals", {}, ["stability", "--model", "sdea", "--set", "M"], ["--set", "NAME=VALUE"]),
    ("model-set-unknown", {}, ["stability", "--model", "sdea", "--set", "K22=1"], ["--set K22=1", "'k22'"]),
    ("model-gains-unknown", {}, ["stability", "--model", "bilateral_2dof", "--set", "gains=Z"],
     ["--set", "gains", "A1, A2, B", "'Z'"]),
    ("model-unknown", {}, ["stability", "--model", "sdae"], ["--model sdae", "'sdea'"]),
    ("model-and-file", {"n.yaml": NET_OK}, ["stability", "{d}/n.yaml", "--model", "sdea"], ["--model"]),
    ("stability-nothing", {}, ["stability"], ["--model"]),
    ("stability-bad-criterion", {}, ["stability", "--model", "sdea", "--criterion", "nyquist"], ["--criterion"]),
    ("stability-unknown-flag", {}, ["stability", "--model", "sdea", "--bogus"], ["--bogus"]),
    # ---- hil design
    ("design-b22-negative", {}, ["design", "--b22", "-1"], ["--b22 -1", "positive"]),
    ("design-b22-zero", {}, ["design", "--b22", "0"], ["--b22 0"]),
    ("design-b22-nan", {}, ["design", "--b22", "nan"], ["--b22 nan"]),
    ("design-b22-inf", {}, ["design", "--b22", "inf"], ["--b22 inf"]),
    ("design-alpha-above-1", {}, ["design", "--alpha", "1.5"], ["--alpha 1.5", "[0, 1]"]),
    ("design-alpha-negative", {}, ["design", "--b22", "0.1", "--alpha", "-0.1"], ["--alpha -0.1"]),
    ("design-alpha-not-number", {}, ["design", "--alpha", "x"], ["--alpha", "'x'"]),
    ("design-set-not-number", {}, ["design", "--set", "M=abc"], ["--set M=abc"]),
    ("design-set-design-variable", {}, ["design", "--set", "k22=3"], ["--set k22=3"]),
    ("design-bad-criterion", {}, ["design", "--criterion", "llewellyn"], ["--criterion"]),
    ("design-alpha-and-optimize", {}, ["design", "--alpha", "0.5", "--optimize-alpha"], ["--optimize-alpha"]),
    # ---- hil run / hil certify: flags and output folders (refused before anything runs)
    ("run-missing-scene", {}, ["run", "{d}/nope.yaml"], ["nope.yaml"]),
    ("run-scene-not-utf8", {"s.yaml": b"name: caf\xe9\n"}, ["run", "{d}/s.yaml"], ["s.yaml"]),
    ("run-scene-binary", {"s.yaml": RANDOM}, ["run", "{d}/s.yaml"], ["s.yaml"]),
    ("run-scene-directory", {"s.yaml/x": "1"}, ["run", "{d}/s.yaml"], ["s.yaml"]),
    ("run-scene-bad-yaml", {"s.yaml": "name: [x\n"}, ["run", "{d}/s.yaml"], ["s.yaml"]),
    ("run-scene-no-devices", {"s.yaml": "name: x\nrate_hz: 1000\n"}, ["run", "{d}/s.yaml"], ["s.yaml", "devices"]),
    ("run-scene-negative-rate", {"s.yaml": "name: x\nrate_hz: -5\ndevices: []\nexperiments: []\n"},
     ["run", "{d}/s.yaml"], ["s.yaml", "rate_hz"]),
    ("run-scene-unknown-target", {"s.yaml": "SCENE:target: motor=target: motr"}, ["run", "{d}/s.yaml"],
     ["s.yaml", "'motr'", "'motor'"]),
    ("certify-scene-unknown-target", {"s.yaml": "SCENE:target: motor=target: motr"}, ["certify", "{d}/s.yaml"],
     ["s.yaml", "'motr'"]),
    ("run-seed-not-int", {}, ["run", "sdea_bench", "--seed", "x"], ["--seed", "'x'"]),
    ("run-seed-negative", {}, ["run", "sdea_bench", "--seed", "-5"], ["--seed", "got -5"]),
    ("run-experiment-index", {}, ["run", "sdea_bench", "--experiment", "9"], ["--experiment 9"]),
    ("run-experiment-type", {}, ["run", "sdea_bench", "--experiment", "sine"], ["--experiment sine"]),
    ("run-realtime-and-lockstep", {}, ["run", "sdea_bench", "--realtime", "--lockstep"], ["--lockstep"]),
    ("run-out-under-file", {"f": "x"}, ["run", "sdea_bench", "--out", "{d}/f/out"], ["f/out", "is a file"]),
    ("run-out-is-file", {"f": "x"}, ["run", "sdea_bench", "--out", "{d}/f"], ["/f", "not a folder"]),
    ("run-out-not-empty", {"o/00_chirp_locked.h5": "x"}, ["run", "sdea_bench", "--out", "{d}/o"],
     ["/o", "--overwrite"]),
    ("run-out-missing-value", {}, ["run", "sdea_bench", "--out"], ["--out"]),
    ("certify-out-not-empty", {"o/certificate.json": "{}"}, ["certify", "--out", "{d}/o"], ["/o", "--overwrite"]),
    ("certify-out-under-file", {"f": "x"}, ["certify", "--out", "{d}/f/r"], ["f/r"]),
    ("certify-seed-negative", {}, ["certify", "--seed", "-1"], ["--seed", "got -1"]),
    ("certify-missing-scene", {}, ["certify", "{d}/nope.yaml"], ["nope.yaml"]),
    # ---- hil import: CSV and .mat
    ("import-csv-binary", {"r.csv": RANDOM}, ["import", "{d}/r.csv"], ["r.csv", "binary"]),
    ("import-csv-not-utf8", {"r.csv": b"t,v\n0,1\n1,caf\xe9\n"}, ["import", "{d}/r.csv"], ["r.csv", "UTF-8"]),
    ("import-csv-ragged", {"r.csv": "t,v\n0,1\n1,2,3\n"}, ["import", "{d}/r.csv"], ["r.csv:3"]),
    ("import-csv-text-cell", {"r.csv": "t,v\n0,1\n1,abc\n"}, ["import", "{d}/r.csv"], ["r.csv:3", "'abc'"]),
    ("import-csv-no-time", {"r.csv": "a,b\n0,1\n1,2\n"}, ["import", "{d}/r.csv"], ["r.csv", "--time"]),
    ("import-csv-time-decreasing", {"r.csv": "t,v\n0,1\n2,2\n1,3\n"}, ["import", "{d}/r.csv"],
     ["r.csv", "decreases"]),
    ("import-csv-one-row", {"r.csv": "t,v\n0,1\n"}, ["import", "{d}/r.csv"], ["r.csv", "2 samples"]),
    ("import-csv-empty", {"r.csv": ""}, ["import", "{d}/r.csv"], ["r.csv", "empty"]),
    ("import-csv-duplicate-columns", {"r.csv": "t,v,v\n0,1,2\n1,2,3\n"}, ["import", "{d}/r.csv"],
     ["r.csv", "duplicate"]),
    ("import-map-missing-column", {"r.csv": CSV_OK}, ["import", "{d}/r.csv", "--time", "t", "--map", "x=nope"],
     ["r.csv", "'nope'"]),
    ("import-map-bad", {"r.csv": CSV_OK}, ["import", "{d}/r.csv", "--map", "x"], ["--map"]),
    ("import-sidecar-missing", {"r.csv": CSV_OK}, ["import", "{d}/r.csv", "--sidecar", "{d}/side.yaml"],
     ["side.yaml"]),
    ("import-sidecar-binary", {"r.csv": CSV_OK, "side.yaml": RANDOM},
     ["import", "{d}/r.csv", "--sidecar", "{d}/side.yaml"], ["side.yaml"]),
    ("import-out-exists", {"r.csv": CSV_OK, "r.h5": "old"}, ["import", "{d}/r.csv"], ["r.h5", "--overwrite"]),
    ("import-out-is-folder", {"r.csv": CSV_OK, "o/x": "1"}, ["import", "{d}/r.csv", "--out", "{d}/o"],
     ["/o", "folder"]),
    ("import-sidecar-bad-yaml", {"r.csv": CSV_OK, "side.yaml": "x: [\n"},
     ["import", "{d}/r.csv", "--sidecar", "{d}/side.yaml"], ["side.yaml", "sidecar"]),
    ("import-out-under-file", {"r.csv": CSV_OK, "f": "x"}, ["import", "{d}/r.csv", "--out", "{d}/f/r.h5"],
     ["f/r.h5"]),
    ("import-wrong-extension", {"r.xlsx": "x"}, ["import", "{d}/r.xlsx"], ["r.xlsx", ".csv"]),
    ("import-directory", {"r.csv/x": "1"}, ["import", "{d}/r.csv"], ["r.csv", "folder"]),
    ("import-mat-garbage", {"r.mat": RANDOM}, ["import", "{d}/r.mat"], ["r.mat", "not a readable .mat"]),
    ("import-mat-empty", {"r.mat": b""}, ["import", "{d}/r.mat"], ["r.mat"]),
    ("import-mat-no-time", {"r.mat": "MAT:a,b"}, ["import", "{d}/r.mat"], ["r.mat", "--time"]),
    # --sidecar is accepted for .mat (issue 25 defect 4): a missing one is named
    ("import-mat-sidecar-missing", {"r.mat": "MAT:t,v"}, ["import", "{d}/r.mat", "--sidecar", "{d}/s.yaml"],
     ["s.yaml", "no such sidecar"]),
    ("import-scale-not-a-number", {"r.csv": CSV_OK}, ["import", "{d}/r.csv", "--scale", "v=abc"],
     ["--scale", "v=abc", "number"]),
    ("import-scale-unmapped", {"r.csv": CSV_OK}, ["import", "{d}/r.csv", "--scale", "nope=2"],
     ["--scale nope", "no such channel"]),
    ("import-unit-unknown", {"r.csv": CSV_OK}, ["import", "{d}/r.csv", "--unit", "v=furlongz"],
     ["r.csv", "unknown unit 'furlongz'"]),
    ("import-unit-offset", {"r.csv": CSV_OK}, ["import", "{d}/r.csv", "--unit", "v=degC"], ["'degC'", "offset"]),
    ("import-unit-time-not-time", {"r.csv": CSV_OK}, ["import", "{d}/r.csv", "--unit", "t=mm"],
     ["t: unit 'mm' is not a unit of time"]),
    # ---- hil identify: records and flags
    ("identify-missing", {}, ["identify", "{d}/missing.h5"], ["missing.h5"]),
    ("identify-h5-garbage", {"r.h5": RANDOM}, ["identify", "{d}/r.h5"], ["r.h5"]),
    ("identify-h5-empty", {"r.h5": b""}, ["identify", "{d}/r.h5"], ["r.h5"]),
    ("identify-csv-binary", {"r.csv": RANDOM}, ["identify", "{d}/r.csv"], ["r.csv", "binary"]),
    ("identify-csv-not-utf8", {"r.csv": b"t,v\n0,\xff\n"}, ["identify", "{d}/r.csv"], ["r.csv", "UTF-8"]),
    ("identify-mat-garbage", {"r.mat": RANDOM}, ["identify", "{d}/r.mat"], ["r.mat"]),
    ("identify-npz-garbage", {"r.npz": RANDOM}, ["identify", "{d}/r.npz"], ["r.npz", "not a readable .npz"]),
    ("identify-npz-empty", {"r.npz": b""}, ["identify", "{d}/r.npz"], ["r.npz"]),
    ("identify-npz-missing", {}, ["identify", "{d}/r.npz"], ["r.npz", "no such file"]),
    ("identify-directory", {"r.h5/x": "1"}, ["identify", "{d}/r.h5"], ["r.h5", "folder"]),
    ("identify-set-not-number", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--set", "M=abc"], ["--set M=abc"]),
    ("identify-set-no-equals", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--set", "M"], ["--set"]),
    ("identify-band-reversed", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--band", "10", "1"], ["--band"]),
    ("identify-band-nan", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--band", "nan", "1"], ["--band"]),
    ("identify-period-negative", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--period", "-1"], ["--period"]),
    ("identify-seed-negative", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--seed", "-1"], ["--seed"]),
    ("identify-max-seconds-zero", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--max-seconds", "0"],
     ["--max-seconds"]),
    ("identify-resolution-bogus", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--resolution", "float99"],
     ["--resolution float99"]),
    ("identify-noise-bogus", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--noise", "pink"], ["--noise"]),
    ("identify-out-for-h5", {"r.h5": RANDOM}, ["identify", "{d}/r.h5", "--out", "{d}/x.h5"], ["--out"]),
    ("identify-out-exists", {"r.csv": CSV_OK, "x.h5": "old"}, ["identify", "{d}/r.csv", "--out", "{d}/x.h5"],
     ["x.h5", "--overwrite"]),
    ("identify-output-bad", {"r.csv": CSV_OK}, ["identify", "{d}/r.csv", "--output", "force"], ["--output"]),
    ("identify-debug-before", {}, ["--debug", "identify", "{d}/missing.h5"], ["missing.h5"]),
    # ---- hil replay / hil report
    ("export-missing", {}, ["export", "{d}/missing.h5", "--format", "mcap"], ["missing.h5"]),
    ("export-garbage", {"r.h5": RANDOM}, ["export", "{d}/r.h5", "--format", "csv"], ["r.h5"]),
    ("export-bad-format", {"r.h5": RANDOM}, ["export", "{d}/r.h5", "--format", "xlsx"], ["--format", "xlsx"]),
    ("import-list-with-map", {"r.csv": CSV_OK}, ["import", "{d}/r.csv", "--list", "--map", "x=v"], ["--list"]),
    ("import-bag-folder-without-metadata", {"b/x.db3": "x"}, ["import", "{d}/b"], ["folder", "metadata.yaml"]),
    ("import-tdms-garbage", {"r.tdms": RANDOM}, ["import", "{d}/r.tdms", "--map", "x=g/c"], ["r.tdms"]),
    ("import-mcap-garbage", {"r.mcap": RANDOM}, ["import", "{d}/r.mcap", "--map", "x=/a:b"], ["r.mcap", "MCAP"]),
    ("import-bag-garbage", {"r.bag": RANDOM}, ["import", "{d}/r.bag", "--map", "x=/a:b"], ["r.bag", "ROS bag"]),
    ("import-hdf5-garbage", {"r.hdf5": RANDOM}, ["import", "{d}/r.hdf5", "--map", "x=/a"], ["r.hdf5", "HDF5"]),
    ("import-mat73-garbage", {"r.mat": b"\x89HDF\r\n\x1a\n" + RANDOM}, ["import", "{d}/r.mat"], ["r.mat"]),
    ("replay-missing", {}, ["replay", "{d}/missing.h5"], ["missing.h5"]),
    ("replay-garbage", {"r.h5": RANDOM}, ["replay", "{d}/r.h5"], ["r.h5"]),
    ("replay-empty", {"r.h5": b""}, ["replay", "{d}/r.h5"], ["r.h5"]),
    ("report-missing", {}, ["report", "{d}/nothing"], ["nothing"]),
    ("report-malformed", {"c/certificate.json": '{"decision": "GO", "reasons": 3}'}, ["report", "{d}/c"],
     ["certificate.json"]),
    ("report-out-not-empty", {"c/certificate.json": "{}", "o/report.html": "other"},
     ["report", "{d}/c", "--out", "{d}/o"], ["/o", "--overwrite"]),
    ("report-out-under-file", {"c/certificate.json": "{}", "f": "x"}, ["report", "{d}/c", "--out", "{d}/f/r"],
     ["f/r"]),
    # ---- hil mock serve (argument errors; nothing is started)
    ("mock-duration-negative", {}, ["mock", "serve", "sdea_bench", "--duration", "-1"], ["--duration"]),
    ("mock-duration-not-number", {}, ["mock", "serve", "sdea_bench", "--duration", "x"], ["--duration"]),
    ("mock-spec-garbage", {}, ["mock", "serve", "--spec", "garbage"], ["--spec"]),
    ("mock-scene-and-spec", {}, ["mock", "serve", "sdea_bench", "--spec", "[]"], ["--spec"]),
    ("mock-can-channel-bad", {}, ["mock", "serve", "sdea_bench", "--can-channel", "x"], ["--can-channel"]),
    ("mock-stream-rate-zero", {}, ["mock", "serve", "sdea_bench", "--stream-rate", "0"], ["--stream-rate"]),
    ("mock-seed-negative", {}, ["mock", "serve", "sdea_bench", "--seed", "-2"], ["--seed"]),
    ("mock-missing-scene", {}, ["mock", "serve", "{d}/nope.yaml"], ["nope.yaml"]),
    ("mock-no-serve", {}, ["mock", "start"], ["serve"]),
    ("mock-debug-before", {}, ["--debug", "mock", "serve", "--duration", "-1"], ["--duration"]),
    # ---- issue 28: inputs that used to fail badly (MemoryError, a hang, a misleading stop, an empty folder)
    ("scene-duration-1e9", {"s.yaml": "SCENE:duration: 16.0=duration: 1.0e9"}, ["run", "{d}/s.yaml"],
     ["s.yaml", "experiments[0].duration", "1e+09 s", "GiB"]),
    ("certify-duration-1e9", {"s.yaml": "SCENE:duration: 16.0=duration: 1.0e9"}, ["certify", "{d}/s.yaml"],
     ["s.yaml", "experiments[0].duration", "ticks"]),
    ("stability-dev-zero", {}, ["stability", "/dev/zero"], ["/dev/zero", "larger than"]),
    ("run-dev-zero", {}, ["run", "/dev/zero"], ["zero: cannot read", "larger than"]),
    ("certify-dev-zero", {}, ["certify", "/dev/zero"], ["zero: cannot read", "larger than"]),
    ("scene-watchdog-below-a-tick", {"s.yaml": "SCENE:watchdog_ms: 50=watchdog_ms: 0.01"}, ["run", "{d}/s.yaml"],
     ["s.yaml", "safety.watchdog_ms", "one tick"]),
    ("run-no-experiments", {"s.yaml": "SCENEPOP:experiments,certification"}, ["run", "{d}/s.yaml"],
     ["s.yaml", "no experiments"]),
    ("certify-no-certification", {"s.yaml": "SCENEPOP:certification"}, ["certify", "{d}/s.yaml"],
     ["s.yaml", "no 'certification' section"]),
    ("scene-50mb-list-under-unknown-key", {"s.yaml": "BIG:name: x\njunk:\n"}, ["run", "{d}/s.yaml"],
     ["s.yaml", "larger than 1 MiB"]),
    ("run-real-devices-absent", {"s.yaml": "SCENEPOP:simulation,certification;REAL"}, ["run", "{d}/s.yaml"],
     ["s.yaml", "could not be opened", "no experiment ran"]),
    ("certify-real-devices-absent", {"s.yaml": "SCENEPOP:simulation;REAL"}, ["certify", "{d}/s.yaml", "--json"],
     ["could not be opened", "no experiment ran"]),
    # ---- top level
    ("unknown-command", {}, ["certfy"], ["certfy"]),
    ("debug-unknown-command", {}, ["--debug", "bogus"], ["bogus"]),
]


def _write(d: Path, files: dict[str, str | bytes]) -> None:
    for name, content in files.items():
        p = d / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, str) and content.startswith("SCENE:"):  # the built-in sdea_bench with one edit
            import hil.scene.spec

            old, new = content[6:].split("=", 1)
            text = (Path(hil.scene.spec.__file__).parent / "builtin" / "sdea_bench.yaml").read_text()
            assert old in text
            p.write_text(text.replace(old, new, 1))
        elif isinstance(content, str) and content.startswith("SCENEPOP:"):  # sdea_bench without these sections
            import yaml

            from hil.scene.spec import load_scene

            keys, _, real = content[9:].partition(";")
            d = yaml.safe_load(load_scene("sdea_bench").source_text)
            for k in keys.split(","):
                d.pop(k, None)
            if real:  # real devices: no simulated twins, a CAN interface this machine does not have
                for dev in d["devices"]:
                    dev.pop("body", None)
                    dev.pop("sim", None)
                d["devices"][0]["params"].update(interface="socketcan", channel="hil_absent0")
            p.write_text(yaml.safe_dump(d, sort_keys=False), encoding="utf-8")
        elif isinstance(content, str) and content.startswith("BIG:"):  # a YAML list of 50 MB
            with open(p, "w", encoding="utf-8") as f:
                f.write(content[4:].replace("\\n", "\n"))
                f.write("  - 1.2345\n" * 5_000_000)
        elif isinstance(content, str) and content.startswith("MAT:"):
            from scipy.io import savemat

            savemat(p, {k: np.arange(5.0) for k in content[4:].split(",")})
        elif isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content, encoding="utf-8")


def test_the_table_is_large_enough() -> None:
    assert len(CASES) >= 60
    assert len({c[0] for c in CASES}) == len(CASES)


@pytest.mark.timeout(60)
@pytest.mark.parametrize(("files", "argv", "must"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_malformed_input_gives_one_line_and_exit_2(tmp_path, capsys, monkeypatch, files, argv, must) -> None:
    monkeypatch.chdir(tmp_path)  # default output folders (runs/, reports/) would land here
    monkeypatch.setenv("HIL_PROGRESS_SECONDS", "600")  # progress lines of a slow machine are not errors
    _write(tmp_path, files)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert_one_line_error([a.replace("{d}", str(tmp_path)) for a in argv], capsys, must)
    after = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert after == before, "a refused command must leave nothing on disk"


# ---------------------------------------------------------------------------------------------- beyond the table


def test_unreadable_file_is_one_line(tmp_path, capsys) -> None:
    if os.geteuid() == 0:
        pytest.skip("root reads every file")
    f = tmp_path / "n.yaml"
    f.write_text("type: impedance\nmatrix: [[{num: [1]}]]\n")
    f.chmod(0)
    assert_one_line_error(["stability", str(f)], capsys, ["n.yaml", "permission"])


def test_unwritable_out_is_one_line(tmp_path, capsys) -> None:
    if os.geteuid() == 0:
        pytest.skip("root writes everywhere")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    assert_one_line_error(["run", "sdea_bench", "--out", str(ro / "x")], capsys, ["ro/x", "permission"])


def test_unexpected_exception_is_one_line_exit_1_and_traceback_only_with_debug(capsys, monkeypatch) -> None:
    import hil.cli.scenes as cli_scenes

    def boom(args):  # stands for a bug
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(cli_scenes, "run", boom)
    line = assert_one_line_error(["scenes"], capsys, ["internal error", "ZeroDivisionError", "--debug"], code=1)
    assert line.startswith("hil scenes: error:")
    code, _out, err = run_cli(["--debug", "scenes"], capsys)
    assert code == 1 and "Traceback" in err and "ZeroDivisionError" in err


def test_debug_works_before_passthrough_subcommands(tmp_path, capsys) -> None:
    # before the fix these printed the top-level help and exited 2 without a word about the file
    line = assert_one_line_error(["--debug", "identify", str(tmp_path / "x.h5")], capsys, "x.h5")
    assert line.startswith("hil identify: error:")
    line = assert_one_line_error(["--debug", "mock", "serve", "sdea_bench", "--duration", "-1"], capsys, "--duration")
    assert line.startswith("hil mock serve: error:")
    code, out, _err = run_cli(["--debug", "stability", "--model", "sdea", "--json"], capsys)
    assert code == 0 and json.loads(out)["verdict"] == "stable"


def test_quoted_numbers_are_refused_but_yaml_exponents_are_numbers(tmp_path, capsys) -> None:
    # PyYAML reads 3.96e4 (no sign in the exponent) as a string; it must still be the number 39600
    f = tmp_path / "n.yaml"
    f.write_text("type: impedance\nmatrix: [[{num: [3.96e4, 1e3], den: [1, 0]}]]\n")
    from hil.scene.netfile import load_network

    tm, _ = load_network(f)
    z = tm.entries[0][0]
    assert z(1j) == pytest.approx((3.96e4 * 1j + 1e3) / 1j)
    code, out, err = run_cli(["stability", str(f), "--json"], capsys)
    assert code == 0 and json.loads(out)["verdict"] == "stable" and err == ""


def test_model_parameters_are_checked_in_the_api_too() -> None:
    from hil.errors import ModelError
    from hil.models import get_model

    with pytest.raises(ModelError, match="gains must be one of"):
        get_model("bilateral_2dof").build(gains="Z")
    with pytest.raises(ModelError, match="M must be a number"):
        get_model("sdea").build(M="abc")
    with pytest.raises(ModelError, match="must be a number"):
        get_model("sdea").build(M=True)
    from hil.models.teleop import bilateral_2dof

    with pytest.raises(ModelError, match="unknown gain set 'Z'"):
        bilateral_2dof("Z")


def test_design_api_refuses_bad_inputs() -> None:
    from hil.errors import ModelError
    from hil.models.design import k22_max, optimize_coupler

    for b22 in (-1.0, 0.0, float("nan"), float("inf")):
        with pytest.raises(ModelError, match="b22"):
            k22_max(b22)
    for alpha in (-0.1, 1.5, float("nan")):
        with pytest.raises(ModelError, match="alpha"):
            k22_max(0.17, alpha)
        with pytest.raises(ModelError, match="alpha"):
            optimize_coupler("passivity", alpha)
    with pytest.raises(ModelError, match="b22 bounds"):
        optimize_coupler("passivity", 1.0, b22_bounds=(0.5, 0.1))


def _record(path: Path, n: int = 4000, closed: bool = True) -> Path:
    """A small run record: a periodic input and its response, 1 kHz."""
    from hil.record.hdf5 import ChannelSpec, RecordWriter

    t = np.arange(n) / 1000.0
    u = np.sin(2 * np.pi * 5 * t)
    specs = {"motor.effort_cmd": ChannelSpec((), "N", ""), "motor.velocity": ChannelSpec((), "m/s", "")}
    w = RecordWriter(path, scene_text="", scene_sha256="", meta={}, rate_hz=1000.0, channels=specs)
    w.append_block(t, {"motor.effort_cmd": u, "motor.velocity": 0.1 * u})
    if closed:
        w.close(stop_reason="completed", status="ok")
    return path


@pytest.mark.parametrize("argv", [["replay", "{r}"],
                                  ["identify", "{r}", "--model", "mbk", "--input", "motor.effort_cmd", "--output",
                                   "velocity_0=motor.velocity", "--period", "1"]])
def test_a_record_with_a_channel_cut_short_is_refused(tmp_path, capsys, argv) -> None:
    """A closed record whose one channel holds half the samples (edited, or damaged) is refused in one
    line naming the channel; ``hil replay`` and ``hil identify`` accepted it, truncating every
    channel to the shortest."""
    import h5py

    rec = _record(tmp_path / "r.h5")
    with h5py.File(rec, "a") as f:
        f["channels"]["motor.velocity"].resize(2000, axis=0)
    line = assert_one_line_error([a.replace("{r}", str(rec)) for a in argv], capsys,
                                 ["r.h5", "channel motor.velocity has 2000 samples but the time column 4000"])
    assert "damaged or altered" in line


def test_an_intact_record_is_read_whole(tmp_path, capsys) -> None:
    from hil.record.hdf5 import RunRecord

    rec = _record(tmp_path / "r.h5")
    assert RunRecord.open(rec).t.size == 4000
    code, out, _ = run_cli(["replay", str(rec)], capsys)
    assert code == 0 and "4000" in out


def test_a_csv_timed_in_milliseconds_warns(tmp_path, capsys, caplog) -> None:
    """Time in ms read as seconds gives a 1 Hz record: imported (the data may be right), with a warning
    naming the rate and the fix."""
    import logging

    csv = tmp_path / "ms.csv"
    csv.write_text("time,force,vel\n" + "\n".join(f"{k},{np.sin(k / 10):.6f},{np.cos(k / 10):.6f}" for k in range(200)))
    with caplog.at_level(logging.WARNING, logger="hil.record.importers"):
        code, _, _ = run_cli(["import", str(csv), "--map", "motor.effort_cmd=force", "--map", "motor.velocity=vel"],
                             capsys)
    assert code == 0
    msgs = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert any("sample rate of 1 Hz, implausible" in m and "--unit t=ms" in m for m in msgs), msgs
    caplog.clear()
    ok = tmp_path / "s.csv"
    ok.write_text("time,force,vel\n" + "\n".join(f"{k / 1000},{k},{k}" for k in range(200)))
    with caplog.at_level(logging.WARNING, logger="hil.record.importers"):
        assert run_cli(["import", str(ok), "--map", "motor.effort_cmd=force", "--map", "motor.velocity=vel"],
                       capsys)[0] == 0
    assert not [r for r in caplog.records if "implausible" in r.getMessage()]
