"""Certificate reports: one self-contained HTML page and a PDF for signing, from the record alone.

Everything a report shows comes from a :class:`hil.certify.certificate.Certificate` (plots included, as
data series), so ``hil report PATH`` rebuilds both documents later from ``certificate.json``.

* :func:`render_html` -- one HTML file, no external resources: CSS inline, plots as base64 PNG
  (matplotlib Agg), printable. Jinja2 templates from ``hil/report/templates/`` with autoescaping.
* :func:`render_pdf` -- a PDF laid out with matplotlib only (``PdfPages``): a title page (decision,
  reasons, policy, measurements; long tables continue on the next pages), one page per section
  present in the record, plot pages and a signature page.
* :func:`write_json` / :func:`load_certificate` -- the record itself (validated on load; broken or
  missing files raise :class:`ReportError` with a one-line message).
* :func:`build_reports` -- ``certificate.json`` (sealed: it carries its digest), ``report.html``
  and ``report.pdf`` in one folder.
* :func:`rebuild_reports` -- what ``hil report PATH [--out DIR] [--public-key PUB] [--allow-modified]``
  does (hil.cli.main parses it): exit 0, or 2 with a one-line error.

Integrity (see :mod:`hil.certify.verify`): the reports show the certificate's digest, its evidence files
and, on the signature page/section, who signed and whether the signature holds (when checked with
a public key). A certificate whose content does not match its digest (or has none, or whose
signature fails with the given key) is refused by ``hil report``; with ``--allow-modified`` it is
rendered, and then every PDF page and the HTML page (on screen and on every printed page) carry
``MODIFIED: NOT A VALID CERTIFICATE`` and the decision badge is grey, never the decision's colour.
The render functions apply the same marking whenever the digest does not match (or is missing), whoever
calls them.

Only the sections present in the record appear (an absent section is not rendered empty).
matplotlib and jinja2 (the ``report`` extra) are imported inside the functions that need them,
so importing this module costs neither.

Plot convention (:class:`hil.certify.certificate.Series`): ``lines`` are drawn as lines over ``x`` when
``x`` is monotonic and as markers (a scatter, e.g. posterior draws of two parameters) when it is
not; ``bands`` are shaded between (lo, hi) in the colour of the line of the same name when there
is one; ``points`` are marked and named in the legend; ``hline`` is a dashed reference line.
``None`` values are gaps. A line whose length differs from ``x`` is left out of the figure and
the omission is noted under it (the report never fails on a malformed plot).
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from hil.certify.certificate import SCHEMA_VERSION, Certificate, content_digest, seal
from hil.certify.verify import MODIFIED, IntegrityStatus, check_certificate
from hil.report.common import (
    CERT_NAME,
    OUTCOME_STYLE,
    SECTION_TITLES,
    TEMPLATES,
    ReportError,
    _digest_text,
    _evidence_note,
    _gauge,
    _one_line,
    _outcome_counts,
    _policy_label,
    _present_sections,
    _robust_status,
    _status,
    _style,
    _value_unit,
    bench_banner,
    fmt_band,
    fmt_freq,
    fmt_limits,
)
from hil.report.drawing import _charts_png, _Plot, _plots_png
from hil.report.pdf import _status_class, render_pdf, summary_rows
from hil.report.sections import (
    Table,
    definition_link,
    fmt,
    fmt_p,
    headroom,
    margin_note,
    measurements_table,
    report_sections,
)

logger = logging.getLogger(__name__)

# the PDF and the shared names are re-exported: ``from hil.report.render import render_pdf`` etc.
__all__ = [
    "ReportError",
    "bench_banner",
    "build_reports",
    "load_certificate",
    "rebuild_reports",
    "render_html",
    "render_pdf",
    "write_json",
]


# ---------------------------------------------------------------------------------------------
# JSON record


def _canonical_json(cert: Certificate) -> str:
    """The stored text: every field, except those added after schema 1.1 while at their default
    (so the file minus ``integrity`` is exactly the digested content, hil-c14n/1)."""
    from hil.certify.certificate import drop_new_defaults

    data = json.loads(cert.model_dump_json())
    drop_new_defaults(cert, data)
    return json.dumps(data, indent=2, ensure_ascii=False) + "\n"


def _atomic_write(path: Path, data: bytes) -> Path:
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as exc:
        raise ReportError(f"{path}: cannot write: {exc.strerror or exc}") from None
    return path


def write_json(cert: Certificate, out_path: str | os.PathLike[str]) -> Path:
    """Write the record as ``certificate.json`` (indented UTF-8). The text is checked to load back:
    a non-finite number in a required field (JSON has no NaN) raises :class:`ReportError`."""
    from hil.certify.strict_json import StrictJsonError, loads

    text = _canonical_json(cert)
    try:  # read back as hil verify reads it (strict JSON), so nothing is written that it would refuse
        Certificate.model_validate(loads(text))
    except StrictJsonError as exc:
        raise ReportError(f"certificate would not read back: {exc}") from None
    except ValidationError as exc:
        raise ReportError(f"certificate does not survive JSON (non-finite number?): {_first_error(exc)}") from None
    return _atomic_write(Path(out_path), text.encode("utf-8"))


def _first_error(exc: ValidationError) -> str:
    errs = exc.errors()
    if not errs:
        return _one_line(exc)
    e = errs[0]
    loc = ".".join(str(p) for p in e.get("loc", ())) or "(root)"
    more = f" (and {len(errs) - 1} more)" if len(errs) > 1 else ""
    return _one_line(f"{loc}: {e.get('msg', 'invalid')}{more}")


def _resolve(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    if p.is_dir():
        p = p / CERT_NAME
    return p


def load_certificate(path: str | os.PathLike[str]) -> Certificate:
    """Read and validate a certificate (a ``certificate.json`` file, or a folder holding one)."""
    from hil.certify.strict_json import StrictJsonError, read_json_file

    p = _resolve(path)
    try:  # a regular file, bounded, no duplicate member, only finite numbers (docs/INTEGRITY.md)
        data = read_json_file(p)
    except StrictJsonError as exc:
        raise ReportError(str(exc)) from None
    if not isinstance(data, dict):
        raise ReportError(f"{p}: not a certificate: the top level is not a JSON object")
    ver = str(data.get("schema_version", SCHEMA_VERSION))
    if ver.split(".")[0] != SCHEMA_VERSION.split(".")[0]:
        raise ReportError(f"{p}: schema_version {ver!r} is not supported (this version reads {SCHEMA_VERSION})")
    try:
        return Certificate.model_validate(data)
    except ValidationError as exc:
        raise ReportError(f"{p}: invalid certificate: {_first_error(exc)}") from None


# ---------------------------------------------------------------------------------------------
# HTML


def _jinja_env() -> Any:
    import jinja2

    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(TEMPLATES)), autoescape=True,
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
                             keep_trailing_newline=True)
    env.filters.update(fmt=fmt, fmt_p=fmt_p, fmt_freq=fmt_freq, fmt_band=fmt_band)
    env.globals.update(fmt_limits=fmt_limits, value_unit=_value_unit, policy_label=_policy_label,
                       outcome_class=lambda o: OUTCOME_STYLE.get(str(o), ("o-info", ""))[0],
                       status_class=_status_class, link=definition_link, cell_class=_cell_class)
    return env


def _html_context(cert: Certificate, st: IntegrityStatus, images: dict[str, _Plot] | None = None
                  ) -> dict[str, Any]:
    """The template's context. ``images``: the figures as :func:`render_pdf` drew them (one draw for
    both documents); without them (the HTML alone) each figure is drawn here."""
    short = cert.decision == "ERROR"  # an ERROR certificate's report is short: no figures
    if images is not None:
        plots = {k: v for k, v in images.items() if not k.startswith("chart:")}
        charts = {k.removeprefix("chart:"): v for k, v in images.items() if k.startswith("chart:")}
    else:
        plots = _plots_png(cert) if cert.plots and not short else {}
        charts = _charts_png(cert) if cert.robust is not None and not short else {}
    ctx: dict[str, Any] = {
        "cert": cert,
        "title": (f"{MODIFIED} — " if not st.valid else "") + f"Certificate: {cert.scene.name} — {cert.decision}",
        "decision_class": _style(cert, st)[0],
        "modified": not st.valid,
        "modified_text": MODIFIED,
        "modified_reason": st.reason(),
        "bench": dict(zip(("label", "note", "kind"), bench_banner(cert), strict=True)),
        "integrity": st,
        "digest_text": _digest_text(st),
        "signature_text": st.signature_text(),
        "evidence_note": _evidence_note(st),
        "toc": [(k, SECTION_TITLES[k]) for k in _present_sections(cert)],
        "sections": report_sections(cert),
        "summary": _kv_table(summary_rows(cert, st)),
        "margin_note": margin_note(cert),
        "measurements": measurements_table(cert),
        "outcome_counts": _outcome_counts(cert),
        "plots": plots,
        "charts": charts,
        "robust_status": None,
        "gauge": None,
        "show_truth": False,
        "headroom": headroom(cert.design) if cert.design is not None else "",
    }
    if cert.robust is not None:
        ctx["robust_status"] = _robust_status(cert)
        ctx["gauge"] = _gauge(cert)
    if cert.identification:
        ctx["show_truth"] = any(p.truth is not None for i in cert.identification for p in i.parameters)
    return ctx


def _kv_table(rows: list[tuple[str, str, str, str | None]]) -> Table:
    from hil.report.sections import _kv

    return _kv(rows)


def _cell_class(t: Table, i: int, j: int) -> str:
    """CSS class of a model-table cell: its outcome colour, else num / nowrap."""
    o = t.colours[i][j] if t.colours else None
    if o in OUTCOME_STYLE:
        return OUTCOME_STYLE[o][0]
    c = t.columns[j]
    return " ".join(k for k, on in (("num", c.num), ("nowrap", c.nowrap)) if on)


def render_html(cert: Certificate, out_path: str | os.PathLike[str], *,
                integrity: IntegrityStatus | None = None, images: dict[str, _Plot] | None = None) -> Path:
    """Write the certificate as one self-contained, printable HTML file; returns its path.
    ``integrity`` (default: the digest check of ``cert``) decides the MODIFIED marking and the
    signature status shown."""
    env = _jinja_env()
    html = env.get_template("report.html.j2").render(**_html_context(cert, _status(cert, integrity), images))
    return _atomic_write(Path(out_path), html.encode("utf-8"))



# ---------------------------------------------------------------------------------------------
# all three, and the command


def build_reports(cert: Certificate, out_dir: str | os.PathLike[str], *,
                  integrity: IntegrityStatus | None = None) -> dict[str, Path]:
    """Write ``certificate.json``, ``report.html`` and ``report.pdf`` into ``out_dir``.

    The written certificate carries its digest: an unsealed ``cert`` is sealed first; a sealed one
    whose content no longer matches its digest is refused (:class:`ReportError`), so a record is
    never written with a digest, or a signature, that does not hold. ``integrity`` is the status
    shown in the reports (default: the digest check; ``hil certify --sign`` passes the checked
    signature)."""
    d = Path(out_dir)
    if cert.integrity is None:
        cert = seal(cert)
    elif cert.integrity.digest != content_digest(cert):
        raise ReportError("the certificate was changed after its digest was computed; refusing to write it")
    if integrity is None:  # the evidence was hashed from this folder: the reports say it matches
        integrity = check_certificate(cert, d)
    json_path = write_json(cert, d / CERT_NAME)
    images: dict[str, _Plot] = {}  # each figure drawn once, on its PDF page; the HTML shows that drawing
    pdf = render_pdf(cert, d / "report.pdf", integrity=integrity, images=images)
    return {"json": json_path, "html": render_html(cert, d / "report.html", integrity=integrity, images=images),
            "pdf": pdf}


def rebuild_reports(path: str | Path, out: str | Path | None = None, public_key: str | Path | None = None,
                    allow_modified: bool = False) -> tuple[Certificate, IntegrityStatus, dict[str, Path]]:
    """What ``hil report PATH [--out DIR] [--public-key PUB] [--allow-modified]`` does (parsed by
    hil.cli.main): rebuild report.html and report.pdf from a stored certificate.json (``path`` is the file
    or a folder holding it) into ``out`` (default: the certificate's folder). Returns the
    certificate, its integrity status and the two paths.

    A certificate that does not match its digest (or has none), whose evidence files (records,
    scene copy, relative to the certificate's folder) no longer match their recorded SHA-256, or
    whose signature fails with ``public_key``, raises :class:`ReportError`; ``allow_modified``
    renders it marked MODIFIED: NOT A VALID CERTIFICATE on every page."""
    cert = load_certificate(path)
    key = None
    if public_key:
        from hil.certify.signing import load_public_key

        key = load_public_key(public_key)
    # the evidence files are re-hashed too: a record swapped after certification is refused (or,
    # with --allow-modified, marked on every page), as hil verify refuses it
    st = check_certificate(cert, _resolve(path).parent, public_key=key)
    if key is not None and st.signature == "absent":
        st.signature, st.signature_detail = "invalid", "the certificate is not signed"
    if not st.valid and not allow_modified:
        raise ReportError(f"{_resolve(path)}: {st.reason()}; refusing to render it "
                          f"(--allow-modified renders it marked '{MODIFIED}')")
    folder = Path(out) if out else _resolve(path).parent
    images: dict[str, _Plot] = {}
    pdf = render_pdf(cert, folder / "report.pdf", integrity=st, images=images)
    paths = {"html": render_html(cert, folder / "report.html", integrity=st, images=images), "pdf": pdf}
    return cert, st, paths

