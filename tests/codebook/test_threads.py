"""The batches' BLAS policy also holds for grids (pgdcli.codebook.threads.batch_blas)."""

from __future__ import annotations

import numpy as np

import pgdcli.codebook.evaluate as evaluate_module
import pgdcli.codebook.threads as threads_module
from pgdcli.codebook.codebook import Codebook, CoordinateInfo, TT


def _codebook():
    coords = [CoordinateInfo("t", (0.0, 1.0), 9, "chebyshev", "time"), CoordinateInfo("a", (0.0, 2.0), 6, "chebyshev")]
    rng = np.random.default_rng(41)
    cores = (rng.standard_normal((1, 9, 4)), rng.standard_normal((4, 6, 1)))
    return Codebook(coords, {"u": TT(cores, (0, 1))}, name="grid", report={})


def test_large_grids_run_on_one_blas_thread_and_small_ones_do_not(monkeypatch):
    cb = _codebook()
    seen = []
    original = evaluate_module.grid_tt

    def recording(fm, mats):
        seen.append(threads_module.blas_users())
        return original(fm, mats)

    monkeypatch.setattr(evaluate_module, "grid_tt", recording)
    n = threads_module.BLAS_LIMIT_MIN_POINTS
    big = cb.evaluate_grid({"t": np.linspace(0, 1, n), "a": [0.5]})["u"]
    small = cb.evaluate_grid({"t": np.linspace(0, 1, 7), "a": [0.5]})["u"]
    assert seen == [1, 0] and threads_module.blas_users() == 0  # the limit is lifted afterwards
    points = cb.evaluate({"t": np.linspace(0, 1, n), "a": 0.5})["u"]
    assert np.max(np.abs(big[:, 0] - points)) <= 1e-13 * max(1.0, float(np.max(np.abs(points))))
    assert small.shape == (7, 1)
