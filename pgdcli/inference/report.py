"""What ``pgd fit`` tells and draws besides its output: a summary line, a figure (the output formats are
:mod:`pgdcli.cli.fit_command`'s)."""

from __future__ import annotations

import numpy as np

from ..plot.files import save_figure
from ..plot.options import require_matplotlib

__all__ = ["summary", "plot_fit"]


def summary(result) -> str:
    """One line for stderr: estimate, misfit, effort and the reference check."""
    est = ", ".join(f"{n} = {v:.6g} +/- {result.stderr[n]:.2g}" for n, v in result.estimate.items())
    text = (f"fit: {est}; rms {result.rms:.3g} over {result.residuals.size} values; {result.nfev} evaluations "
            f"from {result.starts} start(s) in {1e3 * result.elapsed:.1f} ms; {result.message}")
    if result.reference_error is not None:
        text += (f"; reference check at the estimate: codebook - reference max {result.reference_error:.2g}, "
                 f"rms with the reference {result.reference_rms:.3g} ({1e3 * result.check_elapsed:.0f} ms)")
    elif result.reference_message:
        text += f"; {result.reference_message}"
    return text


def plot_fit(result, path, dpi: int = 150):
    """Data (markers) and the fitted curve (lines) of every observed unknown; saved as PNG/SVG."""
    require_matplotlib("pgd fit --plot")
    from matplotlib.figure import Figure


    varying = [n for n in result.coordinates if np.ptp(result.fitted[n]) > 0]
    xname = varying[0] if varying else None
    x = result.fitted[xname] if xname else np.arange(result.residuals.size // len(result.observed))
    order = np.argsort(x, kind="stable")
    fig = Figure(figsize=(7, 4.5))
    ax = fig.add_subplot()
    for i, u in enumerate(result.observed):
        color = f"C{i}"
        ax.plot(x[order], result.fitted[u][order], color=color, label=f"{u} (fit)")
        ax.plot(x, result.data[u], "o", color=color, markersize=3, alpha=0.7, label=f"{u} (data)")
    ax.set_xlabel(xname or "row")
    est = ", ".join(f"{n} = {v:.4g}" for n, v in result.estimate.items())
    ax.set_title(_wrap(f"fit: {est}"), fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return save_figure(fig, path, dpi=dpi)


def _wrap(text: str, width: int = 90) -> str:
    if len(text) <= width:
        return text
    cut = text.rfind(", ", 0, width)
    return text[:cut + 1] + "\n" + _wrap(text[cut + 2:], width) if cut > 0 else text
