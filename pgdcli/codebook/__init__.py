"""The codebook layer: the HDF5 file format, its evaluation, derivatives and exports.

Never imports the algorithms: a codebook is read by machines that have no solver.
"""

from . import phases  # noqa: F401  (registers the codebook of an event that acts with Codebook.load)
