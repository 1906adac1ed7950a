"""``pgd plot --kind phase``: one unknown against another along time (a projectile's path, a phase portrait)."""

from __future__ import annotations

import numpy as np

from ..errors import QueryError
from .draw import figure_title, line_style, new_figure
from .options import LINE_POINTS, REFERENCE_MARKERS, count_points, is_steady, point_label
from .solution import line_points, reference_solver, reference_values

__all__ = ["phase_data", "draw_phase", "plot_phase"]


def _axis_quantity(codebook, name: str, option: str) -> tuple[str, bool]:
    """``u`` or ``der(u)`` (u's derivative along the curves' axis) -> (unknown, derivative?)."""
    text = name.replace(" ", "")
    derivative = text.startswith("der(") and text.endswith(")")
    unknown = text[4:-1] if derivative else text
    if unknown not in codebook.fields:
        raise QueryError(f"{option}: unknown {unknown!r}; this codebook has {', '.join(codebook.unknown_names)} "
                         f"(or der(NAME), the rate of one)")
    return unknown, derivative


def _defaults(codebook, x: str | None, y: str | None, axis: str) -> tuple[str, str]:
    """The first unknown against the second, or against its own rate when it is alone."""
    names = codebook.unknown_names
    x = names[0] if x is None else x
    if y is None:
        first = _axis_quantity(codebook, x, "--x")[0]
        y = next((u for u in names if u != first), f"der({first})")
    return x, y


def _values(codebook, quantity: tuple[str, bool], point: dict, axis: str, t: np.ndarray) -> np.ndarray:
    unknown, derivative = quantity
    where = {**point, axis: t}
    if derivative:
        return codebook.gradient(where, wrt=[axis], fields=[unknown])[unknown][axis]
    return codebook.evaluate(where, fields=[unknown])[unknown]


def phase_data(codebook, x: str | None = None, y: str | None = None, *, at=None, points: int | None = None,
               reference=False) -> dict:
    """Quantity ``y`` against quantity ``x`` along time, one curve per parameter point.

    Parameters
    ----------
    x, y : str, optional
        Unknowns (or ``der(u)``: the rate of ``u`` along time, the exact derivative of the codebook's
        interpolant) on the horizontal and vertical axes. Default: the first unknown against the
        second, or against its own rate when it is the only one.
    at : sequence of str or mapping, optional
        Points as for :func:`pgdcli.plot.solution.solution_data` (default: 5 values of the first parameter).
    points : int, optional
        Samples along each curve (201).
    reference : bool or callable
        Add the independent reference at 21 times (markers); not for rates.

    Returns
    -------
    dict
        ``kind`` 'phase', ``problem``, ``x``, ``y`` (names), ``time``, ``t`` (T,), ``points``, ``labels``,
        ``xs``, ``ys`` (P, T): the codebook's values; ``reference`` None or ``{"t", "xs", "ys" (P, Tr),
        "description"}``; ``failures``.
    """
    tc, pts = line_points(codebook, at, "a phase portrait along time")
    xn, yn = _defaults(codebook, x, y, tc.name)
    qx, qy = _axis_quantity(codebook, xn, "--x"), _axis_quantity(codebook, yn, "--y")
    if qx == qy:
        raise QueryError(f"--x and --y: give two different quantities, got {xn!r} twice")
    t = np.linspace(tc.domain[0], tc.domain[1], count_points(points, LINE_POINTS))
    label = {q: (f"d{q[0]}/d{tc.name}" if q[1] else q[0]) for q in (qx, qy)}
    out = {"kind": "phase", "problem": codebook.name, "x": label[qx], "y": label[qy], "time": tc.name, "t": t,
           "points": pts, "labels": [point_label(p) for p in pts],
           "xs": np.array([_values(codebook, qx, p, tc.name, t) for p in pts]),
           "ys": np.array([_values(codebook, qy, p, tc.name, t) for p in pts]), "reference": None, "failures": []}
    ref = reference_solver(codebook) if reference is True else (reference if callable(reference) else None)
    if ref is not None:
        if qx[1] or qy[1]:
            raise QueryError("--reference: the reference gives the unknowns, not their rates; drop der(...) or "
                             "--reference")
        tr = np.linspace(tc.domain[0], tc.domain[1], REFERENCE_MARKERS)
        params = {k: np.array([p[k] for p in pts]) for k in pts[0]} if pts and pts[0] else {}
        axis = tc.name if is_steady(codebook) else None
        rx, fx = reference_values(ref, qx[0], params, tr, axis)
        ry, _ = reference_values(ref, qy[0], params, tr, axis)
        out["reference"] = {"t": tr, "xs": rx, "ys": ry, "description": getattr(ref, "description", "reference")}
        out["failures"] = fx
    return out


def draw_phase(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`phase_data`: codebook curves as lines (a dot at the start), the reference as open markers."""
    from matplotlib.lines import Line2D


    fig = new_figure(fig, figsize or (7.0, 5.2))
    ax = fig.subplots()
    ref = data["reference"]
    for i, label in enumerate(data["labels"]):
        st = line_style(i)
        ax.plot(data["xs"][i], data["ys"][i], color=st["color"], linestyle=st["linestyle"], linewidth=1.6, label=label)
        ax.plot(data["xs"][i][:1], data["ys"][i][:1], linestyle="none", marker="o", markersize=4, color=st["color"],
                label="_start")
        if ref is not None:
            ax.plot(ref["xs"][i], ref["ys"][i], linestyle="none", marker=st["marker"], markersize=6,
                    markerfacecolor="none", markeredgecolor=st["color"], markeredgewidth=1.1, label="_reference")
    handles, labels = ax.get_legend_handles_labels()
    if ref is not None:
        handles.append(Line2D([], [], linestyle="none", marker="s", markerfacecolor="none", markeredgecolor="0.2"))
        labels.append(f"reference ({ref['description']})")
    handles.append(Line2D([], [], linestyle="none", marker="o", markersize=4, color="0.2"))
    labels.append(f"{data['time']} = start")
    fig.legend(handles, labels, fontsize="small", loc="outside right upper")
    ax.set_xlabel(data["x"])
    ax.set_ylabel(data["y"])
    ax.grid(True, linewidth=0.4, alpha=0.5)
    figure_title(fig, data, f"{data['y']} against {data['x']} along {data['time']}")
    return fig


def plot_phase(codebook, x: str | None = None, y: str | None = None, *, fig=None, figsize=None, **options):
    """:func:`phase_data` drawn by :func:`draw_phase`; returns the Figure."""
    return draw_phase(phase_data(codebook, x, y, **options), fig=fig, figsize=figsize)
