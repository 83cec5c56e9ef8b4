"""Parameter sweeps on a Dask LocalCluster of 2 workers: rows per point and
seed, a diverging point as a row, resume, a killed worker, the maps."""

import csv
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from matplotlib.figure import Figure

from drake_contact.app.sweep import Task, load_sweep, run_sweep, sweeps_dir
from drake_contact.app.sweep_figures import plot_heat_map

#: One worker runs this module and its fixture is session-scoped, so the fixture
#: runs once (-n auto; docs/developer/testing.md, "Shared runs").
pytestmark = pytest.mark.xdist_group("test_sweep")

#: push_constant rests through the tare and pushes from 2.1 s; 1e9 N/m makes
#: its force run away (diverged) within milliseconds of the touch.
SMALL = """
description: "test grid"
scenario: push_constant
duration: 2.6
grid:
  environment.stiffness: [7000.0, 1.0e+9]
  environment.damping: [20.0, 50.0]
seeds: [0, 1]
maps:
  - {metric: steady_force_n, x: environment.stiffness, y: environment.damping}
  - {metric: peak_force_n, x: environment.damping}
"""


@pytest.fixture(scope="session")
def small(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep")
    (root / "small.yaml").write_text(SMALL)
    sweep = load_sweep(root / "small.yaml")
    result = run_sweep(sweep, root / "out", workers=2)
    return sweep, result, root


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_a_small_grid_gives_one_row_per_point_and_seed(small):
    sweep, result, root = small
    rows = read_csv(root / "out" / "results.csv")
    assert len(rows) == 8 == len({r["point"] for r in rows})
    assert {(float(r["environment.stiffness"]), float(r["environment.damping"]), int(r["seed"]))
            for r in rows} == {(k, b, s) for k in (7e3, 1e9) for b in (20.0, 50.0)
                               for s in (0, 1)}
    by_status = {r["point"]: r["status"] for r in rows}
    for r in rows:
        soft = float(r["environment.stiffness"]) == 7000.0
        assert by_status[r["point"]] == ("completed" if soft else "diverged"), r["message"]
        if soft:  # a real push settled at f / x = K_e: the metrics came through
            assert abs(float(r["steady_stiffness_error"])) < 0.02
            assert 12.0 < float(r["steady_force_n"]) < 21.0
        else:
            assert "exceeds simulation.force_limit" in r["message"]
    assert result.ran == 8 and result.skipped == 0 and result.workers == 2
    # Each seed is its own noise: the two seeds of a point measured differently.
    point = root / "out" / "runs" / "environment.stiffness=7000__environment.damping=20__seed={}"
    with np.load(str(point).format(0) + "/log.npz") as a, \
            np.load(str(point).format(1) + "/log.npz") as b:
        np.testing.assert_array_equal(a["contact_force_true"], b["contact_force_true"])
        assert not np.array_equal(a["force_measured"], b["force_measured"])


def test_a_rerun_runs_nothing_new(small):
    sweep, first, root = small
    before = (root / "out" / "results.csv").read_text()
    again = run_sweep(sweep, root / "out", workers=2)
    assert again.ran == 0 and again.skipped == 8 and again.workers == 0
    assert (root / "out" / "results.csv").read_text() == before


def test_the_maps_and_the_page_show_the_right_cells(small):
    sweep, result, root = small
    out = root / "out"
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert len(pngs) == 2, pngs
    html = (out / "sweep.html").read_text()
    for png in pngs:
        assert f"src='{png}'" in html or f'src="{png}"' in html
    for row in result.rows:
        assert row["point"] in html
    heat = plot_heat_map(Figure().add_subplot(), result.rows, "steady_force_n",
                         "environment.stiffness", "environment.damping")
    assert list(heat.x_values) == [7000.0, 1e9] and list(heat.y_values) == [20.0, 50.0]
    # The stiff column diverged in every seed: marked; the soft one is not.
    assert heat.marked[:, 1].all() and not heat.marked[:, 0].any()
    assert np.isnan(heat.values[:, 1]).all()  # a truncated run's metric is no value
    soft = [r["steady_force_n"] for r in result.rows
            if r["environment.stiffness"] == 7000.0 and r["environment.damping"] == 20.0]
    assert heat.values[0, 0] == pytest.approx(np.mean(soft))
    # The same map as Markdown: the stiff column's cells say both seeds
    # diverged; the line plot's table pools the seeds of both walls at B_e 20.
    table = [line for line in (out / "maps.md").read_text().splitlines()
             if line.startswith("| 20 |")]
    assert len(table) == 2 and table[0].endswith("diverged 2/2 |"), table
    assert table[1].endswith("diverged 2/4 | 30.3 to 30.3 | 4 |"), table


def test_a_worker_killed_mid_point_loses_no_point(tmp_path):
    from distributed import Client, LocalCluster
    (tmp_path / "kill.yaml").write_text("""
scenario: push_constant
duration: 4.0
grid:
  environment.stiffness: [5000.0, 6000.0, 7000.0, 8000.0, 9000.0, 10000.0]
seeds: [0]
""")
    sweep = load_sweep(tmp_path / "kill.yaml")
    out = tmp_path / "out"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster, Client(cluster) as client:
        pids = list(client.run(os.getpid).values())
        done = []
        thread = threading.Thread(target=lambda: done.append(
            run_sweep(sweep, out, scheduler=cluster.scheduler_address, figures=False)))
        thread.start()
        # Kill a worker while its point is simulating: a run folder with its
        # scenario written and no metrics yet.
        deadline = time.monotonic() + 120
        while not any((d / "scenario.yaml").exists() and not (d / "metrics.json").exists()
                      for d in out.glob("runs/*")):
            assert time.monotonic() < deadline, "no point started"
            time.sleep(0.05)
        time.sleep(0.3)
        os.kill(pids[0], signal.SIGKILL)
        thread.join(timeout=300)
    (result,) = done
    rows = read_csv(out / "results.csv")
    assert len(rows) == 6 == len({r["point"] for r in rows})
    assert all(r["status"] == "completed" for r in rows), [r["message"] for r in rows]
    assert result.ran == 6


def test_points_are_named_by_their_values():
    task = Task({"environment.stiffness": 7000.0, "controller.nn.learning_rate": 5e-5}, 2)
    assert task.name == "environment.stiffness=7000__controller.nn.learning_rate=5e-05__seed=2"
    assert task.overrides() == ["environment.stiffness=7000.0",
                                "controller.nn.learning_rate=5e-05"]


@pytest.mark.parametrize("text,words", [
    ("scenario: push_constant\ngrid: {environment.stifness: [1.0]}",
     "environment.stifness is not a scenario key"),
    ("scenario: push_constant\ngrid: {environment.stiffness: [-1.0]}",
     "environment.stiffness = -1.0 is out of range"),
    ("scenario: push_constant\ngrid: {environment.stiffness: {log: [0, 1, 3]}}",
     "sweep.grid.environment.stiffness = "),
    ("scenario: push_constant\ngrid: {environment.stiffness: [1.0]}\nseeds: [-1]",
     "sweep.seeds = [-1] is out of range"),
    ("scenario: push_constant\ngrid: {environment.stiffness: [1.0]}\nmaps: [{metric: a, x: b}]",
     "sweep.maps[0].x = 'b' is not a varied field"),
    ("scenario: push_constant\ngird: {}", "sweep.gird is not a sweep key"),
    ("scenario: push_constant\ngrid: {environment.stiffness: [1.0]}\nbaseline: 1",
     "sweep.baseline = 1 must be true or false"),
])
def test_bad_sweeps_exit_2_with_one_line_naming_the_field(tmp_path, text, words):
    (tmp_path / "bad.yaml").write_text(text)
    result = subprocess.run([sys.executable, "-m", "drake_contact", "sweep",
                             str(tmp_path / "bad.yaml"), "--out", str(tmp_path / "o")],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and words in result.stderr, result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", sorted(p.stem for p in sweeps_dir().glob("*.yaml")))
def test_bundled_sweeps_load_in_full_and_quick(name):
    full, quick = load_sweep(name), load_sweep(name, quick=True)
    assert len(quick.tasks()) <= 4 < len(full.tasks())
    assert full.maps and all(m.metric for m in full.maps)


def test_the_quick_stability_map_runs_from_the_command_line(tmp_path):
    """CI's short version of the bundled stability_nn map."""
    out = tmp_path / "nn"
    result = subprocess.run([sys.executable, "-m", "drake_contact", "sweep", "stability_nn",
                             "--quick", "--workers", "2", "--out", str(out)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "4 runs (4 points x 1 seeds)" in result.stdout
    rows = read_csv(out / "results.csv")
    assert len(rows) == 4 and all(r["status"] in ("completed", "lost_contact") for r in rows)
    assert all(r["contact_time_s"] for r in rows)  # every point reached the wall
    assert (out / "sweep.html").is_file() and len(list(out.glob("*.png"))) == 3
