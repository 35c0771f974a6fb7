"""Building blocks of every scene schema: the strict base model, SI number and matrix field types,
and the one formatter that turns a pydantic :class:`~pydantic.ValidationError` into one line.

Each concept of a scene owns its schema next to the code that uses it (the experiments in
:mod:`hil.experiments`, the controllers in :mod:`hil.controllers`, devices, simulation and
certification in :mod:`hil.scene.spec`); they all derive from :class:`StrictModel` and use the field
types below, so a mistyped key, a unit written into a number or a ragged matrix is answered the same
way wherever it is.

* :class:`StrictModel`: ``extra="forbid"`` with ``unknown key 'drivr', did you mean 'driver'?``.
* Numbers: finite floats; strings holding only a number are accepted (YAML 1.1 reads ``1e-3`` as a
  string), strings with units are refused with a hint (``numbers are SI: write 5.0``).
* Matrices (:func:`parse_matrix`, the one parser): a number (kept as a scalar: ``x * I`` once the
  size is known), a flat list (a diagonal), a list of rows, or a numpy array. :func:`as_matrix`
  expands a parsed value to ``n x n``; :func:`matrix_shape` is its shape (None for a scalar).
* :func:`validate` validates a mapping against a schema and raises :class:`hil.errors.SceneError`
  ``where.field.path: message`` (:func:`format_validation_error`).
* :class:`FieldError`: a :class:`~hil.errors.SceneError` carrying the scene path of the field it
  is about (cross-reference checks raise it).
"""

from __future__ import annotations

import difflib
import logging
import math
import re
from collections.abc import Callable, Sequence
from typing import Annotated, Any, Protocol, TypeVar

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator
from pydantic_core import PydanticCustomError

from hil.errors import SceneError
from hil.inputs import SEED_MAX, field_path

__all__ = [
    "CriterionName",
    "DofList",
    "FieldError",
    "Name",
    "SceneView",
    "Seed",
    "StrictModel",
    "as_matrix",
    "format_validation_error",
    "matrix_shape",
    "near",
    "number",
    "parse_matrix",
    "register_tagged",
    "unknown_key_message",
    "validate",
]

logger = logging.getLogger(__name__)

M = TypeVar("M", bound=BaseModel)

# ---------------------------------------------------------------------------------------------
# numbers

_LEADING_NUMBER = re.compile(r"\s*([-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)")


def number(value: Any, unit: str = "") -> float:
    """A finite real number. Strings holding only a number are accepted (YAML 1.1 reads ``1e-3``
    as a string); strings with units are rejected with a hint. ``unit`` appears in the message."""
    what = f"a number{(' in ' + unit) if unit else ''}"
    if isinstance(value, bool) or value is None:
        raise PydanticCustomError("number", "expected {what}, got {got}", {"what": what, "got": repr(value)})
    if isinstance(value, int | float | np.integer | np.floating):
        x = float(value)
    elif isinstance(value, str):
        try:
            x = float(value)
        except ValueError:
            m = _LEADING_NUMBER.match(value)
            hint = f" (numbers are SI: write {float(m.group(1))!r})" if m else ""
            raise PydanticCustomError(
                "number", "expected {what}, got {got}{hint}", {"what": what, "got": repr(value), "hint": hint}
            ) from None
    else:
        raise PydanticCustomError("number", "expected {what}, got {got}",
                                  {"what": what, "got": type(value).__name__})
    if not math.isfinite(x):
        raise PydanticCustomError("number", "expected {what}, got {got}", {"what": what, "got": repr(value)})
    return x


def in_unit(unit: str) -> Callable[[Any], float]:
    """A before-validator reading :func:`number` with ``unit`` in its message."""

    def read(value: Any) -> float:
        return number(value, unit)

    return read


Number = Annotated[float, BeforeValidator(in_unit(""))]
Effort = Annotated[float, BeforeValidator(in_unit("N or N.m"))]
EffortNonneg = Annotated[float, BeforeValidator(in_unit("N or N.m")), Field(ge=0)]
Position = Annotated[float, BeforeValidator(in_unit("m or rad"))]
PGain = Annotated[float, BeforeValidator(in_unit("N/m or N.m/rad"))]
VGain = Annotated[float, BeforeValidator(in_unit("N.s/m or N.m.s/rad"))]
MassPos = Annotated[float, BeforeValidator(in_unit("kg or kg.m^2")), Field(gt=0)]
DampNonneg = Annotated[float, BeforeValidator(in_unit("N.s/m or N.m.s/rad")), Field(ge=0)]
StiffPos = Annotated[float, BeforeValidator(in_unit("N/m or N.m/rad")), Field(gt=0)]
StiffNonneg = Annotated[float, BeforeValidator(in_unit("N/m or N.m/rad")), Field(ge=0)]
Fraction = Annotated[float, BeforeValidator(in_unit("[0, 1]")), Field(ge=0, le=1)]
Probability = Annotated[float, BeforeValidator(in_unit("(0, 1)")), Field(gt=0, lt=1)]
Hz = Annotated[float, BeforeValidator(in_unit("Hz")), Field(gt=0)]
HzOrZero = Annotated[float, BeforeValidator(in_unit("Hz")), Field(ge=0)]
Seconds = Annotated[float, BeforeValidator(in_unit("s")), Field(gt=0)]
SecondsOrZero = Annotated[float, BeforeValidator(in_unit("s")), Field(ge=0)]
Positive = Annotated[float, BeforeValidator(in_unit("")), Field(gt=0)]

# ---------------------------------------------------------------------------------------------
# matrices: the one parser

MatrixValue = float | list[list[float]]


def parse_matrix(value: Any, unit: str = "") -> MatrixValue:
    """A matrix field as written in a scene: a number is kept as a scalar (``x * I`` once the size
    is known), a flat list is a diagonal, a list of rows a matrix (rectangular, non-empty); numpy
    arrays are read like the lists they hold. Entries are finite numbers (:func:`number`)."""
    if isinstance(value, np.ndarray):
        value = value.item() if value.ndim == 0 else value.tolist()
    if isinstance(value, int | float | str | np.integer | np.floating) and not isinstance(value, bool):
        return number(value, unit)
    if isinstance(value, Sequence) and not isinstance(value, str):
        if all(not isinstance(r, Sequence | np.ndarray) or isinstance(r, str) for r in value):
            diag = [number(v, unit) for v in value]
            n = len(diag)
            if n == 0:
                raise PydanticCustomError("matrix", "expected a matrix (list of rows), got an empty list")
            return [[diag[i] if i == j else 0.0 for j in range(n)] for i in range(n)]
        rows = []
        for r in value:
            if isinstance(r, np.ndarray):
                r = r.tolist()
            if not isinstance(r, Sequence) or isinstance(r, str):
                raise PydanticCustomError("matrix", "expected a matrix (list of rows of numbers), got a mix")
            rows.append([number(v, unit) for v in r])
        if not rows or any(len(r) != len(rows[0]) for r in rows) or not rows[0]:
            raise PydanticCustomError("matrix", "expected a rectangular matrix (rows of equal length)")
        return rows
    raise PydanticCustomError("matrix", "expected a number or a matrix (list of rows), got {got}",
                              {"got": type(value).__name__})


def in_matrix_unit(unit: str) -> Callable[[Any], MatrixValue]:
    """A before-validator reading :func:`parse_matrix` with ``unit`` in its messages."""

    def read(value: Any) -> MatrixValue:
        return parse_matrix(value, unit)

    return read


MassMat = Annotated[float | list[list[float]], BeforeValidator(in_matrix_unit("kg or kg.m^2"))]
DampMat = Annotated[float | list[list[float]], BeforeValidator(in_matrix_unit("N.s/m or N.m.s/rad"))]
StiffMat = Annotated[float | list[list[float]], BeforeValidator(in_matrix_unit("N/m or N.m/rad"))]


def matrix_shape(value: MatrixValue) -> tuple[int, int] | None:
    """``(rows, cols)`` of a parsed matrix field, None for a scalar (``x * I`` of any size)."""
    if isinstance(value, int | float):
        return None
    return (len(value), len(value[0]) if value else 0)


def as_matrix(value: MatrixValue, n: int) -> np.ndarray:
    """A parsed matrix field as an ``n x n`` array (scalars become ``x * I``; a matrix is returned
    as it is: check its shape with :func:`matrix_shape` first)."""
    if isinstance(value, int | float):
        return float(value) * np.eye(n)
    return np.asarray(value, dtype=float)


# ---------------------------------------------------------------------------------------------
# names, seeds


def _seed(value: Any) -> Any:
    if isinstance(value, bool):
        raise PydanticCustomError("seed", "expected an integer seed in [0, 2**32-1], got {got}", {"got": repr(value)})
    if isinstance(value, int) and not 0 <= value <= SEED_MAX:
        raise PydanticCustomError("seed", "expected an integer seed in [0, 2**32-1], got {got}", {"got": value})
    return value


#: a random seed: an integer in [0, 2**32 - 1] (what numpy's generators and the mocks accept)
Seed = Annotated[int, BeforeValidator(_seed), Field(ge=0, le=SEED_MAX)]
#: a device, body, port or experiment name
Name = Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$", max_length=64)]


def register_tagged(registry: dict[str, Any], name: str, schema: type[BaseModel], entry: Any, what: str) -> None:
    """Put ``entry`` into ``registry`` under ``name``: ``schema.type`` must be ``Literal[name]``
    (the discriminator of the scene's union); a name already registered with another schema is
    refused. ``what``: ``experiment type`` / ``controller type`` (messages). The one registration
    rule of the scene's tagged unions (experiments, controllers)."""
    tag = schema.model_fields["type"].annotation
    if getattr(tag, "__args__", None) != (name,):
        raise TypeError(f"{schema.__name__}.type must be Literal[{name!r}], got {tag!r}")
    if name in registry and registry[name].schema is not schema:
        raise ValueError(f"{what} {name!r} is already registered")
    registry[name] = entry

def _criterion_name(v: Any) -> str:
    """A criterion :func:`hil.stability.criteria.check` runs: ``auto``, a built-in or a
    registered one (entry points are read only for a name that is not built in)."""
    from hil.stability.criteria import criterion_names, is_criterion

    if not isinstance(v, str) or not is_criterion(v):
        names = ("auto", *criterion_names())
        hint = near(v, names) if isinstance(v, str) else ""
        hint = hint if "did you" in hint else ""  # the names are listed already
        raise PydanticCustomError("criterion", "unknown criterion: expected one of {names}, got {got}{hint}",
                                  {"names": ", ".join(names), "got": repr(v), "hint": hint})
    return v


#: a stability criterion's name (``auto`` or one of :func:`hil.stability.criteria.criterion_names`)
CriterionName = Annotated[str, BeforeValidator(_criterion_name)]
#: DOF indices (of a body or a device), at least one
DofList = Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=1)]
#: wrench components (Fx, Fy, Fz, Tx, Ty, Tz) by index
WrenchAxes = Annotated[list[Annotated[int, Field(ge=0, le=5)]], Field(min_length=1)]

# ---------------------------------------------------------------------------------------------
# the strict base model


def unknown_key_message(key: Any, known: Any) -> str:
    """``unknown key 'matrx', did you mean 'matrix'?`` (or the list of known keys when none is
    close): the one message for a mistyped key, shared by every strict mapping."""
    names = sorted(str(k) for k in known)
    close = difflib.get_close_matches(str(key), names, n=1, cutoff=0.6)
    if close:
        return f"unknown key {str(key)!r}, did you mean {close[0]!r}?"
    return f"unknown key {str(key)!r}; expected one of: {', '.join(names)}"


class StrictModel(BaseModel):
    """``extra="forbid"`` with a did-you-mean message naming the offending key."""

    model_config = ConfigDict(extra="forbid", frozen=False, populate_by_name=True)

    @model_validator(mode="before")
    @classmethod
    def _unknown_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            known = set(cls.model_fields) | {f.alias for f in cls.model_fields.values() if f.alias}
            for key in data:
                if key not in known:
                    raise PydanticCustomError("unknown_key", "{msg}",
                                              {"key": str(key), "msg": unknown_key_message(key, known)})
        return data


def near(name: str, known: Sequence[str]) -> str:
    """`` (did you mean 'x'?)`` or ``; known: a, b`` for a name not in ``known``."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.5)
    if close:
        return f" (did you mean {close[0]!r}?)"
    return f"; known: {', '.join(known) if known else '(none)'}"


class FieldError(SceneError):
    """A problem with one field of a scene: ``path`` (``controller.master``) and ``message``."""

    def __init__(self, path: str, message: str) -> None:
        super().__init__(f"{path}: {message}")
        self.path = path
        self.message = message


# ---------------------------------------------------------------------------------------------
# validation errors as one line


def _model_names() -> set[str]:
    names: set[str] = set()
    todo: list[type] = [StrictModel]
    while todo:
        cls = todo.pop()
        names.add(cls.__name__)
        todo += cls.__subclasses__()
    return names


def _strip_tags(loc: Sequence[Any], data: Any) -> list[Any]:
    """Drop discriminator tags and union-member names that pydantic inserts in error locations."""
    out: list[Any] = []
    cur = data
    names = _model_names()
    for part in loc:
        if isinstance(part, int):
            out.append(part)
            cur = cur[part] if isinstance(cur, list) and 0 <= part < len(cur) else None
            continue
        if isinstance(cur, dict) and part in cur:
            out.append(part)
            cur = cur[part]
            continue
        if isinstance(cur, dict) and cur.get("type") == part:
            continue  # discriminator tag
        if isinstance(part, str) and ("[" in part or part in ("float", "int", "str") or part in names):
            continue  # union member names ("float", "list[list[float]]", "HumanCfg", ...)
        out.append(part)
        cur = None
    return out


#: error types whose context names the key the message is about (appended to the location)
_KEYED = ("dofs", "axes", "band", "settle", "servo", "coupler", "environment")


def format_validation_error(exc: ValidationError, data: Any) -> str:
    """``field.path: message`` for the most specific error of ``exc`` (raised validating ``data``)."""
    errs = exc.errors(include_url=False)
    # the deepest location is the most specific (for unions such as ``human: X | list[X]`` the
    # member whose shape matches the input fails deeper than the one that does not)
    err = max(errs, key=lambda e: len(_strip_tags(e["loc"], data)))
    loc = _strip_tags(err["loc"], data)
    ctx = err.get("ctx") or {}
    typ = err["type"]
    msg = str(err["msg"]).removeprefix("Value error, ")
    if typ == "unknown_key" or ("key" in ctx and typ in _KEYED):
        loc = [*loc, ctx["key"]]
    if typ == "union_tag_invalid":
        tag = ctx.get("tag")
        expected = str(ctx.get("expected_tags", "")).replace("'", "").split(", ")
        loc = [*loc, ctx.get("discriminator", "type").strip("'")]
        msg = f"unknown type {tag!r}{near(str(tag), expected)}; expected one of: {', '.join(expected)}"
    elif typ == "union_tag_not_found":
        loc = [*loc, "type"]
        msg = "missing 'type'"
    elif typ == "missing":
        msg = "required field is missing"
    elif typ == "literal_error":
        msg = f"expected {ctx.get('expected', msg)}, got {err.get('input')!r}"
    elif typ in ("int_type", "int_parsing", "int_from_float", "bool_type", "bool_parsing", "string_type",
                 "dict_type", "list_type", "model_type", "model_attributes_type", "tuple_type"):
        msg = f"{msg} (got {err.get('input')!r})"
    elif typ in ("greater_than", "greater_than_equal", "less_than", "less_than_equal", "too_short", "too_long",
                 "string_pattern_mismatch"):
        inp = err.get("input")
        if not isinstance(inp, dict | list):
            msg = f"{msg} (got {inp!r})"
    return f"{field_path(loc)}: {msg}"


def validate(schema: type[M], data: Any, where: str = "") -> M:
    """``data`` validated against ``schema`` (a model instance of ``schema`` is returned as is).
    Raises :class:`SceneError` ``where.field.path: message``."""
    if isinstance(data, schema):
        return data
    if not isinstance(data, dict) and hasattr(data, "items"):
        data = dict(data.items())
    try:
        return schema.model_validate(data)
    except ValidationError as exc:
        msg = format_validation_error(exc, data)
        if where:
            msg = f"{where}: {msg.removeprefix('(top level): ')}" if msg.startswith("(top level)") \
                else f"{where}.{msg}"
        raise SceneError(msg) from None


class SceneView(Protocol):
    """What the scene-level checks of an experiment type or a controller read of the scene
    (:class:`hil.scene.spec.Scene` provides it). The scene composes their schemas, so they see it
    only through this interface (the import rule: the scene imports them, not the reverse)."""

    @property
    def simulation(self) -> Any:
        """The simulated plant block, or None at a real bench."""

    @property
    def network(self) -> Any:
        """The scene's network block (``ports``: the interaction ports)."""

    def device(self, name: str) -> Any:
        """The device called ``name`` (a group of devices is one device of summed ``dof``)."""

    def port(self, name: str) -> Any:
        """The network port called ``name``."""

    def require(self, path: str, name: str, role: str | None = None) -> Any:
        """The device ``name``, refused as a field error at ``path`` when it is missing or (with
        ``role``) has another role."""
