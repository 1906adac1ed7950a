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
    "executor_base": ("pgdcli.blas", "pgdcli.pages"),  # the executor interface; a task in a worker
    "dask_executor": ("pgdcli.errors", "pgdcli.executor_base"),  # tasks on a Dask cluster
    # where independent tasks run: here, a pool, a Dask cluster
    "executors": ("pgdcli.executor_base", "pgdcli.dask_executor"),
    "cluster": ("pgdcli.errors", "pgdcli.dask_executor"),  # opening a Dask cluster
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


# --- sizes and local imports ----------------------------------------------------------------------

MAX_MODULE_LINES = 450
MAX_FUNCTION_CODE_LINES = 60

# third-party modules slow enough to import that a command which may not need them defers them into
# the function that does (the time `pgd query` or `import pgdcli` would otherwise pay at start-up)
HEAVY = ("numpy", "scipy.", "h5py", "matplotlib", "rich.", "yaml", "distributed", "dask", "selenium",
         "threadpoolctl", "xarray", "pandas", "pyarrow",
         "pathlib", "tempfile")  # the standard library's slower imports: a one-point query loads neither


def _heavy(module: str) -> str | None:
    """The heavy third-party name ``module`` loads (``scipy.sparse`` for ``scipy.sparse.linalg``)."""
    for prefix in HEAVY:
        if module == prefix.rstrip(".") and prefix.endswith("."):
            return None  # the bare package (e.g. ``scipy``) is cheap; its subpackages are not
        if module.startswith(prefix) or module == prefix:
            if prefix.endswith("."):
                return ".".join(module.split(".")[:2])
            return prefix
    return None


def _top_level_imports(tree: ast.Module):
    """Import statements that run when the module is imported (``if TYPE_CHECKING`` blocks excluded)."""
    todo = list(tree.body)
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, ast.If) and "TYPE_CHECKING" not in ast.unparse(node.test):
            todo += node.body + node.orelse
        elif isinstance(node, ast.Try):
            todo += node.body + node.orelse + node.finalbody + [s for h in node.handlers for s in h.body]


def _targets(name: str, node) -> tuple[set[str], set[str]]:
    """``(package modules, heavy third-party names)`` an import statement of module ``name`` loads."""
    ours, heavy = set(), set()
    if isinstance(node, ast.Import):
        modules = [a.name for a in node.names]
    else:
        base = _resolve(name, node)
        modules = [base] + [f"{base}.{a.name}" for a in node.names]
    for module in modules:
        if module.split(".")[0] == "pgdcli":
            while module and module not in MODULES:
                module = module.rpartition(".")[0]
            if module:
                ours.add(module)
        elif _heavy(module):
            heavy.add(_heavy(module))
    return ours, heavy


@functools.lru_cache(maxsize=None)
def _import_time_edges(name: str) -> tuple[frozenset[str], frozenset[str]]:
    """``(package modules, heavy names)`` that module ``name``'s own top-level imports load."""
    ours, heavy = set(), set()
    parts = name.split(".")
    ours |= {".".join(parts[:i]) for i in range(1, len(parts))}  # a submodule's packages run first
    for node in _top_level_imports(ast.parse(MODULES[name].read_text())):
        o, h = _targets(name, node)
        ours |= o
        heavy |= h
    return frozenset(ours - {name}), frozenset(heavy)


@functools.lru_cache(maxsize=None)
def _loads_at_import(name: str) -> frozenset[str]:
    """The heavy third-party names that importing package module ``name`` loads (transitively)."""
    seen, todo, heavy = {name}, [name], set()
    while todo:
        ours, theirs = _import_time_edges(todo.pop())
        heavy |= theirs
        todo += [m for m in ours if m not in seen]
        seen |= ours
    return frozenset(heavy)


def _code_lines(lines: list[str], node) -> int:
    """Lines of ``node`` that hold code: no blank line, comment line or docstring."""
    first = node.body[0]
    doc = set()
    if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
        doc = set(range(first.lineno, first.end_lineno + 1))
    return sum(1 for i in range(node.lineno, node.end_lineno + 1)
               if i not in doc and lines[i - 1].strip() and not lines[i - 1].strip().startswith("#"))


def test_modules_fit_in_one_read():
    long = {str(p.relative_to(PACKAGE.parent)): n for p in MODULES.values()
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def test_functions_fit_on_a_screen():
    long = []
    for path in MODULES.values():
        text = path.read_text()
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if (n := _code_lines(lines, node)) > MAX_FUNCTION_CODE_LINES:
                    long.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {node.name} ({n} lines)")
    assert not long, f"functions over {MAX_FUNCTION_CODE_LINES} lines of code:\n" + "\n".join(long)


def test_local_imports_defer_a_heavy_import():
    """An import inside a function defers loading something heavy the module does not load already."""
    needless = []
    for name, path in MODULES.items():
        tree = ast.parse(path.read_text())
        loaded = _loads_at_import(name)
        for func in ast.walk(tree):
            if not isinstance(func, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(func):
                if not isinstance(node, (ast.Import, ast.ImportFrom)):
                    continue
                ours, heavy = _targets(name, node)
                for module in ours:
                    heavy |= _loads_at_import(module)
                if not heavy - loaded:
                    needless.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {ast.unparse(node)}")
    assert not needless, "imports inside functions that defer nothing heavy:\n" + "\n".join(needless)
