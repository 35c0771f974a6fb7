"""Reading what a person hands the suite: text and YAML files and command-line numbers, each refused in
one line that names the file or the value (the CLI turns these into exit code 2).

One place for the checks that every reader needs (a folder, a missing or unreadable file, binary
data, a file that is not UTF-8; a flag value that is not a finite number or not a seed), so the
network-file loader, the CSV importer, ``hil identify`` and ``hil mock serve`` answer the same way.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from hil.errors import HilError

__all__ = ["SEED_MAX", "DuplicateKeyError", "field_path", "number_type", "parse_yaml", "read_text_file", "seed_type",
           "unique_key_loader"]

#: largest seed numpy's SeedSequence-based generators accept from a scene or a flag
SEED_MAX = 2**32 - 1


#: the largest text input read (scenes, network files, certificates): a scene is a few kB, a
#: certificate with its plot data a few MB; anything longer (a device such as /dev/zero, a stray log)
#: is refused after reading at most this much, never read to exhaustion
MAX_TEXT_BYTES = 32 * 1024 * 1024


def read_text_file(path: str | Path, what: str = "file", error: type[HilError] = HilError,
                   max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of ``path`` (a BOM is dropped). Raises ``error`` with one line for a folder, a
    missing or unreadable file, one longer than ``max_bytes`` (read no further: /dev/zero ends
    here), binary data (NUL bytes) or a file that is not UTF-8."""
    p = Path(path)
    if p.is_dir():
        raise error(f"{p}: is a folder, not a {what}")
    if not p.exists():
        raise error(f"{p}: no such file")
    try:
        with open(p, "rb") as f:
            raw = f.read(max_bytes + 1)
        if len(raw) > max_bytes:
            raise error(f"{p}: larger than {max_bytes / 2**20:.0f} MiB: not a {what} (read no further)")
    except PermissionError:
        raise error(f"{p}: cannot read the {what}: permission denied") from None
    except OSError as exc:
        raise error(f"{p}: cannot read the {what}: {exc.strerror or exc}") from None
    if b"\x00" in raw:
        raise error(f"{p}: binary data (NUL bytes), not a text {what}")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(f"{p}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); "
                    f"save the {what} as UTF-8") from None


def number_type(kind: str) -> Callable[[str], float]:
    """argparse ``type=`` for a finite number; ``kind`` is ``"positive"`` (> 0) or ``"nonnegative"``
    / ``"non-negative"`` (≥ 0)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(v) or v < 0 or (kind == "positive" and v == 0):
            raise argparse.ArgumentTypeError(f"{text!r}: expected a finite {kind} number")
        return v

    parse.__name__ = f"{kind} number"
    return parse


def seed_type(text: str) -> int:
    """argparse ``type=`` for a seed: an integer in [0, 2**32-1]."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= v <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"{text!r}: the seed must be an integer in [0, 2**32-1]")
    return v


def field_path(loc: Sequence[Any]) -> str:
    """A location as people write it: ``experiments[0].f0`` (``(top level)`` when empty)."""
    s = ""
    for part in loc:
        s += f"[{part}]" if isinstance(part, int) else ("." if s else "") + str(part)
    return s or "(top level)"


# ---------------------------------------------------------------------------------------------
# YAML: safe, without duplicate keys (plain yaml.safe_load silently keeps the last value)

#: YAML 1.2 floats: ``1e3`` and ``3.96e4`` are numbers (PyYAML's YAML 1.1 resolver reads them as strings)
_FLOAT_RE = re.compile(r"^(?:[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)?"
                       r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")


class DuplicateKeyError(Exception):
    """A YAML mapping holds the same key twice (``path``: where, ``line``/``first``: 1-based lines)."""

    def __init__(self, path: str, key: str, line: int, first: int) -> None:
        super().__init__(f"{path}: duplicate key {key!r} (line {line}; first at line {first})")
        self.path, self.key, self.line, self.first = path, key, line, first


_LOADERS: dict[bool, Any] = {}


def unique_key_loader(*, yaml12_floats: bool = False) -> Any:
    """A :class:`yaml.SafeLoader` subclass that raises :class:`DuplicateKeyError` when a mapping, at
    any depth, holds a key twice. Merge keys (``<<: *anchor``) may still be overridden, as YAML
    intends. ``yaml12_floats``: also read ``1e3`` as a number (network files)."""
    if yaml12_floats in _LOADERS:
        return _LOADERS[yaml12_floats]
    import yaml  # lazy: hil.inputs is imported by every hil command's parser; yaml only when a file is read

    class UniqueKeyLoader(yaml.SafeLoader):
        def construct_document(self, node: Any) -> Any:
            _find_duplicates(node, [], set())
            return super().construct_document(node)

    if yaml12_floats:
        UniqueKeyLoader.yaml_implicit_resolvers = {k: list(v) for k, v in
                                                   yaml.SafeLoader.yaml_implicit_resolvers.items()}
        UniqueKeyLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_RE, list("-+0123456789."))
    _LOADERS[yaml12_floats] = UniqueKeyLoader
    return UniqueKeyLoader


def _find_duplicates(node: Any, path: list[Any], seen: set[int]) -> None:
    import yaml

    if id(node) in seen:  # an alias of a node already walked
        return
    seen.add(id(node))
    if isinstance(node, yaml.MappingNode):
        first: dict[Any, int] = {}
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            scalar = isinstance(key_node, yaml.ScalarNode)
            key = (key_node.tag, key_node.value) if scalar else ("", id(key_node))
            line = key_node.start_mark.line + 1
            if key in first:
                raise DuplicateKeyError(field_path([*path, key_node.value]), str(key_node.value), line, first[key])
            first[key] = line
            _find_duplicates(value_node, [*path, key_node.value if scalar else "?"], seen)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _find_duplicates(item, [*path, i], seen)


def parse_yaml(text: str, label: str, error: type[HilError] = HilError, *, yaml12_floats: bool = False) -> Any:
    """Parse YAML ``text`` with :func:`unique_key_loader` (safe: no code); any problem is one
    ``error`` line ``label: ...`` (``not valid YAML (line L, column C): ...`` or ``field.path:
    duplicate key 'k' (line L; first at line F)``)."""
    import yaml

    try:
        return yaml.load(text, Loader=unique_key_loader(yaml12_floats=yaml12_floats))  # a SafeLoader subclass
    except DuplicateKeyError as exc:
        raise error(f"{label}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).strip().splitlines()[0]
        raise error(f"{label}: not valid YAML{where}: {problem}") from None
    except RecursionError:
        raise error(f"{label}: not valid YAML: nested too deeply") from None
