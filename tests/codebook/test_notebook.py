"""The Python and notebook path: ``cb(points)``, ``Codebook.to_xarray`` and ``Codebook._repr_html_``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor, TT
from pgdcli.errors import PgdError, QueryError


def small_codebook(name="small", description="") -> Codebook:
    rng = np.random.default_rng(5)
    coords = [CoordinateInfo("t", (0.0, 2.0), 9, "chebyshev", "time", (0.0, 0.8, 2.0)),
              CoordinateInfo("k", (1.0, 3.0), 6, "chebyshev"),
              CoordinateInfo("c", (0.0, 1.0), 4, "linear")]
    cores = tuple(rng.standard_normal(s) for s in ((1, 9, 3), (3, 6, 2), (2, 4, 1)))
    return Codebook(coords, {"u": CPTensor(rng.standard_normal(3), tuple(rng.standard_normal((c.nodes, 3))
                                                                          for c in coords)),
                             "w": TT(cores, (0, 1, 2))},
                    name=name, description=description,
                    report={"tolerance": 1e-6, "accurate": 1, "check_error": 2.5e-7, "check_points": 40,
                            "check_where": "t=1, k=2, c=0"})


# ----------------------------------------------------------------------------------------------
# cb(points)
# ----------------------------------------------------------------------------------------------
def test_points_array_gives_rows_of_unknowns_like_regular_grid_interpolator():
    cb = small_codebook()
    rng = np.random.default_rng(6)
    points = np.column_stack([rng.uniform(*c.domain, 50) for c in cb.coordinates])
    out = cb(points)
    assert out.shape == (50, 2)
    by_name = cb(**{c.name: points[:, j] for j, c in enumerate(cb.coordinates)})
    np.testing.assert_array_equal(out[:, 0], by_name["u"])
    np.testing.assert_array_equal(out[:, 1], by_name["w"])
    # the same call shape as scipy's interpolator on the nodal grid (which agrees at the nodes)
    axes = [c.basis().nodes for c in cb.coordinates]
    interpolator = RegularGridInterpolator(axes, cb.nodal_values("u"))
    at_nodes = np.array(np.meshgrid(*axes, indexing="ij")).reshape(3, -1).T[::7]
    np.testing.assert_allclose(cb(at_nodes)[:, 0], interpolator(at_nodes), rtol=0, atol=1e-13)
    assert cb(points[3]).shape == (2,) and cb(points.reshape(5, 10, 3)).shape == (5, 10, 2)
    np.testing.assert_array_equal(cb(points.reshape(5, 10, 3))[2, 4], out[24])


@pytest.mark.parametrize("points, message", [
    (np.zeros((4, 2)), r"points: expected an array of shape \(\.\.\., 3\) with the coordinates t, k, c"),
    (1.0, r"got shape \(\)"),
    (np.array([[0.5, 5.0, 0.5]]), r"coordinate 'k': value 5\.0 is outside the domain \[1, 3\]"),
])
def test_points_errors(points, message):
    with pytest.raises(QueryError, match=message):
        small_codebook()(points)


def test_points_and_keywords_together_are_refused_and_keywords_still_work():
    cb = small_codebook()
    with pytest.raises(QueryError, match="not both"):
        cb(np.zeros((1, 3)), t=0.0)
    value = cb(t=0.5, k=2.0, c=0.25)
    assert set(value) == {"u", "w"} and value["u"].shape == ()


# ----------------------------------------------------------------------------------------------
# to_xarray
# ----------------------------------------------------------------------------------------------
def test_to_xarray_labels_the_grid_and_drops_scalar_coordinates():
    xr = pytest.importorskip("xarray", reason="xarray is not installed (pip install 'pgdcli[xarray]')")
    cb = small_codebook(description="a test")
    t = np.linspace(0, 2, 7)
    ds = cb.to_xarray(t=t, k=[1.5, 2.5], c=0.3)
    assert isinstance(ds, xr.Dataset)
    assert ds["u"].dims == ("t", "k") and ds["w"].shape == (7, 2)
    assert float(ds["c"]) == 0.3 and ds["c"].dims == ()
    grid = cb.evaluate_grid({"t": t, "k": [1.5, 2.5], "c": [0.3]})
    np.testing.assert_array_equal(ds["u"].values, grid["u"][:, :, 0])
    np.testing.assert_array_equal(ds["t"].values, t)
    assert ds["k"].attrs["role"] == "parameter" and list(ds["k"].attrs["domain"]) == [1.0, 3.0]
    assert ds["t"].attrs["discretization"] == "chebyshev" and ds["c"].attrs["nodes"] == 4
    assert ds.attrs["tolerance"] == 1e-6 and ds.attrs["measured_error"] == 2.5e-7 and ds.attrs["accurate"] == 1
    assert ds.attrs["name"] == "small" and ds.attrs["description"] == "a test"
    # a sequence of one value is a dimension; selection works on labels
    one = cb.to_xarray({"t": t, "k": [2.0], "c": [0.3]}, fields=["w"])
    assert list(one.data_vars) == ["w"] and one["w"].dims == ("t", "k", "c")
    np.testing.assert_allclose(one["w"].sel(k=2.0, c=0.3).values, cb.evaluate({"t": t, "k": 2.0, "c": 0.3})["w"],
                               rtol=0, atol=1e-13)


def test_to_xarray_needs_every_coordinate():
    pytest.importorskip("xarray")
    with pytest.raises(QueryError, match=r"missing coordinate 'c' \(domain \[0, 1\]\)"):
        small_codebook().to_xarray(t=[0.5], k=2.0)


def test_to_xarray_without_xarray_says_what_to_install(monkeypatch):
    import builtins

    real = builtins.__import__

    def refuse(name, *args, **kwargs):
        if name == "xarray":
            raise ImportError("no xarray")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", refuse)
    with pytest.raises(PgdError, match=r"pip install 'pgdcli\[xarray\]'"):
        small_codebook().to_xarray(t=[0.5], k=2.0, c=0.1)


# ----------------------------------------------------------------------------------------------
# _repr_html_
# ----------------------------------------------------------------------------------------------
def test_summary_card_shows_what_matters_and_escapes_strings():
    hostile = "<script>alert(1)</script>"
    html = small_codebook(name=hostile, description="x < y & z")._repr_html_()
    assert "<script>" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "x &lt; y &amp; z" in html
    assert "within its tolerance 1e-06" in html and "2.5e-07" in html and "40 points" in html
    assert "tensor train, ranks 3-2" in html and "u (3 modes)" in html
    assert html.count("<tr>") == 4  # a header and one row per coordinate
