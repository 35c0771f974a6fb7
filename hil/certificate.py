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
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

SCHEMA_VERSION = "1.0"

Outcome = Literal["PASS", "FAIL", "MARGINAL", "ERROR", "INFO"]
DecisionStr = Literal["GO", "MARGINAL", "NO-GO", "ERROR"]

__all__ = ["SCHEMA_VERSION", "Certificate", "Measurement", "Series"]


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


class SceneInfo(_M):
    name: str
    sha256: str
    description: str = ""
    source: str = ""


class ConditionRow(_M):
    name: str
    label: str
    status: str
    margin: float | str | None
    worst_frequency: float | str | None
    detail: str = ""


class Nominal(_M):
    """The criterion on the nominal network (posterior mean parameters + the scene's gains)."""

    network: str
    criterion: str
    verdict: Literal["stable", "marginal", "potentially_unstable", "not_applicable"]
    margin: float | None
    worst_frequency: float | str | None
    failed_condition: str | None
    weak: bool
    parameters: dict[str, float]
    conditions: list[ConditionRow]


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


class MultiPort(_M):
    ports: list[int]
    dof_total: int
    symmetrization: str = ""


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
    plots: dict[str, Series] = Field(default_factory=dict)
    errors: list[str] = Field(default_factory=list)
