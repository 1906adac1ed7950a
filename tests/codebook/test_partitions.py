"""Large queries in partitions (pgdcli.codebook.partitions) and codebooks on dask arrays
(pgdcli.codebook.blockwise): the values of Codebook.evaluate on the same blocks, files written
atomically, partitions that do not depend on how the points were read. On a real cluster:
tests/test_cluster.py.
"""

from __future__ import annotations

import pickle

import h5py
import numpy as np
import pytest
from conftest import EXACT, codebook_points

from pgdcli.codebook import partitions
from pgdcli.errors import QueryError

da = pytest.importorskip("dask.array")


@pytest.fixture(scope="module")
def spring(solved):
    return solved("spring").codebook


def points_of(cb, n, seed):
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(*c.domain, size=n) for c in cb.coordinates], axis=1)


def test_partitions_do_not_depend_on_the_chunks_read():
    points = np.arange(3 * 1000, dtype=float).reshape(1000, 3)
    cuts = [0, 7, 300, 301, 999, 1000]
    chunks = [points[a:b] for a, b in zip(cuts[:-1], cuts[1:])]
    got = list(partitions.partitioned(chunks, size=128))
    assert [len(p) for p in got] == [128] * 7 + [104]
    assert np.array_equal(np.concatenate(got), points)


def test_write_points_holds_the_points_and_their_values(spring, tmp_path, monkeypatch):
    monkeypatch.setattr(partitions, "PARTITION", 500)
    points = points_of(spring, 1800, seed=1)
    out = tmp_path / "values.h5"
    written = partitions.write_points(out, spring, partitions.partitioned([points], size=500), ["x"])
    assert written == 1800
    with h5py.File(out) as f:
        assert sorted(f["values"]) == ["x"] and sorted(f["coordinates"]) == ["c", "k", "t"]
        got = {n: f[f"coordinates/{n}"][()] for n in spring.coordinate_names}
        values = f["values/x"][()]
    assert np.array_equal(np.stack([got[n] for n in spring.coordinate_names], axis=1), points)
    blocks = [spring.evaluate(dict(zip(spring.coordinate_names, points[s:s + 500].T)), ["x"])["x"]
              for s in range(0, 1800, 500)]
    assert np.array_equal(values, np.concatenate(blocks))
    exact = EXACT["spring"](got)["x"]
    assert np.max(np.abs(values - exact)) <= spring.report["tolerance"]


def test_a_failed_query_leaves_no_file(spring, tmp_path):
    def chunks():
        yield points_of(spring, 100, seed=2)
        raise QueryError("points.csv: line 102: not a number")

    out = tmp_path / "values.h5"
    out.write_bytes(b"previous")
    with pytest.raises(QueryError):
        partitions.write_points(out, spring, partitions.partitioned(chunks(), size=64))
    assert out.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir()] == ["values.h5"]


def test_a_codebook_pickles_as_its_parts(spring):
    again = pickle.loads(pickle.dumps(spring))
    points = codebook_points(spring, 100, seed=4)
    assert all(np.array_equal(again(**points)[u], spring(**points)[u]) for u in spring.unknown_names)
    assert again.report.keys() == spring.report.keys() and again.spec_text == spring.spec_text


def test_evaluate_on_dask_arrays_is_evaluate_block_by_block(spring):
    points = codebook_points(spring, 3000, seed=5, corners=False)
    lazy = spring.evaluate({n: da.from_array(v, chunks=700) for n, v in points.items()})
    assert isinstance(lazy["x"], da.Array) and lazy["x"].chunks == ((700,) * 4 + (200,),)
    for u in spring.unknown_names:
        blocks = [spring.evaluate({n: v[s:s + 700] for n, v in points.items()})[u] for s in range(0, 3000, 700)]
        assert np.array_equal(lazy[u].compute(scheduler="sync"), np.concatenate(blocks))


def test_dask_arrays_broadcast_with_numbers_and_numpy_arrays(spring):
    t = np.linspace(0.0, 4.0, 30)
    k = np.linspace(1.0, 4.0, 7)[:, None]
    lazy = spring.evaluate({"t": da.from_array(t, chunks=8), "k": k, "c": 0.3}, ["v"])
    assert list(lazy) == ["v"] and lazy["v"].shape == (7, 30)
    np.testing.assert_allclose(lazy["v"].compute(scheduler="sync"), spring.evaluate({"t": t, "k": k, "c": 0.3})["v"],
                               rtol=0, atol=1e-14)


def test_dask_arrays_outside_the_domain_raise_when_computed(spring):
    lazy = spring.evaluate({"t": da.from_array(np.array([1.0, 9.0]), chunks=1), "k": 2.0, "c": 0.3})
    with pytest.raises(QueryError, match="outside the domain"):
        lazy["x"].compute(scheduler="sync")
    with pytest.raises(QueryError, match="unknown field"):  # at once: no graph of a field it lacks
        spring.evaluate({"t": da.from_array(np.array([1.0]), chunks=1), "k": 2.0, "c": 0.3}, ["nope"])
