"""The one march loop (pgdcli.algorithms.march_loop): its handling of the end of the time domain."""

from __future__ import annotations

import numpy as np

from pgdcli import parse_spec
from pgdcli.algorithms.bogacki_shampine import BogackiShampine32
from pgdcli.algorithms.grid_steps import GridRhs, advance, initial_values
from pgdcli.algorithms.march import compile_system
from pgdcli.algorithms.step_control import LOCAL_FRACTION, MIN_STEP

DECAY = """
name: decay
coordinates:
  t: {domain: [0, 1], nodes: 6}
  k: {domain: [1, 2], nodes: 3}
unknowns:
  u: {initial: 1}
equations:
  - "der(u) = -k*u"
"""


class Steered(BogackiShampine32):
    """Bogacki-Shampine whose error estimate is chosen step by step: the error over its allowance
    ``LOCAL_FRACTION * tolerance * h`` (span 1) of each trial step, in turn."""

    def __init__(self, tolerance: float, ratios: list[float]):
        self.allowance, self.ratios = LOCAL_FRACTION * tolerance, list(ratios)

    def local_errors(self, space, K, h):
        return np.full(len(K[0]), self.ratios.pop(0) * self.allowance * h)


def test_a_remainder_below_the_step_floor_joins_the_last_step():
    """Steps of 0.1 and 0.3, then a proposed step that would stop 5e-8 short of the end (below the
    floor MIN_STEP * span): the last step takes the rest instead of failing on 'step size underflow'."""
    system = compile_system(parse_spec(DECAY, source="decay.yaml"), 1e-6)
    short = 0.6 - 0.5 * MIN_STEP
    ratios = [(0.8 / 3.0) ** 2 / 2.0, (0.8 * 0.3 / short) ** 2, 0.5]  # growth capped at 3x, then to `short`
    stepper = Steered(1e-6, ratios)
    kept: list = []
    schedule = advance(system, GridRhs(system), initial_values(system), 1e-6, kept.extend, slab_nodes=6,
                       stepper=stepper)
    assert [round(h, 9) for h in schedule.step_sizes] == [0.1, 0.3, 0.6] and not stepper.ratios
    assert schedule.times[-1] == 1.0 and len(kept) == len(schedule.times)
    # a three-stage third-order step of u' = -k u multiplies u by 1 + z + z^2/2 + z^3/6, z = -k h
    k = system.bases["k"].nodes
    expected = np.prod([1 - k * h + (k * h) ** 2 / 2 - (k * h) ** 3 / 6 for h in (0.1, 0.3, 0.6)], axis=0)
    np.testing.assert_allclose(kept[-1][0], expected, rtol=1e-14)
