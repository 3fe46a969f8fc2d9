"""The import graph of ``ctp_core``, ``service``, ``worker`` and ``ctp``, read from the source with ``ast``
(nothing is imported, so a cycle cannot hide behind the order modules happen to load in).

The rules:

- An edge is any import statement: at module level, inside a function (importing lazily does not make a cycle
  harmless, it only hides it until the function runs) or under ``if TYPE_CHECKING:`` (a type named from a
  higher floor is a dependency on it all the same). ``from a import b`` is an edge to ``a.b`` where that is a
  module, else to ``a``; relative imports are resolved the same way.
- No cycle among these modules, whatever kind its edges are.
- A function-level import that is no part of a cycle may stay: it keeps ``import ctp_core.align`` and the CLI's
  start light (the engine's torch modules load when a stage runs).
- ``service`` imports no torch: nothing reachable from a ``service`` module through an edge that runs (and the
  packages whose ``__init__`` runs on the way) imports ``torch`` or a model library built on it. The API process
  validates configurations and plans with ``ctp_core`` and leaves the engine to the worker.
"""

from __future__ import annotations

import ast
from collections import deque
from dataclasses import dataclass
from functools import cache
from itertools import pairwise
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("ctp_core", "service", "worker", "ctp")
TORCH_PACKAGES = frozenset({"torch", "transformers", "open_clip"})  # what the API process must never load


@dataclass(frozen=True)
class Import:
    """One import statement's target: a module of ``PACKAGES`` or an outside package's top-level name."""

    target: str
    line: int
    lazy: bool  # inside a function
    typing: bool = False  # under ``if TYPE_CHECKING:``: never runs, still a dependency

    def where(self) -> str:
        return f"line {self.line}{', in a function' if self.lazy else ''}{', for typing' if self.typing else ''}"


@cache
def modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module and package of ``PACKAGES``."""
    found = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _module_of(name: str) -> str | None:
    """The longest prefix of ``name`` that is one of ours (``a.b.func`` -> ``a.b``); None for outside packages."""
    while name not in modules():
        if "." not in name:
            return None
        name = name.rpartition(".")[0]
    return name


def _targets(node: ast.Import | ast.ImportFrom, package: str) -> list[str]:
    """The dotted names one statement imports, relative imports resolved against ``package``."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    base = node.module or ""
    if node.level:
        anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
        base = ".".join(anchor + ([base] if base else []))
    return [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules() else base for alias in node.names]


def _type_checking(node: ast.AST) -> bool:
    test = getattr(node, "test", None)
    return isinstance(node, ast.If) and (
        (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
        or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def imports_of(name: str) -> list[Import]:
    """Every import statement of module ``name`` (see the module docstring)."""
    path = modules()[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: list[Import] = []

    def visit(node: ast.AST, lazy: bool, typing: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if _type_checking(child):
                for branch in child.body:
                    visit_one(branch, lazy, True)
                for branch in child.orelse:
                    visit_one(branch, lazy, typing)
            else:
                visit_one(child, lazy, typing)

    def visit_one(node: ast.AST, lazy: bool, typing: bool) -> None:
        if isinstance(node, ast.Import | ast.ImportFrom):
            for target in _targets(node, package):
                ours = _module_of(target)
                found.append(Import(ours or target.partition(".")[0], node.lineno, lazy, typing))
        else:
            visit(node, lazy or isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda), typing)

    visit(ast.parse(path.read_text(), str(path)), False, False)
    return list(dict.fromkeys(found))  # once per statement and target (``from a import b, c``: one edge to ``a``)


@cache
def graph() -> dict[str, dict[str, list[Import]]]:
    """Module -> the modules of ours it imports -> the statements that do (self-imports dropped)."""
    edges: dict[str, dict[str, list[Import]]] = {name: {} for name in modules()}
    for name in modules():
        for item in imports_of(name):
            if item.target in modules() and item.target != name:
                edges[name].setdefault(item.target, []).append(item)
    return edges


def shortest_cycle(edges: dict[str, dict[str, list[Import]]], start: str) -> list[str] | None:
    """The shortest path ``start -> ... -> start`` (its modules, ``start`` at both ends), or None."""
    previous: dict[str, str] = {}
    queue = deque([start])
    while queue:
        node = queue.popleft()
        for nxt in sorted(edges.get(node, {})):
            if nxt == start:
                path = [node]
                while path[-1] != start:
                    path.append(previous[path[-1]])
                return [*reversed(path), start]
            if nxt not in previous:
                previous[nxt] = node
                queue.append(nxt)
    return None


def cycles(edges: dict[str, dict[str, list[Import]]]) -> list[str]:
    """Each distinct cycle once, written with the statements that make it."""
    seen, found = set(), []
    for start in sorted(edges):
        path = shortest_cycle(edges, start)
        if path is None or frozenset(path) in seen:
            continue
        seen.add(frozenset(path))
        steps = [f"{a} -> {b} ({', '.join(i.where() for i in edges[a][b])})" for a, b in pairwise(path)]
        found.append("cycle: " + "; ".join(steps))
    return found


def test_the_packages_have_no_import_cycle():
    found = cycles(graph())
    assert not found, "\n".join(found)


def test_service_imports_no_torch():
    """Reached through any edge from any ``service`` module, with each package ``__init__`` met on the way."""
    start = [name for name in modules() if name.partition(".")[0] == "service"]
    previous: dict[str, str | None] = dict.fromkeys(start)
    queue = deque(start)
    offenders = []
    while queue:
        name = queue.popleft()
        offenders += [(name, item) for item in imports_of(name) if item.target in TORCH_PACKAGES and not item.typing]
        parent = name.rpartition(".")[0]
        running = [target for target, items in graph()[name].items() if any(not i.typing for i in items)]
        for nxt in [*running, *([parent] if parent else [])]:
            if nxt not in previous:
                previous[nxt] = name
                queue.append(nxt)

    def chain(name: str) -> str:
        names = [name]
        while previous[names[-1]] is not None:
            names.append(previous[names[-1]])
        return " -> ".join(reversed(names))

    assert not offenders, "\n".join(f"{chain(name)} imports {item.target} ({item.where()})" for name, item in offenders)


def test_the_graph_sees_function_level_and_typing_imports_and_reports_a_cycle():
    """The checks above are not vacuous: ``align``'s stages are imported in functions and are edges, so are the
    types it names for checking only, and a cycle closed by a function-level import is reported with that
    import."""
    assert any(item.lazy for item in graph()["ctp_core.align"]["ctp_core.optimise"])
    assert not any(item.lazy for item in graph()["ctp_core.align"]["ctp_core.config"])
    assert any(item.typing for item in graph()["ctp_core.align"]["ctp_core.objective"])
    edges = {"a": {"b": [Import("b", 3, False)]}, "b": {"c": [Import("c", 4, False)]},
             "c": {"a": [Import("a", 9, True)]}}
    assert cycles(edges) == ["cycle: a -> b (line 3); b -> c (line 4); c -> a (line 9, in a function)"]


# -- layers ---------------------------------------------------------------------------------------------------
# The engine's families, lowest first (docs/engine.md, "Layers"): a module may import its own layer and the
# layers below, never one above. A family is a package or a concept module of ``ctp_core``; a module's layer is
# its family's, the longest family name that contains it. The words (``reading``: the relations' records, cues and
# readings, places, parts' names; ``priors``) are torch-free, read by the service, below the relations' geometry
# (judges, builders, parts), which is keyed by their names. A new package or top-level module must be given its
# layer here.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("base", ("ctp_core", "errors", "progress", "geometry", "losses")),
    ("words", ("reading", "priors")),
    ("config", ("config",)),
    ("load", ("io", "orientation")),
    ("render", ("render",)),
    ("prepare", ("pairs",)),
    ("guide", ("guide",)),
    ("relations", ("contact", "relations")),
    ("judge", ("objective", "metrics")),
    ("search", ("search",)),
    ("optimise", ("optimise",)),
    ("pipeline", ("align", "adjust", "assembly", "export")),
    ("bench", ("bench",)),
    ("adapters", ("service", "worker")),
    ("cli", ("ctp",)),
)
TOP_LEVEL_MAX = 25  # entries of ctp_core (modules and packages): the tree shows the pipeline


def _family_name(family: str) -> str:
    return family if family in ("ctp_core", "service", "worker", "ctp") else f"ctp_core.{family}"


def layer_of(name: str) -> int | None:
    """The layer of the longest family containing module ``name``; None if no family does."""
    best, found = -1, None
    for index, (_, families) in enumerate(LAYERS):
        for family in map(_family_name, families):
            inside = name == family or (family != "ctp_core" and name.startswith(family + "."))
            if inside and len(family) > best:
                best, found = len(family), index
    return found


def test_every_module_has_a_layer_and_every_family_exists():
    unplaced = [name for name in modules() if layer_of(name) is None]
    missing = [f for _, families in LAYERS for f in families if _family_name(f) not in modules()]
    assert not unplaced, f"give these modules' family a layer in LAYERS (tests/test_imports.py): {unplaced}"
    assert not missing, f"families in LAYERS that are no module or package: {missing}"


def test_ctp_core_top_level_stays_small():
    entries = sorted(p.name for p in (REPO / "ctp_core").iterdir()
                     if p.name != "__pycache__" and (p.suffix == ".py" or (p / "__init__.py").exists()))
    assert len(entries) <= TOP_LEVEL_MAX, f"{len(entries)} entries in ctp_core: {entries}"


def upward(edges: dict[str, dict[str, list[Import]]]) -> list[str]:
    """Each import of a module from a higher layer, written with its statements."""
    return [f"{name} ({LAYERS[layer_of(name)][0]}) imports {target} ({LAYERS[layer_of(target)][0]}, "
            f"{', '.join(i.where() for i in items)})"
            for name, targets in edges.items() for target, items in targets.items()
            if layer_of(target) is not None and layer_of(name) is not None and layer_of(target) > layer_of(name)]


def test_imports_go_down_the_layers():
    """The pipeline reads bottom-up: load -> prepare -> judge -> search -> optimise -> align/export; the service
    and the worker are adapters on top of the engine, the CLI on top of all."""
    found = upward(graph())
    assert not found, "\n".join(found)


def test_the_layer_check_reports_an_upward_import():
    edges = {"ctp_core.relations.predicates": {"ctp_core.align": [Import("ctp_core.align", 7, True)]},
             "ctp_core.pairs": {"ctp_core.render": [Import("ctp_core.render", 3, False)]},
             "ctp_core.reading.records": {"ctp_core.relations.builders": [Import("x", 5, False, True)]}}
    assert upward(edges) == [
        "ctp_core.relations.predicates (relations) imports ctp_core.align (pipeline, line 7, in a function)",
        "ctp_core.reading.records (words) imports ctp_core.relations.builders (relations, line 5, for typing)"]
