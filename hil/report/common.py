"""What the HTML and the PDF report share: the decision and outcome styles, the section titles, the
report error, the formatting of frequencies, bands and limits, and the integrity texts (digest,
evidence, bench banner) and the P(stable) gauge."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

from hil.certify.certificate import Certificate
from hil.certify.verify import IntegrityStatus, check_certificate
from hil.errors import HilError
from hil.report.sections import (
    fmt,
    fmt_range,
    policy_label,
    report_sections,
    robust_status,
)

logger = logging.getLogger(__name__)

__all__ = [
    "BENCH_STYLE",
    "CERT_NAME",
    "DECISION_STYLE",
    "OUTCOME_STYLE",
    "SECTION_TITLES",
    "VOID_STYLE",
    "ReportError",
    "bench_banner",
    "fmt_band",
    "fmt_freq",
    "fmt_limits",
]


TEMPLATES = Path(__file__).resolve().parent / "templates"
CERT_NAME = "certificate.json"

# decision -> (css class, background, text colour); ERROR is purple so it never reads as NO-GO.
DECISION_STYLE: dict[str, tuple[str, str, str]] = {
    "GO": ("d-go", "#1b7f3b", "#ffffff"),
    "MARGINAL": ("d-marginal", "#f2a900", "#1d1d1d"),
    "NO-GO": ("d-nogo", "#c62828", "#ffffff"),
    "ERROR": ("d-error", "#6a3d9a", "#ffffff"),
}
# a certificate that does not match its digest: grey, whatever decision it claims
VOID_STYLE: tuple[str, str, str] = ("d-void", "#5f6368", "#ffffff")
# outcome -> (css class, light cell background)
OUTCOME_STYLE: dict[str, tuple[str, str]] = {
    "PASS": ("o-pass", "#d4efdc"),
    "FAIL": ("o-fail", "#f8d0d0"),
    "MARGINAL": ("o-marginal", "#fde9b3"),
    "ERROR": ("o-error", "#e6dcf2"),
    "INFO": ("o-info", "#e3e9f0"),
}
SECTION_TITLES: dict[str, str] = {
    "errors": "Errors",
    "measurements": "Measurements",
    "nominal": "Nominal verdict",
    "robust": "Robust certification",
    "identification": "Identification",
    "design": "Design guidance",
    "witness": "Instability witness",
    "energy": "Energy evidence",
    "multiport": "Multi-port network",
    "plots": "Plots",
}


class ReportError(HilError, ValueError):
    """A certificate could not be read or a report could not be written (one-line message)."""


# ---------------------------------------------------------------------------------------------
# formatting


def _one_line(s: Any) -> str:
    return " ".join(str(s).split())


def fmt_freq(w: Any) -> str:
    """A frequency in rad/s, with Hz in parentheses; strings (e.g. 'inf', 'dc') as given."""
    if isinstance(w, int | float) and not isinstance(w, bool) and math.isfinite(w):
        return f"{fmt(float(w))} rad/s ({fmt(float(w) / (2 * math.pi))} Hz)"
    return fmt(w)


def fmt_band(b: Any) -> str:
    """A band in rad/s; two different ends never print alike (more digits when needed)."""
    if b is None:
        return "—"
    return f"{fmt_range(*b)} rad/s"


def fmt_limits(lower: float | None, upper: float | None, unit: str = "") -> str:
    u = f" {unit}" if unit else ""
    if lower is not None and upper is not None:
        return f"{fmt(lower)} … {fmt(upper)}{u}"
    if lower is not None:
        return f"≥ {fmt(lower)}{u}"
    if upper is not None:
        return f"≤ {fmt(upper)}{u}"
    return "—"


def _value_unit(v: Any, unit: str) -> str:
    s = fmt(v)
    return f"{s} {unit}" if unit and v is not None and not isinstance(v, bool) else s


def _policy_label(key: str) -> str:
    return policy_label(key)


def _status(cert: Certificate, integrity: IntegrityStatus | None) -> IntegrityStatus:
    """The integrity status to show: the caller's, or the digest check of ``cert`` itself."""
    return integrity if integrity is not None else check_certificate(cert)


def _style(cert: Certificate, st: IntegrityStatus) -> tuple[str, str, str]:
    return DECISION_STYLE[cert.decision] if st.valid else VOID_STYLE


def _digest_text(st: IntegrityStatus) -> str:
    if st.recorded_digest is None:
        return f"NONE recorded (content sha256 {st.computed_digest})"
    if st.digest_ok:
        return f"{st.recorded_digest} (matches the content)"
    return f"{st.recorded_digest} DOES NOT MATCH the content (sha256 {st.computed_digest})"


def _evidence_note(st: IntegrityStatus) -> str:
    if not st.evidence_checked:
        return "Evidence files are not checked by the report: hil verify DIR recomputes their SHA-256."
    if st.evidence_problems:
        return "Evidence check FAILED: " + "; ".join(st.evidence_problems)
    return f"All {st.n_evidence} evidence files match their recorded SHA-256."


def bench_banner(cert: Certificate) -> tuple[str, str, str]:
    """(banner label, sentence, kind) saying where the evidence came from (the certificate's
    ``bench`` block); a certificate written before that block existed says so."""
    b = cert.bench
    if b is None:
        return ("BENCH NOT RECORDED", "This certificate does not record whether its evidence came from a "
                "simulated bench or from hardware (written before schema 1.2 recorded it).", "unknown")
    return b.label, b.note, b.kind


#: bench kind -> (banner background, text colour): a simulated bench is never mistaken for hardware
BENCH_STYLE: dict[str, tuple[str, str]] = {"simulated": ("#fff1c2", "#6b4e00"), "hardware": ("#dbe8f6", "#0b3d91"),
                                           "none": ("#eceff1", "#37474f"), "unknown": ("#eceff1", "#37474f")}


def _present_sections(cert: Certificate) -> list[str]:
    out = ["errors"] if cert.errors else []
    out.append("measurements")
    out += [sec.key for sec in report_sections(cert)]
    return out


def _robust_status(cert: Certificate) -> tuple[str, str]:
    return robust_status(cert)


def _gauge(cert: Certificate) -> dict[str, Any]:
    """Geometry of the P(stable) gauge (an inline SVG): axis [a, 1] zoomed on the interesting part."""
    r = cert.robust
    assert r is not None
    vals = [v for v in (r.lower, r.p_stable, r.required) if math.isfinite(v)]
    lo = min(vals) if vals else 0.0
    a = max(0.0, lo - max(0.25 * (1.0 - lo), 0.005))
    a = math.floor(a * 100) / 100 if a > 0.01 else 0.0
    x0, w = 30.0, 540.0

    def px(v: float) -> float:
        v = min(max(v, a), 1.0) if math.isfinite(v) else a
        return round(x0 + (v - a) / (1.0 - a) * w, 2)

    status, _ = _robust_status(cert)
    colour = {"PASS": "#1b7f3b", "MARGINAL": "#f2a900", "FAIL": "#c62828"}[status]
    p = px(r.p_stable)
    anchor, label_x = ("end", x0 + w) if p > x0 + w - 170 else ("start", x0) if p < x0 + 170 else ("middle", p)
    return {"a": fmt(a), "x0": x0, "x1": x0 + w, "lo": px(r.lower), "hi": px(r.upper),
            "p": p, "req": px(r.required), "colour": colour, "p_label": label_x, "p_anchor": anchor}

def _outcome_counts(cert: Certificate) -> list[tuple[str, int]]:
    counts: dict[str, int] = {}
    for m in cert.measurements:
        counts[m.outcome] = counts.get(m.outcome, 0) + 1
    return [(o, counts[o]) for o in OUTCOME_STYLE if o in counts]
