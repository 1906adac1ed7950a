"""One self-contained HTML page of a codebook: its numbers, uPlot and the page's script, inlined.

The page needs no network and asks for none: its Content-Security-Policy allows only its own two
scripts (by hash), inline styles and ``data:`` images, so nothing can be fetched or sent. The
codebook's JSON sits in a ``<script type="application/json">`` element, escaped so that no text
from the codebook can close it (``<``, ``>`` and ``&`` as ``\\u003c`` ...); the page reads it with
``JSON.parse`` and inserts every string as text.
"""

from __future__ import annotations

import base64
import hashlib
import html
import json
import os
import tempfile
from functools import lru_cache
from pathlib import Path

from ..codebook.phases import refuse_phases
from ..errors import PgdError
from .payload import PAGE_LIMIT, payload

__all__ = ["page_html", "write_page", "script_json", "explore", "Explorer", "UPLOT_VERSION"]

STATIC = Path(__file__).resolve().parent / "static"
UPLOT_VERSION = "1.6.32"


@lru_cache(maxsize=None)
def _static(name: str) -> str:
    return (STATIC / name).read_text(encoding="utf-8")


def script_json(value) -> str:
    """JSON for a ``<script>`` element: ASCII, and no ``<``, ``>`` or ``&`` (so no ``</script>``, no ``<!--``)."""
    text = json.dumps(value, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _script(text: str) -> str:
    if "</script" in text.lower() or "<!--" in text:
        raise PgdError("a page script contains '</script' or '<!--' and cannot be inlined")
    return text


def _uplot() -> str:
    licence = _static("uPlot.LICENSE").strip().replace("*/", "* /")
    return f"/*! uPlot v{UPLOT_VERSION}, https://github.com/leeoniya/uPlot\n{licence}\n*/\n" + _static("uPlot.iife.min.js")


def _hash(text: str) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(text.encode("utf-8")).digest()).decode("ascii") + "'"


def page_html(cb, *, source: str | None = None, data: dict | None = None, limit: int = PAGE_LIMIT,
              force: bool = False) -> str:
    """The page of ``cb`` as text (QueryError for a codebook with phases: the page reads the fields).

    Parameters
    ----------
    cb : Codebook
    source : str, optional
        The codebook's file name, shown in the page's ``pgd query`` command.
    data : dict, optional
        ``{"label", "columns"}`` (:func:`pgdcli.view.payload.data_columns`): drawn as markers.
    limit, force
        Numbers beyond ``limit`` bytes (float64) are refused unless ``force``.

    Raises
    ------
    ViewError
        A codebook too large for a page.
    """
    refuse_phases(cb, "pgd view")
    content = payload(cb, data=data, limit=limit, force=force)
    if source is not None:
        content["meta"]["source"] = str(source)
    scripts = [_script(_uplot()), _script(_static("evaluate.js") + "\n" + _static("view.js"))]
    policy = ("default-src 'none'; " + "script-src " + " ".join(_hash(s) for s in scripts) +
              "; style-src 'unsafe-inline'; img-src data:; base-uri 'none'; form-action 'none'")
    title = html.escape(f"{cb.name} - pgd view", quote=True)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en">',
        "<head>",
        '<meta charset="utf-8">',
        f'<meta http-equiv="Content-Security-Policy" content="{html.escape(policy, quote=True)}">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        '<meta name="generator" content="pgdcli pgd view">',
        '<link rel="icon" href="data:,">',
        f"<title>{title}</title>",
        f"<style>{_static('uPlot.min.css')}</style>",
        f"<style>{_static('view.css')}</style>",
        "</head>",
        "<body>",
        "<noscript>This page evaluates the codebook with JavaScript; please enable it.</noscript>",
        '<div id="app"></div>',
        f'<script type="application/json" id="pgd-data">{script_json(content)}</script>',
        *[f"<script>{s}</script>" for s in scripts],
        "</body>",
        "</html>",
        "",
    ]
    return "\n".join(parts)


def write_page(cb, path: str | os.PathLike, **options) -> Path:
    """Write :func:`page_html` to ``path`` atomically (a temporary file in the same folder, then a rename)."""
    path = Path(path)
    text = page_html(cb, **options)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


class Explorer:
    """The page of a codebook inside a notebook: displayed as a sandboxed ``<iframe>`` holding it.

    Attributes
    ----------
    html : str
        The page (:func:`page_html`).
    height : int
        The frame's height in pixels.
    """

    def __init__(self, html_text: str, height: int = 900):
        self.html = html_text
        self.height = int(height)

    def _repr_html_(self) -> str:
        # the page as the frame's document (escaped as an attribute value); scripts allowed, nothing else:
        # no access to the notebook, no navigation, no network (the page's own policy too)
        return (f'<iframe srcdoc="{html.escape(self.html, quote=True)}" sandbox="allow-scripts" '
                f'style="width: 100%; height: {self.height}px; border: 1px solid #d8dde3; border-radius: 6px">'
                f"</iframe>")

    def save(self, path: str | os.PathLike) -> Path:
        """Write the page to ``path`` (as ``pgd view -o`` does)."""
        path = Path(path)
        path.write_text(self.html, encoding="utf-8")
        return path


def explore(cb, *, height: int = 900, **options) -> Explorer:
    """The ``pgd view`` page of ``cb`` to display in a notebook (the last expression of a cell).

    ``options`` as for :func:`page_html` (``data``, ``limit``, ``force``).

    Examples
    --------
    >>> from pgdcli.view import explore                 # doctest: +SKIP
    >>> explore(pgdcli.Codebook.load("codebooks/drag.h5"))   # doctest: +SKIP
    """
    return Explorer(page_html(cb, **options), height)
