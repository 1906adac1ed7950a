"""Spec text -> plain YAML data, safely: a strict loader (no tags, no duplicate keys), a size limit
and a bound on the nodes after alias expansion. The only module that imports yaml.
"""

from __future__ import annotations

from typing import Any
import yaml

from ..errors import SpecError


MAX_SPEC_BYTES = 1 << 20  # a spec file's largest size (shipped specs: < 3 KiB)
MAX_SPEC_NODES = 100_000  # YAML nodes after expanding aliases (shipped specs: < 300)
# ----------------------------------------------------------------------------------------------
# YAML loading
# ----------------------------------------------------------------------------------------------
class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate mapping keys (PyYAML silently keeps the last)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        if isinstance(node, yaml.MappingNode):
            first_line: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # '<<' merges may legitimately be overridden
                key = self.construct_object(key_node, deep=True)
                try:
                    seen = key in first_line
                except TypeError:
                    continue  # unhashable key: the base class reports it
                if seen:
                    raise yaml.constructor.ConstructorError(
                        None,
                        None,
                        f"duplicate key {key!r} (first defined at line {first_line[key] + 1})",
                        key_node.start_mark,
                    )
                first_line[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep=deep)


def load_yaml(text: str, source: str) -> Any:
    """Parse YAML text; any YAML error becomes one line with its line number.

    The text is bounded (:data:`MAX_SPEC_BYTES`), and its node graph is checked
    (:func:`_check_expansion`) *before* any Python value is built: an alias
    bomb is refused in milliseconds, not expanded.
    """
    if len(text) > MAX_SPEC_BYTES:
        raise SpecError(f"{source}: the spec has {len(text)} characters, more than the limit of {MAX_SPEC_BYTES}")
    loader = None
    try:
        loader = _StrictLoader(text)  # checks the characters already
        node = loader.get_single_node()
        if node is None:
            return None
        _check_expansion(node, source)
        try:
            return loader.construct_document(node)
        except (AttributeError, TypeError, KeyError, IndexError) as exc:
            # PyYAML's constructors assume well-formed tagged scalars: `!!timestamp x` raises
            # AttributeError and `!!bool maybe` KeyError from inside PyYAML
            raise SpecError(f"{source}: invalid YAML: a tagged value cannot be built "
                            f"({type(exc).__name__}: {' '.join(str(exc)[:120].split())}); "
                            f"remove the '!!' tags") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        problem = " ".join(str(problem)[:200].split())
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise SpecError(f"{source}: {where}invalid YAML: {problem}") from None
    except RecursionError:
        raise SpecError(f"{source}: invalid YAML: nested too deeply") from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits (Python's int limit)
        raise SpecError(f"{source}: invalid YAML: {' '.join(str(exc)[:200].split())}") from None
    finally:
        if loader is not None:
            loader.dispose()


def _children(node) -> list:
    """The child nodes of a YAML node (keys and values of a mapping)."""
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _expanded_sizes(root) -> dict:
    """id(node) -> number of nodes below it with every alias expanded (iterative: no recursion limit).

    Raises SpecError for a node that contains itself (a recursive anchor).
    """
    sizes: dict = {}
    open_nodes: set = set()
    stack = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if children_done:
            open_nodes.discard(key)
            total = 1
            for child in _children(node):
                total = min(total + sizes[id(child)], 1 << 62)
            sizes[key] = total
            continue
        if key in sizes:
            continue
        if key in open_nodes:
            raise SpecError(f"line {node.start_mark.line + 1}: a YAML anchor refers to itself")
        open_nodes.add(key)
        stack.append((node, True))
        stack.extend((child, False) for child in _children(node) if id(child) not in sizes)
    return sizes


def _check_expansion(root, source: str) -> None:
    """Refuse a document whose nodes, aliases expanded, exceed :data:`MAX_SPEC_NODES`, naming the key."""
    try:
        sizes = _expanded_sizes(root)
    except SpecError as exc:
        raise SpecError(f"{source}: {exc}") from None
    if sizes[id(root)] <= MAX_SPEC_NODES:
        return
    path, node = [], root
    while True:  # down to the deepest key that is too large by itself
        items = node.value if isinstance(node, yaml.MappingNode) else list(enumerate(node.value)) \
            if isinstance(node, yaml.SequenceNode) else []
        big = [(k, v) for k, v in items if sizes[id(v)] > MAX_SPEC_NODES]
        if not big:
            break
        key, node = big[0]
        path.append(str(key.value)[:40] if isinstance(key, yaml.Node) else f"[{key}]")
    where = ".".join(path).replace(".[", "[") or "the document"
    raise SpecError(f"{source}: {where}: the YAML expands to more than {MAX_SPEC_NODES} values (anchors and "
                    f"aliases repeat their content); a spec needs far fewer")
