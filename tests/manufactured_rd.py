"""Reaction-diffusion problems with exact (manufactured) solutions, for the PDE march and its reference.

Each spec adds to its equations the source that makes a chosen smooth function the exact solution,
written out as an expression of the coordinates: the solvers see an ordinary spec (a source that
depends on time, space and the parameters, non-separable parts included), and the exact solution
is a numpy function to compare with at random points.
"""

from __future__ import annotations

import numpy as np

# -- two space coordinates: Allen-Cahn with a source, data depending on y, value and gradient conditions --
_UE2 = "(1 + x*y + exp(-t)*sin(pi*x)*(1 - cos(pi*y)))"
_UT2 = "(-exp(-t)*sin(pi*x)*(1 - cos(pi*y)))"
_LAP2 = "(exp(-t)*pi**2*sin(pi*x)*(2*cos(pi*y) - 1))"  # the Laplacian of _UE2

PLANE = f"""
coordinates:
  t: {{domain: [0, 1]}}
  x: {{domain: [0, 1]}}
  y: {{domain: [0, 1]}}
  c: {{domain: [0.05, 0.1]}}
unknowns:
  u:
    initial: "1 + x*y + sin(pi*x)*(1 - cos(pi*y))"
    boundary:
      x: {{low: 1, high: "1 + y"}}
      y: {{low: {{gradient: x}}, high: {{gradient: x}}}}
equations:
  - "der(u) = c*(der(u, x, 2) + der(u, y, 2)) + u - u**3 + {_UT2} - c*{_LAP2} - {_UE2} + {_UE2}**3"
solver:
  tolerance: 1e-5
"""


def plane_exact(t, x, y, c=None):
    """The exact solution of :data:`PLANE` (any ``c``)."""
    return 1 + x * y + np.exp(-t) * np.sin(np.pi * x) * (1 - np.cos(np.pi * y))


# -- two species in one space coordinate: a function of the unknowns, data and diffusion depending on a --
_U = "(1 + 0.5*x + 0.5*exp(-t)*(1 - cos(2*pi*x)))"
_UT = "(-0.5*exp(-t)*(1 - cos(2*pi*x)))"
_UX = "(0.5 + pi*exp(-t)*sin(2*pi*x))"
_UXX = "(2*pi**2*exp(-t)*cos(2*pi*x))"
_V = "(a + x + 0.3*exp(-2*t)*sin(pi*x))"
_VT = "(-0.6*exp(-2*t)*sin(pi*x))"
_VXX = "(-0.3*pi**2*exp(-2*t)*sin(pi*x))"

PAIR = f"""
coordinates:
  t: {{domain: [0, 1]}}
  x: {{domain: [0, 1]}}
  a: {{domain: [0.5, 1.5]}}
unknowns:
  u:
    initial: "1 + 0.5*x + 0.5*(1 - cos(2*pi*x))"
    boundary:
      x: {{low: {{gradient: 0.5}}, high: {{gradient: 0.5}}}}
  v:
    initial: "a + x + 0.3*sin(pi*x)"
    boundary:
      x: {{low: a, high: "a + 1"}}
equations:
  - "der(u) = 0.1*der(u, x, 2) - u*v + u*v/(1 + u) + {_UT} - 0.1*{_UXX} + {_U}*{_V} - {_U}*{_V}/(1 + {_U})"
  - "der(v) = 0.05*a*der(v, x, 2) + u*v**2 - v*der(u, x) + {_VT} - 0.05*a*{_VXX} - {_U}*{_V}**2 + {_V}*{_UX}"
solver:
  tolerance: 1e-6
"""


def pair_exact(t, x, a):
    """``(u, v)`` of :data:`PAIR`."""
    u = 1 + 0.5 * x + 0.5 * np.exp(-t) * (1 - np.cos(2 * np.pi * x))
    v = a + x + 0.3 * np.exp(-2 * t) * np.sin(np.pi * x)
    return u, v
