"""The scene field reference, generated from the scene's pydantic schema (docs/scene-reference.md).

Every field of :class:`hil.scene.spec.Scene`, at every depth -- devices, simulation, network,
controller (each registered type), safety, experiments (each registered type), certification --
with its type, unit, allowed range, default and description, read from the models themselves:

* the **type** from the annotation (``Literal`` values listed, ``Annotated`` unwrapped);
* the **unit** from the field's number validator: the scene's numbers go through
  :func:`hil.schema.number` / :func:`hil.schema.in_unit`, which name their unit in the error they
  raise ("expected a number in N or N.m, got …"), so the reference states exactly the unit the
  loader states; ``1`` for a dimensionless number, ``—`` for anything else;
* the **range** from the ``Field`` constraints (``gt``/``ge``/``lt``/``le``, lengths, patterns);
* the **default** (``required`` when there is none);
* the **description** from ``Field(description=…)`` or, for a nested mapping, its class docstring.

``python -m hil.scene.reference --write docs/scene-reference.md`` writes it; ``--check FILE`` exits 1
when the file is not what the schema gives (``tests/scene/test_scene_reference.py`` does the same).
Plugins registered through entry points add their experiment and controller types to the schema,
and so to a reference generated where they are installed; the committed file is the built-in one.
"""

from __future__ import annotations

import inspect
import logging
import sys
import types
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel
from pydantic_core import PydanticCustomError, PydanticUndefined

logger = logging.getLogger(__name__)

__all__ = ["Row", "main", "reference_markdown", "rows"]

HEADER = """# Scene field reference

Generated from the scene schema (`hil.scene.spec.Scene`) by `python -m hil.scene.reference --write
docs/scene-reference.md`; `tests/scene/test_scene_reference.py` fails when it is out of date. Do not
edit by hand. How to write a scene: [the user guide](guide/bench-runs.md); complete examples:
`hil/scene/builtin/*.yaml` (`hil scenes` lists them).

Conventions: **unit** is the SI unit the loader expects (a scene is linear or rotary, `units`:
"N or N.m" means N in a linear scene and N.m in a rotary one); `1` is a dimensionless number, `—`
not a number. **range**: `> 0`, `≥ 0`, `≤ 1`, lengths and patterns the loader enforces (a value
outside is refused at load time, naming the field). **default**: `required` when the field must be
given. A field path reads `devices[].sim.noise_std`: the `sim` mapping of any item of the `devices`
list. A key the schema does not list is refused (with a did-you-mean hint).
"""


@dataclass(frozen=True)
class Row:
    """One field of the reference."""

    path: str
    type: str
    unit: str
    range: str
    default: str
    description: str


# ---------------------------------------------------------------------------------------------
# reading annotations


def _unwrap(tp: Any) -> tuple[Any, list[Any]]:
    """(the type inside any ``Annotated``, the metadata collected on the way)."""
    meta: list[Any] = []
    while typing.get_origin(tp) is typing.Annotated:
        args = typing.get_args(tp)
        tp, meta = args[0], [*meta, *args[1:]]
    return tp, meta


def _is_model(tp: Any) -> bool:
    return inspect.isclass(tp) and issubclass(tp, BaseModel)


def _union_args(tp: Any) -> tuple[Any, ...] | None:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return typing.get_args(tp)
    return None


def _type_name(tp: Any) -> str:
    tp, _ = _unwrap(tp)
    if tp is type(None):
        return "null"
    if tp is Any:
        return "any"
    u = _union_args(tp)
    if u is not None:
        names = [_type_name(a) for a in u]
        return " or ".join(dict.fromkeys(names))
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        return "one of " + ", ".join(f"`{v}`" for v in typing.get_args(tp))
    if origin in (list, tuple):
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        if origin is tuple and len(args) > 1:
            return "pair of " + " and ".join(dict.fromkeys(_type_name(a) for a in args)) \
                if len(args) == 2 else f"{len(args)}-tuple"
        return "list of " + (_type_name(args[0]) if args else "any")
    if origin is dict:
        kv = typing.get_args(tp)
        return f"mapping of {_type_name(kv[0])} to {_type_name(kv[1])}" if kv else "mapping"
    if _is_model(tp):
        return "mapping"
    return {float: "number", int: "integer", str: "string", bool: "boolean"}.get(tp, getattr(tp, "__name__", str(tp)))


def _unit(meta: list[Any], tp: Any) -> str:
    """The unit the field's number validator names ('' when it has none)."""
    for m in meta:
        func = getattr(m, "func", None)
        if func is None:
            continue
        for probe in (None, "not a number"):  # a matrix validator reads a string as an entry
            try:
                func(probe)
            except PydanticCustomError as exc:
                what = str((exc.context or {}).get("what", ""))
                if what.startswith("a number"):
                    unit = what.removeprefix("a number").strip().removeprefix("in ").strip()
                    if not unit or unit.startswith(("[", "(")) or unit == "fraction":  # a range, not a unit
                        return "1"
                    return unit
            except Exception:  # a validator failing otherwise names no unit
                logger.debug("validator %r names no unit", func)
    for member in _members(tp):
        inner, imeta = _unwrap(member)
        if imeta and inner is not tp:
            u = _unit(imeta, inner)
            if u not in ("—", "1"):
                return u
    base, _ = _unwrap(tp)
    if base in (float, int) and base is not bool:
        return "1"
    return "—"


def _members(tp: Any) -> list[Any]:
    """The non-null members of a union (the type itself otherwise)."""
    inner, _ = _unwrap(tp)
    u = _union_args(inner)
    return [a for a in u if a is not type(None)] if u is not None else [tp]


def _constraints(meta: list[Any], text: bool = False) -> list[str]:
    """The constraints in ``meta`` as text (``text``: lengths count characters, not items)."""
    out: list[str] = []
    for m in meta:
        for key, sym in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤")):
            v = getattr(m, key, None)
            if v is not None and type(m).__name__ in (key.capitalize(), "FieldInfo", "Interval"):
                out.append(f"{sym} {_num(v)}")
        for key, what in (("min_length", "at least {}"), ("max_length", "at most {}")):
            v = getattr(m, key, None)
            if v is not None and type(m).__name__ in ("MinLen", "MaxLen", "FieldInfo"):
                out.append(what.format(v) + (" characters" if text else " item" if v == 1 else " items"))
        pat = getattr(m, "pattern", None)
        if isinstance(pat, str):
            out.append(f"pattern `{pat}`")
        for sub in getattr(m, "metadata", []) or []:  # a FieldInfo's own constraints
            out += _constraints([sub], text)
    return list(dict.fromkeys(out))


def _num(v: Any) -> str:
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return str(int(v))
    return str(v)


def _range(info: Any, tp: Any) -> str:
    members = _members(tp)
    inner0, _ = _unwrap(members[0])
    parts = _constraints(list(info.metadata), inner0 is str)
    for member in [tp, *members]:
        inner, meta = _unwrap(member)
        parts += _constraints(meta, inner is str)
        # list items' own constraints (e.g. DOF indices ≥ 0)
        if typing.get_origin(inner) is list and typing.get_args(inner):
            item, imeta = _unwrap(typing.get_args(inner)[0])
            ic = _constraints(imeta, item is str)
            if ic:
                parts.append("each item " + ", ".join(ic))
    return ", ".join(dict.fromkeys(parts)) or "—"


def _default(info: Any) -> str:
    if info.default_factory is not None:
        try:
            v = info.default_factory()
        except TypeError:  # a factory taking the validated data
            return "(computed)"
        if isinstance(v, BaseModel):
            return "(its defaults)"
        return _show(v)
    if info.default is PydanticUndefined:
        return "required"
    return _show(info.default)


def _show(v: Any) -> str:
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return _num(v)
    if isinstance(v, list | dict | tuple | str) and not v:
        return "empty"
    text = f"{v}"
    return f"`{text}`" if len(text) <= 40 else "(see the schema)"


def _doc(cls: Any) -> str:
    d = inspect.cleandoc(cls.__dict__.get("__doc__") or "")  # its own docstring, not an inherited one
    first = d.split("\n\n")[0]
    return " ".join(first.split())


def _cell(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


# ---------------------------------------------------------------------------------------------
# walking the models


def _models_in(tp: Any) -> list[type[BaseModel]]:
    """Models a field's type refers to (through Annotated, Optional/unions, lists and mappings)."""
    tp, _ = _unwrap(tp)
    if _is_model(tp):
        return [tp]
    u = _union_args(tp)
    args = u if u is not None else typing.get_args(tp) if typing.get_origin(tp) in (list, tuple, dict) else ()
    out: list[type[BaseModel]] = []
    for a in args:
        out += _models_in(a)
    return out


def _suffix(tp: Any) -> str:
    """The path suffix of a field's items: ``[]`` for a list, ``.<key>`` for a mapping of models."""
    tp, _ = _unwrap(tp)
    u = _union_args(tp)
    if u is not None:
        for a in u:
            s = _suffix(a)
            if s:
                return s
        return ""
    origin = typing.get_origin(tp)
    if origin is list:
        args = typing.get_args(tp)
        return "[]" + (_suffix(args[0]) if args else "")
    if origin is dict:
        return ".<name>"
    return ""


def _type_tag(model: type[BaseModel]) -> str | None:
    """The ``type:`` value a variant of a discriminated union is selected by."""
    f = model.model_fields.get("type")
    if f is None:
        return None
    tp, _ = _unwrap(f.annotation)
    if typing.get_origin(tp) is typing.Literal:
        return ", ".join(str(v) for v in typing.get_args(tp))
    return None


def _walk(model: type[BaseModel], path: str, seen: set[tuple[str, type]]) -> Iterator[tuple[str, type[BaseModel],
                                                                                            list[Row]]]:
    key = (path, model)
    if key in seen:
        return
    seen.add(key)
    rows_: list[Row] = []
    nested: list[tuple[str, type[BaseModel]]] = []
    for name, info in model.model_fields.items():
        alias = info.alias or name
        tp = info.annotation
        p = f"{path}.{alias}" if path else alias
        desc = info.description or ""
        subs = _models_in(tp)
        if subs and not desc:
            desc = _doc(subs[0]) if len(subs) == 1 else "one of the types listed below (selected by `type`)"
        inner, meta = _unwrap(tp)
        rows_.append(Row(p, _type_name(tp), _unit([*meta, *info.metadata], inner), _range(info, tp),
                         _default(info), desc))
        for sub in subs:
            nested.append((p + _suffix(tp), sub))
    yield path, model, rows_
    for p, sub in nested:
        tag = _type_tag(sub)
        yield from _walk(sub, f"{p}" + (f"{{type: {tag}}}" if tag and len(_models_in_field(model, p)) > 1 else ""),
                         seen)


def _models_in_field(model: type[BaseModel], path: str) -> list[type[BaseModel]]:
    name = path.rsplit(".", 1)[-1].split("[")[0]
    f = model.model_fields.get(name)
    return _models_in(f.annotation) if f is not None else []


def rows() -> list[tuple[str, str, list[Row]]]:
    """(path, description, rows) of every mapping of the scene, in reading order."""
    from hil.scene.spec import Scene

    out = []
    for path, model, rs in _walk(Scene, "", set()):
        out.append((path or "(top level)", _doc(model), rs))
    return out


def reference_markdown() -> str:
    """The reference as Markdown (deterministic: the same schema gives the same text)."""
    parts = [HEADER]
    for path, doc, rs in rows():
        parts.append(f"\n## `{path}`\n" if path != "(top level)" else "\n## Top level\n")
        if doc:
            parts.append(f"\n{doc}\n")
        parts.append("\n| field | type | unit | range | default | description |\n|---|---|---|---|---|---|\n")
        for r in rs:
            parts.append(f"| `{r.path}` | {_cell(r.type)} | {_cell(r.unit)} | {_cell(r.range)} | {_cell(r.default)} | "
                         f"{_cell(r.description)} |\n")
    return "".join(parts)


def main(argv: list[str] | None = None) -> int:
    """``python -m hil.scene.reference [--write FILE | --check FILE]``: print, write or check it
    (a maintenance script, not a ``hil`` command: two flags, read by hand)."""
    args = list(sys.argv[1:] if argv is None else argv)
    text = reference_markdown()
    if not args:
        sys.stdout.write(text)
        return 0
    if len(args) != 2 or args[0] not in ("--write", "--check"):
        print("usage: python -m hil.scene.reference [--write FILE | --check FILE]", file=sys.stderr)
        return 2
    flag, target = args
    if flag == "--write":
        Path(target).write_text(text, encoding="utf-8")
        return 0
    current = Path(target).read_text(encoding="utf-8") if Path(target).is_file() else ""
    if current != text:
        print(f"{target} is out of date: python -m hil.scene.reference --write {target}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
