"""A codebook's summary as plain Python data (what ``pgd info`` prints), read from its report.

numpy only (``pgd info`` reads codebooks on machines without the solver).
"""

from __future__ import annotations

import os

import numpy as np

from .fields import TT
from .io import FORMAT_NAME, FORMAT_VERSION

__all__ = ["accurate", "coordinate_ratios", "integrity", "nodes_chosen", "summary"]


def integrity(version: str | None) -> str:
    """What protects a codebook's numbers: checksums and digests from format 1.1 on."""
    if version is None:
        return "not written to a file yet"
    major, _, minor = version.partition(".")
    if (int(major), int(minor or 0)) >= (1, 1):
        return "checked (Fletcher-32 and SHA-256 of every array, SHA-256 of the metadata)"
    return "unchecked (format 1.0 files carry no checksums)"


def accurate(report) -> bool | None:
    """True: the measured error met the tolerance; False: written anyway (``--keep-inaccurate``);
    None: not measured (an older codebook, or a reference that could not run)."""
    value = report.get("accurate")
    if value is None or int(value) < 0:
        return None
    return bool(int(value))


def nodes_chosen(report, coordinate_names) -> dict | None:
    """The automatic resolution's solves (see :meth:`Codebook.nodes_chosen`); None without them."""
    if "resolution_rounds" not in report:
        return None
    rounds = np.asarray(report["resolution_rounds"], dtype=float)
    auto = [n for n in str(report.get("resolution_auto", "")).split(",") if n]
    return {"automatic": auto, "reason": str(report.get("resolution_reason", "")),
            "rounds": [{"nodes": {c: int(n) for c, n in zip(coordinate_names, row[:-1])},
                        "ratio": float(row[-1]) if np.isfinite(row[-1]) else None} for row in rounds]}


def field_summary(fm) -> dict:
    """Representation, modes (or ranks) and stored floats of one field."""
    if isinstance(fm, TT):
        return {"representation": "tensor-train", "modes": fm.rank, "ranks": list(fm.ranks), "floats": fm.size}
    return {"representation": "cp", "modes": fm.rank, "floats": int(fm.weights.size + sum(m.size for m in fm.factors))}


def summary(cb, path: str | os.PathLike | None = None) -> dict:
    """:meth:`Codebook.info`: the codebook's description, coordinates, fields and solver report."""
    rep = cb.report
    out = {
        "name": cb.name,
        "description": cb.description,
        "format": f"{FORMAT_NAME} {cb.format_version or FORMAT_VERSION}",
        "integrity": integrity(cb.format_version),
        "created": cb.created,
        "coordinates": [
            {"name": c.name, "role": c.role, "domain": [c.domain[0], c.domain[1]], "nodes": c.nodes,
             "discretization": c.discretization,
             **({"elements": len(c.breakpoints) - 1} if c.breakpoints and c.role != "time" else {})}
            for c in cb.coordinates
        ],
        "unknowns": {u: field_summary(fm) for u, fm in cb.fields.items()},
        "method": str(rep.get("method", "pgd")),
        **({"method_reason": str(rep["method_reason"])} if "method_reason" in rep else {}),
        "converged": bool(rep.get("converged", False)),
        "accurate": accurate(rep),
        "relative_tolerance": float(rep.get("relative_tolerance", 0.0)),
        "residual": float(rep.get("residual", np.nan)),
        **({"steps": int(rep["steps"]), "rejected_steps": int(rep.get("rejected_steps", 0))} if "steps" in rep else {}),
        "tolerance": float(rep.get("tolerance", np.nan)),
        "solve_time": float(rep.get("wall_time", np.nan)),
        "gate_time": float(rep["gate_time"]) if "gate_time" in rep else None,
        "pgdcli_version": str(rep.get("pgdcli_version", "")),
    }
    if "march" in rep:  # which march: 'grid' (the whole array, compressed once), 'cross' or 'train'
        out["march"] = str(rep["march"])
    if "cross_trajectories" in rep:  # the cross march (pgdcli.algorithms.cross_march)
        out["cross_march"] = {"trajectories": int(rep["cross_trajectories"]), "sweeps": int(rep["cross_sweeps"]),
                              "error": float(rep["cross_error"]), "pilot_points": int(rep["pilot_points"])}
    if "cross_abandoned" in rep:  # auto tried the cross march first, the grid march built the codebook
        out["cross_abandoned"] = str(rep["cross_abandoned"])
    if "roundings_exact" in rep:
        out["roundings"] = {k: int(rep[f"roundings_{k}"]) for k in ("exact", "sketched", "redone")}
    if "crosses" in rep:  # functions of the unknowns, by cross approximation (pgdcli.algorithms.general_rhs)
        out["crosses"] = {"count": int(rep["crosses"]), "not_converged": int(rep["crosses_not_converged"]),
                          "evaluations": int(rep["cross_evaluations"]), "max_rank": int(rep["cross_max_rank"]),
                          "failure": str(rep["cross_failure"])}
    if "check_error" in rep:
        out["check"] = _check_summary(rep)
    if "resolution_rounds" in rep:
        out["nodes_chosen"] = nodes_chosen(rep, [c.name for c in cb.coordinates])
    if "rates" in rep:  # {rate unknown: the unknown it is the time derivative of}
        out["rates"] = dict(pair.split("=", 1) for pair in str(rep["rates"]).split(",") if "=" in pair)
    if "separated_coefficients" in rep:  # how many terms each non-separable coefficient needed
        out["separated_coefficients"] = [line for line in str(rep["separated_coefficients"]).split("; ") if line]
    if "resolution" in rep and "resolution_coordinates" in rep:
        names = str(rep["resolution_coordinates"]).split(",")
        table = np.asarray(rep["resolution"], dtype=float)
        out["resolution"] = {u: {c: (float(v) if np.isfinite(v) else None) for c, v in zip(names, row)}
                             for u, row in zip(cb.fields, table)}
    if cb.events:
        out["events"] = event_summary(cb)
    if getattr(cb, "phases", None) is not None:  # an event that acts (pgdcli.codebook.phases)
        out["phases"] = phase_summary(cb)
    if path is not None:
        out["size_bytes"] = os.path.getsize(path)
    return out


def phase_summary(cb) -> dict:
    """The acting event of a codebook with phases: its name, action, phases and their measured error."""
    rep = cb.report
    error, ratio = rep.get("phase_error"), rep.get("phase_ratio")
    return {"event": cb.acting, "action": cb.action, "count": len(cb.phases) + 1,
            "error": float(error) if error is not None else None, "ratio": float(ratio) if ratio is not None else None}


def phase_text(phases: dict) -> str:
    """What a :func:`phase_summary` says, in one clause: ``"resets the motion: 5 phases, within ..."``."""
    what = "ends the motion" if phases["action"] == "terminal" else f"resets the motion: {phases['count']} phases"
    error = "" if phases["error"] is None else f", within {phases['error']:.2e} of solve_ivp restarted at each event"
    return what + error


def event_summary(cb) -> dict:
    """Event name -> its condition, direction, and the error of its time measured at the solve (if any)."""
    rep = cb.report
    checked = str(rep.get("events", "")).split(",")
    errors = np.asarray(rep.get("event_errors", []), dtype=float).reshape(-1)
    ratios = np.asarray(rep.get("event_ratios", []), dtype=float).reshape(-1)
    out = {}
    for name, event in cb.events.items():
        entry = {"when": event.when, "direction": event.direction, "error": None, "ratio": None}
        if name in checked and checked.index(name) < min(errors.size, ratios.size):
            k = checked.index(name)
            entry["error"] = float(errors[k]) if np.isfinite(errors[k]) else None
            entry["ratio"] = float(ratios[k]) if np.isfinite(ratios[k]) else None
        out[name] = entry
    return out


def _check_summary(rep) -> dict:
    """The solve-time check's entries (JSON has no NaN: an unchecked march gives None)."""
    def finite(key):
        v = float(rep[key])
        return v if np.isfinite(v) else None

    out = {"error": finite("check_error"), "node_error": finite("check_node_error"),
           "between_error": finite("check_between_error"), "points": int(rep["check_points"]),
           "failed": int(rep["check_failed"]), "where": str(rep["check_where"])}
    for key, name in (("check_ratio", "ratio"), ("march_tolerance", "march_tolerance")):
        if key in rep:
            out[name] = finite(key)
    if "check_method" in rep:
        out["method"] = str(rep["check_method"])
    ratios = coordinate_ratios(rep)
    if ratios is not None:
        out["coordinate_ratio"] = ratios
    return out


def coordinate_ratios(rep) -> dict | None:
    """Per coordinate, the solve-time check's error off its nodes over the tolerance (the parts a
    refusal names; None for NaN), or None when the report has none."""
    if "check_coordinates" not in rep or not str(rep["check_coordinates"]):
        return None
    ratios = np.atleast_1d(np.asarray(rep["check_coordinate_ratio"], dtype=float))
    return {n: (float(v) if np.isfinite(v) else None) for n, v in zip(str(rep["check_coordinates"]).split(","), ratios)}
