"""Pictures of a codebook: solution, modes, convergence, error, phase and sensitivity (``pgd plot``).

Two layers, so that tests check numbers rather than pixels (modules: :mod:`.options` the
arguments, :mod:`.modes` and :mod:`.solution` the data, :mod:`.draw` the figures,
:mod:`.files` the images and :func:`render`):

- ``*_data`` functions compute what is drawn, as plain dicts of numpy arrays:
  :func:`modes_data`, :func:`convergence_data`, :func:`solution_data`,
  :func:`error_data`, :func:`phase_data` (:mod:`.phase`), :func:`sensitivity_data`
  (:mod:`.sobol`). Every array handed to matplotlib comes from them.
- ``draw_*`` functions turn such a dict into a :class:`matplotlib.figure.Figure`;
  ``plot_*`` do both (``plot_modes(codebook, ...) -> Figure``), and
  :func:`render` does what ``pgd plot`` does: load, compute, draw, save.

Figures are built as bare :class:`~matplotlib.figure.Figure` objects, never
through ``matplotlib.pyplot``: no display, no GUI backend and no global state
are involved (saving goes through matplotlib's Agg / SVG canvases), and
importing this module does not change the backend of an interactive session.

Conventions
-----------
- Curves ("lines" layout) run along the time coordinate, one per parameter
  point; a point that leaves a non-time coordinate unset takes the midpoint of
  its domain. Codebook curves are lines (color and line style tell them apart);
  markers mean the independent reference (open) or one marked point (the largest
  error, a phase portrait's start).
- Maps ("map" layout) are drawn over two coordinates ``(x, y)``; every other
  coordinate is fixed, by default at the midpoint of its domain.
- Tensor-train codebooks (the nonlinear time march) have no stored modes:
  ``modes`` shows their HOSVD modes (:func:`tt_hosvd_modes`, normalized, with
  the singular values), and ``convergence`` the march's accepted step sizes
  and the state's tensor-train ranks at the time nodes.
- The independent reference is :func:`pgdcli.checks.reference.solve_reference`
  (scipy ``solve_ivp``) on the spec embedded in the codebook; any callable
  ``reference(params, times) -> result`` with ``result.values[unknown]`` of
  shape ``(S, T)``, ``result.success`` (S,) and ``result.messages`` can be
  passed instead.
"""

from __future__ import annotations

from .draw import (draw_convergence, draw_error, draw_modes, draw_solution, plot_convergence, plot_error, plot_modes,
                   plot_solution)
from .files import default_output, render, save_figure
from .modes import convergence_data, modes_data, tt_hosvd_modes
from .options import DEFAULT_DPI, FORMATS, KINDS, parse_over, parse_point, parse_size
from .phase import draw_phase, phase_data, plot_phase
from .sobol import draw_sensitivity, plot_sensitivity, sensitivity_data
from .solution import error_data, reference_solver, solution_data

__all__ = ["KINDS", "FORMATS", "DEFAULT_DPI", "modes_data", "tt_hosvd_modes", "convergence_data", "solution_data",
           "error_data", "draw_modes", "draw_convergence", "draw_solution", "draw_error", "plot_modes",
           "plot_convergence", "plot_solution", "plot_error", "reference_solver", "parse_point", "parse_over",
           "parse_size", "default_output", "save_figure", "render", "phase_data", "draw_phase", "plot_phase",
           "sensitivity_data", "draw_sensitivity", "plot_sensitivity"]
