"""Self-contained evaluators of a codebook for other programs (``pgd export``).

Three targets share one description of the numbers (:func:`layout`):

``json``
    The numbers for any language (schema ``pgdcli-export``, version 1, below).
``c``
    One C99 header with the numbers as ``static const`` arrays and
    ``int pgd_<name>_eval(const double *coords, double *out)`` plus a float32
    variant ``pgd_<name>_eval_f`` (libc only): see :mod:`pgdcli.codebook.export_c`.
``glsl``
    A shader function over constant arrays: see :mod:`pgdcli.codebook.export_c`.

JSON schema (all arrays flat, row-major)::

    {"format": "pgdcli-export", "version": 1, "name": str,
     "coordinates": [{"name", "domain": [lo, hi], "kind": "chebyshev" | "linear",
                      "nodes": [n values], "breakpoints": [S + 1 values],   # chebyshev: slabs (1 slab: [lo, hi])
                      "slab_size": m, "bary": [m values]}, ...],           # chebyshev only
     "unknowns": [{"name", "representation": "cp", "rank": R, "alphas": [R],
                   "modes": [[n_j * R values] per coordinate]}               # modes[j][i * R + r]
                  | {"name", "representation": "tt", "mode_order": [d ints],
                     "shapes": [[r0, n, r1] per core], "cores": [[r0 * n * r1 values] per core]}]}

Evaluation: per coordinate the cardinal weights of ``x`` (Chebyshev: the slab ``s`` with
``breakpoints[s] <= x < breakpoints[s + 1]`` (the last slab takes the upper end), barycentric
weights ``c_k = bary[k] / (x - nodes[s (m - 1) + k])`` normalized by their sum, a unit weight
at a node; linear: the element ``[nodes[i], nodes[i + 1]]`` with ``nodes[i] <= x`` (the last
element at the upper end), weights ``1 - theta, theta``), then the CP sum
``sum_r alphas[r] prod_j (w_j . modes_j[:, r])`` or the tensor-train product of the cores
contracted with the weights in ``mode_order``.
"""

from __future__ import annotations

import json
import re

import numpy as np

from ..errors import PgdError
from ..names import identifier_problem, printable, problem_name_problem
from .export_c import FLOAT32_MAX, c_header, glsl_source
from .fields import TT
from .phases import refuse_phases

__all__ = ["ExportError", "TARGETS", "DEFAULT_LIMIT", "layout", "export", "size_of"]

TARGETS = ("c", "glsl", "json")
DEFAULT_LIMIT = 16 * 2**20  # bytes of float64 numbers; larger exports need force=True (--force)


class ExportError(PgdError):
    """An export that cannot be made (unknown target, too large without force)."""


def c_name(name: str) -> str:
    """The codebook's name as a C/GLSL identifier fragment: ``[A-Za-z0-9_]``, not starting with a digit."""
    ident = re.sub(r"[^A-Za-z0-9_]", "_", name) or "codebook"
    return ident if not ident[0].isdigit() else "cb_" + ident


def layout(cb) -> dict:
    """The numbers of a codebook as plain Python data (the JSON schema of this module)."""
    coords = []
    for c in cb.coordinates:
        basis = c.basis()
        entry = {"name": c.name, "domain": [float(c.domain[0]), float(c.domain[1])], "kind": c.discretization,
                 "nodes": [float(v) for v in basis.nodes]}
        if c.discretization == "chebyshev":
            bp = list(getattr(basis, "breakpoints", ())) or [float(c.domain[0]), float(c.domain[1])]
            entry["breakpoints"] = [float(v) for v in bp]
            entry["slab_size"] = int(getattr(basis, "slab_size", 0) or basis.nodes.size)
            entry["bary"] = [float(v) for v in basis.bary]
        coords.append(entry)
    unknowns = []
    for u, fm in cb.fields.items():
        if isinstance(fm, TT):
            unknowns.append({"name": u, "representation": "tt", "mode_order": [int(j) for j in fm.mode_order],
                             "shapes": [list(map(int, core.shape)) for core in fm.cores],
                             "cores": [core.reshape(-1).tolist() for core in fm.cores]})
        else:
            unknowns.append({"name": u, "representation": "cp", "rank": int(fm.rank), "alphas": fm.weights.tolist(),
                             "modes": [m.reshape(-1).tolist() for m in fm.factors]})
    return {"format": "pgdcli-export", "version": 1, "name": cb.name, "coordinates": coords, "unknowns": unknowns}


def size_of(lay: dict) -> int:
    """Bytes of the exported numbers as float64."""
    count = 0
    for c in lay["coordinates"]:
        count += len(c["nodes"]) + len(c.get("breakpoints", ())) + len(c.get("bary", ()))
    for u in lay["unknowns"]:
        count += sum(len(m) for m in u.get("modes", ())) + len(u.get("alphas", ()))
        count += sum(len(core) for core in u.get("cores", ()))
    return 8 * count


def _check_names(cb) -> None:
    """Names reach generated code only as checked identifiers (whatever built the codebook)."""
    why = problem_name_problem(cb.name)
    if why:
        raise ExportError(f"problem name {printable(cb.name, 60)!r}: {why}")
    for what, names in (("coordinate", cb.coordinate_names), ("unknown", cb.unknown_names)):
        for name in names:
            why = identifier_problem(name)
            if why:
                raise ExportError(f"{what} name {printable(name, 60)!r}: {why}")


def _check_float32(cb, target: str) -> None:
    """Numbers a float32 cannot spell (C's float variant, GLSL) refuse the export, naming the unknown."""
    for u, fm in cb.fields.items():
        arrays = fm.cores if isinstance(fm, TT) else (fm.weights, *fm.factors)
        largest = max((float(np.abs(a).max()) for a in arrays if a.size), default=0.0)
        if not largest <= FLOAT32_MAX:
            raise ExportError(f"unknown {u!r} holds numbers up to {largest:.3g}, beyond float32's range "
                              f"({FLOAT32_MAX:.3g}) that the {target} export needs; export --to json instead")


def export(cb, target: str, *, force: bool = False, limit: int = DEFAULT_LIMIT) -> tuple[dict, int]:
    """Export ``cb`` to ``target``.

    Returns
    -------
    files : dict of str to str
        File name -> text (``pgd_<name>.h``, ``pgd_<name>.glsl`` or ``<name>.json``).
    size : int
        Bytes of the numbers as float64 (the C header holds them once more as float32).

    Raises
    ------
    ExportError
        Unknown target; numbers beyond ``limit`` bytes without ``force``.
    QueryError
        A codebook with phases (an event that acts): its fields are one phase's.
    """
    refuse_phases(cb, f"export to {target}")
    if target not in TARGETS:
        raise ExportError(f"unknown export target {target!r}; expected one of {', '.join(TARGETS)}")
    _check_names(cb)
    lay = layout(cb)
    size = size_of(lay)
    if size > limit and not force:
        raise ExportError(f"the codebook's numbers take {size / 2**20:.1f} MiB, over the export limit of "
                          f"{limit / 2**20:.0f} MiB; use --force to export anyway")
    ident = c_name(cb.name)
    if target != "json":
        _check_float32(cb, target)
    if target == "json":
        return {f"{cb.name}.json": json.dumps(lay, separators=(",", ":")) + "\n"}, size
    if target == "c":
        return {f"pgd_{ident}.h": c_header(lay, ident)}, size
    return {f"pgd_{ident}.glsl": glsl_source(lay, ident)}, size

