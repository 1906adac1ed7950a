"""The discretization layer: one-dimensional bases (nodes, quadrature, interpolation) per coordinate.
"""
