"""Codebook evaluation and HDF5 files (pgdcli.codebook.codebook)."""

from __future__ import annotations

import os

import h5py
import numpy as np
import pytest
from conftest import codebook_points, reseal

from pgdcli.codebook import io as codebook_io
from pgdcli.codebook.codebook import FORMAT_NAME, FORMAT_VERSION, TT, Codebook, CoordinateInfo, CPTensor
from pgdcli.codebook.fields import cp_field, tt_field
from pgdcli.errors import CodebookError, QueryError

EPS = np.finfo(float).eps


def _one_line(exc) -> str:
    text = str(exc)
    assert "\n" not in text and text.strip() == text and text
    return text


def _small_codebook():
    """A hand-made codebook with small-integer modes: every nodal sum is exact in float64."""
    coords = [
        CoordinateInfo("t", (0.0, 2.0), 5, "chebyshev", "time"),
        CoordinateInfo("k", (1.0, 3.0), 4, "chebyshev"),
        CoordinateInfo("a", (-1.0, 1.0), 3, "linear"),
    ]
    rng = np.random.default_rng(0)
    fields = {
        "u": CPTensor(np.array([1.0, -2.0, 0.5]), tuple(rng.integers(-4, 5, (c.nodes, 3)).astype(float) for c in coords)),
        "w": CPTensor(np.array([3.0]), tuple(rng.integers(-4, 5, (c.nodes, 1)).astype(float) for c in coords)),
    }
    return Codebook(coords, fields, name="small", spec_text="name: small\n", report={"converged": True})


def _node_grid(cb):
    grids = np.meshgrid(*[c.basis().nodes for c in cb.coordinates], indexing="ij")
    return dict(zip(cb.coordinate_names, grids))


def _reference_sum(fm, index):
    """sum_r alpha_r prod_j modes_j[i_j, r] and the sum of absolute terms (for a rounding bound)."""
    terms = fm.weights.copy()
    for m, i in zip(fm.factors, index):
        terms = terms * m[i]
    return terms.sum(), np.abs(terms).sum()


# ----------------------------------------------------------------------------------------------
# evaluation
# ----------------------------------------------------------------------------------------------
def test_evaluate_at_nodes_is_bitwise_exact_when_sums_are_exact():
    cb = _small_codebook()
    grid = _node_grid(cb)
    values = cb(**grid)
    for u in cb.unknown_names:
        nodal = cb.nodal_values(u)
        assert np.array_equal(values[u], nodal)
        for index in [(0, 0, 0), (4, 3, 2), (2, 1, 1), (3, 0, 2)]:
            assert nodal[index] == _reference_sum(cb.fields[u], index)[0]


@pytest.mark.parametrize("name", ["parametric", "spring", "relaxation"])
def test_evaluate_at_nodes_returns_nodal_values(solved, name):
    """No interpolation error at nodes: differences are at most the rounding of the mode sum itself."""
    cb = solved(name).codebook
    grid = _node_grid(cb)
    values = cb(**grid)
    for u in cb.unknown_names:
        nodal = cb.nodal_values(u)
        fm = cb.fields[u]
        letters = "abcdefgh"[: len(fm.factors)]
        abs_terms = np.einsum(",".join(f"{l}r" for l in letters) + ",r->" + letters,
                              *[np.abs(m) for m in fm.factors], np.abs(fm.weights))
        bound = 2 * (fm.rank + len(fm.factors)) * EPS * abs_terms
        assert np.all(np.abs(values[u] - nodal) <= bound)
        # spot check against an independent sum
        rng = np.random.default_rng(1)
        for _ in range(5):
            index = tuple(int(rng.integers(c.nodes)) for c in cb.coordinates)
            ref, scale = _reference_sum(fm, index)
            assert abs(values[u][index] - ref) <= 2 * (fm.rank + len(fm.factors)) * EPS * scale


def test_evaluate_between_nodes_uses_the_basis_interpolants():
    cb = _small_codebook()
    rng = np.random.default_rng(4)
    p = {c.name: rng.uniform(*c.domain, 50) for c in cb.coordinates}
    # independent interpolants: numpy Chebyshev fit through the nodes (degree n-1) and np.interp
    from numpy.polynomial import Chebyshev

    for u, fm in cb.fields.items():
        per_coord = []
        for c, m in zip(cb.coordinates, fm.factors):
            nodes = c.basis().nodes
            if c.discretization == "linear":
                per_coord.append(np.stack([np.interp(p[c.name], nodes, m[:, r]) for r in range(fm.rank)], axis=1))
            else:
                per_coord.append(np.stack([Chebyshev.fit(nodes, m[:, r], c.nodes - 1, domain=list(c.domain))(p[c.name])
                                           for r in range(fm.rank)], axis=1))
        ref = np.prod(per_coord, axis=0) @ fm.weights
        np.testing.assert_allclose(cb(**p)[u], ref, rtol=0, atol=1e-12)


def test_broadcasting_shapes(solved):
    cb = solved("parametric").codebook
    out = cb(t=5.0, k=2.0)
    assert set(out) == {"u"}
    assert isinstance(out["u"], np.ndarray) and out["u"].shape == ()
    assert float(out["u"]) == pytest.approx(20.0, abs=1e-12)
    t = np.array([[0.0], [5.0], [10.0]])
    k = np.array([1.0, 2.0, 5.0, 10.0])
    out = cb(t=t, k=k)["u"]
    assert out.shape == (3, 4)
    np.testing.assert_allclose(out, (10.0 / k - 1.0) * t, rtol=0, atol=1e-12)
    assert cb(t=[1.0, 2.0], k=2.0)["u"].shape == (2,)
    assert cb(t=np.ones((2, 1, 3)), k=np.full((4, 1), 2.0))["u"].shape == (2, 4, 3)


def test_field_selection(solved):
    cb = solved("spring").codebook
    out = cb.evaluate({"t": 1.0, "k": 2.0, "c": 0.3}, fields=["v"])
    assert list(out) == ["v"]
    both = cb.evaluate({"t": 1.0, "k": 2.0, "c": 0.3}, fields=["v", "x"])
    assert list(both) == ["v", "x"]
    assert list(cb(t=1.0, k=2.0, c=0.3)) == ["x", "v"]


def test_domain_ends_are_accepted(solved):
    cb = solved("parametric").codebook
    out = cb(t=[0.0, 10.0], k=[1.0, 10.0])["u"]
    np.testing.assert_allclose(out, [0.0, 0.0], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "coords,fields,patterns",
    [
        ({"t": 11.0, "k": 2.0}, None, ["'t'", "11.0", "[0, 10]"]),
        ({"t": 1.0, "k": 0.5}, None, ["'k'", "0.5", "[1, 10]"]),
        ({"t": [1.0, -0.5], "k": 2.0}, None, ["'t'", "-0.5", "[0, 10]"]),
        ({"t": float("nan"), "k": 2.0}, None, ["'t'", "[0, 10]"]),
        ({"t": 1.0}, None, ["missing", "'k'", "[1, 10]"]),
        ({"t": 1.0, "k": 2.0, "z": 1.0}, None, ["unknown coordinate", "'z'"]),
        ({"t": 1.0, "k": 2.0}, ["w"], ["unknown field", "'w'"]),
    ],
)
def test_query_errors_name_the_coordinate_and_domain(solved, coords, fields, patterns):
    cb = solved("parametric").codebook
    with pytest.raises(QueryError) as info:
        cb.evaluate(coords, fields=fields)
    text = _one_line(info.value)
    for p in patterns:
        assert p in text, (p, text)


def test_codebook_validation_names_the_problem():
    coords = [CoordinateInfo("t", (0.0, 1.0), 3, "chebyshev", "time")]
    with pytest.raises(CodebookError, match=r"unknown 'u': modes of coordinate 0 \('t'\) have shape \(4, 1\)"):
        Codebook(coords, {"u": CPTensor(np.ones(1), (np.ones((4, 1)),))})
    with pytest.raises(CodebookError, match="non-finite"):
        Codebook(coords, {"u": CPTensor(np.array([np.nan]), (np.ones((3, 1)),))})
    with pytest.raises(CodebookError, match="unknown 'u': expected a CPTensor or a TT, got dict"):
        Codebook(coords, {"u": {"alphas": np.ones(1)}})
    two = coords + [CoordinateInfo("k", (1.0, 2.0), 4)]
    with pytest.raises(CodebookError, match=r"unknown 'u': core 1 \('t'\) has shape \(2, 4, 1\), expected \(2, 3, r\)"):
        Codebook(two, {"u": TT((np.ones((1, 4, 2)), np.ones((2, 4, 1))), (1, 0))})
    with pytest.raises(CodebookError, match="tensor-train mode order \\[0\\] is not a permutation of the 2"):
        Codebook(two, {"u": TT((np.ones((1, 3, 1)),))})


def test_a_malformed_field_in_a_file_names_the_unknown_and_the_factor(codebook_path, tmp_path):
    """A mode matrix of the wrong shape is refused by the reader before any tensor is built."""
    path = tmp_path / "bad.h5"
    path.write_bytes(codebook_path("spring").read_bytes())
    with h5py.File(path, "r+") as f:
        modes = f["unknowns"]["x"]["modes"]
        rank = modes["k"].shape[1]
        del modes["k"]
        modes.create_dataset("k", data=np.ones((20, rank + 1)))
    with pytest.raises(CodebookError, match=f"dataset 'unknowns/x/modes/k' has shape \\(20, {rank + 1}\\), "
                                            f"expected \\(20, {rank}\\)"):
        Codebook.load(path)


def test_the_tensor_types_checks_become_codebook_errors_naming_the_unknown():
    with pytest.raises(CodebookError, match="unknown 'x': factor 1 has 3 columns, expected rank 2"):
        cp_field("x", np.ones(2), (np.ones((4, 2)), np.ones((5, 3))))
    with pytest.raises(CodebookError, match="unknown 'w': core 1 has left rank 3, core 0 right rank 2"):
        tt_field("w", (np.ones((1, 4, 2)), np.ones((3, 5, 1))), (0, 1))


# ----------------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["parametric", "spring", "relaxation"])
def test_round_trip_is_exact(solved, codebook_path, name):
    original = solved(name).codebook
    loaded = Codebook.load(codebook_path(name))
    assert loaded.name == original.name == name
    assert loaded.coordinate_names == original.coordinate_names
    assert loaded.unknown_names == original.unknown_names
    assert loaded.coordinates == original.coordinates
    assert loaded.spec_text == original.spec_text
    assert loaded.description == original.description
    assert loaded.created == original.created
    for u in original.fields:
        assert np.array_equal(loaded.fields[u].weights, original.fields[u].weights)
        for a, b in zip(loaded.fields[u].factors, original.fields[u].factors):
            assert np.array_equal(a, b)
    points = codebook_points(original, 500, seed=9)
    a, b = original(**points), loaded(**points)
    for u in original.fields:
        assert np.array_equal(a[u], b[u])  # bitwise
    for key in ("converged", "residual", "modes", "tolerance", "pgdcli_version", "status", "message"):
        assert loaded.report[key] == original.report[key], key
    np.testing.assert_array_equal(loaded.report["residual_history"], original.report["residual_history"])
    np.testing.assert_array_equal(loaded.report["iterations"], original.report["iterations"])


def test_file_is_self_describing(codebook_path):
    with h5py.File(codebook_path("spring"), "r") as f:
        assert f.attrs["encoding-type"] == FORMAT_NAME
        assert f.attrs["encoding-version"] == FORMAT_VERSION
        assert list(f.attrs["coordinate-order"]) in (["t", "k", "c"], [b"t", b"k", b"c"])
        assert set(f["coordinates"]) == {"t", "k", "c"}
        assert set(f["unknowns"]) == {"x", "v"}
        assert f["coordinates"]["t"]["nodes"].shape == (36,)
        assert f["unknowns"]["x"]["modes"]["k"].shape[0] == 20
        assert "report" in f and "spec" in f


def test_info_summary(codebook_path):
    path = codebook_path("relaxation")
    info = Codebook.load(path).info(path)
    assert info["name"] == "relaxation"
    assert [c["name"] for c in info["coordinates"]] == ["t", "k", "a", "u0"]
    assert info["coordinates"][2]["discretization"] == "linear"
    assert info["coordinates"][0]["domain"] == [0.0, 3.0]
    assert info["converged"] is True
    assert info["size_bytes"] == os.path.getsize(path)


def test_save_is_atomic_on_failure(tmp_path, monkeypatch):
    cb = _small_codebook()
    target = tmp_path / "cb.h5"

    def boom(self, f):
        f.attrs["encoding-type"] = "half written"
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(codebook_io, "write_contents", boom)
    with pytest.raises(RuntimeError, match="disk on fire"):
        cb.save(target)
    assert list(tmp_path.iterdir()) == []  # neither the target nor a temporary file
    monkeypatch.undo()
    cb.save(target)
    before = target.read_bytes()
    monkeypatch.setattr(codebook_io, "write_contents", boom)
    with pytest.raises(RuntimeError):
        cb.save(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cb.h5"]
    assert target.read_bytes() == before
    monkeypatch.undo()
    assert np.array_equal(Codebook.load(target)(t=1.0, k=2.0, a=0.5)["u"], cb(t=1.0, k=2.0, a=0.5)["u"])


def test_save_creates_parent_directories(tmp_path):
    target = tmp_path / "deep" / "er" / "cb.h5"
    _small_codebook().save(target)
    assert Codebook.load(target).name == "small"


def _assert_codebook_error(path, *needles):
    with pytest.raises(CodebookError) as info:
        Codebook.load(path)
    text = _one_line(info.value)
    assert str(path) in text
    for n in needles:
        assert n in text, (n, text)
    return text


def test_load_missing_file(tmp_path):
    _assert_codebook_error(tmp_path / "nope.h5", "no such file")


def test_load_directory(tmp_path):
    _assert_codebook_error(tmp_path)


def test_load_non_hdf5_file(tmp_path):
    path = tmp_path / "spec.h5"
    path.write_text("name: not a codebook\ncoordinates: {}\n")
    _assert_codebook_error(path)


def test_load_empty_file(tmp_path):
    path = tmp_path / "empty.h5"
    path.write_bytes(b"")
    _assert_codebook_error(path)


@pytest.mark.parametrize("fraction", [0.02, 0.1, 0.5, 0.9])
def test_load_truncated_file(tmp_path, codebook_path, fraction):
    data = codebook_path("spring").read_bytes()
    path = tmp_path / "cut.h5"
    path.write_bytes(data[: int(len(data) * fraction)])
    _assert_codebook_error(path)


def test_load_hdf5_without_encoding_type(tmp_path):
    path = tmp_path / "plain.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("x", data=np.arange(3.0))
    _assert_codebook_error(path, "not a pgdcli codebook")


def test_load_codebook_with_encoding_type_removed(tmp_path, codebook_path):
    path = tmp_path / "stripped.h5"
    path.write_bytes(codebook_path("parametric").read_bytes())
    with h5py.File(path, "r+") as f:
        del f.attrs["encoding-type"]
    _assert_codebook_error(path, "not a pgdcli codebook")


def test_load_newer_major_version_asks_to_upgrade(tmp_path, codebook_path):
    path = tmp_path / "future.h5"
    path.write_bytes(codebook_path("parametric").read_bytes())
    with h5py.File(path, "r+") as f:
        f.attrs["encoding-version"] = "2.0"
    text = _assert_codebook_error(path, "2.0")
    assert "upgrade" in text.lower()


@pytest.mark.parametrize("version", ["0.9", "abc", ""])
def test_load_unsupported_or_unreadable_version(tmp_path, codebook_path, version):
    path = tmp_path / "odd.h5"
    path.write_bytes(codebook_path("parametric").read_bytes())
    with h5py.File(path, "r+") as f:
        f.attrs["encoding-version"] = version
    _assert_codebook_error(path)


def test_load_newer_minor_version_is_accepted(tmp_path, codebook_path):
    path = tmp_path / "minor.h5"
    path.write_bytes(codebook_path("parametric").read_bytes())
    with h5py.File(path, "r+") as f:
        f.attrs["encoding-version"] = "1.7"
    reseal(path)
    cb = Codebook.load(path)
    assert float(cb(t=5.0, k=2.0)["u"]) == pytest.approx(20.0, abs=1e-12)


def test_load_codebook_missing_a_group(tmp_path, codebook_path):
    path = tmp_path / "broken.h5"
    path.write_bytes(codebook_path("parametric").read_bytes())
    with h5py.File(path, "r+") as f:
        del f["unknowns"]
    _assert_codebook_error(path)
