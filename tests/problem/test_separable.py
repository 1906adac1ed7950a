"""Sums of separated terms evaluated at many times (pgdcli.problem.separable.TimeSplit) against evaluating
the whole sum at every time."""

import numpy as np

from pgdcli.problem.separable import TimeSplit
from pgdcli.problem.spec import parse_spec

SPEC = """
coordinates:
  t: {domain: [0, 1]}
  x: {domain: [0, 1]}
  a: {domain: [1, 2]}
unknowns:
  u: {initial: "0", boundary: {x: {low: 0, high: 0}}}
equations:
  - "der(u) = der(u, x, 2) + COEF*u"
"""


def test_time_split_agrees_with_the_whole_sum_at_every_time():
    coefficient = "exp(-t)*sin(pi*x)*a + 3*exp(-t)*x**2 + cos(2*t)*a + x*a + sin(a*t)*x + sin(x*a)"
    problem = parse_spec(SPEC.replace("COEF", f"({coefficient})"), source="c.yaml")
    sep = next(s for m, s in problem.equations[0].polynomial.items() if m and m[0].unknown == "u" and not m[0].order)
    assert sep.joints and any("t" in j.coordinates for j in sep.joints)  # sin(a*t): evaluated at every call
    values = {"x": np.linspace(0, 1, 7)[:, None], "a": np.array([1.0, 1.5, 2.0])[None, :]}
    split = TimeSplit(sep, "t", values)
    assert len(split.timed) == 2  # exp(-t) and cos(2*t), each with its two terms summed once
    for t in (0.0, 0.3, 1.0):
        want = sep.evaluate(**values, t=np.asarray(t))
        assert np.allclose(split(t), want, rtol=1e-14, atol=1e-14)
