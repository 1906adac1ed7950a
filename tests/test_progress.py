"""The typed progress events: fractions, descriptions, and item access for callbacks written for dicts."""

from __future__ import annotations

import math

import pytest

from pgdcli.progress import CrossSweep, EnrichmentStep, MarchStep, PhaseStarted, ReferenceProgress


def test_every_event_says_its_phase_fraction_and_what_it_did():
    events = [PhaseStarted("check", "error gate against scipy's DOP853", 2),
              EnrichmentStep(3, 1e-5, 4, 1e-10, 100),
              MarchStep(0.25, 0.5, 12, [(1, 4, 1), (1, 3, 1)], 0.0),
              CrossSweep(2, 1e-4, 1e-8, 5000, [1, 7, 5]),
              ReferenceProgress(3, 12),
              ReferenceProgress(0.5, 2.0, "time")]
    assert [e.phase for e in events] == ["check", "solve", "solve", "solve", "check", "check"]
    fractions = [e.fraction() for e in events]
    assert fractions == pytest.approx([0.0, 0.5, 0.5, 0.5, 0.25, 0.25])
    texts = [e.describe() for e in events]
    assert texts[0] == "error gate against scipy's DOP853"
    assert texts[1] == "3/100 modes, residual 1.00e-05 (target 1e-10)"
    assert texts[2] == "t = 0.25/0.5, 12 steps, max rank 4"
    assert texts[3].startswith("cross sweep 2: 5,000 trajectories") and texts[3].endswith("max rank 7")
    assert texts[4] == "reference at 3/12 parameter points"
    assert texts[5] == "reference at 25% of the time domain"


def test_fractions_stay_within_zero_and_one_or_are_unknown():
    assert EnrichmentStep(1, 10.0, 1, 1e-6).fraction() == 0.0  # a residual above 1: no decade reached
    assert EnrichmentStep(1, 0.0, 1, 1e-6).fraction() == 1.0
    assert EnrichmentStep(1, 1e-9, 1, 1e-6).fraction() == 1.0
    assert EnrichmentStep(1, math.nan, 1, 1e-6).fraction() is None
    assert MarchStep(1.0, 1.0, 1, [], 1.0).fraction() is None  # an empty time domain
    assert ReferenceProgress(0, 0).fraction() is None


def test_an_event_reads_as_the_dict_it_replaces():
    """Callbacks written for the dicts of earlier versions (``info["residual"]``, ``"time" in info``) still work."""
    step = EnrichmentStep(2, 1e-3, 5)
    assert (step["mode"], step["residual"], step["iterations"]) == (2, 1e-3, 5)
    march = MarchStep(0.1, 1.0, 3, [])
    assert "time" in march and "mode" not in march and march["end"] == 1.0
    sweep = CrossSweep(4, 1e-3, 1e-6, 10, [2])
    assert "cross" in sweep and sweep["cross"] == 4 and sweep["trajectories"] == 10
    with pytest.raises(KeyError):
        march["residual"]


def test_events_are_frozen():
    with pytest.raises(AttributeError):
        MarchStep(0.1, 1.0, 3, []).time = 0.2
