"""A codebook's events in memory and on disk: validation, and crafted files refused with one line."""

from __future__ import annotations

import shutil
import subprocess

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from pgdcli import Codebook
from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import CoordinateInfo
from pgdcli.codebook.events import EventTime
from pgdcli.errors import CodebookError, QueryError
from pgdcli.tensors.tt import TT
from tests.conftest import reseal

COORDS = (CoordinateInfo("t", (0.0, 1.0), 5, "chebyshev", "time"), CoordinateInfo("k", (1.0, 2.0), 5))


def _codebook(events=None):
    field = TT([np.ones((1, 5, 1)), np.linspace(1, 2, 5).reshape(1, 5, 1)])
    return Codebook(COORDS, {"u": field}, name="toy", events=events)


def _event(value=0.5, k_nodes=9):
    mine = (CoordinateInfo("t", (0.0, 1.0), 2, "chebyshev", "time"), CoordinateInfo("k", (1.0, 2.0), k_nodes))
    k = mine[1].basis().nodes
    return EventTime("u = 1.5", "rising", mine, TT([np.ones((1, 2, 1)), (value * k).reshape(1, k_nodes, 1)]))


def test_event_times_interpolate_on_the_events_own_nodes():
    cb = _codebook({"half": _event()})
    np.testing.assert_allclose(cb.event_times({"k": np.array([1.0, 1.3, 2.0])})["half"], [0.5, 0.65, 1.0],
                               rtol=1e-14)
    assert float(cb.event_times({"k": 1.5})["half"]) == pytest.approx(0.75, rel=1e-14)


def test_event_times_errors_are_query_errors():
    cb = _codebook({"half": _event()})
    with pytest.raises(QueryError, match="does not depend on 't'"):
        cb.event_times({"k": 1.5, "t": 0.2})
    with pytest.raises(QueryError, match="unknown event 'whole'"):
        cb.event_times({"k": 1.5}, ["whole"])
    with pytest.raises(QueryError, match="outside|domain"):
        cb.event_times({"k": 7.0})
    with pytest.raises(QueryError, match="records no events"):
        _codebook().event_times({"k": 1.5})


def test_events_are_validated_against_the_coordinates():
    bad = _event()
    other = (bad.coordinates[0], CoordinateInfo("k", (1.0, 3.0), 9))
    with pytest.raises(CodebookError, match="event 'half': its coordinates are not the codebook's"):
        _codebook({"half": EventTime(bad.when, bad.direction, other, bad.field)})
    with pytest.raises(CodebookError, match="direction 'up'"):
        _codebook({"half": EventTime(bad.when, "up", bad.coordinates, bad.field)})
    with pytest.raises(CodebookError, match="event name"):
        _codebook({"1half": bad})


def test_a_codebook_without_events_has_no_events_group(tmp_path):
    path = tmp_path / "plain.h5"
    _codebook().save(path)
    with h5py.File(path) as f:
        assert "events" not in f and "event-order" not in f.attrs
    assert Codebook.load(path).events == {}


@pytest.fixture
def saved(tmp_path):
    path = tmp_path / "events.h5"
    _codebook({"half": _event()}).save(path)
    return path


def _edit(path, change):
    with h5py.File(path, "r+") as f:
        change(f)
    reseal(path)


@pytest.mark.parametrize("change, message", [
    (lambda f: f["events/half"].attrs.__setitem__("direction", "sideways"), "event 'half' has no condition or direction"),
    (lambda f: f["events/half"].attrs.__setitem__("coordinate-nodes", np.array([2])), "no node count for each"),
    (lambda f: f["events/half"].attrs.__setitem__("coordinate-nodes", np.array([2, 10 ** 9])), "do not fit"),
    (lambda f: f["events/half"].attrs.__setitem__("coordinate-nodes", np.array([3, 9])), "do not fit"),
    (lambda f: f["events/half"].attrs.__setitem__("representation", "cp"), "not stored as a tensor train"),
    (lambda f: f.attrs.__setitem__("event-order", np.array(["half", "gone"], dtype=object)), "no event 'gone'"),
    (lambda f: f.attrs.__setitem__("event-order", np.array(["x;rm"], dtype=object)), "event name"),
    (lambda f: (f["events/half/cores"].__delitem__("k"),
                f["events/half/cores"].create_dataset("k", data=np.ones((1, 4, 1)))), "core 'k' has shape"),
])
def test_crafted_event_entries_are_refused(saved, change, message):
    _edit(saved, change)
    with pytest.raises(CodebookError, match=message) as info:
        Codebook.load(saved)
    assert "\n" not in str(info.value)


def test_saved_events_load_back(saved):
    back = Codebook.load(saved, evaluation_only=True)
    assert back.events["half"].when == "u = 1.5" and back.events["half"].coordinates[1].nodes == 9
    assert float(back.event_times({"k": 2.0})["half"]) == pytest.approx(1.0, rel=1e-14)


def test_event_codebook_drops_time_wherever_its_core_sits():
    rng = np.random.default_rng(4)
    mine = (CoordinateInfo("k", (1.0, 2.0), 6), CoordinateInfo("t", (0.0, 1.0), 2, "chebyshev", "time"),
            CoordinateInfo("a", (0.0, 3.0), 5))
    coords = (CoordinateInfo("k", (1.0, 2.0), 5), COORDS[0], CoordinateInfo("a", (0.0, 3.0), 4))
    field = TT([rng.normal(size=(1, 6, 2)), np.stack([np.eye(2)] * 2, axis=1) * 1.5, rng.normal(size=(2, 5, 1))])
    base = Codebook(coords, {"u": TT([np.ones((1, 5, 1)), np.ones((1, 5, 1)), np.ones((1, 4, 1))])},
                    events={"e": EventTime("u = 1", "any", mine, field)}, name="three")
    alone = base.event_codebook("e")
    assert alone.coordinate_names == ["k", "a"] and alone.unknown_names == ["e"]
    k, a = rng.uniform(1, 2, 50), rng.uniform(0, 3, 50)
    np.testing.assert_allclose(alone.evaluate({"k": k, "a": a})["e"], base.event_times({"k": k, "a": a})["e"],
                               rtol=1e-13)
    with pytest.raises(QueryError, match="unknown event 'f'"):
        base.event_codebook("f")


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (cc) on this machine")
def test_exported_event_time_in_c_matches_the_codebook(saved, tmp_path):
    run = CliRunner().invoke(cli, ["export", str(saved), "--event", "half", "--to", "c", "-o",
                                   str(tmp_path / "half.h")], prog_name="pgd")
    assert run.exit_code == 0, run.output
    (tmp_path / "main.c").write_text('#include <stdio.h>\n#include "half.h"\nint main(void) {\n'
                                     '  double k[3] = {1.0, 1.37, 2.0}, out[1]; int i;\n'
                                     '  for (i = 0; i < 3; ++i) { pgd_toy_half_eval(&k[i], out); '
                                     'printf("%.17g\\n", out[0]); }\n  return 0;\n}\n')
    subprocess.run(["cc", "-std=c99", "-O1", "-o", str(tmp_path / "main"), str(tmp_path / "main.c")], check=True)
    got = [float(v) for v in subprocess.run([str(tmp_path / "main")], capture_output=True, text=True,
                                            check=True).stdout.split()]
    np.testing.assert_allclose(got, [0.5, 0.685, 1.0], rtol=1e-13)
