"""The numbers and facts a page carries: the JSON export's layout, the codebook's summary, optional data.

Everything here is plain JSON data (no NaN: None in its place). The strings in it come from the
codebook file (names, description, report messages) and the data file; the page inserts them as
text only (``textContent``), and :func:`pgdcli.view.page.script_json` escapes the JSON for the
``<script>`` element that carries it.
"""

from __future__ import annotations

import math
import os
from typing import Mapping

import numpy as np

from ..codebook.export import layout
from ..errors import PgdError
from ..inference.data import read_data, split_columns

__all__ = ["ViewError", "PAGE_LIMIT", "payload", "numbers_size", "check_size", "data_columns"]

# Bytes of float64 numbers a page holds without --force: about 2.5x that in page text, which a
# browser parses in a second or two; larger pages load slowly and strain a notebook.
PAGE_LIMIT = 8 * 2**20


class ViewError(PgdError):
    """A page that cannot be made (too large without force, unreadable data)."""


def numbers_size(cb) -> int:
    """Bytes of the page's numbers as float64 (:func:`pgdcli.codebook.export.size_of` of its layout),
    counted on the arrays: a codebook too large for a page is refused before its numbers become text."""
    count = 0
    for c in cb.coordinates:
        slabs = max(len(c.breakpoints) - 1, 1)
        count += c.nodes + ((slabs + 1) + (c.nodes - 1) // slabs + 1 if c.discretization == "chebyshev" else 0)
    count += sum(fm.size for fm in cb.fields.values())
    return 8 * int(count)


def check_size(cb, limit: int, force: bool) -> int:
    """The numbers' bytes; ViewError beyond ``limit`` unless ``force``."""
    size = numbers_size(cb)
    if size > limit and not force:
        raise ViewError(f"the codebook's numbers take {size / 2**20:.1f} MiB, over the page limit of "
                        f"{limit / 2**20:.0f} MiB (about {2.5 * size / 2**20:.0f} MiB of page text, slow to load "
                        f"in a browser); use --force to write the page anyway, or pgd export --to json for programs")
    return size


def _finite(value):
    """JSON-safe: NaN and infinities as None, numpy scalars as Python numbers, recursively."""
    if isinstance(value, Mapping):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite(value.tolist())
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def _meta(cb) -> dict:
    """The summary the page shows: domains, roles, representation, tolerance, the measured error."""
    info = cb.info()
    report = cb.report
    keep = ("name", "description", "created", "method", "converged", "accurate", "tolerance",
            "relative_tolerance", "steps", "pgdcli_version", "coordinates", "unknowns", "check")
    meta = {k: info[k] for k in keep if k in info}
    meta["message"] = str(report.get("message", ""))
    for c, entry in zip(cb.coordinates, meta["coordinates"]):
        if c.breakpoints:
            entry["breakpoints"] = [float(v) for v in c.breakpoints]
    return _finite(meta)


def data_columns(cb, path: str | os.PathLike) -> dict:
    """A ``pgd fit`` data file read and checked against the codebook: ``{"label", "columns"}``."""
    label = os.path.basename(str(path))
    data = read_data(path, label=str(path))
    split_columns(cb, data, str(path))  # the same checks as pgd fit: columns, domains
    return {"label": label, "columns": {k: v.tolist() for k, v in data.items()}}


def payload(cb, *, data: dict | None = None, limit: int = PAGE_LIMIT, force: bool = False) -> dict:
    """The page's JSON: ``{"format": "pgdcli-view", "version": 1, "layout", "meta", "data"}``.

    ``layout`` is :func:`pgdcli.codebook.export.layout` (the JSON export's schema); ``meta`` the
    summary of :meth:`Codebook.info` the page shows; ``data`` a data file's columns or None.

    Raises
    ------
    ViewError
        Numbers beyond ``limit`` bytes without ``force``.
    """
    check_size(cb, limit, force)
    lay = layout(cb)
    return {"format": "pgdcli-view", "version": 1, "layout": lay, "meta": _meta(cb), "data": _finite(data)}
