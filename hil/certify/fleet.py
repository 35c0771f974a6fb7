"""Fleet certification: ``hil certify SCENE SCENE ...`` (or a folder of scenes) in parallel.

Each scene is certified by its own ``hil certify SCENE --out OUT/<name> --json`` process, so a
fleet run is, scene for scene, the same command a person would run alone (same records, same
certificate, same exit code); the fleet adds the scheduling, one summary table, ``index.html``
linking every report, and an exit code that is the worst decision (ERROR > NO-GO > MARGINAL > GO;
a scene whose run fails without a certificate counts as ERROR).

Where the files go: the worker (a local process or a remote Dask worker) runs ``hil certify`` in a
scratch folder of its own, naming the client's folder in the certificate and reports, and sends the
finished folder back as a tar archive; the client writes it at ``OUT/<name>`` as a unit (built in a
sibling, renamed into place; :func:`hil.record.outdir.stage_out_dir`). A relative ``--out`` is the
client's, and nothing stays on a worker's disk.

Scheduling: scenes with a simulated bench (``simulation:`` present) run in parallel on the
executor (:data:`hil.certify.sweep.EXECUTORS`: a local process pool by default, Dask with a scheduler
address). Scenes on real devices never share a transport: those naming the same CAN channel,
serial port or Modbus address form one group run one after another; distinct groups may run in
parallel with the rest.
"""

from __future__ import annotations

import html
import io
import json
import logging
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil.errors import DECISION_EXIT, HilError

logger = logging.getLogger(__name__)

__all__ = ["CERTIFICATE_FOLDER", "DECISION_ORDER", "FleetEntry", "FleetResult", "certify_fleet", "expand_scenes",
           "transport_groups"]

#: what ``hil certify`` writes into its folder (``--overwrite`` replaces a folder holding only these)
CERTIFICATE_FOLDER = ("certificate.json", "report.html", "report.pdf", "scene.yaml", "records")
#: worst last; the fleet's decision is the maximum
DECISION_ORDER = ("GO", "MARGINAL", "NO-GO", "ERROR")
_EXIT = DECISION_EXIT  # the one exit-code table (hil.errors)
#: device parameters that name a transport endpoint (two real scenes sharing one run in series)
_ENDPOINT_KEYS = ("channel", "port", "device", "url", "address", "host")


class FleetError(HilError, ValueError):
    """A fleet that cannot be set up (no scenes, a scene that does not load, duplicate names)."""


@dataclass
class FleetEntry:
    """One scene's outcome: decision, reasons, exit code of its ``hil certify``, folder, seconds."""

    scene: str
    name: str
    decision: str
    reasons: list[str]
    exit_code: int
    out: str
    seconds: float
    files: dict[str, str] = field(default_factory=dict)
    simulated: bool = True

    def to_dict(self) -> dict[str, Any]:
        return {"scene": self.scene, "name": self.name, "decision": self.decision, "reasons": self.reasons,
                "exit_code": self.exit_code, "out": self.out, "seconds": round(self.seconds, 3),
                "files": self.files, "simulated": self.simulated}


@dataclass
class FleetResult:
    entries: list[FleetEntry]
    out: Path

    @property
    def decision(self) -> str:
        return max((e.decision for e in self.entries), key=DECISION_ORDER.index, default="ERROR")

    @property
    def exit_code(self) -> int:
        return _EXIT[self.decision]

    def to_dict(self) -> dict[str, Any]:
        return {"decision": self.decision, "out": str(self.out), "scenes": [e.to_dict() for e in self.entries]}


def expand_scenes(items: Sequence[str]) -> list[str]:
    """Scene arguments with folders replaced by their ``*.yaml`` / ``*.yml`` files (sorted)."""
    out: list[str] = []
    for it in items:
        p = Path(it)
        if p.is_dir():
            found = sorted([*p.glob("*.yaml"), *p.glob("*.yml")])
            if not found:
                raise FleetError(f"{it}: the folder holds no scene files (*.yaml)")
            out.extend(str(f) for f in found)
        else:
            out.append(it)
    if not out:
        raise FleetError("give at least one scene")
    return out


def _endpoints(scene: Any) -> set[str]:
    eps = set()
    for d in scene.devices:
        for k in _ENDPOINT_KEYS:
            v = d.params.get(k)
            if v not in (None, ""):
                eps.add(f"{k}={v}")
    return eps


def transport_groups(scenes: Sequence[Any]) -> list[list[int]]:
    """Indices of the real-device scenes grouped so that scenes sharing a transport endpoint are
    in the same group (connected components); simulated scenes each form their own group."""
    parent = list(range(len(scenes)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    owner: dict[str, int] = {}
    for i, sc in enumerate(scenes):
        if sc.simulation is not None:
            continue
        for ep in _endpoints(sc):
            if ep in owner:
                parent[find(i)] = find(owner[ep])
            else:
                owner[ep] = i
    groups: dict[int, list[int]] = {}
    for i in range(len(scenes)):
        groups.setdefault(find(i), []).append(i)
    return sorted(groups.values())


def _default_sigint() -> None:
    """In the child ``hil certify``: SIGINT back to its default (the pool's workers ignore it, and an
    ignored signal would be inherited), so a Ctrl-C reaches every scene's own safe stop."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _certify_group(items: list[tuple[str, str, int | None, list[str]]]) -> list[dict[str, Any]]:
    """Run ``hil certify`` for each (scene, out, seed, extra args) one after another (a worker task):
    in a scratch folder of this worker, the certificate naming ``out`` (the client's absolute
    folder); the folder comes back as tar bytes (``"folder"``, None when nothing was written) and
    the scratch folder is removed."""
    results = []
    for scene, out, seed, extra in items:
        scratch = Path(tempfile.mkdtemp(prefix="hil-fleet-"))
        try:
            work = scratch / Path(out).name
            cmd = [sys.executable, "-m", "hil", "certify", scene, "--out", str(work), "--named-as", out, "--json",
                   *extra]
            if seed is not None:
                cmd += ["--seed", str(seed)]
            t0 = time.perf_counter()
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False, preexec_fn=_default_sigint)
            results.append({"scene": scene, "out": out, "work": str(work), "code": proc.returncode,
                            "stdout": proc.stdout, "stderr": proc.stderr, "seconds": time.perf_counter() - t0,
                            "folder": _pack(work)})
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
    return results


def _pack(folder: Path) -> bytes | None:
    """``folder``'s regular files and subfolders as an uncompressed tar (names relative to it; links
    and special files left out), or None when it does not exist."""
    if not folder.is_dir():
        return None
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for p in sorted(folder.rglob("*")):
            if p.is_symlink() or not (p.is_file() or p.is_dir()):
                continue
            tar.add(p, arcname=p.relative_to(folder).as_posix(), recursive=False)
    return buf.getvalue()


def _unpack(data: bytes, final: Path, overwrite: bool) -> None:
    """Write a folder sent by :func:`_pack` at ``final`` as a unit (staged sibling, renamed into
    place); only regular files and folders inside it are extracted (tarfile's ``data`` filter)."""
    from hil.record.outdir import stage_out_dir

    staged = stage_out_dir(final, default_stem=final.name, overwrite=overwrite, owned=CERTIFICATE_FOLDER)
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:") as tar:
            tar.extractall(staged.path, filter="data")
        staged.commit()
    except BaseException:
        staged.abandon()
        raise


def _entry(r: dict[str, Any], name: str, simulated: bool, overwrite: bool = False) -> FleetEntry:
    """The client's entry for a worker's result: the folder written at ``r["out"]`` (paths the worker
    reported under its scratch folder named there)."""
    try:
        doc = json.loads(r["stdout"]) if r["stdout"].strip() else None
    except json.JSONDecodeError:
        doc = None
    last = (r["stderr"].strip().splitlines() or [f"exit {r['code']} without a certificate"])[-1]
    if r.get("folder") is not None:
        try:
            _unpack(r["folder"], Path(r["out"]), overwrite)
        except (HilError, OSError, tarfile.TarError) as exc:
            return FleetEntry(r["scene"], name, "ERROR", [f"{r['out']}: cannot write the certificate folder: {exc}"],
                              r["code"], r["out"], r["seconds"], {}, simulated)
    if isinstance(doc, dict) and doc.get("decision") in DECISION_ORDER:
        work = Path(r.get("work") or r["out"])
        files = {}
        for k, v in (doc.get("files") or {}).items():
            p = Path(str(v))
            files[k] = str(Path(r["out"]) / p.relative_to(work)) if p.is_relative_to(work) else str(p)
        return FleetEntry(r["scene"], name, doc["decision"], list(doc.get("reasons", [])), r["code"], r["out"],
                          r["seconds"], files, simulated)
    return FleetEntry(r["scene"], name, "ERROR", [last], r["code"], r["out"], r["seconds"], {}, simulated)


def certify_fleet(scenes: Sequence[str], out_root: str | Path, *, executor: Any = None, seed: int | None = None,
                  extra_args: Sequence[str] = (),
                  progress: Callable[[int, int, FleetEntry], None] | None = None,
                  should_stop: Callable[[], bool] | None = None, overwrite: bool = False) -> FleetResult:
    """Certify every scene (names or files) into ``out_root/<scene name>``; see the module docstring.
    ``executor`` is a :class:`hil.certify.sweep.Executor` (default a local process pool). When
    ``should_stop()`` turns true no further scene is started (those running finish or stop on their
    own signal handling); the scenes not run are ERROR entries saying so, and the index is written.
    When the executor is lost (:class:`hil.certify.sweep.ExecutorLost`: no worker left, scheduler
    gone) the scenes not finished are ERROR entries naming it; the finished ones are written.
    ``overwrite``: a scene's existing certificate folder is replaced as a whole."""
    from hil.certify.sweep import ExecutorLost, ProcessExecutor
    from hil.scene.spec import load_scene

    args = expand_scenes(scenes)
    loaded = [load_scene(s) for s in args]  # every scene loads before anything runs
    names = [sc.name for sc in loaded]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise FleetError(f"two scenes share the name {dup[0]!r}: their report folders would collide")
    root = Path(out_root).absolute()  # the client's folder: a worker's working directory is not it
    groups = transport_groups(loaded)
    tasks = [([(args[i], str(root / names[i]), seed, list(extra_args)) for i in g],) for g in groups]
    ex = executor or ProcessExecutor()
    entries: dict[int, FleetEntry] = {}
    not_run = "not run: the fleet was stopped"
    try:
        for gi, results in ex.map_unordered(_certify_group, tasks):
            for i, r in zip(groups[gi], results, strict=True):
                entries[i] = _entry(r, names[i], loaded[i].simulation is not None, overwrite)
                if progress is not None:
                    progress(len(entries), len(args), entries[i])
            if should_stop is not None and should_stop():
                break  # closing the generator cancels the scenes not started yet
    except ExecutorLost as exc:
        not_run = f"not run: {exc}"
        logger.error("%s: %d of %d scenes not certified", exc, len(args) - len(entries), len(args))
    finally:
        if executor is None:
            ex.close()
    for i in range(len(args)):
        if i not in entries:
            entries[i] = FleetEntry(args[i], names[i], "ERROR", [not_run], -1,
                                    str(root / names[i]), 0.0, {}, loaded[i].simulation is not None)
    res = FleetResult([entries[i] for i in range(len(args))], root)
    write_index(res)
    return res


def write_index(res: FleetResult) -> Path:
    """``index.html`` (summary table, each scene linking its report) and ``fleet.json`` in the root."""
    colour = {"GO": "#1a7f37", "MARGINAL": "#9a6700", "NO-GO": "#cf222e", "ERROR": "#8250df"}
    rows = []
    for e in res.entries:
        link = e.files.get("html")
        rel = Path(link).relative_to(res.out.resolve()) if link and Path(link).is_absolute() and \
            Path(link).resolve().is_relative_to(res.out.resolve()) else (Path(link) if link else None)
        name = html.escape(e.name)
        cell = f'<a href="{html.escape(rel.as_posix())}">{name}</a>' if rel is not None else name
        rows.append(f"<tr><td>{cell}</td><td style=\"color:{colour[e.decision]};font-weight:bold\">"
                    f"{e.decision}</td><td>{'simulated' if e.simulated else 'real devices'}</td>"
                    f"<td>{e.seconds:.1f}</td><td>{html.escape('; '.join(e.reasons))}</td></tr>")
    doc = ("<!doctype html><html><head><meta charset=\"utf-8\"><title>hil fleet certification</title>"
           "<style>body{font-family:sans-serif;margin:2em}td,th{padding:4px 10px;border-bottom:1px solid #ddd;"
           "text-align:left;vertical-align:top}</style></head><body>"
           f"<h1>Fleet certification: <span style=\"color:{colour[res.decision]}\">{res.decision}</span></h1>"
           f"<p>{len(res.entries)} scene(s); the fleet's decision is the worst of them.</p>"
           "<table><tr><th>scene</th><th>decision</th><th>bench</th><th>time [s]</th><th>reasons</th></tr>"
           + "".join(rows) + "</table></body></html>")
    res.out.mkdir(parents=True, exist_ok=True)
    (res.out / "fleet.json").write_text(json.dumps(res.to_dict(), indent=2), encoding="utf-8")
    p = res.out / "index.html"
    p.write_text(doc, encoding="utf-8")
    return p
