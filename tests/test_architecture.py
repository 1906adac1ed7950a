"""The package's imports point one way: no cycle, no other module's private names, layers respected.

Walks every module of ``pgdcli/`` with :mod:`ast` (imports inside functions included: a cycle dodged
by a local import is still a cycle) and builds the graph module -> modules it imports.
"""

from __future__ import annotations

import ast
import functools
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "pgdcli"

# layer -> layers it may import (besides itself and the package root/errors); the diagram in README.md
# problem -> discretization -> tensors <- algorithms <- driver -> codebook <- checks <- cli
LOWER = {
    "problem": set(),
    "discretization": {"problem", "tensors"},  # a problem becomes separated operators
    "tensors": set(),
    "codebook": {"discretization", "tensors"},
    "algorithms": {"problem", "discretization", "tensors", "codebook"},
    "checks": {"problem", "discretization", "tensors", "codebook"},
    "driver": {"problem", "discretization", "tensors", "algorithms", "codebook", "checks", "adapt"},
    "adapt": {"problem", "discretization", "tensors", "algorithms", "codebook", "checks"},
    "plot": {"problem", "discretization", "tensors", "codebook", "checks"},
    "inference": {"problem", "discretization", "tensors", "codebook", "checks", "plot"},
    "view": {"discretization", "tensors", "codebook", "inference"},  # a page of a codebook (and data)
    "family": {"problem", "driver"},  # several specs, one task each
    "cli": {"problem", "discretization", "tensors", "algorithms", "codebook", "checks", "driver", "adapt",
            "plot", "inference", "view", "family"},
}


# modules at the package root that every layer may import -> the package modules they import
LEAVES = {
    "errors": (),  # the exception hierarchy
    "pages": (),  # arrays in memory pages of a chosen size
    "names": (),  # what a name may be; text safe for a terminal
    "limits": ("pgdcli.errors",),  # the documented limits and their environment overrides
    "progress": (),  # the typed progress events of a solve
    "blas": (),  # BLAS on one thread while a block of work runs: the one limiter
    "tuning": ("pgdcli.errors",),  # the machine-specific tuning constants and their environment overrides
    "executors": ("pgdcli.errors", "pgdcli.blas"),  # where independent tasks run: here, a pool, a Dask cluster
    "cluster": ("pgdcli.errors", "pgdcli.executors"),  # opening a Dask cluster
}


def module_names() -> dict[str, pathlib.Path]:
    """``{dotted module name: path}`` of every module in the package (``pgdcli.x.y``)."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = module_names()


def _is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def _resolve(importer: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = importer.split(".")
    if not _is_package(importer):
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(name: str) -> list[tuple[str, str | None, int]]:
    """``(module imported, name taken from it or None, line)`` for every import of a package module."""
    tree = ast.parse(MODULES[name].read_text())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(a.name, None, node.lineno) for a in node.names if a.name.split(".")[0] == "pgdcli"]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(name, node)
            if target.split(".")[0] != "pgdcli":
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in MODULES:  # `from . import module`
                    found.append((sub, None, node.lineno))
                else:
                    found.append((target, alias.name, node.lineno))
    return found


@functools.lru_cache(maxsize=None)
def _graph() -> dict[str, set[str]]:
    graph = {}
    for name in MODULES:
        edges = set()
        for target, _, _ in imports_of(name):
            while target not in MODULES:  # `import pgdcli.x.y` of a name, not a module: the module
                target = target.rsplit(".", 1)[0]
            if target != name:
                edges.add(target)
        graph[name] = edges
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the directed graph (a list of nodes, first == last), or None."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                cycle = visit(nxt)
                if cycle:
                    return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            if cycle:
                return cycle
    return None


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle():
    # the package root only names its lazy imports in strings: importing it is not a cycle
    graph = {name: {t for t in edges if t != "pgdcli"} for name, edges in _graph().items()}
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))


def test_no_private_name_of_another_module():
    offences = []
    for name in MODULES:
        for target, taken, line in imports_of(name):
            if taken and taken.startswith("_") and not taken.startswith("__") and target != name:
                offences.append(f"{MODULES[name].relative_to(PACKAGE.parent)}:{line} imports {target}.{taken}")
        # `module._name` through a module imported whole
        tree = ast.parse(MODULES[name].read_text())
        aliases = {}
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for alias in node.names:
                    aliases[alias.asname or alias.name] = alias.name
        modules_bound = {a for a, real in aliases.items()
                         if any(m.endswith("." + real) or m == real for m in MODULES)}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in modules_bound and node.attr.startswith("_")
                    and not node.attr.startswith("__")):
                offences.append(f"{MODULES[name].relative_to(PACKAGE.parent)}:{node.lineno} uses "
                                f"{node.value.id}.{node.attr}")
    assert not offences, "\n".join(offences)


def _layer(name: str) -> str:
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else ""


@pytest.mark.parametrize("name", sorted(MODULES))
def test_layers_point_one_way(name):
    layer = _layer(name)
    if layer not in LOWER:
        return
    allowed = LOWER[layer] | {layer, ""} | set(LEAVES)  # leaves every layer uses
    wrong = sorted({t for t in _graph()[name] if _layer(t) not in allowed})
    assert not wrong, f"{name} ({layer}) imports {wrong}"


@pytest.mark.parametrize("leaf", sorted(LEAVES))
def test_leaf_modules_import_only_leaves(leaf):
    imported = {t for t in _graph()[f"pgdcli.{leaf}"] if t != "pgdcli"}
    assert imported <= set(LEAVES[leaf]), f"pgdcli.{leaf} imports {sorted(imported)}"
