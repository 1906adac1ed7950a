"""Events that act: a bounce (a reset, solved as phases) and a motion that ends (a terminal event).

The drag-free ball of ``problems/bounce.yaml`` has a closed form for every flight; it is checked at
random points, faces and corners of the box at times across every phase, and against solve_ivp
stopped at each impact and restarted from the reset state (written here, independent of pgdcli's
reference). A thrown ball that lands (terminal) has no values after its landing.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.integrate import solve_ivp

import pgdcli
from conftest import reseal
from pgdcli.cli.main import cli
from pgdcli.codebook.io import to_bytes
from pgdcli.errors import PgdError
from pgdcli.problem.spec import load_spec, parse_spec

PROBLEMS = Path(__file__).resolve().parents[2] / "problems"
G = 9.81
T_END, H, E = 2.0, (1.0, 2.0), (0.7, 0.9)


def ball(t, h, e):
    """The drag-free ball dropped from ``h`` with restitution ``e``: y, v at times ``t`` and the impact times."""
    t, h, e = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (t, h, e)))
    y, v, impacts = np.full(t.shape, np.nan), np.full(t.shape, np.nan), []
    start, y0, v0 = np.zeros(t.shape), h.copy(), np.zeros(t.shape)
    for _ in range(40):
        flight = (v0 + np.sqrt(v0 ** 2 + 2 * G * y0)) / G
        now = np.isnan(y) & (t < start + flight)
        tau = t - start
        y = np.where(now, y0 + v0 * tau - 0.5 * G * tau ** 2, y)
        v = np.where(now, v0 - G * tau, v)
        impacts.append(start + flight)
        start, y0, v0 = start + flight, np.zeros(t.shape), e * G * flight - e * v0
    return y, v, np.stack(impacts, axis=-1)


def restarted(h: float, e: float, t_end: float):
    """solve_ivp stopped at each impact and restarted with v -> -e v: [(start, end, dense output)], impacts."""
    def hit(t, s):
        return s[0]

    hit.terminal, hit.direction = True, -1
    segments, impacts, t, s = [], [], 0.0, np.array([h, 0.0])
    while t < t_end:
        sol = solve_ivp(lambda t, s: [s[1], -G], (t, t_end), s, method="DOP853", rtol=1e-12, atol=1e-13,
                        events=hit, dense_output=True)
        segments.append(sol.sol)
        if sol.status != 1:
            break
        t = float(sol.t_events[0][0])
        impacts.append(t)
        s = np.array([sol.y_events[0][0][0], -e * sol.y_events[0][0][1]])
    return segments, np.array(impacts)


def _box(n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    h, e = rng.uniform(*H, n), rng.uniform(*E, n)
    faces_h = np.r_[np.full(8, H[0]), np.full(8, H[1]), rng.uniform(*H, 16)]
    faces_e = np.r_[rng.uniform(*E, 16), np.full(8, E[0]), np.full(8, E[1])]
    corners = np.array(list(itertools.product(H, E)))
    return {"h": np.r_[h, faces_h, corners[:, 0]], "e": np.r_[e, faces_e, corners[:, 1]]}


@pytest.fixture(scope="module")
def bounce():
    result = pgdcli.solve(load_spec(PROBLEMS / "bounce.yaml"))
    assert result.converged and result.accurate, result.message
    return result.codebook


@pytest.mark.slow
def test_bounce_within_tolerance_of_the_closed_form_and_restarted_solve_ivp(bounce):
    cb = bounce
    assert len(cb.phases) + 1 == cb.report["phases"] >= 4  # several bounces before the end time
    p = _box(300, 5)
    S, T = p["h"].size, 24
    t = np.random.default_rng(6).uniform(0, T_END, (S, T))
    t[:, 0], t[:, 1] = 0.0, T_END
    got = cb.evaluate({"t": t, "h": p["h"][:, None], "e": p["e"][:, None]})
    y, v, impacts = ball(t, p["h"][:, None], p["e"][:, None])
    mine = cb.event_sequence(p)  # (S, phases): the impacts the codebook stores
    exact = impacts[:, 0, :mine.shape[1]]
    before = exact < T_END
    assert np.abs(mine - exact)[before].max() <= 1e-6
    # between the codebook's impact time and the true one the two are on either side of the jump: the
    # codebook's own impact times decide which flight a time belongs to
    same = (mine[:, None, :] <= t[..., None]).sum(-1) == (exact[:, None, :] <= t[..., None]).sum(-1)
    assert same.mean() > 0.999
    assert np.abs(got["y"] - y)[same].max() <= 1e-6 and np.abs(got["v"] - v)[same].max() <= 1e-6
    for i in range(0, S, 12):  # an independent integration at every twelfth point
        segments, hits = restarted(p["h"][i], p["e"][i], T_END)
        np.testing.assert_allclose(mine[i, :hits.size], hits, atol=1e-6)
        k = np.searchsorted(mine[i], t[i], side="right")
        ref = np.array([segments[k[j]](t[i, j]) for j in range(T)])
        assert np.abs(got["y"][i] - ref[:, 0]).max() <= 1e-6 and np.abs(got["v"][i] - ref[:, 1]).max() <= 1e-6


def test_bounce_saves_loads_and_queries_by_phase(bounce, tmp_path):
    path = tmp_path / "bounce.h5"
    bounce.save(path)
    back = pgdcli.Codebook.load(path)
    assert back.format_version == "1.3" and len(back.phases) == len(bounce.phases)
    runner = CliRunner()
    run = runner.invoke(cli, ["query", str(path), "--t", "0.3,1.0,1.9", "--h", "1.5", "--e", "0.8", "--format", "json"])
    assert run.exit_code == 0, run.output
    rows = json.loads(run.stdout)
    y, v, impacts = ball(np.array([0.3, 1.0, 1.9]), 1.5, 0.8)
    np.testing.assert_allclose([r["y"] for r in rows], y, atol=1e-6)
    np.testing.assert_allclose([r["v"] for r in rows], v, atol=1e-6)
    run = runner.invoke(cli, ["query", str(path), "--event", "impact", "--h", "1.5", "--e", "0.8"])
    assert run.exit_code == 0 and abs(float(run.stdout) - impacts[0, 0]) <= 1e-6  # the first impact
    np.testing.assert_allclose(back.event_sequence({"h": 1.5, "e": 0.8})[:3], impacts[0, :3], atol=1e-6)
    report = pgdcli.verify(path, samples=8, times=8)
    assert report.passed() and {"impact", "impact[2]"} <= set(report.events)


def test_paths_that_read_one_phase_refuse(bounce, tmp_path):
    for call in (lambda: bounce.evaluate_grid({"t": [1.0], "h": [1.5], "e": [0.8]}),
                 lambda: bounce.evaluate_series({"h": 1.5, "e": 0.8}, {"t": [1.0]}),
                 lambda: bounce.gradient({"t": 1.0, "h": 1.5, "e": 0.8}),
                 lambda: bounce.sensitivity(times=[1.0])):
        with pytest.raises(PgdError, match="reads the fields of one phase"):
            call()
    path = tmp_path / "bounce.h5"
    bounce.save(path)
    for args in (["export", str(path), "--to", "c", "-o", str(tmp_path / "b.h")],
                 ["view", str(path), "-o", str(tmp_path / "b.html")]):
        run = CliRunner().invoke(cli, args)
        assert run.exit_code == 2 and "reads the fields of one phase" in run.stderr and "Traceback" not in run.output


def _crafted(bounce, tmp_path, edit) -> str:
    path = tmp_path / "crafted.h5"
    bounce.save(path)
    with h5py.File(path, "r+") as f:
        edit(f)
    reseal(path)
    run = CliRunner().invoke(cli, ["query", str(path), "--t", "1", "--h", "1.5", "--e", "0.8"])
    assert run.exit_code == 2 and run.stderr.startswith("Error: ") and len(run.stderr.splitlines()) == 1, run.output
    assert "Traceback" not in run.output
    return run.stderr


def _replace(f, where: str, data: bytes) -> None:
    del f[where]
    f.create_dataset(where, data=np.frombuffer(data, dtype=np.uint8))


def test_a_crafted_phased_codebook_is_refused_on_read(bounce, tmp_path):
    def action(f):
        f["phases"].attrs["action"] = "explode"

    def count(f):
        f["phases"].attrs["count"] = len(bounce.phases) + 1

    def unmarked(f):
        f["unknowns/y"].attrs["representation"] = "cp"

    def no_phases(f):
        del f["phases"]

    def garbage(f):
        _replace(f, "phases/1", b"not an HDF5 file at all")

    def wrong_phase(f):  # a phase that does not record the time to its next impact
        _replace(f, "phases/1", to_bytes(pgdcli.Codebook(bounce.coordinates, bounce.fields)))

    def nested(f):  # a phase with phases of its own
        _replace(f, "phases/1", to_bytes(bounce))

    for edit, needle in [(action, "action 'explode'"), (count, "phase"), (unmarked, "mark of phase 0"),
                         (no_phases, "mark of phase 0"), (garbage, "phase 1: corrupt codebook"),
                         (wrong_phase, "phase 1: it records no time of event 'impact'"), (nested, "phase 1")]:
        assert needle in _crafted(bounce, tmp_path, edit), edit.__name__


THROW = """
name: throw
coordinates:
  t: {domain: [0, 1.5]}
  h: {domain: [0, 1]}
  v0: {domain: [2, 4]}
unknowns:
  y: {initial: h}
  v: {initial: v0}
equations:
  - "der(y) = v"
  - "der(v) = -9.81"
events:
  landing: {when: "y = 0", direction: falling, terminal: true}
solver:
  tolerance: 1.0e-6
"""


def test_a_terminal_event_ends_the_motion(tmp_path):
    result = pgdcli.solve(parse_spec(THROW, source="throw.yaml"))
    assert result.converged and result.accurate, result.message
    cb = result.codebook
    rng = np.random.default_rng(3)
    h, v0, t = rng.uniform(0, 1, 400), rng.uniform(2, 4, 400), rng.uniform(0, 1.5, 400)
    landing = (v0 + np.sqrt(v0 ** 2 + 2 * G * h)) / G
    assert landing.max() < 1.5 and np.abs(cb.event_times({"h": h, "v0": v0})["landing"] - landing).max() <= 1e-6
    got = cb.evaluate({"t": t, "h": h, "v0": v0})
    flying = t < landing - 1e-6
    assert np.abs(got["y"] - (h + v0 * t - 0.5 * G * t ** 2))[flying].max() <= 1e-6
    assert np.isnan(got["y"][t > landing + 1e-6]).all() and np.isnan(got["v"][t > landing + 1e-6]).all()
    path = tmp_path / "throw.h5"
    cb.save(path)
    runner = CliRunner()
    one = runner.invoke(cli, ["query", str(path), "--t", "1.4", "--h", "0.5", "--v0", "3"])
    assert one.exit_code == 2 and "is at or after the terminal event 'landing' at t=0.7" in one.stderr
    points = tmp_path / "points.csv"
    points.write_text("t,h,v0\n0.2,0.5,3\n1.4,0.5,3\n")
    run = runner.invoke(cli, ["query", str(path), "--points", str(points), "--format", "csv"])
    assert run.exit_code == 0
    rows = run.stdout.splitlines()
    assert rows[2].endswith("nan,nan") and "nan" not in rows[1]
    assert run.stderr.count("Warning: 1 of 2 points are at or after the terminal event 'landing'") == 1
    out = tmp_path / "out.h5"
    run = runner.invoke(cli, ["query", str(path), "--points", str(points), "--output", str(out)])
    assert run.exit_code == 0 and "Warning: 1 of 2 points are at or after the terminal event 'landing'" in run.stderr
    with h5py.File(out) as f:
        assert np.isnan(f["values/y"][1]) and abs(f["values/y"][0] - (0.5 + 0.6 - 0.5 * G * 0.04)) <= 1e-6
    assert pgdcli.verify(path, samples=8, times=8).passed()


def test_a_zeno_motion_is_refused_with_the_point(tmp_path):
    text = THROW.replace("terminal: true", 'then: {v: "-0.3*v"}').replace("[0, 1.5]", "[0, 3]")
    path = tmp_path / "zeno.yaml"
    path.write_text(text)
    run = CliRunner().invoke(cli, ["solve", str(path), "-o", str(tmp_path / "zeno.h5")])
    assert run.exit_code == 2 and not (tmp_path / "zeno.h5").exists(), run.output
    lines = [line for line in run.stderr.splitlines() if line.startswith("Error: ")]
    assert len(lines) == 1 and "event 'landing' happens more than" in lines[0] and "Zeno" in lines[0]
    assert "at h=" in lines[0]


def test_the_solve_summary_states_the_error_over_every_phase(tmp_path):
    """The error a user reads first is the whole motion's, not the first flight's (exact, a parabola)."""
    path = tmp_path / "bounce.h5"
    run = CliRunner().invoke(cli, ["solve", str(PROBLEMS / "bounce.yaml"), "-o", str(path)])
    assert run.exit_code == 0, run.output
    rep = pgdcli.Codebook.load(path).report
    rows: dict = {}
    label = None
    for line in run.stderr.splitlines():
        if line.count("│") == 3:  # a row of the summary table, or the continuation of one
            label = line.split("│")[1].strip() or label
            rows[label] = (rows.get(label, "") + " " + line.split("│")[2].strip()).strip()
    row = rows["max error"]
    phases = int(rep["phases"])
    assert row.startswith(f"{float(rep['phase_error']):.3e} over the {phases} phases vs solve_ivp restarted"), row
    assert f"the first phase: {float(rep['check_error']):.3e}" in row
