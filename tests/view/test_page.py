"""The page's text (pgdcli.view) and ``pgd view``: self-contained, escaped, size-limited, one-line errors.

What the page does in a browser is tested in test_browser.py.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor
from pgdcli.codebook.export import layout
from pgdcli.view import PAGE_LIMIT, UPLOT_VERSION, ViewError, page_html
from pgdcli.view.page import script_json
from pgdcli.view.payload import numbers_size


def tiny(name="tiny", description="", report=None) -> Codebook:
    rng = np.random.default_rng(2)
    coords = [CoordinateInfo("t", (0.0, 1.0), 5, "chebyshev", "time"), CoordinateInfo("k", (1.0, 2.0), 3, "linear")]
    return Codebook(coords, {"u": CPTensor(rng.standard_normal(2), tuple(rng.standard_normal((c.nodes, 2))
                                                                          for c in coords))},
                    name=name, description=description, report=report or {})


def _data(html: str) -> dict:
    match = re.search(r'<script type="application/json" id="pgd-data">(.*?)</script>', html, re.S)
    return json.loads(match.group(1))


def _scripts(html: str) -> list[str]:
    return re.findall(r"<script>(.*?)</script>", html, re.S)


def test_page_is_self_contained_and_carries_the_export_layout():
    cb = tiny()
    html = page_html(cb, source="tiny.h5")
    assert html.startswith("<!DOCTYPE html>") and html.isascii()
    assert "src=" not in html and "href=\"http" not in html and "@import" not in html
    data = _data(html)
    assert data["format"] == "pgdcli-view" and data["layout"] == json.loads(json.dumps(layout(cb)))
    assert data["meta"]["source"] == "tiny.h5" and [c["role"] for c in data["meta"]["coordinates"]] == ["time",
                                                                                                        "parameter"]
    scripts = _scripts(html)
    assert len(scripts) == 2 and f"uPlot v{UPLOT_VERSION}" in scripts[0] and "Leon Sorokin" in scripts[0]
    assert "Permission is hereby granted" in scripts[0]  # the licence travels with the library
    policy = re.search(r'http-equiv="Content-Security-Policy" content="([^"]*)"', html).group(1).replace("&#x27;", "'")
    assert "default-src 'none'" in policy and "connect-src" not in policy
    for s in scripts:  # each inline script allowed by its hash, nothing else
        digest = base64.b64encode(hashlib.sha256(s.encode()).digest()).decode()
        assert f"'sha256-{digest}'" in policy


def test_strings_cannot_close_the_data_script_or_the_title():
    hostile = "</script><script>alert(1)</script><!-- & \u2028"
    cb = tiny(name=hostile, description=hostile, report={"message": hostile})
    html = page_html(cb)
    assert html.count("</script>") == 3 and html.count("<script") == 3
    assert "<!--" not in html
    assert _data(html)["meta"]["description"] == hostile and _data(html)["layout"]["name"] == hostile
    title = re.search(r"<title>(.*)</title>", html).group(1)
    assert "<" not in title and "&lt;/script&gt;" in title
    text = script_json({"a": "</SCRIPT>&<"})
    assert "<" not in text and ">" not in text and "&" not in text and json.loads(text) == {"a": "</SCRIPT>&<"}


def test_size_limit_refuses_with_a_clear_message_and_force_overrides():
    cb = tiny()
    size = numbers_size(cb)
    from pgdcli.codebook.export import size_of

    assert size == size_of(layout(cb))
    with pytest.raises(ViewError, match=r"over the page limit of 0 MiB .* use --force"):
        page_html(cb, limit=size - 8)
    assert page_html(cb, limit=size - 8, force=True)
    assert PAGE_LIMIT == 8 * 2**20


def test_cli_writes_the_page_next_to_the_codebook(tmp_path):
    path = tiny().save(tmp_path / "tiny.h5")
    r = CliRunner().invoke(cli, ["view", str(path)], catch_exceptions=False)
    assert r.exit_code == 0 and r.stdout == f"{tmp_path / 'tiny.html'}\n" and r.stderr == ""
    assert _data((tmp_path / "tiny.html").read_text())["meta"]["source"] == "tiny.h5"


@pytest.mark.parametrize("args, message", [
    (["-o", "page.png"], "--output page.png: unsupported file type '.png'; expected .html or .htm"),
    (["--data", "missing.csv"], "missing.csv: cannot read"),
    (["--data", "{bad}"], "is neither a coordinate (t, k), an unknown (u) nor sigma_<unknown>"),
    (["--data", "{outside}"], "column 'k': value 5.0 is outside the domain [1, 2]"),
])
def test_cli_errors_are_one_line_exit_2(tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    path = tiny().save(tmp_path / "tiny.h5")
    (tmp_path / "bad.csv").write_text("t,q\n0,1\n")
    (tmp_path / "outside.csv").write_text("t,u,k\n0,1,5\n")
    args = [a.replace("{bad}", "bad.csv").replace("{outside}", "outside.csv") for a in args]
    r = CliRunner().invoke(cli, ["view", str(path), *args], catch_exceptions=False)
    assert r.exit_code == 2 and r.stdout == ""
    assert len(r.stderr.splitlines()) == 1 and r.stderr.startswith("Error: ") and message in r.stderr, r.stderr
    assert not list(tmp_path.glob("*.html"))


def test_cli_refuses_a_codebook_too_large_for_a_page(tmp_path):
    rng = np.random.default_rng(3)
    coords = [CoordinateInfo("t", (0.0, 1.0), 1999, "chebyshev", "time", tuple(np.linspace(0, 1, 1000))),
              CoordinateInfo("k", (0.0, 1.0), 600, "chebyshev")]
    modes = (rng.standard_normal((1999, 600)), rng.standard_normal((600, 600)))  # 1.56e6 numbers: 12.5 MB
    path = Codebook(coords, {"u": CPTensor(rng.standard_normal(600), modes)}, name="big", report={}).save(
        tmp_path / "big.h5")
    r = CliRunner().invoke(cli, ["view", str(path)], catch_exceptions=False)
    assert r.exit_code == 2 and "over the page limit of 8 MiB" in r.stderr and "--force" in r.stderr
    assert not (tmp_path / "big.html").exists()
    r = CliRunner().invoke(cli, ["view", str(path), "--force"], catch_exceptions=False)
    assert r.exit_code == 0 and (tmp_path / "big.html").stat().st_size > 8 * 2**20
