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
from hil.inputs import field_path, parse_yaml, read_text_file
from hil.schema import CriterionName
from hil.stability.rational import TransferMatrix

__all__ = ["NetworkFile", "load_network"]

#: largest coefficient magnitude accepted: products of a few coefficients must stay finite in float64
_MAX_COEF = 1e100

# YAML 1.2 / JSON floats: PyYAML (YAML 1.1) reads ``1e3`` and ``3.96e4`` (no dot, or no exponent sign) as strings

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
    criterion: CriterionName = "auto"  # auto | positive_real | passivity | llewellyn | absolute_stability | registered
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


def load_network(path: str | Path) -> tuple[TransferMatrix, str]:
    """Load a network file; returns the transfer matrix and the requested criterion."""
    p = Path(path)
    text = read_text_file(p, "network file", SceneError, max_bytes=4 * 1024 * 1024)  # a network is a few kB
    if p.suffix.lower() == ".json":
        try:
            data = json.loads(text, parse_constant=lambda c: float(c))
        except (ValueError, RecursionError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise SceneError(f"{p}: not valid JSON: {first}") from None
    else:  # YAML 1.2 floats (1e3 is a number), duplicate keys refused
        data = parse_yaml(text, str(p), SceneError, yaml12_floats=True)
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
            where = field_path(err["loc"][:-1]) + ": " if len(err["loc"]) > 1 else ""
            raise SceneError(f"{p}: {where}unknown key {key!r}{hint}") from None
        msg = err["msg"].removeprefix("Value error, ")
        extra = f" (got {err['input']!r})" if err["type"] not in ("missing", "value_error") and not isinstance(
            err.get("input"), dict | list) else ""
        raise SceneError(f"{p}: {field_path(err['loc'])}: {msg}{extra}") from None
    try:
        return nf.to_transfer_matrix(), nf.criterion
    except HilError as exc:
        raise SceneError(f"{p}: {exc}") from None
