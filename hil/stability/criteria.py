"""Passivity and absolute-stability criteria for LTI networks, decided exactly.

Criteria (each returns a :class:`~hil.stability.results.StabilityResult`):

* :func:`positive_real` -- positive realness of a one-port or of a transfer matrix
  (Definition 2 of paper 000 / Definition 3 of paper 001): no RHP poles; imaginary-axis poles
  simple with Hermitian positive semidefinite residue matrices; G(jω) + G(jω)ᴴ ⪰ 0 for all ω,
  checked through *all* principal minors of the Hermitian part (each a polynomial in x = ω²).
* :func:`two_port_passivity` -- Theorem 2 of paper 002 = positive realness of any immittance
  matrix of the two-port (for m-DOF ports too).
* :func:`llewellyn` -- Llewellyn's absolute stability (Theorem 3 of paper 002; appendix of 000).
* :func:`absolute_stability` -- Theorem 1 of paper 000 (m-DOF n-port), with the
  symmetrization conditions A and B. Stability vs *weak* stability (paper 001) is the strict
  vs non-strict reading of the same conditions: see ``StabilityResult.weak``.
* :func:`check` -- picks the cheapest sufficient test for the network's size.

Frequency conditions are reduced to real polynomials in x = ω², formed exactly over Q from the
float coefficients (python-flint), and decided without rounding (:mod:`exact`); dense sweeps are
only used (and flagged ``method: sweep``) for Theorem 1 blocks of size ≥ 3 whose symmetrized
matrix Z' is not rational. Poles are located exactly (:func:`hil.stability.exact.exact_poles`: RHP
count by Routh-Hurwitz over Q, imaginary-axis poles from gcd(Re d(jω), Im d(jω)/ω)); no pole
tolerance. Verdicts, statuses and margins are defined in docs/VERDICTS.md.
"""

from __future__ import annotations

import itertools
import logging
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from flint import fmpq

from hil.errors import ModelError
from hil.stability.conditions import _hermitian_minors, _llewellyn_eta

# re-exported (``X as X``): hil.models, hil.certify, benchmarks and tests import these from here
from hil.stability.forms import _axis_factor as _axis_factor
from hil.stability.forms import _exact_llewellyn_polys, _exact_minor_polys, _lbl, _qpoly_float
from hil.stability.forms import _lcm as _lcm
from hil.stability.forms import hermitian_minor_poly as hermitian_minor_poly
from hil.stability.forms import llewellyn_polys as llewellyn_polys
from hil.stability.normalize import _as_tm, _netinfo, _rescale
from hil.stability.normalize import _normalized as _normalized
from hil.stability.normalize import _scaled_exact as _scaled_exact
from hil.stability.poles import _rhp_poles as _rhp_poles
from hil.stability.poles import infinity_condition as infinity_condition
from hil.stability.poles import pole_conditions as pole_conditions
from hil.stability.rational import _RF, Rational, TransferMatrix, _to_rf
from hil.stability.ratios import _eta_ratio as _eta_ratio
from hil.stability.ratios import _freq_range as _freq_range
from hil.stability.ratios import _hermitian_ratio as _hermitian_ratio
from hil.stability.results import Condition, StabilityResult, combine
from hil.stability.theorem1 import _components, _exact_symmetrize, _sqrt_of_pair, _sweep_block
from hil.stability.theorem1 import _exact_sqrt as _exact_sqrt
from hil.stability.theorem1 import _rational_sqrt as _rational_sqrt
from hil.stability.theorem1 import _rf_equal as _rf_equal
from hil.stability.theorem1 import _symmetrize as _symmetrize
from hil.stability.tolerances import POLE_TOL as POLE_TOL
from hil.stability.tolerances import RESIDUE_TOL as RESIDUE_TOL
from hil.stability.tolerances import TOL, Tolerances

logger = logging.getLogger(__name__)

__all__ = [
    "Tolerances",
    "absolute_stability",
    "check",
    "infinity_condition",
    "llewellyn",
    "margin_curve",
    "pole_conditions",
    "positive_real",
    "two_port_passivity",
]


# ------------------------------------------------------------------------------------------
# criteria


def positive_real(g: TransferMatrix | Rational, tol: Tolerances = TOL, margins: bool = True) -> StabilityResult:
    """Positive realness of a one-port Z(s) or an n×n transfer matrix G(s) (passivity).

    ``margins=False`` returns the same verdict without computing margins (faster)."""
    tm0 = _as_tm(g)
    tm, w0 = _normalized(tm0)
    conds = pole_conditions(tm, "hermitian", tol, w0, margins)
    conds += _hermitian_minors(tm.entries, list(range(tm.n)), tol, "E",
                               "G(jω)+G(jω)ᴴ ⪰ 0" if tm.n > 1 else "Re Z(jω) ≥ 0", margins)
    crit = "positive_real" if tm.n > 1 else "positive_real (one-port)"
    return combine(crit, [*_rescale(conds, w0), infinity_condition(tm0, "hermitian", margins)], _netinfo(tm0, w0))


def two_port_passivity(tm: TransferMatrix, tol: Tolerances = TOL, margins: bool = True) -> StabilityResult:
    """Two-port passivity (Theorem 2 of paper 002) in whatever immittance form ``tm`` is given.

    For the hybrid form this is exactly (a) no RHP poles, (b) simple imaginary poles with
    admissible residues, (c-i) Re h11 ≥ 0, Re h22 ≥ 0, (c-ii) Re h11 Re h22 - |h12* + h21|²/4 ≥ 0,
    i.e. positive realness of the immittance matrix; m-DOF ports are handled blockwise.
    """
    if tm.n_ports != 2:
        raise ModelError(f"two-port passivity needs a two-port, got {tm.n_ports} ports")
    r = positive_real(tm, tol, margins)
    r.criterion = "two_port_passivity"
    return r



def llewellyn(tm: TransferMatrix, tol: Tolerances = TOL, margins: bool = True) -> StabilityResult:
    """Llewellyn's absolute stability criterion for a 1-DOF two-port (any immittance form).

    (a) no RHP poles, (b) imaginary poles simple with k11, k22 ≥ 0 and k11k22 - k12k21 ≥ 0,
    (c) Re p11 ≥ 0, Re p22 ≥ 0 and η = 2 Re p11 Re p22 - Re(p12 p21) - |p12 p21| ≥ 0 for all ω.
    """
    if tm.n != 2:
        raise ModelError("Llewellyn's criterion applies to 1-DOF two-ports (2×2 immittance matrices)")
    tm0 = tm
    tm, w0 = _normalized(tm0)
    conds = pole_conditions(tm, "minors", tol, w0, margins)
    diag: list[Condition] = []
    for k in range(2):
        diag += _hermitian_minors(tm.entries, [k], tol, "E", "Re p(jω) ≥ 0", margins)
    conds += diag
    conds.append(_llewellyn_eta(tm.entries, 0, 1, tol, margins, all(c.status == "satisfied" for c in diag)))
    return combine("llewellyn", [*_rescale(conds, w0), infinity_condition(tm0, "minors", margins)], _netinfo(tm0, w0))


def absolute_stability(tm: TransferMatrix, tol: Tolerances = TOL, margins: bool = True) -> StabilityResult:
    """Theorem 1 of paper 000: absolute stability of an m-DOF n-port (impedance form, or any
    immittance form by its Remark 1).

    Preconditions (symmetrization): (A) z_ij z_jk z_ki = z_ji z_kj z_ik for all distinct i, j, k;
    (B) each diagonal block Z_ll is symmetric. If either fails the result is ``not_applicable``
    with the failing entries. Then: (C) no RHP poles; (D) imaginary-axis poles simple with
    non-negative principal minors of the residue matrix; (E) all principal minors of
    Re Z'(jω) ≥ 0 where z'_ij = γ_ij √(z_ij z_ji) (signs γ chosen so Z' and Z have equal principal
    minors). Blocks of Re Z' are decided exactly: 1×1 and 2×2 blocks through Re z_ii and
    Llewellyn's η (eq. 15b); larger blocks through the Hermitian minors of the rational Z' when
    √(z_ij z_ji) is rational, otherwise by a flagged numerical sweep. ``margins=False`` returns
    the same verdict without computing margins (faster).
    """
    tm0 = tm
    tm, w0 = _normalized(tm0)
    n = tm.n
    net = _netinfo(tm0, w0)
    conds: list[Condition] = []
    RF = _to_rf(tm.entries)  # exact entries over Q(s): A, B and the symmetrization are exact
    # (B) diagonal blocks symmetric
    off = 0
    bad_b = []
    for m in tm.port_dofs:
        for a in range(off, off + m):
            for b in range(a + 1, off + m):
                if not _rf_equal(RF[a][b], RF[b][a]):
                    bad_b.append((a, b))
        off += m
    if bad_b:
        a, b = bad_b[0]
        conds.append(Condition("B", "diagonal blocks Z_ll symmetric", "not_applicable", math.nan, None,
                               f"z{a + 1}{b + 1} ≠ z{b + 1}{a + 1} inside a port block", {"entries": bad_b}))
    else:
        conds.append(Condition("B", "diagonal blocks Z_ll symmetric", "satisfied", 1.0))
    # (A) cycle condition on all triples
    bad_a = []
    for i, j, k in itertools.combinations(range(n), 3):
        lhs = RF[i][j] * RF[j][k] * RF[k][i]
        rhs = RF[j][i] * RF[k][j] * RF[i][k]
        if not _rf_equal(lhs, rhs):
            bad_a.append((i, j, k))
    if bad_a:
        i, j, k = bad_a[0]
        conds.append(Condition("A", "symmetrization: z_ij z_jk z_ki = z_ji z_kj z_ik", "not_applicable", math.nan, None,
                               f"fails for (i,j,k) = ({i + 1},{j + 1},{k + 1})",
                               {"triples": [[a + 1, b + 1, c + 1] for a, b, c in bad_a]}))
    else:
        conds.append(Condition("A", "symmetrization: z_ij z_jk z_ki = z_ji z_kj z_ik", "satisfied", 1.0))
    if bad_a or bad_b:
        return combine("absolute_stability_nport", conds, net,
                       reason="Theorem 1 does not apply: the symmetrization conditions do not hold")
    # pairs with z_ij z_ji ≢ 0 define the coupling graph of Z'
    nz = np.zeros((n, n), bool)
    roots: dict[tuple[int, int], tuple[fmpq, _RF]] = {}
    irrational: set[tuple[int, int]] = set()
    for i in range(n):
        for j in range(i + 1, n):
            if tm[i, j].is_zero or tm[j, i].is_zero:
                continue
            nz[i, j] = nz[j, i] = True
            r = _sqrt_of_pair(RF[i][j], RF[j][i])
            if r is None:
                irrational.add((i, j))
            else:
                roots[(i, j)] = r
    conds += pole_conditions(tm, "minors", tol, w0, margins)
    for comp in _components(nz):
        if len(comp) == 1:
            conds += _hermitian_minors(tm.entries, comp, tol, "E", "Re z_ii(jω) ≥ 0", margins)
            continue
        edges = {(i, j) for i in comp for j in comp if i < j and nz[i, j]}
        # 2×2 blocks: Llewellyn's η on the given entries (eq. 15b), formed exactly; larger blocks
        # through the Hermitian minors of Z' (exactly, up to a diagonal similarity) when
        # √(z_ij z_ji) is a rational function up to a constant
        if len(comp) > 2 and not (edges & irrational):
            Sq, why = _exact_symmetrize(RF, comp, {e: roots[e] for e in edges})
            if Sq is not None:
                for c in _hermitian_minors(tm.entries, list(range(len(comp))), tol, "E", "Re Z'(jω) ⪰ 0", margins,
                                           q=Sq):
                    # relabel local indices to global ones
                    loc = [int(t) - 1 for t in c.name[2:-1].split(",")]
                    c.name = "E" + _lbl([comp[t] for t in loc])
                    c.label = f"principal minor {c.name[1:]} of Re Z'(jω) ≥ 0 (Z' exact over Q)"
                    c.evidence["formed"] = "exact (Z' up to a diagonal similarity, over Q)"
                    conds.append(c)
                continue
            if why != "irrational":
                conds.append(Condition("A*", "equal principal minors of Z' and Z", "not_applicable", math.nan, None,
                                       why))
                return combine("absolute_stability_nport", _rescale(conds, w0), net,
                               reason="Theorem 1 does not apply: Z is not symmetrizable")
        if len(comp) == 2:
            i, j = comp
            diag = (_hermitian_minors(tm.entries, [i], tol, "E", "Re z_ii(jω) ≥ 0", margins)
                    + _hermitian_minors(tm.entries, [j], tol, "E", "Re z_ii(jω) ≥ 0", margins))
            conds += diag
            conds.append(_llewellyn_eta(tm.entries, i, j, tol, margins, all(c.status == "satisfied" for c in diag)))
        else:
            conds += _sweep_block(tm, comp, tol)
    return combine("absolute_stability_nport", [*_rescale(conds, w0), infinity_condition(tm0, "minors", margins)], net)


#: a criterion's function: (network, tolerances, margins) -> result; ``margins=False`` may skip
#: the margins (the same verdict, faster)
CriterionFn = Callable[[TransferMatrix, Tolerances, bool], StabilityResult]


@dataclass(frozen=True)
class Criterion:
    """A named stability criterion :func:`check` can run: ``run(tm, tol, margins)``."""

    name: str
    run: CriterionFn
    description: str = ""


def _passivity(tm: TransferMatrix, tol: Tolerances, margins: bool) -> StabilityResult:
    return two_port_passivity(tm, tol, margins) if tm.n_ports == 2 else positive_real(tm, tol, margins)


#: the built-in criteria :func:`check` runs by name (besides ``auto``, which picks one by the
#: network's size)
CRITERIA: tuple[str, ...] = ("positive_real", "passivity", "llewellyn", "absolute_stability")

#: criterion name -> :class:`Criterion`: the built-ins, then those registered with
#: :func:`register_criterion` or through the entry-point group :data:`ENTRY_POINT_GROUP`
_REGISTRY: dict[str, Criterion] = {
    "positive_real": Criterion("positive_real", positive_real, "positive realness (one-port or matrix)"),
    "passivity": Criterion("passivity", _passivity, "two-port passivity (002 Theorem 2)"),
    "llewellyn": Criterion("llewellyn", llewellyn, "Llewellyn's absolute stability (002 Theorem 3)"),
    "absolute_stability": Criterion("absolute_stability", absolute_stability, "m-DOF n-port (000 Theorem 1)"),
}
#: entry points of other distributions: each loads a :class:`Criterion` (or a zero-argument
#: callable returning one); read once, on the first name that is not built in
ENTRY_POINT_GROUP = "hil_certify.criteria"
_entry_points_loaded = False


def register_criterion(criterion: Criterion, *, replace: bool = False) -> None:
    """Add a criterion :func:`check`, ``hil stability --criterion``, scenes and network files
    accept by name; refuses to shadow an existing name unless ``replace``."""
    if not re.fullmatch(r"[a-z][a-z0-9_]*", criterion.name) or criterion.name == "auto":
        raise ValueError(f"criterion name {criterion.name!r}: lower-case identifier other than 'auto' expected")
    if criterion.name in _REGISTRY and not replace and _REGISTRY[criterion.name] is not criterion:
        raise ValueError(f"criterion {criterion.name!r} is already registered")
    _REGISTRY[criterion.name] = criterion


def load_entry_points() -> list[str]:
    """Register the criteria other distributions declare in :data:`ENTRY_POINT_GROUP` (once; a
    broken entry point is logged and skipped). Returns the names registered."""
    global _entry_points_loaded
    if _entry_points_loaded:
        return []
    _entry_points_loaded = True
    from importlib.metadata import entry_points  # scanned only when a name is not built in

    out: list[str] = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
            crit = obj() if callable(obj) and not isinstance(obj, Criterion) else obj
            if not isinstance(crit, Criterion):
                raise TypeError(f"{ep.value} is not a Criterion")
            register_criterion(crit)
            out.append(crit.name)
        except Exception:
            logger.warning("criterion entry point %r (%s) could not be registered", ep.name, ep.value,
                           exc_info=True)
    return out


def criterion_names() -> tuple[str, ...]:
    """Every criterion :func:`check` runs by name (built-in first, then registered ones)."""
    load_entry_points()
    return tuple(_REGISTRY)


def is_criterion(name: str) -> bool:
    """Whether :func:`check` runs ``name`` (``auto`` included); entry points are read only for a
    name that is not built in."""
    if name == "auto" or name in _REGISTRY:
        return True
    load_entry_points()
    return name in _REGISTRY


class CriterionChoices(tuple[str, ...]):
    """``auto`` (optional) and the criterion names, for argparse ``choices``: membership of a
    built-in name reads no entry points (start-up time); iteration (an error message, help)
    lists every registered name."""

    _auto: bool

    def __new__(cls, auto: bool = True) -> CriterionChoices:
        obj = super().__new__(cls, (("auto",) if auto else ()) + CRITERIA)
        obj._auto = auto
        return obj

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and (self._auto or name != "auto") and is_criterion(name)

    def __iter__(self) -> Iterator[str]:
        return iter((("auto",) if self._auto else ()) + criterion_names())


def check(tm: TransferMatrix | Rational, criterion: str = "auto", tol: Tolerances = TOL,
          margins: bool = True) -> StabilityResult:
    """Run the criterion that fits the network (``auto``) or the named one.

    ``auto``: a one-port → positive realness; a 1-DOF two-port → Llewellyn; anything larger →
    Theorem 1 (which reduces to Llewellyn for m = 1, n = 2). Names: ``positive_real``,
    ``passivity`` (two-port passivity), ``llewellyn``, ``absolute_stability``, and any criterion
    registered (:func:`register_criterion`, entry points). ``margins=False``: the same verdict
    without margins (faster).
    """
    tm = _as_tm(tm)
    if criterion == "auto":
        if tm.n == 1:
            return positive_real(tm, tol, margins)
        if tm.n == 2 and tm.n_ports == 2:
            return llewellyn(tm, tol, margins)
        return absolute_stability(tm, tol, margins)
    if not is_criterion(criterion):
        raise ModelError(f"unknown criterion {criterion!r}; expected auto, {', '.join(criterion_names())}")
    return _REGISTRY[criterion].run(tm, tol, margins)


def margin_curve(g: TransferMatrix | Rational, condition: str = "E{1}") -> Callable[[np.ndarray], np.ndarray]:
    """ω ↦ p(x)/m_r(x) of one frequency condition, the quantity whose minimum is that condition's
    frequency-domain margin (docs/VERDICTS.md: p before imaginary-axis factors are cancelled, m its
    magnitude polynomial restricted to p's degree range), for plots: ω in physical rad/s, values
    in [-1, 1].

    ``condition`` is a condition name as in the results: ``E{i,j,...}`` (a principal minor of
    G + Gᴴ) or, for a 1-DOF two-port, ``L1`` / ``L2`` (Llewellyn's polynomials of E{1,2})."""
    from hil.stability.minimize import _Ratio

    tm, w0 = _normalized(_as_tm(g))
    if condition in ("L1", "L2"):
        if tm.n != 2:
            raise ModelError("L1/L2 are defined for 1-DOF two-ports")
        pair = _exact_llewellyn_polys([[tm[a, b] for b in (0, 1)] for a in (0, 1)])
        cp = pair[0] if condition == "L1" else pair[1]
    else:
        try:
            idx = tuple(int(t) - 1 for t in condition[2:-1].split(","))
        except ValueError:
            raise ModelError(f"unknown condition {condition!r}; expected E{{i,...}}, L1 or L2") from None
        if not condition.startswith("E{") or any(i < 0 or i >= tm.n for i in idx):
            raise ModelError(f"unknown condition {condition!r} for a {tm.n}x{tm.n} network")
        sub = [[tm[a, b] for b in idx] for a in idx]
        cp = _exact_minor_polys(sub)[tuple(range(len(idx)))]
    p = cp.full
    if p.is_zero():
        return lambda om: np.zeros_like(np.asarray(om, float))
    c = _qpoly_float(p)
    m = np.asarray(cp.m, float)
    n = c.size
    a = next(i for i in range(n) if p[i] != 0)
    mm = np.maximum(np.pad(m, (0, max(0, n - m.size)))[:n], np.abs(c))
    mm[:a] = 0.0
    ratio = _Ratio(c, mm)

    def f(om: np.ndarray) -> np.ndarray:
        x = (np.asarray(om, float) / w0) ** 2
        return ratio(x)

    return f
