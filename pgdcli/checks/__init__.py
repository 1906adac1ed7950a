"""The checking layer: the independent scipy reference, the solve-time error check and ``pgd verify``.

The reference shares no numerical code with the solvers (deliberate: an independent check).
"""
