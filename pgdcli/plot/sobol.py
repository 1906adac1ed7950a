"""``pgd plot --kind sensitivity``: the mean and spread of an unknown and its Sobol indices over time."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from .draw import figure_title, line_style, new_figure
from .options import LINE_POINTS, count_points, field_name

__all__ = ["sensitivity_data", "draw_sensitivity", "plot_sensitivity"]


def sensitivity_data(codebook, field: str | None = None, *, at: Mapping[str, float] | None = None,
                     points: int | None = None, densities: Mapping | None = None) -> dict:
    """:meth:`Codebook.sensitivity` of one unknown at ``points`` times (201) over the time domain.

    Returns
    -------
    dict
        ``kind`` 'sensitivity', ``problem``, ``field``, ``time`` (None for a steady codebook), ``t`` (T,),
        ``inputs``, ``mean``, ``std`` (T,), ``first``, ``total`` (T, inputs), ``at``, ``densities``.
    """
    name = field_name(codebook, field)
    tc = next((c for c in codebook.coordinates if c.role == "time"), None)
    times = None if tc is None else np.linspace(tc.domain[0], tc.domain[1], count_points(points, LINE_POINTS))
    result = codebook.sensitivity(times=times, at=at, densities=densities, fields=[name])
    return {"kind": "sensitivity", "problem": codebook.name, "field": name, "time": result.time, "t": result.times,
            "inputs": result.inputs, "mean": result.mean[name], "std": np.sqrt(result.variance[name]),
            "first": result.first[name], "total": result.total[name], "at": result.at,
            "densities": result.densities}


def _note(data: dict) -> str:
    parts = [f"{k}={v:g}" for k, v in data["at"].items()]
    parts += [f"{k} ~ {d}" for k, d in data["densities"].items() if d != "uniform"]
    return f" ({', '.join(parts)})" if parts else ""


def draw_sensitivity(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`sensitivity_data`: (a) the mean with a band of one standard deviation, (b) the
    first-order (solid) and total (dashed) index of every input, one color an input; a steady codebook:
    bars."""
    field, inputs = data["field"], data["inputs"]
    if data["time"] is None:
        fig = new_figure(fig, figsize or (6.4, 4.2))
        ax = fig.subplots()
        k = np.arange(len(inputs))
        ax.bar(k - 0.2, data["first"][0], width=0.4, color="#0072B2", label="first order")
        ax.bar(k + 0.2, data["total"][0], width=0.4, color="#D55E00", label="total")
        ax.set_xticks(k, inputs)
        ax.set_ylim(0, 1.05)
        ax.set_ylabel(f"Sobol index of {field}")
        ax.legend(fontsize="small")
        ax.grid(True, axis="y", linewidth=0.4, alpha=0.5)
        figure_title(fig, data, f"sensitivity of {field}: mean {data['mean'][0]:.4g}, "
                                f"std {data['std'][0]:.3g}{_note(data)}")
        return fig
    fig = new_figure(fig, figsize or (7.0, 5.2))
    ax1, ax2 = fig.subplots(2, 1, sharex=True, height_ratios=(1, 1.4))
    t, mean, std = data["t"], data["mean"], data["std"]
    ax1.fill_between(t, mean - std, mean + std, color="#0072B2", alpha=0.2, linewidth=0, label="mean \u00b1 std")
    ax1.plot(t, mean, color="#0072B2", linewidth=1.6, label="mean")
    ax1.set_ylabel(field)
    ax1.grid(True, linewidth=0.4, alpha=0.5)
    ax1.legend(fontsize="small", loc="best")
    ax1.set_title(f"(a) mean and spread of {field} over the inputs", fontsize="medium", loc="left")
    for i, name in enumerate(inputs):
        st = line_style(i)
        ax2.plot(t, data["first"][:, i], color=st["color"], linestyle="-", linewidth=1.6, label=f"{name}: first order")
        ax2.plot(t, data["total"][:, i], color=st["color"], linestyle="--", linewidth=1.4, label=f"{name}: total")
    ax2.set_ylim(-0.02, 1.02)
    ax2.set_xlim(t[0], t[-1])
    ax2.set_xlabel(data["time"])
    ax2.set_ylabel("Sobol index")
    ax2.grid(True, linewidth=0.4, alpha=0.5)
    ax2.set_title("(b) share of the variance: first order (solid), total (dashed)", fontsize="medium", loc="left")
    ax2.legend(fontsize="x-small", loc="best", ncol=2 if len(inputs) > 3 else 1)
    figure_title(fig, data, f"sensitivity of {field}{_note(data)}")
    return fig


def plot_sensitivity(codebook, field: str | None = None, *, fig=None, figsize=None, **options):
    """:func:`sensitivity_data` drawn by :func:`draw_sensitivity`; returns the Figure."""
    return draw_sensitivity(sensitivity_data(codebook, field, **options), fig=fig, figsize=figsize)
