"""The codebook layer: the HDF5 file format, its evaluation, derivatives and exports.

Never imports the algorithms: a codebook is read by machines that have no solver.
"""
