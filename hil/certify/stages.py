"""The certification stages' typed inputs and outputs, and measurements that declare their limits.

``hil certify`` (:func:`hil.certify.pipeline.certify_scene`) runs seven stages in order -- **run**,
**identify**, **nominal**, **robust**, **design**, **decide**, **witness** -- each a function of
:mod:`hil.certify.pipeline` taking the :class:`Context` and the outputs of the stages before it (frozen
dataclasses defined here) and returning its own::

    run(ctx)                         -> RunOutput      records, energy evidence
    identify(ctx, run)               -> PosteriorDraws  independent draws of the uncertain parameters
    nominal(ctx, draws)              -> NominalOutput   the network at the posterior centre, its verdict
    robust(ctx, draws, nominal)      -> RobustOutput    P(stable), worst case, β, rare-event path
    design(ctx, draws, nominal)      -> Design | None   the largest safe design parameter, headroom
    decide(ctx, ...)                 -> Verdict         GO / MARGINAL / NO-GO / ERROR and reasons
    witness(ctx, nominal, verdict)   -> WitnessOutput   a destabilizing passive termination

What the stages measure goes on one :class:`Sheet` (the certificate's measurements, plots and
errors, the stages' timings). An unexpected exception inside a stage -- a defect, not a finding
-- ends the certification as ERROR with the stage and the reason recorded, never as FAIL: FAIL is
a measured value outside its limits. (A :class:`~hil.errors.HilError` propagates to the caller
with its exit code.)

Measurements (OpenHTF style, ``openhtf.core.measurements``): a :class:`MeasurementSpec` declares,
as data, the limits (:class:`Limit`) and the required categorical results (:class:`Expect`) a
value is judged against; :meth:`MeasurementSpec.measure` derives the outcome from them in one place
(:func:`judge`):

* no validator: INFO (evidence shown, not judged);
* a validator that cannot judge the value (missing, NaN) gives ERROR, and so does a value its own
  estimate declares not meaningful (``invalid``, e.g. an importance-sampling estimate with too
  few failing samples); FAIL means the value is outside a limit (or a categorical result the spec
  names as failing);
* several validators: the worst outcome in the order FAIL > ERROR > MARGINAL > PASS (a failure
  decided by evidence that exists stands even when another validator lacks its evidence).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from hil.certify.certificate import (
    Design,
    EnergyEvidence,
    Identification,
    Measurement,
    Nominal,
    RareEvent,
    Robust,
    Series,
)
from hil.certify.certificate import Witness as WitnessSection
from hil.certify.statistics import Decision, Policy
from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = [
    "HEADROOM",
    "HEADROOM_TOL",
    "MARGIN",
    "MARGIN_TOL",
    "Context",
    "Expect",
    "Limit",
    "MeasurementSpec",
    "NominalOutput",
    "Outcome",
    "PosteriorDraws",
    "RobustOutput",
    "RunOutput",
    "Sheet",
    "Verdict",
    "WitnessOutput",
    "judge",
    "one_line",
]

Outcome = Literal["PASS", "FAIL", "MARGINAL", "ERROR", "INFO"]

#: a margin within this of zero is MARGINAL (the batch path's round-off tolerance, hil.models.batch)
MARGIN_TOL = 1e-9

#: a headroom within this of zero is MARGINAL (the relative tolerance of the limit searches)
HEADROOM_TOL = 1e-6

_SEVERITY: dict[str, int] = {"PASS": 0, "MARGINAL": 1, "ERROR": 2, "FAIL": 3}


def _finite(v: object) -> float | None:
    """``v`` as a finite float, or None (missing, not a number, NaN, ±inf)."""
    if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer):
        return None
    x = float(v)
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class Limit:
    """A numeric limit: the value must be ≥ ``lower`` and ≤ ``upper`` (either may be None).

    ``tol`` > 0 declares a MARGINAL band around each limit: a value within ``tol`` of a limit (the
    closed band [limit − tol, limit + tol]) is MARGINAL, beyond it on the wrong side FAIL. With
    ``tol`` = 0 a value equal to the limit passes.

    An interval estimate (``lo``, ``hi``) -- e.g. the confidence interval of a probability -- is
    judged as a whole: PASS when every value in it passes, FAIL when every value fails, MARGINAL
    when it straddles a limit. A missing or non-finite value gives ERROR."""

    lower: float | None = None
    upper: float | None = None
    tol: float = 0.0

    def _point(self, v: float) -> Outcome:
        t = self.tol
        if (self.lower is not None and v < self.lower - t) or (self.upper is not None and v > self.upper + t):
            return "FAIL"
        if t > 0 and ((self.lower is not None and v <= self.lower + t)
                      or (self.upper is not None and v >= self.upper - t)):
            return "MARGINAL"
        return "PASS"

    def outcome(self, value: object, interval: tuple[float, float] | None = None) -> Outcome:
        """The outcome of ``value`` (or of the ``interval`` estimating it, when given)."""
        if interval is None:
            v = _finite(value)
            return "ERROR" if v is None else self._point(v)
        lo, hi = _finite(interval[0]), _finite(interval[1])
        if lo is None or hi is None:
            return "ERROR"
        ends = {self._point(lo), self._point(hi)}
        if ends == {"PASS"}:
            return "PASS"
        below = self.lower is not None and lo < self.lower - self.tol
        above = self.upper is not None and hi > self.upper + self.tol
        if ends == {"FAIL"} and not (below and above):
            return "FAIL"
        return "MARGINAL"


@dataclass(frozen=True)
class Expect:
    """A required categorical result (a status, a verdict, a flag): ``outcomes`` maps each named
    result to its outcome; any other result gets ``otherwise``."""

    outcomes: Mapping[object, Outcome]
    otherwise: Outcome = "ERROR"

    def outcome(self, result: object) -> Outcome:
        if isinstance(result, np.bool_ | np.str_):
            result = result.item()
        for k, o in self.outcomes.items():
            if type(k) is type(result) and k == result:  # True is not 1, "stable" is not a number
                return o
        return self.otherwise


def judge(outcomes: list[Outcome]) -> Outcome:
    """One outcome from the validators' outcomes: INFO without validators, else the worst in the
    order FAIL > ERROR > MARGINAL > PASS."""
    judged = [o for o in outcomes if o != "INFO"]
    if not judged:
        return "INFO"
    return max(judged, key=lambda o: _SEVERITY[o])


_UNSET: Any = object()


@dataclass(frozen=True)
class MeasurementSpec:
    """A certificate measurement declared as data: its name and unit, the :class:`Limit` its
    value is judged against and the :class:`Expect`-ed categorical result (of the value itself, or
    of a ``result`` given with it, e.g. the verdict behind a margin). The limits are recorded in
    the measurement (``lower``/``upper``); the outcome is derived by :meth:`measure`."""

    name: str
    unit: str = ""
    limit: Limit | None = None
    expect: Expect | None = None
    description: str = ""

    def outcome(self, value: object, *, interval: tuple[float, float] | None = None,
                result: object = _UNSET, invalid: bool = False) -> Outcome:
        """The derived outcome (:func:`judge` over this spec's validators). ``invalid``: the
        value's own estimate says it is not meaningful: ERROR, whatever the limits say (a value
        that means nothing cannot fail)."""
        if invalid:
            return "ERROR"
        got: list[Outcome] = []
        if self.limit is not None:
            got.append(self.limit.outcome(value, interval))
        if self.expect is not None:
            got.append(self.expect.outcome(value if result is _UNSET else result))
        return judge(got)

    def measure(self, value: float | str | bool | None, *, interval: tuple[float, float] | None = None,
                result: object = _UNSET, invalid: bool = False, description: str | None = None,
                lower: float | None = None) -> Measurement:
        """The certificate row of ``value``. ``lower``: the reference bound shown for a measurement
        judged on a categorical ``result`` (e.g. the noise bound beside the minimum energy)."""
        shown_lower = self.limit.lower if self.limit is not None else lower
        return Measurement(name=self.name, value=value, unit=self.unit, lower=shown_lower,
                           upper=None if self.limit is None else self.limit.upper,
                           outcome=self.outcome(value, interval=interval, result=result, invalid=invalid),
                           description=self.description if description is None else description)


# ---------------------------------------------------------------------------------------------
# the measurements of a certificate (every judged row; INFO rows are specs without validators)

#: a margin (normalized, hil.stability) against its limit 0
MARGIN = Limit(lower=0.0, tol=MARGIN_TOL)
#: a design headroom (limit / current − 1) against its limit 0
HEADROOM = Limit(lower=0.0, tol=HEADROOM_TOL)
#: the verdict behind a margin: potentially unstable fails it, marginal caps it at MARGINAL
MARGIN_VERDICT = Expect({"potentially_unstable": "FAIL", "marginal": "MARGINAL"}, otherwise="PASS")


def experiment_spec(name: str) -> MeasurementSpec:
    """An experiment's status: completed passes, a safety stop fails, anything else is ERROR."""
    return MeasurementSpec(f"experiment {name}", expect=Expect({"completed": "PASS", "safety_stop": "FAIL"}))


def energy_spec(name: str) -> MeasurementSpec:
    """The minimum port energy of an energy-injection run, judged on the experiment's own finding
    (E_s(t) + bound(t) went negative at some t: FAIL)."""
    return MeasurementSpec(f"E_s(t) ≥ -bound ({name})", unit="J", expect=Expect({False: "PASS"}, otherwise="FAIL"),
                           description="minimum port energy over the run against its noise bound")


def converged_spec(model: str) -> MeasurementSpec:
    """The posterior's convergence: not converged is MARGINAL (evidence insufficient, not unstable)."""
    return MeasurementSpec(f"posterior converged ({model})", expect=Expect({True: "PASS"}, otherwise="MARGINAL"),
                           description="integrated autocorrelation time, ≥ 50 τ, acceptance, split-R̂")


def nominal_verdict_spec(criterion: str) -> MeasurementSpec:
    return MeasurementSpec(f"nominal {criterion}", expect=Expect(
        {"stable": "PASS", "marginal": "MARGINAL", "potentially_unstable": "FAIL"}))


NOMINAL_MARGIN = MeasurementSpec("nominal margin", limit=MARGIN, expect=MARGIN_VERDICT,
                                 description="normalized margin of the decisive condition")


def p_stable_spec(policy: Policy) -> MeasurementSpec:
    """The Clopper-Pearson interval of P(stable) against the required probability."""
    return MeasurementSpec("P(stable), lower confidence bound", limit=Limit(lower=policy.required_probability))


def p_stable_is_spec(policy: Policy) -> MeasurementSpec:
    """The importance-sampling interval of P(stable) (ERROR when fewer than 10 samples fail)."""
    return MeasurementSpec("P(stable), lower confidence bound (importance sampling)",
                           limit=Limit(lower=policy.required_probability))


def beta_spec(required_beta: float) -> MeasurementSpec:
    return MeasurementSpec("reliability index β", limit=Limit(lower=required_beta))


def worst_case_spec(policy: Policy) -> MeasurementSpec:
    return MeasurementSpec(f"worst-case margin over the {policy.credible:.0%} credible region", limit=MARGIN,
                           description="minimum of the nominal margin's function (exact criterion) over the "
                                       "region; ≤ the nominal margin")


def headroom_spec(parameter: str, what: str) -> MeasurementSpec:
    return MeasurementSpec(f"{parameter} headroom {what}", limit=HEADROOM,
                           description=f"limit / current {parameter} − 1 (0 at the stability boundary)")


def info_spec(name: str, unit: str = "") -> MeasurementSpec:
    """Evidence shown, not judged (outcome INFO)."""
    return MeasurementSpec(name, unit=unit)


# ---------------------------------------------------------------------------------------------
# stage inputs and outputs


@dataclass(frozen=True)
class Context:
    """What every stage reads: the scene and its certification section, the output folder, the
    seed, the verdict policy, the network model's name, criterion and fixed parameters."""

    scene: Any
    cert: Any  # hil.scene.spec.CertificationCfg
    out: Path
    seed: int
    policy: Policy
    model: str
    criterion: str
    params: Mapping[str, Any]
    say: Callable[[str], None]


@dataclass
class Sheet:
    """What the stages record (OpenHTF's test record): measurements in order, plots, evidence
    errors (any makes the decision ERROR), the failures of optional stages (recorded, deciding
    nothing but their own section), and each stage's wall time [s]."""

    measurements: list[Measurement] = field(default_factory=list)
    plots: dict[str, Series] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    optional_errors: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)  # optional stage -> reason
    timings: dict[str, float] = field(default_factory=dict)

    def add(self, m: Measurement) -> None:
        self.measurements.append(m)

    def optional(self, name: str, fn: Callable[..., Any], *args: Any, default: Any = None) -> Any:
        """Run an optional stage (witness, plots, energy evidence): a failure is logged and
        recorded as one line ``"<stage> failed: <reason>"``, and the stage yields ``default``."""
        try:
            return fn(*args)
        except Exception as exc:  # recorded, never swallowed (hil.certify.pipeline's docstring)
            reason = one_line(exc)
            logger.warning("optional stage %s failed: %s", name, reason, exc_info=logger.isEnabledFor(logging.DEBUG))
            self.optional_errors.append(f"{name} failed: {reason}")
            self.failed[name] = reason
            return default

    def timed(self, name: str, say: Callable[[str], None], label: str) -> _Timed:
        """A context manager timing stage ``name`` (announced as ``"<label>: <name> ..."``)."""
        return _Timed(self, name, say, label)


class _Timed:
    def __init__(self, sheet: Sheet, name: str, say: Callable[[str], None], label: str) -> None:
        self.sheet, self.name, self.say, self.label = sheet, name, say, label
        self.t0 = 0.0

    def __enter__(self) -> None:
        self.t0 = time.perf_counter()
        self.say(f"{self.label}: {self.name} ...")

    def __exit__(self, *exc: object) -> None:
        self.sheet.timings[self.name] = time.perf_counter() - self.t0


def one_line(exc: BaseException, limit: int = 300) -> str:
    """``exc`` as one line: its message (with the exception type unless it is one of ours)."""
    msg = " ".join(str(exc).split()) or "(no message)"
    if not isinstance(exc, HilError):
        msg = f"{type(exc).__name__}: {msg}"
    return msg if len(msg) <= limit else msg[: limit - 1] + "…"


@dataclass(frozen=True)
class RunOutput:
    """The run stage: each experiment's outcome (name -> hil.run.runner.ExperimentOutcome) and the
    energy evidence read from them."""

    outcomes: Mapping[str, Any]
    energy: tuple[EnergyEvidence, ...] = ()


@dataclass(frozen=True)
class PosteriorDraws:
    """The identify stage: independent draws of every uncertain parameter (name -> (n,) array;
    empty when nothing is uncertain), the identification sections, whether every posterior
    converged, the independent draws available before subsampling, how the draws were made, and
    what caps the decision at MARGINAL."""

    draws: Mapping[str, np.ndarray]
    identification: tuple[Identification, ...] = ()
    converged: bool = True
    n_independent: int | None = None
    sampling: tuple[str, ...] = ()
    #: reasons the decision can be at most MARGINAL: a misfit plant model, energy evidence that only
    #: dry friction kept above its bound (hil.certify.friction)
    caps: tuple[str, ...] = ()


@dataclass(frozen=True)
class NominalOutput:
    """The nominal stage: the parameters at the posterior centre, the network built from them
    (None when it could not be built), the criterion's result and its certificate section."""

    params: Mapping[str, Any]
    network: Any = None  # hil.stability.rational.TransferMatrix
    result: Any = None  # hil.stability.results.StabilityResult
    section: Nominal | None = None

    @property
    def verdict(self) -> str | None:
        return None if self.result is None else str(self.result.verdict)


@dataclass(frozen=True)
class RobustOutput:
    """The robust stage: the stability of every independent draw, the section, the FORM result
    (β) and the importance-sampling estimate (None where not made)."""

    stable_draws: np.ndarray | None = None
    section: Robust | None = None
    form: Any = None  # hil.stability.reliability.FormResult
    rare: RareEvent | None = None


@dataclass(frozen=True)
class Verdict:
    """The decide stage: the decision and its reasons."""

    decision: Decision
    reasons: tuple[str, ...]


@dataclass(frozen=True)
class WitnessOutput:
    """The witness stage: the witness section (None: none searched or found) and the reasons it adds."""

    witness: WitnessSection | None = None
    reasons: tuple[str, ...] = ()


@dataclass(frozen=True)
class DesignOutput:
    """The design stage: the design section (None without a design parameter)."""

    design: Design | None = None
