"""Structured results of stability criteria.

A :class:`StabilityResult` is built from :class:`Condition` records, one per checked condition
(pole location, residue, one frequency-domain polynomial). The verdict is derived, never set by
hand (definitions with their tests: docs/VERDICTS.md):

* ``potentially_unstable`` -- some condition is violated: its exact sign for the given
  coefficients (read as the binary rationals they are) is negative somewhere;
* ``marginal`` -- no violation, but some condition is marginal: with a user tolerance
  (``Tolerances(rtol=R)``, ``hil stability --rtol R``) its status can flip under a relative
  perturbation R of the coefficients; or, on the flagged paths that form a condition from derived
  (rounded) entries or a sweep, the rounding bound straddles zero;
* ``stable`` -- every condition holds. When some condition holds only with *equality*
  (an identically-zero minor, a real part touching zero at isolated frequencies, a singular
  residue matrix) the result is flagged ``weak``: the network is stable against strictly passive
  terminations ("weakly stable" in paper 001; "absolutely stable" in paper 000, whose Theorem 1
  uses non-strict inequalities);
* ``not_applicable`` -- the criterion's preconditions fail (e.g. the symmetrization conditions
  A/B of Theorem 1), with the reason.

Margins are dimensionless distances to instability (docs/VERDICTS.md, hil.stability.margins):
for frequency conditions min p(x)/M_r(x) (M the envelope magnitude polynomial restricted to p's
exact degree range); for poles the damping ratio -Re(p)/|p| (0 on the imaginary axis); for
residue matrices the smallest eigenvalue (or minor) over their envelope. The result's margin is
the smallest over the deciding conditions, those holding with equality included (0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Literal

ConditionStatus = Literal["satisfied", "equality", "marginal", "violated", "not_applicable"]

__all__ = ["Condition", "StabilityResult", "Verdict", "combine"]


class Verdict(StrEnum):
    STABLE = "stable"
    MARGINAL = "marginal"
    POTENTIALLY_UNSTABLE = "potentially_unstable"
    NOT_APPLICABLE = "not_applicable"


@dataclass
class Condition:
    """One checked condition.

    ``name`` is short and stable (e.g. ``"E[1,2]"``), ``label`` says what it is in the papers'
    words, ``worst_frequency`` is in rad/s (``inf`` for the high-frequency limit, ``None`` for
    conditions without a frequency), ``evidence`` holds what was checked (polynomial coefficients
    in descending powers of x = ω², negative bands in rad/s, poles, residues, method).
    """

    name: str
    label: str
    status: ConditionStatus
    margin: float
    worst_frequency: float | None = None
    detail: str = ""
    evidence: dict[str, Any] = field(default_factory=dict)
    #: a frequency condition's normalized ratio, for its critical band (hil.stability.margins):
    #: (p exact before axis cancellation, m_r ascending floats), in the network's normalized x;
    #: not serialized
    ratio: Any = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "label": self.label,
            "status": self.status,
            "margin": _num(self.margin),
            "worst_frequency": _num(self.worst_frequency),
            "detail": self.detail,
            "evidence": _jsonable(self.evidence),
        }


@dataclass
class StabilityResult:
    """Outcome of one criterion on one network."""

    verdict: Verdict
    criterion: str
    margin: float
    worst_frequency: float | None
    failed_condition: str | None
    conditions: list[Condition]
    weak: bool = False
    reason: str = ""
    network: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.verdict == Verdict.STABLE

    def condition(self, name: str) -> Condition:
        for c in self.conditions:
            if c.name == name:
                return c
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        return {
            "verdict": str(self.verdict),
            "criterion": self.criterion,
            "margin": _num(self.margin),
            "worst_frequency": _num(self.worst_frequency),
            "failed_condition": self.failed_condition,
            "weak": self.weak,
            "reason": self.reason,
            "network": _jsonable(self.network),
            "conditions": [c.to_dict() for c in self.conditions],
        }

    def summary(self) -> str:
        wf = "" if self.worst_frequency is None else f" at ω = {_fmt_w(self.worst_frequency)}"
        s = f"{self.criterion}: {self.verdict}"
        if self.verdict == Verdict.STABLE and self.weak:
            s += " (weak: holds with equality in " + ", ".join(
                c.name for c in self.conditions if c.status == "equality") + ")"
        if self.failed_condition:
            s += f"; failed {self.failed_condition}"
        if self.reason:
            s += f"; {self.reason}"
        return s + f"; margin {self.margin:.3g}{wf}"


def _fmt_w(w: float) -> str:
    return "∞" if w is not None and math.isinf(w) else f"{w:.4g} rad/s"


def _num(v: float | None) -> float | str | None:
    if v is None:
        return None
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if isinstance(v, float) and math.isnan(v):
        return None
    return float(v)


def _jsonable(o: Any) -> Any:
    import numpy as np

    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, complex | np.complexfloating):
        return {"re": _num(float(o.real)), "im": _num(float(o.imag))}
    if isinstance(o, float | np.floating):
        return _num(float(o))
    if isinstance(o, np.integer | np.bool_):
        return o.item()
    return o


_RANK = {"violated": 3, "marginal": 2, "equality": 1, "satisfied": 0, "not_applicable": -1}


def combine(criterion: str, conditions: list[Condition], network: dict[str, Any] | None = None,
            reason: str = "") -> StabilityResult:
    """Derive the verdict, overall margin and decisive condition from condition records."""
    network = network or {}
    na = [c for c in conditions if c.status == "not_applicable"]
    if na:
        why = reason or "; ".join(f"{c.name}: {c.detail}" for c in na)
        return StabilityResult(Verdict.NOT_APPLICABLE, criterion, math.nan, None, na[0].name, conditions,
                               reason=why, network=network)
    violated = [c for c in conditions if c.status == "violated"]
    marginal = [c for c in conditions if c.status == "marginal"]
    worst: Condition | None
    if violated:
        worst = min(violated, key=lambda c: c.margin)
        verdict = Verdict.POTENTIALLY_UNSTABLE
        failed: str | None = worst.name
    elif marginal:
        worst = min(marginal, key=lambda c: c.margin)
        verdict = Verdict.MARGINAL
        failed = worst.name
    else:
        # every condition counts, those holding with equality too (margin 0): a network on the
        # boundary has margin 0, so the margin is continuous there (issue 31, item 3); NaN margins
        # (verdict-only path) are skipped; ties go to the first condition in order
        known = [c for c in conditions if c.margin == c.margin]
        worst = min(known, key=lambda c: c.margin) if known else (conditions[0] if conditions else None)
        verdict = Verdict.STABLE
        failed = None
    weak = verdict == Verdict.STABLE and any(c.status == "equality" for c in conditions)
    margin = worst.margin if worst else math.nan
    wf = worst.worst_frequency if worst else None
    return StabilityResult(verdict, criterion, margin, wf, failed, conditions, weak, reason, network)
