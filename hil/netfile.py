"""Network description files (YAML or JSON) for ``hil stability FILE``.

Format::

    name: my two-port              # optional
    type: hybrid                   # impedance | admittance | hybrid | inverse_hybrid
    ports: [1, 1]                  # DOFs of each port (optional: one DOF per row)
    criterion: auto                # optional: auto | positive_real | passivity | llewellyn | absolute_stability
    matrix:                        # rows of entries; coefficients in descending powers of s, SI units
      - [{num: [0.05, 1.0], den: [1.0, 0.0]}, {num: [1.0], den: [1.0]}]
      - [{num: [-1.0]},                       {num: [1.0, 0.0], den: [0.17, 300.0]}]

``den`` defaults to ``[1]``. Any mistake raises :class:`hil.errors.SceneError` with a one-line
message naming the file and the field (e.g. ``net.yaml: matrix[1][0].den: ...``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from hil.errors import HilError, SceneError
from hil.stability.rational import TransferMatrix

__all__ = ["NetworkFile", "load_network"]


class Entry(BaseModel):
    model_config = ConfigDict(extra="forbid")
    num: list[float] = Field(min_length=1)
    den: list[float] = Field(default_factory=lambda: [1.0], min_length=1)

    @field_validator("num", "den")
    @classmethod
    def _finite(cls, v: list[float]) -> list[float]:
        if not all(math.isfinite(x) for x in v):
            raise ValueError("coefficients must be finite numbers")
        return v

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
    ports: list[int] | None = None
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


def load_network(path: str | Path) -> tuple[TransferMatrix, str]:
    """Load a network file; returns the transfer matrix and the requested criterion."""
    p = Path(path)
    if not p.exists():
        raise SceneError(f"{p}: no such file")
    text = p.read_text(encoding="utf-8")
    try:
        if p.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            import yaml

            data = yaml.safe_load(text)
    except Exception as exc:  # yaml.YAMLError / json.JSONDecodeError
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SceneError(f"{p}: not valid {'JSON' if p.suffix.lower() == '.json' else 'YAML'}: {first}") from None
    if not isinstance(data, dict):
        raise SceneError(f"{p}: expected a mapping with 'type' and 'matrix' at the top level")
    try:
        nf = NetworkFile.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        msg = err["msg"].removeprefix("Value error, ")
        extra = f" (got {err['input']!r})" if err["type"] not in ("missing",) and not isinstance(
            err.get("input"), dict | list) else ""
        raise SceneError(f"{p}: {_loc(err['loc'])}: {msg}{extra}") from None
    try:
        return nf.to_transfer_matrix(), nf.criterion
    except HilError as exc:
        raise SceneError(f"{p}: {exc}") from None
