"""The fitting tutorial end to end: docs/examples/enzyme.yaml solved, progress curves made by
docs/examples/enzyme_data.py (scipy alone), and pgdcli.fit recovering the enzyme's constants."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import pgdcli

EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples"


def _data_module():
    spec = importlib.util.spec_from_file_location("enzyme_data", EXAMPLES / "enzyme_data.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def enzyme():
    result = pgdcli.solve(pgdcli.load_spec(EXAMPLES / "enzyme.yaml"))
    assert result.converged and result.accurate, result.message
    return result.codebook


def _progress(vmax, km=2.0, s0=8.0, noise=0.05, seed=0):
    times = np.linspace(0.0, 10.0, 21)
    s = _data_module().progress_curve(vmax, km, s0, times)
    return {"t": times, "s": s + np.random.default_rng(seed).normal(0.0, noise, times.size)}


def test_the_tutorials_fit_recovers_the_constants_within_their_standard_errors(enzyme):
    truth = {"vmax": 1.2, "km": 2.0, "s0": 8.0}
    result = pgdcli.fit(enzyme, _progress(truth["vmax"]), sigma={"s": 0.05})
    assert result.success and result.at_bound == []
    for name, value in truth.items():
        assert abs(result.estimate[name] - value) <= 3 * result.stderr[name], (name, result.estimate, result.stderr)
    assert 0.5 < result.rms < 1.5  # in units of sigma: the noise
    assert result.reference_error < 1e-4  # the codebook's tolerance, at the estimate


def test_an_enzyme_faster_than_the_domain_is_flagged_at_the_bound(enzyme):
    result = pgdcli.fit(enzyme, _progress(2.6), sigma={"s": 0.05}, check=False)
    assert not result.success and result.at_bound == ["vmax"] and result.estimate["vmax"] == pytest.approx(2.0)
