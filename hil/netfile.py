"""Network description files (YAML or JSON) for ``hil stability FILE``.

Format::

    name: my two-port              # optional
    type: hybrid                   # impedance | admittance | hybrid | inverse_hybrid
    ports: [1, 1]                  # DOFs of each port (optional: one DOF per row)
    criterion: auto                # optional: auto | positive_real | passivity | llewellyn | absolute_stability
    matrix:                        # rows of entries; coefficients in descending powers of s, SI units
      - [{num: [0.05, 1.0], den: [1.0, 0.0]}, {num: [1.0], den: [1.0]}]
      - [{num: [-1.0]},                       {num: [1.0, 0.0], den: [0.17, 300.0]}]

``den`` defaults to ``[1]``. Coefficients are numbers (YAML ``1e3`` is a number, as in YAML 1.2
and JSON; a quoted ``'1'`` or a boolean is refused), finite, and small enough that the criteria's
arithmetic stays finite. A key given twice in one mapping is refused. Any mistake raises
:class:`hil.errors.SceneError` with a one-line message naming the file and the field (e.g.
``net.yaml: matrix[1][0].den: ...``); so does a file that is not UTF-8 text, a binary file, a folder
or an unreadable file.
"""

from __future__ import annotations

import difflib
import json
import math
import re
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    field_validator,
)

from hil.errors import HilError, SceneError
from hil.stability.rational import TransferMatrix

__all__ = ["NetworkFile", "load_network", "safe_yaml_load"]

#: largest coefficient magnitude accepted: products of a few coefficients must stay finite in float64
_MAX_COEF = 1e100

# YAML 1.2 / JSON floats: PyYAML (YAML 1.1) reads ``1e3`` and ``3.96e4`` (no dot, or no exponent sign) as strings
_FLOAT_RE = re.compile(r"^(?:[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)?"
                       r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")


def _number(x: Any) -> Any:
    if isinstance(x, bool) or not isinstance(x, int | float):
        raise ValueError(f"must be a number, got {x!r}")
    if isinstance(x, int) and abs(x) > _MAX_COEF:
        raise ValueError(f"is too large ({x:.3e}; at most {_MAX_COEF:g} in magnitude: rescale the units)")
    return x


def _finite(x: float) -> float:
    if not math.isfinite(x):
        raise ValueError(f"must be a finite number, got {x!r}")
    if abs(x) > _MAX_COEF:
        raise ValueError(f"is too large ({x:g}; at most {_MAX_COEF:g} in magnitude: rescale the units)")
    return x


#: one coefficient: a real number (not a string, not a boolean), finite, at most 1e100 in magnitude
Coefficient = Annotated[float, BeforeValidator(_number), AfterValidator(_finite)]


class Entry(BaseModel):
    model_config = ConfigDict(extra="forbid")
    num: list[Coefficient] = Field(min_length=1)
    den: list[Coefficient] = Field(default_factory=lambda: [1.0], min_length=1)

    @field_validator("den")
    @classmethod
    def _nonzero(cls, v: list[float]) -> list[float]:
        if not any(v):
            raise ValueError("denominator must not be identically zero")
        return v


class NetworkFile(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = ""
    type: Literal["impedance", "admittance", "hybrid", "inverse_hybrid"] = "impedance"
    ports: list[Annotated[int, Strict(), Field(ge=1)]] | None = None
    criterion: Literal["auto", "positive_real", "passivity", "llewellyn", "absolute_stability"] = "auto"
    matrix: list[list[Entry]] = Field(min_length=1)

    @field_validator("matrix")
    @classmethod
    def _square(cls, m: list[list[Entry]]) -> list[list[Entry]]:
        n = len(m)
        for i, row in enumerate(m):
            if len(row) != n:
                raise ValueError(f"row {i} has {len(row)} entries; the matrix must be square ({n}x{n})")
        return m

    def to_transfer_matrix(self) -> TransferMatrix:
        rows = [[{"num": e.num, "den": e.den} for e in row] for row in self.matrix]
        return TransferMatrix.from_coefficients(rows, self.type, self.ports or None, self.name)


def _loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def _yaml_loader() -> type:
    import yaml

    class _Loader(yaml.SafeLoader):
        """Safe loader with YAML 1.2 floats (``1e3``) and duplicate keys refused."""

    _Loader.yaml_implicit_resolvers = {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
    _Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_RE, list("-+0123456789."))

    def construct_mapping(loader: Any, node: Any, deep: bool = False) -> dict[Any, Any]:
        loader.flatten_mapping(node)
        out: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = loader.construct_object(key_node, deep=deep)
            if key in out:
                mark = key_node.start_mark
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r} (line {mark.line + 1}): each key may appear once", None)
            out[key] = loader.construct_object(value_node, deep=deep)
        return out

    _Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, construct_mapping)
    return _Loader


def safe_yaml_load(text: str) -> Any:
    """``yaml.safe_load`` with YAML 1.2 floats (``1e3`` is a number) and duplicate keys refused
    (:class:`yaml.YAMLError`)."""
    import yaml

    return yaml.load(text, Loader=_yaml_loader())  # a SafeLoader subclass


def read_text_file(p: Path, what: str = "file") -> str:
    """The UTF-8 text of ``p``; :class:`SceneError` with one line for a missing, unreadable, binary
    or non-UTF-8 file, or a folder."""
    if p.is_dir():
        raise SceneError(f"{p}: is a folder, not a {what}")
    if not p.exists():
        raise SceneError(f"{p}: no such file")
    try:
        raw = p.read_bytes()
    except PermissionError:
        raise SceneError(f"{p}: cannot read the {what}: permission denied") from None
    except OSError as exc:
        raise SceneError(f"{p}: cannot read the {what}: {exc.strerror or exc}") from None
    if b"\x00" in raw:
        raise SceneError(f"{p}: binary data (NUL bytes), not a text {what}")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise SceneError(f"{p}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start})") from None


def load_network(path: str | Path) -> tuple[TransferMatrix, str]:
    """Load a network file; returns the transfer matrix and the requested criterion."""
    p = Path(path)
    text = read_text_file(p, "network file")
    try:
        if p.suffix.lower() == ".json":
            data = json.loads(text, parse_constant=lambda c: float(c))
        else:
            data = safe_yaml_load(text)
    except Exception as exc:  # yaml.YAMLError / json.JSONDecodeError / RecursionError
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if "duplicate key" in str(exc):
            first = next(ln.strip() for ln in str(exc).splitlines() if "duplicate key" in ln)
        raise SceneError(f"{p}: not valid {'JSON' if p.suffix.lower() == '.json' else 'YAML'}: {first}") from None
    if not isinstance(data, dict):
        raise SceneError(f"{p}: expected a mapping with 'type' and 'matrix' at the top level")
    try:
        nf = NetworkFile.model_validate(data)
    except ValidationError as exc:
        errs = exc.errors()
        # an unknown key explains a missing one ("matrx" -> "matrix: Field required"): report it first
        err = next((e for e in errs if e["type"] == "extra_forbidden"), errs[0])
        if err["type"] == "extra_forbidden":
            key = str(err["loc"][-1])
            model = NetworkFile if len(err["loc"]) == 1 else Entry
            known = list(model.model_fields)
            close = difflib.get_close_matches(key, known, n=1)
            hint = f", did you mean {close[0]!r}" if close else f" (known: {', '.join(known)})"
            where = _loc(err["loc"][:-1]) + ": " if len(err["loc"]) > 1 else ""
            raise SceneError(f"{p}: {where}unknown key {key!r}{hint}") from None
        msg = err["msg"].removeprefix("Value error, ")
        extra = f" (got {err['input']!r})" if err["type"] not in ("missing", "value_error") and not isinstance(
            err.get("input"), dict | list) else ""
        raise SceneError(f"{p}: {_loc(err['loc'])}: {msg}{extra}") from None
    try:
        return nf.to_transfer_matrix(), nf.criterion
    except HilError as exc:
        raise SceneError(f"{p}: {exc}") from None
