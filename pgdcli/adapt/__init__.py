"""The automatic resolution: which coordinates get more nodes after a measured error, and why a refusal.

A tolerance is a promise about the codebook, not about the solver: every solve is
followed by a measurement of its error against an independent reference
(:mod:`pgdcli.checks.check`). The driver's refinement loop (:mod:`pgdcli.driver.refinement`)
first lowers the solver's own error at the nodes (a tighter march, a smaller residual);
:class:`~pgdcli.adapt.rounds.Resolution` then turns the measurement of the codebook it kept into a decision:

* the error within the tolerance (``ratio <= 1``): done;
* too large along a coordinate whose nodes the solver chooses (``nodes: auto`` or no
  ``nodes:``), by the error measured off its nodes or, where the check measures the
  error as a whole (space coordinates), by its Chebyshev tail: that coordinate, and
  only it, gets the nodes at which the geometric decay of its error (measured over
  its last refinement, or read from its Chebyshev spectrum) brings the error to its
  share of the tolerance (n -> 2n - 1 without a rate to go by) or, for a parameter
  whose error does not fall geometrically with its nodes, more elements where the
  error is (hp-refinement), and the problem is solved again, up to
  ``solver.max_nodes`` nodes in all per coordinate;
* otherwise a refusal (:func:`~pgdcli.adapt.refusal.refusal`): one clause saying how large the
  error is, where, which coordinate lacks resolution and what is predicted to meet the tolerance;
  the driver marks the result inaccurate (status :data:`INACCURATE`), and the CLI writes nothing
  then (exit 1) unless asked to keep it.

The report records the nodes tried per coordinate, the measured ratio of each
round, and why the last round ended (:meth:`~pgdcli.adapt.rounds.Resolution.report_entries`).
"""

from .refusal import refusal
from .resolution import (INACCURATE, MAX_ROUNDS, REFINE_AT, ROOM, TARGET, initial_nodes, next_nodes,
                         refined_nodes, split_elements, total_nodes)
from .rounds import Resolution, Verdict

__all__ = ["INACCURATE", "MAX_ROUNDS", "REFINE_AT", "ROOM", "TARGET", "Resolution", "Verdict", "refusal",
           "refined_nodes", "initial_nodes", "total_nodes", "split_elements", "next_nodes"]
