"""Fuzz suite for codebook files: a real codebook mutated in its bytes, attributes, arrays and links.

The invariant, whatever the file: ``Codebook.load`` raises nothing but ``CodebookError``; a file
that loads gives exactly the original's numbers unless the mutation recomputed its digests (a
file intact as a file and wrong in its numbers is the checks' business, not the reader's);
``pgd info`` and ``pgd query`` end with status 0, 1 or 2 and at most one ``Error:`` line, no
traceback, in bounded time.

The budget and the ``PGD_FUZZ=long`` profile are those of ``tests/cli/test_fuzz.py``.
"""

from __future__ import annotations

import time

import h5py
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from conftest import reseal
from pgdcli.codebook.codebook import Codebook
from pgdcli.errors import CodebookError
from test_fuzz import budget, check_result, invoke

SHIPPED = ("spring", "coupled")
HOSTILE_TEXT = st.sampled_from(["", "x", "*/ int pwned; /*", "a\nb", "\x1b[2J", "../x", "1.0", "2.0", "t",
                                "tensor-train", "cp", "chebyshev", "linear", "é" * 70])


def _objects(f) -> tuple[list[str], list[str]]:
    groups, datasets = [""], []
    f.visititems(lambda n, o: (datasets if isinstance(o, h5py.Dataset) else groups).append(n))
    return groups, datasets


def _attribute_value(draw):
    kind = draw(st.sampled_from(["int", "float", "text", "texts", "array", "empty"]))
    if kind == "int":
        return draw(st.integers(-2**40, 2**40))
    if kind == "float":
        return draw(st.floats(allow_nan=True, allow_infinity=True))
    if kind == "text":
        return draw(HOSTILE_TEXT)
    if kind == "texts":
        return np.array(draw(st.lists(HOSTILE_TEXT, max_size=5)), dtype=object)
    if kind == "array":
        return np.full(draw(st.integers(0, 40)), draw(st.floats(-1e300, 1e300)))
    return np.zeros(0)


@st.composite
def mutations(draw):
    """A list of (kind, parameters) applied in order to a copy of a shipped codebook."""
    steps = []
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["flip", "attribute", "dataset", "link", "delete"]))
        if kind == "flip":
            steps.append((kind, draw(st.floats(0.0, 1.0, exclude_max=True)), draw(st.integers(1, 255))))
        elif kind == "attribute":
            steps.append((kind, draw(st.integers(0, 10**6)), draw(HOSTILE_TEXT | st.sampled_from(
                ["domain", "discretization", "encoding-version", "coordinate-order", "unknown-order",
                 "mode-order", "representation", "breakpoints", "name", "sha256"])), _attribute_value(draw)))
        elif kind == "dataset":
            shape = tuple(draw(st.lists(st.integers(0, 64), max_size=3)))
            steps.append((kind, draw(st.integers(0, 10**6)), shape, draw(st.sampled_from(["f8", "i4", "f4", "u1"])),
                          draw(st.booleans())))
        elif kind == "link":
            steps.append((kind, draw(st.integers(0, 10**6)), draw(st.sampled_from(["soft", "external", "hard"]))))
        else:
            steps.append((kind, draw(st.integers(0, 10**6))))
    return steps, draw(st.booleans())


def _apply(path, steps) -> None:
    for step in steps:
        kind = step[0]
        if kind == "flip":
            data = bytearray(path.read_bytes())
            data[int(step[1] * len(data))] ^= step[2]
            path.write_bytes(bytes(data))
            continue
        with h5py.File(path, "r+") as f:
            groups, datasets = _objects(f)
            if kind == "attribute":
                objects = groups + datasets
                target = f[objects[step[1] % len(objects)] or "/"]
                target.attrs[step[2] or "_"] = step[3]
            elif kind == "dataset" and datasets:
                name = datasets[step[1] % len(datasets)]
                del f[name]
                if step[4]:
                    f.create_dataset(name, shape=step[2], dtype=step[3])  # declared, nothing stored
                else:
                    f.create_dataset(name, data=np.ones(step[2], dtype=step[3]))
            elif kind == "link" and datasets:
                name = datasets[step[1] % len(datasets)]
                other = datasets[(step[1] + 1) % len(datasets)]
                del f[name]
                f[name] = {"soft": h5py.SoftLink("/" + other), "external": h5py.ExternalLink("/etc/hostname", "/x"),
                           "hard": f[other]}[step[2]]
            elif kind == "delete":
                objects = groups[1:] + datasets
                if objects:
                    del f[objects[step[1] % len(objects)]]


@pytest.fixture(scope="module")
def originals(codebook_path):
    out = {}
    for name in SHIPPED:
        cb = Codebook.load(codebook_path(name))
        rng = np.random.default_rng(0)
        points = {c.name: rng.uniform(*c.domain, 7) for c in cb.coordinates}
        out[name] = (codebook_path(name), cb, points)
    return out


@budget(60)
@given(shipped=st.sampled_from(SHIPPED), mutation=mutations())
def test_a_mutated_codebook_is_refused_or_unchanged(tmp_path_factory, originals, shipped, mutation):
    steps, resealed = mutation
    source, original, points = originals[shipped]
    path = tmp_path_factory.mktemp("fuzz") / "cb.h5"
    path.write_bytes(source.read_bytes())
    try:
        _apply(path, steps)
        if resealed:
            reseal(path)
    except (OSError, KeyError, ValueError, TypeError, RuntimeError, CodebookError):
        return  # h5py could not make this mutation, or the file no longer opens (nor reseals)
    started = time.perf_counter()
    try:
        cb = Codebook.load(path)
    except CodebookError as exc:
        assert "\n" not in str(exc)
        cb = None
    assert time.perf_counter() - started < 5.0
    if cb is not None and not resealed:
        got, want = cb.evaluate(points), original.evaluate(points)
        assert all(np.array_equal(got[u], want[u]) for u in want), steps
    for args in (["info", str(path)], ["query", str(path)] + [f"--{c}={float(np.mean(v))}" for c, v in points.items()]):
        result = invoke(args)
        check_result(result.exit_code, result.stdout, result.stderr)
