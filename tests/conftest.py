"""Shared fixtures and references of the test suite.

The shipped problems are solved once per test run (``solved``) and their
codebooks written once to a temporary directory of the run (``codebook_path``).
Exact solutions are written here from the comments of ``problems/*.yaml``;
they never use pgdcli. Inline YAML specs come from one factory, :func:`spec_text` (a base spec
with top-level sections replaced, added or removed) and the ``write_spec`` fixture (the same,
written to a file): write a new test's spec as ``spec_text(BASE, equations=[...])`` when it is a
variant of another.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import textwrap
from pathlib import Path
from typing import Mapping

import numpy as np
import pytest
import scipy.linalg  # noqa: F401 - its BLAS loaded now, to be limited with numpy's below
import threadpoolctl

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"
SHIPPED = ("parametric", "spring", "relaxation")

if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1:
    # One BLAS thread per worker of -n auto: the workers fill the cores, and more BLAS threads only
    # wait for each other (a QR of a test took ten times longer with two per worker on two busy cores).
    # pgdcli.solve runs on one BLAS thread whatever the caller's, so no result changes.
    _ONE_BLAS_THREAD = threadpoolctl.threadpool_limits(1, user_api="blas")


@pytest.fixture
def two_blas_threads():
    """BLAS on two threads during the test, whatever the suite's workers run on: the tests of a limit and
    of its lifting see a change."""
    with threadpoolctl.threadpool_limits(2, user_api="blas"):
        yield


def pytest_collection_modifyitems(config, items):
    """The modules with long accuracy tests (``slow``) first, each kept whole (its module fixtures
    are made once): the workers of ``-n auto`` take them while the short ones are left to even
    out the end (the suite ended with a slow test otherwise)."""
    slow = {item.module.__name__ for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.module.__name__ not in slow)


# ----------------------------------------------------------------------------------------------
# exact solutions (from the comments of problems/*.yaml)
# ----------------------------------------------------------------------------------------------
def exact_parametric(p):
    """k (u' + 1) = 10, u(0) = 0  ->  u = (10/k - 1) t."""
    return {"u": (10.0 / p["k"] - 1.0) * p["t"]}


def exact_spring(p):
    """x'' + c x' + k x = 0, x(0) = 1, x'(0) = 0 (underdamped); v = x'."""
    t, k, c = p["t"], p["k"], p["c"]
    wd = np.sqrt(k - c * c / 4.0)
    decay = np.exp(-c * t / 2.0)
    x = decay * (np.cos(wd * t) + c / (2.0 * wd) * np.sin(wd * t))
    v = -decay * (k / wd) * np.sin(wd * t)
    return {"x": x, "v": v}


def exact_relaxation(p):
    """u' = -k u + a sin(2t), u(0) = u0."""
    t, k, a, u0 = p["t"], p["k"], p["a"], p["u0"]
    e = np.exp(-k * t)
    return {"u": u0 * e + a * (k * np.sin(2 * t) - 2 * np.cos(2 * t) + 2 * e) / (k * k + 4.0)}


EXACT = {"parametric": exact_parametric, "spring": exact_spring, "relaxation": exact_relaxation}


def random_points(domains: dict, n: int, seed: int, corners: bool = True) -> dict:
    """``n`` points uniform in the box ``domains`` (name -> (low, high)), plus every corner.

    Returns name -> 1D array, in the order of ``domains``.
    """
    rng = np.random.default_rng(seed)
    names = list(domains)
    cols = [rng.uniform(lo, hi, n) for lo, hi in domains.values()]
    if corners:
        box = np.array(list(itertools.product(*[(float(lo), float(hi)) for lo, hi in domains.values()])))
        cols = [np.concatenate([c, box[:, j]]) for j, c in enumerate(cols)]
    return dict(zip(names, cols))


def codebook_points(cb, n: int, seed: int, corners: bool = True) -> dict:
    return random_points({c.name: c.domain for c in cb.coordinates}, n, seed, corners)


def nodal_points(cb, size: int, seed: int, special: float = 0.25) -> dict:
    """``size`` uniform points in the codebook's domain, a share ``special`` of each coordinate's values
    on its nodes (slab breakpoints and the domain's ends among them). Returns name -> 1D array."""
    rng = np.random.default_rng(seed)
    out = {}
    for c in cb.coordinates:
        nodes = c.basis().nodes
        x = rng.uniform(*c.domain, size)
        hit = rng.random(size) < special
        x[hit] = nodes[rng.integers(0, nodes.size, int(hit.sum()))]
        out[c.name] = x
    return out


def max_abs_error(cb, exact, points) -> dict:
    values = cb(**points)
    ref = exact(points)
    return {u: float(np.max(np.abs(values[u] - ref[u]))) for u in ref}


# ----------------------------------------------------------------------------------------------
# inline YAML specs: one factory (a base spec with top-level sections replaced, added or removed)
# ----------------------------------------------------------------------------------------------
#: The minimal spec: one time coordinate, one unknown, one equation (YAML text of each section, as
#: written after ``key:``).
MINIMAL_SECTIONS = {"coordinates": "\n  t: {domain: [0, 1], nodes: 4}", "unknowns": "\n  u: {initial: 0}",
                    "equations": "\n  - der(u) = -u"}


def spec_sections(text: str) -> dict[str, str]:
    """The top-level sections of a YAML spec, in order: ``{key: the text after 'key:'}`` (lines of
    its block included; comments between sections stay with the section before them)."""
    out: dict[str, str] = {}
    key = None
    for line in textwrap.dedent(text).strip("\n").splitlines():
        top = line[:1] not in ("", " ", "\t", "#", "-") and ":" in line
        if top:
            key, rest = line.split(":", 1)
            out[key] = rest
        elif key is not None:
            out[key] += "\n" + line
    return out


def _section_text(value) -> str:
    """A section value as YAML text after ``key:``: text as is; a mapping as one ``name: value`` line per
    entry (values are inline YAML text); a list as ``- item`` lines (items are YAML text)."""
    if isinstance(value, str):
        return value
    if isinstance(value, Mapping):
        return "".join(f"\n  {k}: {v}" for k, v in value.items())
    return "".join(f"\n  - {item}" for item in value)


def spec_text(base: str | Mapping[str, str] | None = None, **sections) -> str:
    """YAML text of a test problem: ``base`` with top-level sections replaced or added, or removed (None).

    Parameters
    ----------
    base : str or mapping, optional
        A spec's YAML text, or its sections (see :func:`spec_sections`); default: the minimal spec
        (:data:`MINIMAL_SECTIONS`).
    **sections
        Section name -> YAML text after ``key:`` (e.g. ``" {tolerance: 1e-9}"`` or
        ``"\n  t: {domain: [0, 2], nodes: 8}"``), a mapping ``{entry: inline YAML}``, a list of YAML
        items (equations), or None to remove the section.
    """
    merged = dict(MINIMAL_SECTIONS if base is None else spec_sections(base) if isinstance(base, str) else base)
    for key, value in sections.items():
        if value is None:
            merged.pop(key, None)
        else:
            merged[key] = _section_text(value)
    return "".join(f"{key}:{value}\n" for key, value in merged.items())


@pytest.fixture
def write_spec(tmp_path):
    """``write_spec(base=None, name="spec.yaml", **sections)`` -> Path of :func:`spec_text` written in ``tmp_path``."""

    def write(base: str | Mapping[str, str] | None = None, name: str = "spec.yaml", **sections) -> Path:
        path = tmp_path / name
        path.write_text(spec_text(base, **sections))
        return path

    return write


# ----------------------------------------------------------------------------------------------
# fixtures of the whole run: each shipped problem solved once, its codebook written once
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="session")
def solved():
    """``solved(name)`` -> SolveResult of ``problems/<name>.yaml`` (solved once per test run)."""
    from pgdcli import load_spec, solve

    cache: dict = {}

    def get(name: str):
        if name not in cache:
            cache[name] = solve(load_spec(PROBLEMS / f"{name}.yaml"))
        return cache[name]

    return get


@pytest.fixture(scope="session")
def codebook_path(solved, tmp_path_factory):
    """``codebook_path(name)`` -> Path of the saved codebook of a shipped problem (written once)."""
    directory = tmp_path_factory.mktemp("codebooks")
    cache: dict = {}

    def get(name: str) -> Path:
        if name not in cache:
            path = directory / f"{name}.h5"
            solved(name).codebook.save(path)
            cache[name] = path
        return cache[name]

    return get


@contextlib.contextmanager
def train_march():
    """Send every nonlinear ODE problem to the tensor-train march, however small or large its grid (the grid
    march, ``pgdcli.algorithms.grid_march``, would take the small grids of the tests, the cross march,
    ``pgdcli.algorithms.cross_march``, the large ones)."""
    from pgdcli.algorithms import grid_march, march

    saved = grid_march.GRID_LIMIT, march.CROSS_BY_DEFAULT
    grid_march.GRID_LIMIT, march.CROSS_BY_DEFAULT = 0, False
    try:
        yield
    finally:
        grid_march.GRID_LIMIT, march.CROSS_BY_DEFAULT = saved


def assert_solved(result) -> None:
    """The solver itself converged; its measured error may exceed the spec's tolerance.

    For convergence studies on deliberately coarse grids, whose tolerance is the
    solver's stopping target there and which the error gate (rightly) refuses.
    """
    from pgdcli.adapt import INACCURATE

    assert result.converged or result.status == INACCURATE, result.message


def reseal(path) -> None:
    """Recompute the digests of a codebook file edited in place (``h5py.File(path, "r+")``).

    A test that simulates an intact file with wrong numbers (a solver's bug, not a disk's)
    edits the arrays and then reseals the file, so that only the numbers differ.
    """
    import json

    import h5py

    from pgdcli.codebook.file_checks import ARRAY_DIGESTS, CONTENT_DIGEST, array_digest, metadata_digest, survey

    with h5py.File(path, "r+") as f:
        digests = {}

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                value = obj[()]
                digests[name] = array_digest(value.decode() if isinstance(value, bytes) else value)

        f.visititems(visit)
        f.attrs[ARRAY_DIGESTS] = json.dumps(digests, sort_keys=True, separators=(",", ":"))
        f.attrs[CONTENT_DIGEST] = metadata_digest(survey(f, str(path)))
