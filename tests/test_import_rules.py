"""The import direction between the subpackages (docs/ARCHITECTURE.md, "Import rule"), checked on the source.

Every module's imports are read with :mod:`ast` (imports inside functions and under
``TYPE_CHECKING`` count too: a lazy import is still a dependency) and resolved to modules of the
``hil`` namespace (``hil.identify`` is the folder identify/, ``hil.protocols`` protocols/,
``hil.mocks`` mocks/). Two rules:

* :data:`MAY_IMPORT`: what the lower layers may import from the rest of ``hil``;
* no import cycle between packages: the module graph collapsed to its nodes (each subpackage of
  :data:`SUBPACKAGES` is one node, each top-level module of hil/ another) has no strongly connected
  component of more than one node;
* :data:`LAYERS`: every edge of that graph points down the data flow (cli -> report -> certify ->
  run -> bench / record -> scene -> experiments / controllers -> models / mocks -> ... -> errors).

Work in progress is listed in :data:`KNOWN_VIOLATIONS` and :data:`KNOWN_CYCLES`. These lists may only
shrink: a listed case that no longer occurs fails the test too, so whoever fixes it removes its line.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: import name -> folder (pyproject.toml [tool.setuptools] package-dir; tests/test_types.py checks it)
FOLDERS = {"hil.identify": "identify", "hil.protocols": "protocols", "hil.mocks": "mocks", "hil": "hil"}
#: the nodes of the package graph besides the top-level modules of hil/
SUBPACKAGES = ("hil.scene", "hil.experiments", "hil.controllers", "hil.bench", "hil.run", "hil.record", "hil.certify",
               "hil.report", "hil.cli",
               "hil.stability", "hil.models", "hil.identify", "hil.protocols", "hil.mocks")

#: the protocol codec modules (frame layouts, CRCs, link budgets: no transport, no adapter) that the
#: simulated devices may import to speak the same bytes as the adapters. One table: update it when
#: codecs move.
CODEC_MODULES = ("hil.protocols.codecs", "hil.protocols.crc", "hil.protocols.link_budget")

#: package (prefix) -> what its modules may import from ``hil`` outside the package itself (prefixes).
#: ``hil.lti`` is the exact LTI core (state space, ZOH/FOH discretization) that the simulated plants
#: and the time-domain identification share.
MAY_IMPORT: dict[str, tuple[str, ...]] = {
    "hil.protocols": ("hil.errors",),
    "hil.mocks": ("hil.errors", "hil.lti", *CODEC_MODULES),
    "hil.identify": ("hil.errors", "hil.lti"),
    "hil.stability": ("hil.errors",),
    "hil.lti": ("hil.errors",),
}

#: the data flow as layers, top (the command line) to bottom (the error hierarchy): every import
#: between nodes points strictly down this list (so nodes of one layer never import each other).
#: A new subpackage or top-level module must be placed here.
LAYERS: list[tuple[str, ...]] = [
    ("hil.__main__",),
    ("hil.cli",),
    ("hil.report",),
    ("hil.certify", "hil.pytest_plugin"),
    ("hil.run",),
    ("hil.bench", "hil.record"),
    ("hil.scene",),
    ("hil.experiments", "hil.controllers"),
    ("hil.models", "hil.mocks"),
    ("hil.identify", "hil.protocols", "hil.schema"),
    ("hil.stability", "hil.lti"),
    ("hil", "hil.inputs", "hil.plugins"),
    ("hil.errors",),
]

#: (importing module, imported module) pairs that break MAY_IMPORT today (work in progress). Empty:
#: keep it so.
KNOWN_VIOLATIONS: set[tuple[str, str]] = set()

#: strongly connected components of the package graph that exist today. Empty: keep it so.
KNOWN_CYCLES: list[frozenset[str]] = []


def _modules() -> dict[str, Path]:
    """Every module of the ``hil`` namespace: dotted name -> source file."""
    out: dict[str, Path] = {}
    for pkg, folder in FOLDERS.items():
        for p in sorted((ROOT / folder).rglob("*.py")):
            parts = list(p.relative_to(ROOT / folder).with_suffix("").parts)
            if pkg == "hil" and parts[0] in ("identify", "protocols", "mocks"):
                continue  # not there in the repository; never shadow the mapped folders
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([pkg, *parts])] = p
    return out


MODULES = _modules()


def _resolve(name: str) -> str | None:
    """The module of ``hil`` that ``name`` (a module, or a module's attribute) denotes."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def imports_of(module: str, path: Path) -> Iterator[tuple[str, int]]:
    """(imported module of ``hil``, line) for every import statement in the file, at any depth."""
    is_pkg = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the importing module's package
                base = module.split(".") if is_pkg else module.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join([*base, *([node.module] if node.module else [])])
            else:
                mod = node.module or ""
            names = [f"{mod}.{a.name}" for a in node.names]  # resolves to the submodule, or to mod
        for n in names:
            if n == "hil" or n.startswith("hil."):
                target = _resolve(n)
                if target is not None and target != "hil":
                    yield target, node.lineno


def _edges() -> set[tuple[str, str]]:
    return {(m, t) for m, p in MODULES.items() for t, _ in imports_of(m, p)}


def _inside(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def violations() -> set[tuple[str, str]]:
    bad = set()
    for src, dst in _edges():
        for pkg, allowed in MAY_IMPORT.items():
            if _inside(src, pkg) and not _inside(dst, pkg) and not any(_inside(dst, a) for a in allowed):
                bad.add((src, dst))
    return bad


def node_of(module: str) -> str:
    """The package-graph node of a module: its subpackage, or itself (a top-level module of hil/)."""
    for sub in SUBPACKAGES:
        if _inside(module, sub):
            return sub
    return ".".join(module.split(".")[:2])


def package_graph() -> dict[str, set[str]]:
    g: dict[str, set[str]] = {node_of(m): set() for m in MODULES}
    for src, dst in _edges():
        a, b = node_of(src), node_of(dst)
        if a != b:
            g[a].add(b)
    return g


def cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """Strongly connected components with more than one node (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[frozenset[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = set()
                while True:
                    x = stack.pop()
                    on_stack.discard(x)
                    comp.add(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    found.append(frozenset(comp))
    return found


# ---------------------------------------------------------------------------------------------


def test_the_reader_sees_every_kind_of_import(tmp_path: Path) -> None:
    # a function-level import, a relative import, a from-import of a submodule and of a name
    src = ("import hil.errors\nfrom hil.stability import rational\nfrom .criteria import check\n"
           "def f():\n    from hil.models.sdea import sdea_vsic\n    import hil.cli.main as c\n")
    p = tmp_path / "criteria_user.py"
    p.write_text(src, encoding="utf-8")
    got = {t for t, _ in imports_of("hil.stability.criteria_user", p)}
    assert got == {"hil.errors", "hil.stability.rational", "hil.stability.criteria", "hil.models.sdea", "hil.cli.main"}


def test_tarjan_finds_cycles_and_only_cycles() -> None:
    g = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": {"e"}, "e": {"d"}, "f": {"a"}}
    assert sorted(map(sorted, cycles(g))) == [["a", "b", "c"], ["d", "e"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_module_table_covers_the_tree() -> None:
    assert "hil.identify.api" in MODULES and "hil.protocols.base" in MODULES and "hil.stability.exact" in MODULES
    assert all(p.is_file() for p in MODULES.values())


def test_lower_layers_import_only_what_the_rule_allows() -> None:
    bad = violations()
    new = sorted(bad - KNOWN_VIOLATIONS)
    assert not new, ("imports against the import rule (docs/ARCHITECTURE.md): "
                     + ", ".join(f"{a} -> {b}" for a, b in new))


def test_known_violations_only_shrink() -> None:
    fixed = sorted(KNOWN_VIOLATIONS - violations())
    assert not fixed, "fixed: remove from KNOWN_VIOLATIONS: " + ", ".join(f"{a} -> {b}" for a, b in fixed)


def test_no_new_package_cycle() -> None:
    found = cycles(package_graph())
    new = [sorted(c) for c in found if not any(c <= k for k in KNOWN_CYCLES)]
    assert not new, f"import cycles between packages: {new}"


def test_known_cycles_only_shrink() -> None:
    found = set(cycles(package_graph()))
    stale = [sorted(k) for k in KNOWN_CYCLES if k not in found]
    assert not stale, (f"KNOWN_CYCLES is out of date (a cycle shrank or is gone): {stale}; today's cycles: "
                       f"{sorted(sorted(c) for c in found)}")


def layer_of(node: str) -> int:
    for i, layer in enumerate(LAYERS):
        if node in layer:
            return i
    raise KeyError(node)


def test_every_node_has_one_layer() -> None:
    nodes = set(package_graph())
    placed = [n for layer in LAYERS for n in layer]
    assert len(placed) == len(set(placed)), "a node is in two layers"
    assert nodes <= set(placed), f"place these in LAYERS: {sorted(nodes - set(placed))}"


def test_imports_point_down_the_data_flow() -> None:
    up = []
    for src, dst in sorted(_edges()):
        a, b = node_of(src), node_of(dst)
        if a != b and layer_of(a) >= layer_of(b):
            up.append(f"{src} -> {dst}")
    assert not up, "imports against the data flow (tests/test_import_rules.py LAYERS): " + ", ".join(up)


def test_the_layer_check_sees_an_upward_import(tmp_path: Path) -> None:
    # a scene module importing the certification would be refused
    p = tmp_path / "x.py"
    p.write_text("def f():\n    from hil.certify.pipeline import certify_scene\n", encoding="utf-8")
    (dst, _), = imports_of("hil.scene.x", p)
    assert layer_of(node_of("hil.scene.x")) > layer_of(node_of(dst))
