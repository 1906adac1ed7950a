"""Figures from the ``*_data`` dicts (matplotlib ``Figure`` objects, no pyplot), and ``plot_*`` = data + draw."""

from __future__ import annotations

from typing import Mapping
import math

import numpy as np

from .modes import convergence_data, modes_data
from .options import DEFAULT_COUNT, DEFAULT_DPI, point_label, require_matplotlib
from .solution import error_data, solution_data

__all__ = ["draw_modes", "draw_convergence", "draw_solution", "draw_error", "plot_modes", "plot_convergence", "plot_solution", "plot_error"]


# Okabe-Ito colors (color-blind safe), each paired with its own line style and marker so
# that curves stay distinguishable in grayscale.
_COLORS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000")
_LINESTYLES = ("-", "--", "-.", ":", (0, (6, 2, 1, 2, 1, 2)), (0, (10, 3)), (0, (1, 3)))
_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
_MAP_CMAP = "viridis"
_ERROR_CMAP = "cividis"


def line_style(i: int) -> dict:
    return {"color": _COLORS[i % len(_COLORS)], "linestyle": _LINESTYLES[i % len(_LINESTYLES)],
            "marker": _MARKERS[i % len(_MARKERS)]}


# ----------------------------------------------------------------------------------------------
# drawing
# ----------------------------------------------------------------------------------------------
def new_figure(fig, figsize):
    if fig is not None:
        return fig
    require_matplotlib()
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, dpi=DEFAULT_DPI, layout="constrained")


def figure_title(fig, data: dict, what: str) -> None:
    fig.suptitle(f"{data['problem']}: {what}", fontsize="large")


def _fixed_note(fixed: Mapping[str, float]) -> str:
    return f" ({point_label(fixed)})" if fixed else ""


def _compact(v: float) -> str:
    """Two significant digits, short exponents: 243 -> '240', 1.4e-05 -> '1.4e-5'."""
    a = abs(v)
    if a == 0 or 1e-3 <= a < 1e4:
        return f"{v:.2g}" if a < 100 else f"{float(f'{v:.2g}'):.0f}"
    mant, exp = f"{v:.1e}".split("e")
    return f"{mant}e{int(exp)}"


def _sci(v: float) -> str:
    """Two significant digits, exponent without padding: 1e-09 -> '1e-9'."""
    return f"{v:.2g}".replace("e-0", "e-").replace("e+0", "e+")


def _sigma_title(rank: int, sigma: np.ndarray, count: int, chars: int) -> str:
    """'unfolding rank R' and the first ``count`` singular values, wrapped at ``chars`` characters a
    line on at most two lines (values that do not fit are left out, as the ones after ``count`` are)."""
    lines, line = [], "\u03c3 = "
    values = [_compact(v) for v in sigma[:max(count, 1)]]
    shown = 0
    for i, v in enumerate(values):
        piece = v + ("," if i < len(values) - 1 else "")
        if len(line) + len(piece) + 2 > chars and shown:  # room for ' …'
            if len(lines) == 1:
                break
            lines.append(line.rstrip())
            line = ""
        line += piece + " "
        shown += 1
    line = line.rstrip()
    if shown < sigma.size:
        line = line.rstrip(",") + ", \u2026"
    lines.append(line)
    return "\n".join([f"unfolding rank {rank}"] + lines)


def draw_modes(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`modes_data`: one panel per coordinate, one curve per mode.

    CP codebooks: the legend gives each mode's weight alpha. Tensor trains: the
    HOSVD modes (unit norm over the nodes), the singular values above each panel.
    """
    panels = data["panels"]
    tt = data.get("representation") == "tensor-train"
    npan = len(panels)
    ncols = npan if npan <= 3 else (2 if npan == 4 else 3)
    nrows = math.ceil(npan / ncols)
    fig = new_figure(fig, figsize or (3.6 * ncols + 1.4, (3.2 if tt else 2.9) * nrows + 0.6))
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    field = data["field"]
    for ax, panel in zip(axes, panels):
        x, vals = panel["x"], panel["values"]
        step = max(1, x.size // 8)
        for i in range(vals.shape[1]):
            st = line_style(i)
            label = f"mode {i + 1}" if tt else f"mode {i + 1} (\u03b1={data['alphas'][i]:.3g})"
            ax.plot(x, vals[:, i], color=st["color"], linestyle=st["linestyle"], marker=st["marker"],
                    markersize=4.5, markerfacecolor="white", markevery=(i * step // max(vals.shape[1], 1), step),
                    linewidth=1.6, label=label)
        ax.axhline(0.0, color="0.6", linewidth=0.6, zorder=0)
        # the basis nodes as a rug along the bottom: where the stored values live
        ax.plot(panel["nodes"], np.zeros(panel["nodes"].size), linestyle="none", marker=2, markersize=6,
                color="0.35", transform=ax.get_xaxis_transform(), clip_on=False, label="_nodes")
        role = "time, " if panel["role"] == "time" else ""
        ax.set_xlabel(f"{panel['coordinate']}  ({role}{panel['nodes'].size} nodes: ticks on the axis)")
        ax.set_ylabel(f"modes of {field} in {panel['coordinate']}")
        ax.set_xlim(*panel["domain"])
        ax.grid(True, linewidth=0.4, alpha=0.5)
        if tt:
            # about 15 characters of the small font per inch of panel
            chars = max(12, int(15 * (fig.get_size_inches()[0] - 1.4) / ncols))
            ax.set_title(_sigma_title(panel["rank"], panel["singular_values"], panel["count"], chars),
                         fontsize="small", loc="left")
    for ax in axes[npan:]:
        ax.set_visible(False)
    if tt:
        widest = max(range(npan), key=lambda k: panels[k]["values"].shape[1])
        handles, labels = axes[widest].get_legend_handles_labels()
        ranks = "-".join(str(r) for r in data["ranks"]) or "none"
        fig.legend(handles, labels, loc="outside right upper", fontsize="small", title_fontsize="small",
                   title=f"{field}: tensor train\nranks {ranks}\n\nHOSVD modes,\nnormalized to\n"
                         f"unit 2-norm\nat the nodes")
        figure_title(fig, data, f"first {data['count']} HOSVD modes of {field}" if data["count"]
               else f"{field} is zero at every node: no HOSVD modes")
        return fig
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right upper", fontsize="small", title=f"{field}: {data['rank']} modes")
    figure_title(fig, data, f"first {data['count']} modes of {field}")
    return fig


def draw_convergence(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`convergence_data`: residual (log) per mode, and the outer iteration if recorded;
    for a time march, the step sizes against time and the ranks at the time nodes."""
    if data.get("method") == "march":
        return _draw_march_convergence(data, fig=fig, figsize=figsize)
    outer = data["outer"]
    fig = new_figure(fig, figsize or ((10.0, 4.2) if outer is not None else (6.4, 4.2)))
    axes = fig.subplots(1, 2 if outer is not None else 1, squeeze=False).ravel()
    ax = axes[0]
    res = np.where(data["residual"] > 0, data["residual"], np.nan)
    ax.semilogy(data["modes"], res, color=_COLORS[0], linestyle="-", marker="o", markersize=4,
                markerfacecolor="white", linewidth=1.6, label="relative residual")
    tol = data["tolerance"]
    if math.isfinite(tol) and tol > 0:
        ax.axhline(tol, color="0.25", linestyle="--", linewidth=1.0, label=f"tolerance {tol:.1e}")
    ax.set_xlabel("number of modes")
    ax.set_ylabel("relative residual")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.grid(True, which="both", linewidth=0.4, alpha=0.5)
    ax.legend(fontsize="small")
    state = "converged" if data["converged"] else "not converged"
    ax.set_title(f"{data['modes'][-1]} enrichment modes, {state}", fontsize="medium")
    if outer is not None:
        ax2 = axes[1]
        change = np.where(outer["change"] > 0, outer["change"], np.nan)
        ax2.semilogy(outer["iteration"], change, color=_COLORS[1], linestyle="--", marker="s", markersize=4,
                     markerfacecolor="white", linewidth=1.6)
        ax2.set_xlabel("outer iteration")
        ax2.set_ylabel("change per iteration")
        ax2.xaxis.get_major_locator().set_params(integer=True)
        ax2.grid(True, which="both", linewidth=0.4, alpha=0.5)
        ax2.set_title("outer (nonlinear) iteration", fontsize="medium")
    figure_title(fig, data, "convergence")
    return fig


def _draw_march_convergence(data: dict, *, fig=None, figsize=None):
    """(a) accepted step sizes against time, (b) tensor-train rank per time node and unknown."""
    fig = new_figure(fig, figsize or (8.4, 6.4))
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    tname, nodes = data["time"], data["node_times"]
    sizes, start, end = data["step_sizes"], data["step_start"], data["step_end"]
    # each step size held over the interval it covers, a marker where the step ends
    ax1.stairs(sizes, np.concatenate([start[:1], end]), color=_COLORS[0], linewidth=1.6, baseline=None,
               label="_intervals")
    ax1.plot(end, sizes, linestyle="none", marker="o", markersize=4.5, markerfacecolor="white",
             color=_COLORS[0], label="accepted step (marker at its end)", clip_on=False, zorder=4)
    positive = sizes[sizes > 0]
    if positive.size and positive.max() > 10 * positive.min():
        ax1.set_yscale("log")
    else:
        ax1.set_ylim(0.0, 1.15 * float(sizes.max()) if sizes.size else 1.0)
    ax1.plot(nodes, np.zeros(nodes.size), linestyle="none", marker=2, markersize=6, color="0.35",
             transform=ax1.get_xaxis_transform(), clip_on=False, label="_nodes")
    ax1.set_ylabel("step size")
    ax1.grid(True, which="both", linewidth=0.4, alpha=0.5)
    ax1.legend(fontsize="small", loc="best")
    rejected = f", {data['rejected']} rejected" if data["rejected"] else ", none rejected"
    ax1.set_title(f"(a) {sizes.size} accepted steps{rejected} (ticks on the axis: time nodes)",
                  fontsize="medium", loc="left")
    ranks = data["ranks"]
    seen: dict[tuple, str] = {}
    for i, u in enumerate(data["unknowns"]):
        st = line_style(i)
        key = tuple(ranks[:, i].tolist())
        label = u if key not in seen else f"{u} (same as {seen[key]})"
        seen.setdefault(key, u)
        # later lines drawn thinner with larger open markers: coinciding curves stay visible
        ax2.plot(nodes, ranks[:, i], color=st["color"], linestyle=st["linestyle"], marker=st["marker"],
                 markersize=4.5 + 2.0 * i, markerfacecolor="none", linewidth=max(0.8, 1.8 - 0.4 * i),
                 label=label, zorder=3 + len(data["unknowns"]) - i, clip_on=False)
    ax2.set_xlabel(f"{tname}  (time, {nodes.size} nodes)")
    ax2.set_ylabel("tensor-train rank\n(largest bond)")
    ax2.set_ylim(0, max(1, int(ranks.max()) if ranks.size else 1) * 1.15 + 0.5)
    ax2.yaxis.get_major_locator().set_params(integer=True)
    ax2.set_xlim(nodes[0], nodes[-1])
    ax2.grid(True, linewidth=0.4, alpha=0.5)
    ax2.legend(fontsize="small", loc="lower right", title="unknown", title_fontsize="small")
    ax2.set_title("(b) rank of the state over the non-time coordinates, at the time nodes", fontsize="medium",
                  loc="left")
    state = "" if data["converged"] else ", not converged"
    measured = "" if np.isnan(data["check_error"]) else f"max error {_sci(data['check_error'])} vs scipy, "
    figure_title(fig, data, f"time march, {measured}RMS estimate {_sci(data['error_estimate'])} "
                      f"(tolerance {_sci(data['tolerance'])}){state}")
    return fig


def _draw_lines(ax, data: dict) -> None:
    """The codebook's curves: lines only (color and line style), markers being the reference's."""
    t, vals = data["t"], data["values"]
    for i, label in enumerate(data["labels"]):
        st = line_style(i)
        ax.plot(t, vals[i], color=st["color"], linestyle=st["linestyle"], linewidth=1.6, label=label)


def _mark_inside(ax, x: float, y: float, label: str, log_y: bool = False) -> None:
    """A marker at (x, y), the view widened so that the whole marker lies inside the frame."""
    ax.plot([x], [y], linestyle="none", marker="X", markersize=10, markerfacecolor="white", markeredgecolor="black",
            label=label, zorder=5)
    margin = 0.03  # of the axis span: more than half the marker on a figure of the default size
    x0, x1 = ax.get_xlim()
    pad = margin * (x1 - x0)
    ax.set_xlim(min(x0, x - pad), max(x1, x + pad))
    y0, y1 = ax.get_ylim()
    if log_y and y0 > 0 and y > 0:
        f = ((y1 / y0) ** margin)
        ax.set_ylim(min(y0, y / f), max(y1, y * f))
    else:
        pad = margin * (y1 - y0)
        ax.set_ylim(min(y0, y - pad), max(y1, y + pad))


def _map_mesh(ax, fig, data: dict, z, *, cmap: str, norm=None, label: str):
    mesh = ax.pcolormesh(data["xv"], data["yv"], z, cmap=cmap, norm=norm, shading="nearest", rasterized=True)
    fig.colorbar(mesh, ax=ax, label=label, extend="min" if norm is not None else "neither")
    ax.set_xlabel(data["x"])
    ax.set_ylabel(data["y"])
    return mesh


def draw_solution(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`solution_data`: curves along time, or a heat map (reference as markers / contours)."""
    from matplotlib.lines import Line2D

    field = data["field"]
    ref = data.get("reference")
    if data["layout"] == "lines":
        fig = new_figure(fig, figsize or (8.4, 4.6))
        ax = fig.subplots()
        _draw_lines(ax, data)
        if ref is not None:
            for i in range(len(data["labels"])):
                st = line_style(i)
                ax.plot(ref["t"], ref["values"][i], linestyle="none", marker=st["marker"], markersize=6,
                        markerfacecolor="none", markeredgecolor=st["color"], markeredgewidth=1.1)
            handles, labels = ax.get_legend_handles_labels()
            handles.append(Line2D([], [], linestyle="none", marker="s", markerfacecolor="none",
                                  markeredgecolor="0.2", markersize=6))
            labels.append("reference (open markers)")
            handles.insert(0, Line2D([], [], color="0.2", linewidth=1.6))
            labels.insert(0, "PGD codebook")
            fig.legend(handles, labels, fontsize="small", loc="outside right upper")
            ax.set_title(f"markers: reference ({ref['description']})", fontsize="small", pad=8)
        else:
            fig.legend(*ax.get_legend_handles_labels(), fontsize="small", loc="outside right upper")
        ax.set_xlabel(data["time"])
        ax.set_ylabel(field)
        ax.set_xlim(data["t"][0], data["t"][-1])
        ax.grid(True, linewidth=0.4, alpha=0.5)
        figure_title(fig, data, f"{field} against {data['time']}")
        return fig
    fig = new_figure(fig, figsize or (7.0, 5.2))
    ax = fig.subplots()
    _map_mesh(ax, fig, data, data["values"], cmap=_MAP_CMAP, label=field)
    if ref is not None:
        z = data["values"]
        levels = np.linspace(np.nanmin(z), np.nanmax(z), 9)[1:-1]
        if levels.size and np.ptp(levels) > 0:
            ax.contour(data["xv"], data["yv"], z, levels=levels, colors="black", linewidths=1.4)
            ax.contour(data["xv"], data["yv"], ref["values"], levels=levels, colors="white", linewidths=1.0,
                       linestyles="--")
        ax.legend([Line2D([], [], color="black", linewidth=1.4), Line2D([], [], color="white", linestyle="--")],
                  ["PGD codebook (contours)", f"reference ({ref['description']})"], fontsize="small",
                  loc="upper right", facecolor="0.75", framealpha=0.9)
    figure_title(fig, data, f"{field} over {data['x']}, {data['y']}{_fixed_note(data['fixed'])}")
    return fig


def draw_error(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`error_data`: |error| along time (log axis) or as a log-scaled heat map."""
    from matplotlib.colors import LogNorm

    field = data["field"]
    what = f"|{field} \u2212 {field}_ref|"
    if data["layout"] == "lines":
        fig = new_figure(fig, figsize or (8.4, 4.6))
        ax = fig.subplots()
        shown = dict(data)
        shown["values"] = np.where(data["values"] > 0, data["values"], np.nan)  # log axis: exact zeros omitted
        shown["labels"] = [f"{lab} (max {np.nanmax(v) if np.isfinite(v).any() else float('nan'):.2g})"
                           for lab, v in zip(data["labels"], data["values"])]
        _draw_lines(ax, shown)
        ax.set_yscale("log")
        ax.set_xlabel(data["time"])
        ax.set_ylabel(f"absolute error {what}")
        ax.set_xlim(data["t"][0], data["t"][-1])
        if data.get("argmax") and np.isfinite(data["max"]) and data["max"] > 0:
            _mark_inside(ax, data["argmax"][data["time"]], data["max"], f"max {data['max']:.2g}", log_y=True)
        ax.grid(True, which="both", linewidth=0.4, alpha=0.5)
        fig.legend(*ax.get_legend_handles_labels(), fontsize="small", loc="outside right upper")
        ax.set_title(f"reference: {data['description']}", fontsize="small", pad=8)
        figure_title(fig, data, f"error of {field} against {data['time']}")
        return fig
    fig = new_figure(fig, figsize or (7.0, 5.2))
    ax = fig.subplots()
    z = data["values"]
    positive = z[np.isfinite(z) & (z > 0)]
    if positive.size:
        vmax = float(positive.max())
        vmin = max(float(positive.min()), vmax * 1e-5)  # five decades: rounding-level zeros clip
        if vmin >= vmax:
            vmin = vmax / 10.0
        shown = np.clip(np.where(np.isfinite(z), z, np.nan), vmin, vmax)
        _map_mesh(ax, fig, data, shown, cmap=_ERROR_CMAP, norm=LogNorm(vmin=vmin, vmax=vmax),
                  label=f"absolute error {what}")
    else:  # identical everywhere (or the reference failed everywhere)
        _map_mesh(ax, fig, data, np.where(np.isfinite(z), z, np.nan), cmap=_ERROR_CMAP,
                  label=f"absolute error {what}")
    if data.get("argmax"):
        am = data["argmax"]
        _mark_inside(ax, am[data["x"]], am[data["y"]], f"max {data['max']:.2g}")
        ax.legend(fontsize="small", loc="upper right", framealpha=0.9)
    ax.set_title(f"reference: {data['description']}", fontsize="small", pad=10)
    figure_title(fig, data, f"error of {field} over {data['x']}, {data['y']}{_fixed_note(data['fixed'])}")
    return fig


def plot_modes(codebook, count: int = DEFAULT_COUNT, field: str | None = None, *, points=None, fig=None,
               figsize=None):
    """:func:`modes_data` drawn by :func:`draw_modes`; returns the Figure."""
    return draw_modes(modes_data(codebook, count, field, points=points), fig=fig, figsize=figsize)


def plot_convergence(codebook, *, fig=None, figsize=None):
    """:func:`convergence_data` drawn by :func:`draw_convergence`; returns the Figure."""
    return draw_convergence(convergence_data(codebook), fig=fig, figsize=figsize)


def plot_solution(codebook, field: str | None = None, *, fig=None, figsize=None, **options):
    """:func:`solution_data` drawn by :func:`draw_solution`; returns the Figure."""
    return draw_solution(solution_data(codebook, field, **options), fig=fig, figsize=figsize)


def plot_error(codebook, field: str | None = None, *, fig=None, figsize=None, **options):
    """:func:`error_data` drawn by :func:`draw_error`; returns the Figure."""
    return draw_error(error_data(codebook, field, **options), fig=fig, figsize=figsize)
