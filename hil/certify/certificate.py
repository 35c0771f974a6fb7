"""The certificate record: everything a reviewer needs, as one JSON document (schema below).

The JSON file written by ``hil certify`` (``certificate.json``) validates against
:class:`Certificate` (``Certificate.model_json_schema()`` is exported to
``docs/certificate.schema.json``). Reports (HTML, PDF) are rendered from this record alone --
plots included, as data series -- so ``hil report`` can rebuild them later.

Conventions: frequencies in rad/s; margins are the dimensionless normalized margins of
``hil.stability`` (positive = inside the stable region); probabilities in [0, 1]; units of
identified parameters as the identification model states them.

Measurements follow OpenHTF's idea: each is a named value with limits and an outcome, and the
outcome is PASS / FAIL / MARGINAL for a decided measurement but ERROR when the evidence is
missing or broken -- never confused with FAIL.

Tamper evidence (``integrity`` and ``evidence``)
------------------------------------------------
``evidence`` lists the files the certificate rests on -- every run record and the scene text --
with their SHA-256, size in bytes and a path relative to the certificate's folder.
``integrity.digest`` is the SHA-256 (lower-case hex) of the certificate's *canonical content*,
``hil-c14n/1``, defined as:

1. take every field of the validated certificate except ``integrity`` itself, as JSON values
   (exactly what ``certificate.json`` stores: tuples become arrays, and a non-finite float --
   NaN, +inf, -inf -- becomes ``null``, as pydantic writes it; JSON has no NaN), leaving out, at
   every level, a field added after schema 1.1 (marked ``"since": "1.2"`` in the JSON schema)
   while it holds its default value -- so a certificate written by an earlier version, read by
   this one (which fills those fields with their defaults), keeps its digest;
2. serialize them as JSON with object keys sorted by Unicode code point at every level, no
   whitespace at all (separators ``,`` and ``:``), strings with every non-ASCII character
   escaped as ``\\uXXXX`` (UTF-16 surrogate pairs above U+FFFF), so the bytes are pure ASCII;
   integers in decimal; floats by Python's ``repr`` (the shortest text that reads back to the
   same double: ``0.1``, ``1e-05``, ``1e+300``, ``-0.0``, ``2.0``); ``true``/``false``/``null``;
3. hash those bytes with SHA-256.

Because the digest is computed from the validated record, re-indenting or re-ordering the keys of
``certificate.json`` does not change it, while any change of a value (a decision, a measurement, a
reason, an evidence hash) does. ``integrity.signature`` (optional, Ed25519, see
:mod:`hil.certify.signing`) signs the digest together with the signer's name and key fingerprint.
"""

from __future__ import annotations

import hashlib
import json
import math
from typing import Any, Final, Literal

from pydantic import BaseModel, ConfigDict, Field

SCHEMA_VERSION = "1.2"
CANONICALIZATION: Final = "hil-c14n/1"
#: marks a field added after schema 1.1 (``Field(json_schema_extra=SINCE_1_2)``): left out of the
#: canonical content while it holds its default, so certificates written before it still verify
SINCE_1_2: dict[str, Any] = {"since": "1.2"}
_HEX64 = r"^[0-9a-f]{64}$"

Outcome = Literal["PASS", "FAIL", "MARGINAL", "ERROR", "INFO"]
DecisionStr = Literal["GO", "MARGINAL", "NO-GO", "ERROR"]
VerdictStr = Literal["stable", "marginal", "potentially_unstable", "not_applicable"]

__all__ = [
    "CANONICALIZATION",
    "SCHEMA_VERSION",
    "BenchInfo",
    "Certificate",
    "Evidence",
    "Integrity",
    "Measurement",
    "RareEvent",
    "Reliability",
    "Series",
    "Signature",
    "canonical_bytes",
    "canonical_json",
    "content_digest",
    "seal",
]


class _M(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Measurement(_M):
    """A measured quantity with its limits and outcome."""

    name: str
    value: float | str | bool | None
    unit: str = ""
    lower: float | None = None
    upper: float | None = None
    outcome: Outcome
    description: str = ""


class Series(_M):
    """A plot: x values and named y series (lines), optional shaded bands and marked points."""

    title: str
    x: list[float]
    x_label: str
    y_label: str
    log_x: bool = False
    log_y: bool = False
    lines: dict[str, list[float | None]] = Field(default_factory=dict)
    bands: dict[str, tuple[list[float | None], list[float | None]]] = Field(default_factory=dict)
    points: dict[str, tuple[float, float]] = Field(default_factory=dict)
    hline: float | None = None
    # (additive, report issue 18) axis labels end with their unit in brackets: "ω [rad/s]", "[1]"
    kind: Literal["xy", "corner"] = Field(
        json_schema_extra=SINCE_1_2, default="xy", description="xy: lines over x; corner: a corner plot of "
                                          "the ``lines`` (each a parameter's posterior draws, named 'p [unit]')")
    shade_negative: bool = Field(
        json_schema_extra=SINCE_1_2, default=False, description="shade where the first line is below 0 (a violation)")
    vlines: dict[str, float] = Field(
        json_schema_extra=SINCE_1_2, default_factory=dict, description="named x positions marked by vertical lines")
    bars: dict[str, float] = Field(
        json_schema_extra=SINCE_1_2, default_factory=dict, description="named values drawn as a bar chart panel (e.g. "
                                   "imaginary-axis and infinity residue margins) beside the curve")
    panels: list[Series] = Field(
        json_schema_extra=SINCE_1_2, default_factory=list, description="further axes stacked beneath, sharing x")


class SceneInfo(_M):
    name: str
    sha256: str
    description: str = ""
    source: str = ""
    units: Literal["linear", "rotary"] | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="the scene's units: linear (N, m, "
                                                       "m/s) or rotary (N.m, rad, rad/s); SI throughout")


class ConditionRow(_M):
    name: str
    label: str
    status: str
    margin: float | str | None
    worst_frequency: float | str | None
    detail: str = ""


class Nominal(_M):
    """The criterion on the nominal network: each drawn parameter at its median (the posterior median
    of an identified one, the stated value of an uncertain one) plus the scene's gains."""

    network: str
    criterion: str
    verdict: VerdictStr
    margin: float | None
    worst_frequency: float | str | None
    failed_condition: str | None
    weak: bool
    parameters: dict[str, float]
    conditions: list[ConditionRow]


class Reliability(_M):
    """The first-order reliability index (docs/CERTIFICATION.md#reliability-index-β)."""

    beta: float = Field(description="signed distance, in posterior-standardized coordinates u = L⁻¹(θ − μ), "
                        "from the posterior centre to the nearest parameter set whose verdict differs from the "
                        "centre's (negative when the centre is not stable)")
    phi_beta: float = Field(description="Φ(β): the first-order approximation of P(stable)")
    required_beta: float = Field(description="Φ⁻¹(required probability): the β a GO needs")
    design_point: dict[str, float] = Field(description="the nearest such parameter set θ* = μ + L u*")
    design_point_u: list[float] = Field(description="u*, in the order of design_point's keys")
    censored: bool = Field(default=False, description="no such point within the search radius: β ≥ |beta|")
    bracket: tuple[float, float] | None = Field(default=None, description="the crossing lies between these "
                                                "distances along u*'s ray")
    evaluations: int = Field(default=0, description="verdicts evaluated by the search")
    verified: bool | None = Field(default=None, description="the exact criterion (check) confirms the verdicts "
                                  "at 0.95·u* and 1.05·u* (None: it calls a side marginal)")
    coordinates: str = ("the nominal point (each parameter's median) and the Cholesky factor of the posterior "
                        "covariance of the independent draws")
    method: str = ""


class RareEvent(_M):
    """P(stable) by importance sampling around the FORM design point (the rare-event path)."""

    method: str
    n: int
    n_fail: int
    p_failure: float
    std_error: float
    p_stable: float
    lower: float = Field(description="lower confidence bound of P(stable)")
    upper: float = Field(description="upper confidence bound of P(stable)")
    confidence: float
    ess: float = Field(description="effective sample size of the failing samples' weights")
    reliable: bool = Field(description="at least 10 failing samples: the standard error is meaningful")


class Robust(_M):
    """The criterion over the posterior."""

    n_draws: int
    p_stable: float
    lower: float
    upper: float
    confidence: float
    required: float
    credible: float
    worst_case_margin: float | None
    worst_case_parameters: dict[str, float] | None
    critical_band_rad_s: tuple[float, float] | None = None
    method: str = ""
    n_requested: int | None = Field(default=None, description="draws the scene asked for (certification.draws)")
    n_independent: int | None = Field(default=None, description="independent posterior draws available after "
                                      "thinning the MCMC chain by its autocorrelation time")
    sampling: str = Field(default="", description="how the draws were obtained (thinning, shortfall)")
    worst_case_quantity: str = Field(
        json_schema_extra=SINCE_1_2, default="", description="the function minimized over the credible region "
                                     "(the nominal margin's function)")
    reliability: Reliability | None = Field(default=None, json_schema_extra=SINCE_1_2)
    rare_event: RareEvent | None = Field(default=None, json_schema_extra=SINCE_1_2)
    p_stable_method: Literal["monte_carlo", "importance_sampling"] = Field(
        json_schema_extra=SINCE_1_2,
        default="monte_carlo", description="which estimate's confidence interval the decision used: Clopper-Pearson "
        "on the independent draws (lower/upper above) or importance sampling (rare_event)")


class ParameterSummary(_M):
    name: str
    unit: str = ""
    truth: float | None = None
    mean: float
    median: float
    q05: float
    q95: float
    std: float
    ls_std: float | None = None
    crb_std: float | None = None


class Identification(_M):
    model: str
    record: str
    converged: bool
    reason: str = ""
    parameters: list[ParameterSummary]
    diagnostics: dict[str, Any] = Field(default_factory=dict)


class Design(_M):
    """Guidance for a free design parameter (e.g. the largest passive virtual-coupler stiffness)."""

    parameter: str
    unit: str = ""
    current: float | None = None
    max_value: float | None
    probability_at_max: float | None
    required: float
    note: str = ""
    nominal_limit: float | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="largest passive value at the nominal plant "
                                        "(hil.models.design.k22_max)")
    nominal_headroom: float | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="nominal_limit / current − 1")
    posterior_limit: float | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="value where the lower bound of P(stable) "
                                          "crosses the requirement")
    posterior_limit_kind: Literal["exact", "at_least", "at_most"] | None = Field(default=None,
                                                                             json_schema_extra=SINCE_1_2)
    posterior_headroom: float | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="posterior_limit / current − 1")


class EnergyEvidence(_M):
    experiment: str
    port: str
    record: str
    went_negative: bool
    min_energy: float
    bound: float
    first_time: float | None = None


class Witness(_M):
    """A passive termination set under which the network delivers energy, with its simulation."""

    terminations: dict[str, Any]
    drive_frequency_rad_s: float
    band_rad_s: tuple[float, float | str] | None
    margin: float
    simulation: dict[str, Any] = Field(default_factory=dict)
    # (additive, report issue 18) what the destabilizing termination does, in SI units
    units: Literal["linear", "rotary"] | None = Field(default=None, json_schema_extra=SINCE_1_2)
    closed_loop_poles: list[tuple[float, float]] = Field(
        json_schema_extra=SINCE_1_2, default_factory=list, description="poles (re, im) [1/s] "
                                                         "of the terminated network driven by a force at the operator "
                                                         "port (poles of Y_in = Z_in⁻¹), right-half plane first")
    growth_rate_1_s: float | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="largest real part of the closed-loop poles [1/s] "
                                          "(> 0: the response grows as e^(σt))")
    drive_amplitude: float | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="amplitude of the simulated drive force [N or N.m]")
    limits: dict[str, float] = Field(
        json_schema_extra=SINCE_1_2, default_factory=dict, description="the bench's safety limits compared against "
                                     "(max_velocity [m/s or rad/s], max_position [m or rad], max_energy [J])")
    limit_exceeded: str | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="which limit the simulated response crosses first")
    time_to_limit_s: float | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="simulated time until the first limit is "
                                          "exceeded [s]")
    energy_to_limit_J: float | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="port energy E_s = ∫ F·V dt at that time [J] "
                                            "(negative: delivered by the network)")


class MultiPort(_M):
    ports: list[int]
    dof_total: int
    symmetrization: str = ""


class BenchInfo(_M):
    """Where the evidence came from (docs/CERTIFICATION.md#bench; :mod:`hil.certify.provenance`)."""

    kind: Literal["simulated", "hardware", "none"] = Field(
        description="simulated: the scene's simulated devices (no hardware); hardware: real devices; none: no "
                    "experiment ran (the scene's stated parameters only)")
    clock: Literal["lockstep", "realtime"] | None = Field(
        default=None, description="lockstep: simulated time, one control period per tick; realtime: the wall "
                                  "clock; None when nothing ran")
    devices: list[str] = Field(default_factory=list, description="the scene's devices, 'name (driver)'")
    label: str = Field(description="the banner the reports print on every page, e.g. 'SIMULATED BENCH — lockstep'")
    note: str = Field(default="", description="one sentence saying what the label means")


class Evidence(_M):
    """A file the certificate rests on: a run record or the scene text."""

    path: str = Field(description="POSIX path relative to the folder holding certificate.json")
    sha256: str = Field(pattern=_HEX64, description="SHA-256 of the file's bytes, lower-case hex")
    bytes: int = Field(ge=0, description="file size in bytes")
    role: Literal["record", "scene"]


class Signature(_M):
    """An Ed25519 signature over the digest (see :func:`hil.certify.signing.signed_message`)."""

    algorithm: Literal["ed25519"] = "ed25519"
    public_key: str = Field(description="the signer's raw 32-byte public key, base64")
    public_key_sha256: str = Field(pattern=_HEX64, description="fingerprint: SHA-256 of the raw public key, hex")
    signer: str = Field(default="", description="who signed (free text, e.g. a name; signed too)")
    signed_utc: str
    value: str = Field(description="the 64-byte Ed25519 signature, base64")


class Integrity(_M):
    """The digest of the canonical content (every field but this block) and an optional signature."""

    algorithm: Literal["sha256"] = "sha256"
    canonicalization: Literal["hil-c14n/1"] = CANONICALIZATION
    digest: str = Field(pattern=_HEX64, description="SHA-256 of the canonical content, lower-case hex")
    signature: Signature | None = None


class Certificate(_M):
    """One signed-or-refused answer for one scene."""

    schema_version: str = SCHEMA_VERSION
    created_utc: str
    software: dict[str, str]
    scene: SceneInfo
    decision: DecisionStr
    reasons: list[str]
    policy: dict[str, float]
    measurements: list[Measurement]
    nominal: Nominal | None = None
    robust: Robust | None = None
    identification: list[Identification] | None = None
    design: Design | None = None
    witness: Witness | None = None
    energy: list[EnergyEvidence] | None = None
    multiport: MultiPort | None = None
    bench: BenchInfo | None = Field(
        json_schema_extra=SINCE_1_2, default=None, description="where the evidence came from: simulated bench "
                                                               "or hardware, and on which clock")
    plots: dict[str, Series] = Field(default_factory=dict)
    errors: list[str] = Field(default_factory=list)
    evidence: list[Evidence] = Field(default_factory=list)
    integrity: Integrity | None = None


# ---------------------------------------------------------------------------------------------
# canonical content and digest (hil-c14n/1, see the module docstring)


def _finite(v: Any) -> Any:
    """JSON values with non-finite floats as None (lists/tuples as lists)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {str(k): _finite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_finite(x) for x in v]
    return v


def canonical_json(value: Any) -> bytes:
    """``hil-c14n/1`` bytes of a JSON value (dict, list, str, int, float, bool, None): sorted keys,
    no whitespace, ASCII with ``\\u`` escapes, floats by ``repr``, NaN/inf as ``null``."""
    return json.dumps(_finite(value), sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False).encode("ascii")


def _is_default(f: Any, value: Any) -> bool:
    try:
        return bool(value == f.get_default(call_default_factory=True))
    except Exception:  # pragma: no cover - a default that cannot be built or compared
        return False


def drop_new_defaults(model: BaseModel, data: Any) -> None:
    """Remove, in place, the JSON of fields added after their model's first schema (marked with
    ``since`` in ``json_schema_extra``) that hold their default value, at every level."""
    if not isinstance(data, dict):
        return
    for name, f in type(model).model_fields.items():
        key = f.serialization_alias or f.alias or name
        if key not in data:
            continue
        value = getattr(model, name)
        extra = f.json_schema_extra if isinstance(f.json_schema_extra, dict) else {}
        if "since" in extra and _is_default(f, value):
            del data[key]
            continue
        _drop_in_value(value, data[key])


def _drop_in_value(value: Any, data: Any) -> None:
    if isinstance(value, BaseModel):
        drop_new_defaults(value, data)
    elif isinstance(value, list | tuple) and isinstance(data, list):
        for v, d in zip(value, data, strict=False):
            _drop_in_value(v, d)
    elif isinstance(value, dict) and isinstance(data, dict):
        for k, v in value.items():
            if str(k) in data:
                _drop_in_value(v, data[str(k)])


def canonical_bytes(cert: Certificate) -> bytes:
    """The canonical content of a certificate: every field except ``integrity``, as stored in JSON,
    without the fields added after schema 1.1 that hold their default (module docstring)."""
    data = json.loads(cert.model_dump_json(exclude={"integrity"}))
    drop_new_defaults(cert, data)
    return canonical_json(data)


def content_digest(cert: Certificate) -> str:
    """Hex SHA-256 of :func:`canonical_bytes` (what ``integrity.digest`` must equal)."""
    return hashlib.sha256(canonical_bytes(cert)).hexdigest()


def seal(cert: Certificate) -> Certificate:
    """A copy of ``cert`` carrying the digest of its current content (and no signature: a
    signature made over another digest would no longer hold)."""
    return cert.model_copy(update={"integrity": Integrity(digest=content_digest(cert))})
