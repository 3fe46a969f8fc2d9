"""The import graph of ``ctp_core``, ``service``, ``worker`` and ``ctp``, read from the source with ``ast``
(nothing is imported, so a cycle cannot hide behind the order modules happen to load in).

The rules:

- An edge is an import statement that can run: at module level, or inside a function (a function-level import
  counts as an edge: importing lazily does not make a cycle harmless, it only hides it until the function runs).
  Imports under ``if TYPE_CHECKING:`` never run and are not edges. ``from a import b`` is an edge to ``a.b`` where
  that is a module, else to ``a``; relative imports are resolved the same way.
- No cycle among these modules, whatever kind its edges are.
- A function-level import that is no part of a cycle may stay: it keeps ``import ctp_core.align`` and the CLI's
  start light (the engine's torch modules load when a stage runs).
- ``service`` imports no torch: nothing reachable from a ``service`` module through any edge (and the packages
  whose ``__init__`` runs on the way) imports ``torch`` or a model library built on it. The API process validates
  configurations and plans with ``ctp_core`` and leaves the engine to the worker.
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

    def where(self) -> str:
        return f"line {self.line}{', in a function' if self.lazy else ''}"


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
    """Every import statement of module ``name`` that can run (see the module docstring)."""
    path = modules()[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: list[Import] = []

    def visit(node: ast.AST, lazy: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if _type_checking(child):
                for branch in child.orelse:
                    visit_one(branch, lazy)
            else:
                visit_one(child, lazy)

    def visit_one(node: ast.AST, lazy: bool) -> None:
        if isinstance(node, ast.Import | ast.ImportFrom):
            for target in _targets(node, package):
                ours = _module_of(target)
                found.append(Import(ours or target.partition(".")[0], node.lineno, lazy))
        else:
            visit(node, lazy or isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda))

    visit(ast.parse(path.read_text(), str(path)), False)
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
        offenders += [(name, item) for item in imports_of(name) if item.target in TORCH_PACKAGES]
        parent = name.rpartition(".")[0]
        for nxt in [*graph()[name], *([parent] if parent else [])]:
            if nxt not in previous:
                previous[nxt] = name
                queue.append(nxt)

    def chain(name: str) -> str:
        names = [name]
        while previous[names[-1]] is not None:
            names.append(previous[names[-1]])
        return " -> ".join(reversed(names))

    assert not offenders, "\n".join(f"{chain(name)} imports {item.target} ({item.where()})" for name, item in offenders)


def test_the_graph_sees_function_level_imports_and_reports_a_cycle():
    """The checks above are not vacuous: ``align``'s stages are imported in functions and are edges, and a
    cycle closed by a function-level import is reported with that import."""
    assert any(item.lazy for item in graph()["ctp_core.align"]["ctp_core.optimise"])
    assert not any(item.lazy for item in graph()["ctp_core.align"]["ctp_core.config"])
    edges = {"a": {"b": [Import("b", 3, False)]}, "b": {"c": [Import("c", 4, False)]},
             "c": {"a": [Import("a", 9, True)]}}
    assert cycles(edges) == ["cycle: a -> b (line 3); b -> c (line 4); c -> a (line 9, in a function)"]


# -- layers ---------------------------------------------------------------------------------------------------
# The engine's stages, lowest first (docs/engine.md, "Layers"): a module may import its own layer and the layers
# below, never one above. ``ctp_core`` is one flat package of concept modules (trimesh's model); the layers are what
# a package cut would show, kept true by this test. A new module must be given its layer here.
def _engine(members: str) -> frozenset[str]:
    """``ctp_core``'s modules named without the package (``.`` for the package itself)."""
    return frozenset("ctp_core" if m == "." else f"ctp_core.{m}" for m in members.split())


LAYERS: tuple[tuple[str, frozenset[str]], ...] = (
    ("base", _engine(". errors progress names weights pose frames structures sampling losses proximity")),
    ("words", _engine("priors priors.lexicon priors.relations priors.context priors.prior priors.rules priors.openai"
                       " priors.counts")),
    ("config", _engine("config backends runtime schedule options plan guide_choice model_store")),
    ("load", _engine("io loader canonical orientation examples")),
    ("render", _engine("cameras render")),
    ("prepare", _engine("scene")),
    ("guide", _engine("guidance guide_loaders goals")),
    ("judge", _engine("predicates objective ordering metrics")),
    ("search", _engine("proposals relation_proposals ranking scaling")),
    ("optimise", _engine("optimise")),
    ("pipeline", _engine("align adjust assemble copies export")),
    ("bench", _engine("bench bench.protocol bench.cases bench.baselines bench.guides bench.harness bench.sanity"
                      " bench.summary")),
    ("adapters", frozenset(m for m in modules() if m.partition(".")[0] in ("service", "worker"))),
    ("cli", frozenset(m for m in modules() if m.partition(".")[0] == "ctp")),
)


def layer_of(name: str) -> int | None:
    return next((i for i, (_, members) in enumerate(LAYERS) if name in members), None)


def test_every_module_has_one_layer():
    unplaced = [name for name in modules() if layer_of(name) is None]
    twice = [name for name in modules() if sum(name in members for _, members in LAYERS) > 1]
    assert not unplaced, f"give these modules a layer in LAYERS (tests/test_imports.py): {unplaced}"
    assert not twice, f"in two layers: {twice}"


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
             "ctp_core.pairs": {"ctp_core.render": [Import("ctp_core.render", 3, False)]}}
    assert upward(edges) == ["ctp_core.relations.predicates (judge) imports ctp_core.align (pipeline, line 7, in a function)"]
