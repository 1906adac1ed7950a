"""Codebooks of a motion that an event resets (a bounce) or ends (``terminal``): evaluation by phases.

The solution of a problem whose event acts is piecewise smooth in time, with jumps at event times
``t_k(p)`` that depend on the parameters. It is stored as phases: phase 0 is the codebook of the
problem itself, whose event field gives ``t_1(p)``; phase ``k >= 1`` is a codebook of the same
equations in the local time ``tau = t - t_k(p)`` (its time coordinate spans ``[0, span_k]``),
started from the reset state, whose own event field gives ``t_{k+1}(p) - t_k(p)``. At a point
``(t, p)``: ``k`` is the number of event times ``<= t`` and the value is ``phase_k(t - t_k(p), p)``.
A terminal event has no phase after it: values after ``t_1(p)`` do not exist (NaN).

Paths that read the fields directly (grids, series, gradients, Sobol indices, export) would read
phase 0 beyond its event; :class:`PhasedCodebook` refuses them with one line. numpy only.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ..errors import CodebookError, QueryError
from .codebook import Codebook
from .phase_io import ACTIONS, MAX_PHASES

__all__ = ["PhasedCodebook", "ACTIONS", "MAX_PHASES", "validate_phases", "refuse_phases"]


def validate_phases(cb: Codebook, acting: str, action: str, phases: Sequence[Codebook]) -> tuple:
    """The phases, checked against phase 0 (CodebookError naming what does not fit)."""
    if action not in ACTIONS:
        raise CodebookError(f"phases: action {action!r} is not one of {', '.join(ACTIONS)}")
    if acting not in cb.events:
        raise CodebookError(f"phases: the acting event {acting!r} is not one of the codebook's events")
    if action == "terminal" and phases:
        raise CodebookError("phases: a terminal event has no phase after it")
    if len(phases) + 1 > MAX_PHASES:
        raise CodebookError(f"phases: {len(phases) + 1} phases; at most {MAX_PHASES}")
    mine = [(c.name, c.role) for c in cb.coordinates]
    for k, phase in enumerate(phases, start=1):
        if not isinstance(phase, Codebook) or isinstance(phase, PhasedCodebook):
            raise CodebookError(f"phase {k}: expected a codebook of one phase")
        if [(c.name, c.role) for c in phase.coordinates] != mine or phase.unknown_names != cb.unknown_names:
            raise CodebookError(f"phase {k}: its coordinates or unknowns are not the codebook's")
        for c, own in zip(cb.coordinates, phase.coordinates):
            if c.role != "time" and tuple(own.domain) != tuple(c.domain):
                raise CodebookError(f"phase {k}: the domain of {c.name!r} is not the codebook's")
            if c.role == "time" and not (own.domain[0] == 0.0 and own.domain[1] > 0.0):
                raise CodebookError(f"phase {k}: its time does not start at 0")
        if list(phase.events) != [acting]:
            raise CodebookError(f"phase {k}: it records no time of event {acting!r}")
    return tuple(phases)


class PhasedCodebook(Codebook):
    """A codebook of a motion with an acting event: phase 0 (this codebook's own fields) and its phases.

    Parameters
    ----------
    *args, **kwargs
        Those of :class:`Codebook` (phase 0, with the acting event among its ``events``).
    acting : str
        The event that acts.
    action : str
        ``reset`` (the motion goes on from the reset state) or ``terminal`` (it ends).
    phases : sequence of Codebook
        Phases 1, 2, ...: the same coordinates with time from 0 (the local time since the event), each
        recording the time to its own next event.
    """

    def __init__(self, *args, acting: str, action: str, phases: Sequence[Codebook] = (), **kwargs):
        super().__init__(*args, **kwargs)
        self.acting, self.action = acting, action
        self.phases = validate_phases(self, acting, action, phases)
        self._time = next(c for c in self.coordinates if c.role == "time")
        # phase 0 as a plain codebook: its own evaluation paths, and the event fields' books
        self.zero = Codebook(self.coordinates, self.fields, name=self.name, events=self.events)

    def __reduce__(self):
        build, (coordinates, fields, attributes) = super().__reduce__()
        return _from_parts, (coordinates, fields, attributes, self.acting, self.action, self.phases)

    def with_events(self, events):
        return PhasedCodebook(self.coordinates, self.fields, name=self.name, spec_text=self.spec_text,
                              report=self.report, description=self.description, created=self.created,
                              partial=self.partial, format_version=self.format_version, events=events,
                              acting=self.acting, action=self.action, phases=self.phases)

    @classmethod
    def from_parts(cls, parts: dict, path) -> "PhasedCodebook":
        """The codebook of a file with phases: ``parts`` as :func:`pgdcli.codebook.io.load_parts` reads them."""
        parts = dict(parts)
        acting, action, phases = parts.pop("acting"), parts.pop("action"), parts.pop("phases")
        try:
            books = [Codebook(**phase) for phase in phases]
            return cls(**parts, acting=acting, action=action, phases=books)
        except CodebookError as exc:
            raise CodebookError(f"{path}: corrupt codebook: {exc}") from None

    # ------------------------------------------------------------------ event times of every phase
    def event_times(self, coordinates, events=None):
        return self.zero.event_times(coordinates, events)

    def event_codebook(self, name: str):
        return self.zero.event_codebook(name)

    def event_sequence(self, coordinates: Mapping[str, object]) -> np.ndarray:
        """The acting event's times ``t_1 <= t_2 <= ...`` at points given for every coordinate but time.

        Returns
        -------
        ndarray, shape (..., n_phases)
            ``t_k`` in the time coordinate (the last may lie beyond the end time); for a terminal
            event, ``t_1`` alone.
        """
        first = np.asarray(self.event_times(coordinates, [self.acting])[self.acting], dtype=float)
        times = [first]
        for phase in self.phases:
            times.append(times[-1] + np.asarray(phase.event_times(coordinates, [self.acting])[self.acting]))
        return np.stack(times, axis=-1)

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, coordinates: Mapping[str, object], fields: Sequence[str] | None = None
                 ) -> dict[str, np.ndarray]:
        """As :meth:`Codebook.evaluate`, phase by phase; NaN after a terminal event."""
        names = self.coordinate_names
        if len(coordinates) != len(names) or not set(names).issuperset(coordinates):
            self._check_names(coordinates)
        if any(hasattr(v, "__dask_graph__") for v in coordinates.values()):
            raise QueryError("a codebook with phases (an event that acts) evaluates numpy arrays, not dask arrays")
        selected = self._select(fields)
        scalar = all(np.ndim(coordinates[n]) == 0 for n in names)
        arrays = np.broadcast_arrays(*[np.asarray(coordinates[n], dtype=float) for n in names])
        shape = arrays[0].shape
        flat = {n: self._checked(c, a.reshape(-1)) for n, c, a in zip(names, self.coordinates, arrays)}
        out = self._by_phase(flat, selected)
        return {u: (v.reshape(shape)[()] if scalar else v.reshape(shape)) for u, v in out.items()}

    def _by_phase(self, flat: dict, selected: list) -> dict[str, np.ndarray]:
        time = self._time.name
        t = flat[time]
        params = {n: v for n, v in flat.items() if n != time}
        S = t.size
        out = {u: np.full(S, np.nan) for u in selected}
        if S == 0:
            return out
        sequence = self.event_sequence(params) if params else self.event_sequence({})
        starts = np.broadcast_to(sequence, (S, 1 + len(self.phases)))
        k = np.sum(starts <= t[:, None], axis=1)  # at an event time itself: after it
        books = (self.zero, *self.phases)
        for j in np.unique(k):
            if j >= len(books):
                continue  # beyond the last phase stored, or after a terminal event: no value
            rows = np.flatnonzero(k == j)
            local = t[rows] if j == 0 else t[rows] - starts[rows, j - 1]
            book = books[j]
            span = book.coordinate(time).domain
            at = {n: v[rows] for n, v in params.items()}
            at[time] = np.clip(local, span[0], span[1])
            values = book.evaluate(at, selected)
            for u in selected:
                out[u][rows] = values[u]
        return out

    def ended(self, coordinates: Mapping[str, object]) -> np.ndarray:
        """Where the motion has ended (after a terminal event): bool of the broadcast shape."""
        if self.action != "terminal":
            return np.zeros(np.broadcast_shapes(*(np.shape(v) for v in coordinates.values())), dtype=bool)
        params = {n: v for n, v in coordinates.items() if n != self._time.name}
        first = self.event_times(params, [self.acting])[self.acting]
        return np.asarray(coordinates[self._time.name], dtype=float) >= first

    # ------------------------------------------------------------------ paths that read the fields directly
    def refuse(self, what: str):
        raise QueryError(f"{what} reads the fields of one phase; this codebook has an event that acts "
                         f"({self.acting!r}: {self.action}): evaluate it at points (pgd query, Codebook.evaluate)")

    def evaluate_grid(self, axes, fields=None):
        self.refuse("evaluate_grid")

    def evaluate_series(self, points, series, fields=None):
        self.refuse("evaluate_series")

    def gradient(self, coordinates, wrt=None, fields=None, grid=False):
        self.refuse("gradient")

    def sensitivity(self, **kwargs):
        self.refuse("sensitivity")

    def nodal_values(self, field_name):
        self.refuse("nodal_values")

    def to_xarray(self, axes=None, /, *, fields=None, **coordinates):
        self.refuse("to_xarray")


def refuse_phases(cb, what: str) -> None:
    """QueryError (one line, naming ``what``) for a codebook with phases: ``what`` reads one phase's fields."""
    if isinstance(cb, PhasedCodebook):
        cb.refuse(what)


def _from_parts(coordinates, fields, attributes: dict, acting: str, action: str, phases) -> PhasedCodebook:
    return PhasedCodebook(coordinates, fields, **attributes, acting=acting, action=action, phases=phases)


Codebook.phased_class = PhasedCodebook  # Codebook.load builds it for a file with phases
