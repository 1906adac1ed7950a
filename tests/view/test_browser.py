"""``pgd view`` pages in a real browser (headless Chromium, Selenium): sliders, numbers, plots, data, errors.

The values a page displays after its sliders and number boxes move are compared with ``pgd query``
at the point the page shows (its number boxes): to 1e-12 of the value, or of the unknown's largest
magnitude along the page's curve where the value itself is near zero (rounding of a sum of terms
scales with the terms). Codebooks: shipped problems (CP, tensor-train march, linear elements, a
space coordinate), and codebooks built here to reach every representation and basis the format
allows (tensor trains in any core order, Chebyshev slabs with uneven breakpoints, Chebyshev
elements of a parameter, linear elements, two space coordinates, steady, mixed CP and tensor
trains in one file).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("selenium", reason="selenium is not installed (pip install -e '.[test]')")
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.common.keys import Keys  # noqa: E402

from chromium import browser, open_page  # noqa: F401 (browser: a fixture)
from pgdcli.cli.main import cli  # noqa: E402
from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor, TT
from pgdcli.view import page_html

ROOT = Path(__file__).resolve().parents[2]
RELATIVE = 1e-12


# ----------------------------------------------------------------------------------------------
# codebooks built here: every representation and basis
# ----------------------------------------------------------------------------------------------
def _trains(coords, orders, ranks, rng):
    return {name: TT(tuple(rng.standard_normal((ranks[k], coords[j].nodes, ranks[k + 1]))
                                for k, j in enumerate(order)), order) for name, order in orders.items()}


def mixed_codebook() -> Codebook:
    """Time in uneven Chebyshev slabs, a Chebyshev, a linear and an element-wise Chebyshev parameter, two
    space coordinates; a CP unknown and tensor trains in three core orders."""
    rng = np.random.default_rng(31)
    coords = [CoordinateInfo("t", (0.0, 2.0), 13, "chebyshev", "time", (0.0, 0.3, 1.2, 2.0)),
              CoordinateInfo("a", (-1.0, 1.0), 7, "chebyshev", "parameter"),
              CoordinateInfo("b", (0.0, 3.0), 5, "linear", "parameter"),
              CoordinateInfo("c", (1.0, 2.0), 9, "chebyshev", "parameter", (1.0, 1.25, 2.0)),
              CoordinateInfo("x", (0.0, 1.0), 6, "chebyshev", "space"),
              CoordinateInfo("y", (-0.5, 0.5), 5, "chebyshev", "space")]
    fields = {"p": CPTensor(rng.standard_normal(4), tuple(rng.standard_normal((c.nodes, 4)) + 1.5 for c in coords))}
    fields.update(_trains(coords, {"q": (0, 1, 2, 3, 4, 5), "r": (3, 5, 0, 2, 4, 1), "s": (5, 4, 3, 2, 1, 0)},
                          (1, 3, 4, 5, 3, 2, 1), rng))
    return Codebook(coords, fields, name="mixed", report={})


def steady_codebook() -> Codebook:
    rng = np.random.default_rng(32)
    coords = [CoordinateInfo("x", (0.0, 1.0), 8, "chebyshev", "space"),
              CoordinateInfo("y", (0.0, 2.0), 7, "chebyshev", "space"),
              CoordinateInfo("g", (-1.0, 1.0), 2, "linear", "parameter")]
    return Codebook(coords, {"u": CPTensor(rng.standard_normal(3), tuple(rng.standard_normal((c.nodes, 3))
                                                                              for c in coords))},
                    name="steady", report={})


def front_codebook() -> Codebook:
    """One space coordinate and time, a tensor train of the PDE march's core order (time first)."""
    rng = np.random.default_rng(33)
    coords = [CoordinateInfo("t", (0.0, 0.5), 21, "chebyshev", "time", tuple(np.linspace(0, 0.5, 6) ** 1.5 / 0.5**0.5)),
              CoordinateInfo("x", (0.0, 1.0), 17, "chebyshev", "space"),
              CoordinateInfo("nu", (0.01, 0.1), 9, "chebyshev", "parameter")]
    return Codebook(coords, _trains(coords, {"u": (0, 1, 2)}, (1, 6, 4, 1), rng), name="front", report={})


def single_codebook() -> Codebook:
    """Time alone: no parameter, nothing but the curves and the values."""
    rng = np.random.default_rng(34)
    t = CoordinateInfo("t", (0.0, 5.0), 12, "chebyshev", "time")
    return Codebook([t], {"u": CPTensor(rng.standard_normal(2), (rng.standard_normal((12, 2)),))}, name="single",
                    report={})


BUILT = {"mixed": mixed_codebook, "steady": steady_codebook, "front": front_codebook, "single": single_codebook}


@pytest.fixture(scope="module")
def pages(tmp_path_factory, codebook_path):
    """name -> (Codebook, codebook file, page file): built codebooks and shipped ones, pages written by pgd view."""
    directory = tmp_path_factory.mktemp("view-pages")
    cache = {}

    def get(name):
        if name not in cache:
            if name in BUILT:
                path = BUILT[name]().save(directory / f"{name}.h5")
            else:
                path = codebook_path(name)
            page = directory / f"{name}.html"
            r = CliRunner().invoke(cli, ["view", str(path), "-o", str(page)], catch_exceptions=False)
            assert r.exit_code == 0 and r.stdout == f"{page}\n", r.stderr
            cache[name] = (Codebook.load(path), path, page)
        return cache[name]

    return get


# ----------------------------------------------------------------------------------------------
# what the page shows
# ----------------------------------------------------------------------------------------------
def shown_point(driver, cb) -> dict:
    """The coordinates the page shows in its number boxes."""
    out = {}
    for j, c in enumerate(cb.coordinates):
        box = driver.find_element(By.ID, f"coord-{j}-number")
        assert box.get_attribute("data-coordinate") == c.name
        out[c.name] = float(box.get_property("value"))
    return out


def shown_values(driver, cb) -> dict:
    out = {}
    for i, u in enumerate(cb.unknown_names):
        cell = driver.find_element(By.ID, f"value-{i}")
        assert cell.get_attribute("data-unknown") == u
        out[u] = float(cell.text)
    return out


def query(path, cb, point) -> dict:
    """``pgd query`` at the point (plain format: the unknowns' values on one line)."""
    args = ["query", str(path)]
    for c in cb.coordinates:
        args += [f"--{c.name}", repr(point[c.name])]
    r = CliRunner().invoke(cli, args, catch_exceptions=False)
    assert r.exit_code == 0, r.stderr
    return dict(zip(cb.unknown_names, map(float, r.stdout.split())))


def assert_close_to_query(cb, path, point, shown):
    expected = query(path, cb, point)
    axis = next((c for c in cb.coordinates if c.role == "time"), cb.coordinates[0])
    along = {**point, axis.name: np.linspace(*axis.domain, 101)}
    curve = cb.evaluate(along)
    for u, value in expected.items():
        scale = max(abs(value), float(np.max(np.abs(curve[u]))))
        assert abs(shown[u] - value) <= RELATIVE * scale, (u, shown[u], value, point)


def move(driver, cb, rng, name):
    """Arrow keys on a slider, then a value typed into a number box (a commit: Tab)."""
    j = cb.coordinate_names.index(name)
    slider = driver.find_element(By.ID, f"coord-{j}-slider")
    slider.send_keys(*([Keys.ARROW_RIGHT] * int(rng.integers(3, 40))))
    c = cb.coordinates[j]
    value = float(rng.uniform(*c.domain))
    box = driver.find_element(By.ID, f"coord-{j}-number")
    box.clear()
    box.send_keys(repr(value), Keys.TAB)
    return value


def settle(driver):
    driver.execute_script("return new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")


# ----------------------------------------------------------------------------------------------
# tests
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["spring", "coupled", "relaxation", "mixed", "steady", "front", "single"])
def test_moved_sliders_and_typed_numbers_show_pgd_query_values(browser, pages, name):
    cb, path, page = pages(name)
    logs = open_page(browser, page)
    assert not [e for e in logs if e["level"] == "SEVERE"], logs
    assert_close_to_query(cb, path, shown_point(browser, cb), shown_values(browser, cb))
    rng = np.random.default_rng(41)
    for rounds in range(3):
        for c in cb.coordinates:
            typed = move(browser, cb, rng, c.name)
            settle(browser)
            assert shown_point(browser, cb)[c.name] == typed  # the box shows the value used, exactly
        point = shown_point(browser, cb)
        assert_close_to_query(cb, path, point, shown_values(browser, cb))
    # a slider alone: the box follows it, the values follow the box
    j = len(cb.coordinates) - 1
    browser.find_element(By.ID, f"coord-{j}-slider").send_keys(Keys.HOME, *([Keys.ARROW_RIGHT] * 7))
    settle(browser)
    point = shown_point(browser, cb)
    low, high = cb.coordinates[j].domain
    assert point[cb.coordinates[j].name] == pytest.approx(low + 7 * (high - low) / 1000, rel=1e-9)
    assert_close_to_query(cb, path, point, shown_values(browser, cb))
    assert browser.execute_script("return window.pgdView.errors") == []
    command = browser.find_element(By.ID, "command").text.replace("\n", "")
    assert command.startswith(f"pgd query {path.name} --{cb.coordinates[0].name} ")


@pytest.mark.parametrize("name", ["coupled", "mixed", "front", "steady"])
def test_curves_and_maps_drawn_equal_the_codebook(browser, pages, name):
    cb, _, page = pages(name)
    open_page(browser, page)
    rng = np.random.default_rng(42)
    for c in cb.coordinates:
        move(browser, cb, rng, c.name)
    settle(browser)
    point = shown_point(browser, cb)
    curves = browser.execute_script("return window.pgdView.lastCurves")
    axis = curves["axis"]
    samples = np.array(curves["samples"])
    assert samples.size == 400 and samples[0] == cb.coordinate(axis).domain[0]
    expected = cb.evaluate({**point, axis: samples})
    for u, values in zip(cb.unknown_names, curves["values"]):
        scale = float(np.max(np.abs(expected[u])))
        assert np.max(np.abs(np.array(values) - expected[u])) <= RELATIVE * scale, u
    names = cb.coordinate_names
    if len(names) < 2:
        return
    j, k = (names.index(c.name) for c in cb.coordinates[:2])
    sj = np.linspace(*cb.coordinates[j].domain, 23)
    sk = np.linspace(*cb.coordinates[k].domain, 19)
    for field, u in enumerate(cb.unknown_names):
        xs = [point[n] for n in names]
        grid = browser.execute_script(
            "return Array.from(window.pgdView.codebook.map(arguments[0], arguments[1], arguments[2], arguments[3], "
            "Float64Array.from(arguments[4]), Float64Array.from(arguments[5])))", field, xs, j, k, sj.tolist(),
            sk.tolist())
        expected = cb.evaluate({**point, names[j]: sj[:, None], names[k]: sk[None, :]})[u]
        assert np.max(np.abs(np.array(grid).reshape(sj.size, sk.size) - expected)) <= RELATIVE * np.max(np.abs(expected))


@pytest.mark.parametrize("name", ["parametric", "spring", "relaxation", "coupled", "logistic", "drag", "pendulum",
                                  "forced", "heat1d", "rigid_body", "mixed", "steady", "front", "single"])
def test_pages_load_without_console_errors(browser, pages, name):
    cb, _, page = pages(name)
    logs = open_page(browser, page)
    assert not [e for e in logs if e["level"] in ("SEVERE", "WARNING")], logs
    assert browser.execute_script("return window.pgdView.ready && window.pgdView.errors.length === 0")
    # a slider per coordinate other than time and space, a chart per unknown
    assert len(browser.find_elements(By.CSS_SELECTOR, "input[type=range]")) == len(cb.coordinates)
    assert len(browser.find_elements(By.CSS_SELECTOR, ".grid .uplot")) == len(cb.unknown_names)
    status = browser.find_element(By.ID, "status").text
    assert ("Within its tolerance" in status) == (cb.accurate is True)
    if any(c.role == "space" for c in cb.coordinates) and (len([c for c in cb.coordinates if c.role == "space"]) > 1
                                                           or any(c.role == "time" for c in cb.coordinates)):
        assert browser.find_elements(By.CSS_SELECTOR, ".field .uplot")
    timing = browser.execute_script("return window.pgdView.bench(15)")
    assert timing["samples"] == 400 and timing["curves"] >= 0


def test_play_moves_time_and_keeps_the_values_right(browser, pages):
    cb, path, page = pages("front")
    open_page(browser, page)
    before = shown_point(browser, cb)["t"]
    browser.find_element(By.ID, "play").click()
    browser.execute_script("return new Promise(r => setTimeout(r, 400))")
    browser.find_element(By.ID, "play").click()
    settle(browser)
    point = shown_point(browser, cb)
    assert point["t"] != before
    assert_close_to_query(cb, path, point, shown_values(browser, cb))


def test_a_zoom_survives_slider_moves(browser, pages):
    cb, _, page = pages("spring")
    open_page(browser, page)
    browser.execute_script("window.pgdView.charts[0].setScale('x', {min: 1, max: 2})")  # as a drag across it does
    j = cb.coordinate_names.index("k")
    browser.find_element(By.ID, f"coord-{j}-slider").send_keys(*([Keys.ARROW_LEFT] * 20))
    settle(browser)
    scale = browser.execute_script("const s = window.pgdView.charts[0].scales.x; return [s.min, s.max]")
    assert scale == [1, 2]
    point = shown_point(browser, cb)
    drawn = browser.execute_script("return window.pgdView.charts[0].data[1]")
    np.testing.assert_allclose(drawn, cb.evaluate({**point, "t": np.linspace(0, 4, 400)})["x"], rtol=0, atol=1e-12)
    browser.execute_script("window.pgdView.charts[0].setScale('x', {min: 0, max: 4})")  # double-click: all
    browser.find_element(By.ID, f"coord-{j}-slider").send_keys(Keys.ARROW_RIGHT)
    settle(browser)
    assert browser.execute_script("const s = window.pgdView.charts[0].scales.x; return [s.min, s.max]") == [0, 4]


def test_invalid_number_is_refused_with_a_note(browser, pages):
    cb, _, page = pages("spring")
    open_page(browser, page)
    j = cb.coordinate_names.index("k")
    before = shown_values(browser, cb)
    box = browser.find_element(By.ID, f"coord-{j}-number")
    box.clear()
    box.send_keys("12", Keys.TAB)
    settle(browser)
    assert "k must be a number in [1, 4]" in browser.find_element(By.ID, f"coord-{j}-note").text
    assert shown_values(browser, cb) == before


def test_data_file_is_drawn_as_markers_and_bad_files_get_one_line(browser, pages, tmp_path):
    cb, _, page = pages("spring")
    open_page(browser, page)
    t = np.linspace(0, 4, 9)
    good = tmp_path / "obs.csv"
    good.write_text("t,x,k\n" + "".join(f"{float(v)!r},{float(np.cos(v))!r},2.5\n" for v in t))
    browser.find_element(By.ID, "data-file").send_keys(str(good))
    browser.execute_script("return new Promise(r => setTimeout(r, 300))")
    message = browser.find_element(By.ID, "data-message").text
    assert "obs.csv: 9 rows of x (markers)" in message and "k = 2.5 from the data" in message
    assert shown_point(browser, cb)["k"] == 2.5
    legends = browser.execute_script(
        "return Array.from(document.querySelectorAll('.grid .uplot')).map(u => u.querySelectorAll('.u-series').length)")
    assert legends == [3, 2]  # x: axis, curve, data; v: axis, curve
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x\n0,1\n0.5,abc\n")
    browser.find_element(By.ID, "data-file").send_keys(str(bad))
    browser.execute_script("return new Promise(r => setTimeout(r, 300))")
    assert browser.find_element(By.ID, "data-message").text == \
        "bad.csv: line 3, column \"x\": \"abc\" is not a finite number"
    other = tmp_path / "other.csv"
    other.write_text("t,q\n0,1\n")
    browser.find_element(By.ID, "data-file").send_keys(str(other))
    browser.execute_script("return new Promise(r => setTimeout(r, 300))")
    assert "column \"q\" is neither a coordinate (t, k, c), an unknown (x, v) nor sigma_<unknown>" in \
        browser.find_element(By.ID, "data-message").text
    assert browser.execute_script("return window.pgdView.errors") == []


def test_data_given_to_pgd_view_is_in_the_page(browser, codebook_path, tmp_path):
    path = codebook_path("spring")
    data = tmp_path / "measured.csv"
    data.write_text("t,v\n0,0\n1,-0.5\n2,0.1\n")
    page = tmp_path / "spring.html"
    r = CliRunner().invoke(cli, ["view", str(path), "-o", str(page), "--data", str(data)], catch_exceptions=False)
    assert r.exit_code == 0, r.stderr
    open_page(browser, page)
    browser.execute_script("return new Promise(r => setTimeout(r, 100))")
    assert browser.find_element(By.ID, "data-message").text.startswith("measured.csv: 3 rows of v")


def test_strings_from_the_codebook_are_text_not_markup(browser, tmp_path):
    hostile = "</script><img src=x onerror=\"window.pwned=1\"><b>bold</b>"
    cb = steady_codebook()
    cb = Codebook(cb.coordinates, {"<i>u</i>": cb.fields["u"]}, name=hostile, description=hostile + " & more",
                  report={"message": hostile})
    page = tmp_path / "hostile.html"
    page.write_text(page_html(cb, source=hostile))
    logs = open_page(browser, page)
    assert browser.execute_script("return window.pgdView.ready && !window.pwned")
    assert not browser.find_elements(By.TAG_NAME, "img") and not browser.find_elements(By.CSS_SELECTOR, "header b")
    assert browser.find_element(By.TAG_NAME, "h1").text == hostile
    assert browser.find_element(By.CSS_SELECTOR, "header .description").text == hostile + " & more"
    assert browser.find_element(By.ID, "value-0").get_attribute("data-unknown") == "<i>u</i>"
    assert not [e for e in logs if e["level"] == "SEVERE"], logs


def test_the_page_asks_for_nothing_over_the_network(browser, pages):
    """Its policy allows no fetch: an attempt is refused by the browser, and the page itself makes none."""
    _, _, page = pages("coupled")
    open_page(browser, page)
    resources = browser.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
    assert resources == []
    refused = browser.execute_script(
        "return fetch('https://example.com/').then(() => 'fetched', () => 'refused')")
    assert refused == "refused"
    policy = browser.execute_script(
        "return document.querySelector('meta[http-equiv=Content-Security-Policy]').content")
    assert "default-src 'none'" in policy and json.dumps(policy).count("sha256-") == 2


def test_the_notebook_explorer_runs_the_page_in_a_sandboxed_frame(browser, pages, tmp_path):
    from pgdcli.view import explore

    cb, path, _ = pages("coupled")
    frame_html = explore(cb, height=700)._repr_html_()
    assert frame_html.startswith("<iframe srcdoc=") and 'sandbox="allow-scripts"' in frame_html
    notebook = tmp_path / "notebook.html"
    notebook.write_text(f"<!DOCTYPE html><html><body><h1>cell output</h1>{frame_html}</body></html>")
    browser.get(notebook.resolve().as_uri())
    browser.switch_to.frame(browser.find_element(By.TAG_NAME, "iframe"))
    try:
        from selenium.webdriver.support.ui import WebDriverWait

        WebDriverWait(browser, 30).until(lambda d: d.execute_script("return window.pgdView && window.pgdView.ready"))
        settle(browser)
        assert_close_to_query(cb, path, shown_point(browser, cb), shown_values(browser, cb))
        assert browser.execute_script("return window.pgdView.errors") == []
    finally:
        browser.switch_to.default_content()
