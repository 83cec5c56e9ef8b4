"""The campaign engine, extended the documented way: a campaign declared in
the test (its points, scores, an aggregate table and a report) runs on a
Dask LocalCluster, several points per task; a point whose configuration
does not load is refused before any run; rerunning resumes; the tables are
the CSV files. (Runs that raise or whose worker dies: test_campaign_failures.py.)"""

import csv

import pytest

from drake_contact import ScenarioError
from drake_contact.app.campaign import (
    Campaign, Point, finished_metrics, run_campaign, run_status, write_csv)

pytestmark = pytest.mark.xdist_group("test_campaign")


# [docs: campaign]
class Stiffness(Campaign):
    """push_constant (2.4 s: it touches at 2.1 s) on walls of three
    stiffnesses."""

    name = "stiffness"
    columns = {"runs": ["wall", "status"], "summary": ["completed"]}

    def points(self):
        return [Point(f"k{k:g}", "push_constant", ("simulation.duration=2.4",
                                                   f"environment.stiffness={k}"), seed=1)
                for k in (5000.0, 7000.0, 9000.0)]

    def score(self, point, run_dir):
        metrics = finished_metrics(run_dir)
        row = {"wall": point.name, "status": "failed" if metrics is None else run_status(metrics)}
        if metrics is not None:
            row["peak_force_n"] = metrics["peak_force_n"]
        return {"runs": [row]}

    def aggregate(self, tables):
        return {"summary": [{"completed": sum(r["status"] == "completed"
                                              for r in tables["runs"])}]}

    def resolved(self):
        return {"walls": [5000.0, 7000.0, 9000.0]}

    def report(self, out, result):
        (out / "report.md").write_text(f"{result.tables['summary'][0]['completed']} completed\n")
# [docs: end]


def _read(path):
    with path.open() as f:
        return list(csv.DictReader(f))


def test_a_campaign_declared_in_a_few_lines_runs_scores_and_resumes(tmp_path):
    seen = []
    result = run_campaign(Stiffness(), tmp_path, workers=2, points_per_task=2,
                          progress=lambda done, failed, total, eta, name: seen.append(name))
    assert (result.ran, result.skipped, result.workers) == (3, 0, 2)
    assert (result.checked, result.failed, result.diverged) == (1, {}, [])
    assert sorted(seen) == ["k5000", "k7000", "k9000"]
    runs = _read(tmp_path / "runs.csv")
    assert [r["wall"] for r in runs] == ["k5000", "k7000", "k9000"]  # the plan's order
    assert [r["status"] for r in runs] == ["completed"] * 3
    peaks = [float(r["peak_force_n"]) for r in runs]
    assert all(p > 0 for p in peaks)
    assert _read(tmp_path / "summary.csv") == [{"completed": "3"}]
    assert (tmp_path / "report.md").read_text() == "3 completed\n"
    assert "walls:" in (tmp_path / "stiffness.yaml").read_text()
    assert (tmp_path / "runs" / "k5000" / "run.log").read_text().startswith("completed")
    # Rerun: the finished points are skipped, and not checked again.
    again = run_campaign(Stiffness(), tmp_path, workers=1)
    assert (again.ran, again.skipped, again.checked) == (0, 3, 0)
    assert _read(tmp_path / "runs.csv") == runs


def test_a_point_that_does_not_load_stops_the_campaign_before_any_run(tmp_path):
    class WithATypo(Stiffness):
        def points(self):
            return super().points() + [Point("bad", "push_constant",
                                             ("environment.stifness=1",))]

    with pytest.raises(ScenarioError, match="environment.stifness is not a scenario key"):
        run_campaign(WithATypo(), tmp_path / "out", workers=1)
    assert not (tmp_path / "out").exists()


def test_csv_tables_put_their_first_columns_first(tmp_path):
    path = write_csv([{"b": 1, "a": None, "z": 2.5}, {"c": "x"}], tmp_path / "t.csv", ["z"])
    assert path.read_text().splitlines() == ["z,a,b,c", "2.5,,1,", ",,,x"]
    assert not (tmp_path / "t.csv.partial").exists()


def test_two_points_with_one_name_are_refused(tmp_path):
    class Twice(Stiffness):
        def points(self):
            return [Point("same", "push_constant"), Point("same", "push_constant")]

    with pytest.raises(ValueError, match="two points share a name"):
        run_campaign(Twice(), tmp_path)


def test_packed_points_write_the_logs_they_write_alone(tmp_path, monkeypatch):
    import numpy as np
    from drake_contact.app import campaign
    from drake_contact.app.campaign import ensemble_packs
    # Three points pack only below the default's smallest ensemble.
    assert [len(pack) for pack in ensemble_packs(
        [(p, tmp_path / p.name) for p in Stiffness().points()], 16, workers=1)] == [1, 1, 1]
    monkeypatch.setattr(campaign, "MIN_ENSEMBLE", 2)
    packed = run_campaign(Stiffness(), tmp_path / "packed", workers=1, ensemble=16)
    alone = run_campaign(Stiffness(), tmp_path / "alone", workers=1, ensemble=1)
    assert packed.tables["runs"] == alone.tables["runs"]
    assert "ensemble of 3" in (tmp_path / "packed/runs/k5000/run.log").read_text()
    for wall in ("k5000", "k7000", "k9000"):
        with np.load(tmp_path / "packed/runs" / wall / "log.npz") as a, \
                np.load(tmp_path / "alone/runs" / wall / "log.npz") as b:
            assert a.files == b.files
            for key in a.files:
                np.testing.assert_array_equal(a[key], b[key], err_msg=f"{wall} {key}")
    # Packs: points sharing a controller, an even share per worker as far as
    # each pack keeps MIN_ENSEMBLE (here 2: three points are one pack, not
    # two and one); a point that does not load is alone.
    points = [(p, tmp_path / p.name) for p in Stiffness().points()]
    points.append((Point("bad", "push_constant", ("environment.stifness=1",)), tmp_path / "bad"))
    assert [[p.name for p, _ in pack] for pack in ensemble_packs(points, 16, workers=2)] == [
        ["k5000", "k7000", "k9000"], ["bad"]]
    assert [len(pack) for pack in ensemble_packs(points, 1, workers=1)] == [1, 1, 1, 1]


def test_a_packs_baselines_run_as_an_ensemble_and_write_what_they_write_alone(tmp_path,
                                                                            monkeypatch):
    """The hybrid-only baselines of a pack's nn runs run as one ensemble
    after it: each run's baseline log and baseline_* metrics are its run
    alone's, bit for bit."""
    import json

    import numpy as np
    import drake_contact as dc
    from drake_contact.app import runner
    scenarios = [dc.load_scenario("nn_styrofoam", [
        "controller.hybrid.approach.hold_time_s=0.1",
        "controller.hybrid.approach.step_period_s=0.15", f"environment.stiffness={k}",
        "scoring.window_start_s=0.05", "scoring.window_end_s=0.1"], duration=1.2, seed=seed)
        for seed, k in ((3, 7000.0), (4, 12000.0))]
    calls = []
    ensemble = runner.simulate_ensemble
    monkeypatch.setattr(runner, "simulate_ensemble",
                        lambda s, **k: calls.append(len(s)) or ensemble(s, **k))
    packed = runner.run_ensemble(scenarios, [tmp_path / "packed" / f"{i}" for i in range(2)],
                                 baselines=["window", "window"], pack_baselines=2)
    assert calls == [2, 2]  # the runs, then their baselines
    for i, scenario in enumerate(scenarios):
        runner.run(scenario, tmp_path / "alone" / f"{i}", figures=False, baseline="window")
        for folder in ("", "baseline"):
            with np.load(tmp_path / "packed" / f"{i}" / folder / "log.npz") as a, \
                    np.load(tmp_path / "alone" / f"{i}" / folder / "log.npz") as b:
                assert a.files == b.files
                for key in a.files:
                    np.testing.assert_array_equal(a[key], b[key], err_msg=f"{i} {folder} {key}")
        metrics = [json.loads((tmp_path / kind / f"{i}" / "metrics.json").read_text())
                   for kind in ("packed", "alone")]
        base = {k: v for k, v in metrics[1].items() if k.startswith("baseline_")}
        assert base and all(metrics[0][k] == v for k, v in base.items())
    assert packed[0].status == "completed"


def test_a_group_is_never_cut_below_the_smallest_ensemble_to_balance_the_workers(tmp_path):
    """Packs are spread evenly over the workers only where each stays an
    ensemble that pays (MIN_ENSEMBLE): 12 points of one structure on 2
    workers are one ensemble of 12 (the reproduction's nn_* runs), not two of
    6, which would run point by point; 16 are two of 8; 7 run alone."""
    from drake_contact.app.campaign import MIN_ENSEMBLE, ensemble_packs
    assert MIN_ENSEMBLE == 8
    points = [(Point(f"k{k}", "push_constant", (f"environment.stiffness={k}",)),
               tmp_path / f"k{k}") for k in range(5000, 21000, 1000)]
    assert [len(p) for p in ensemble_packs(points[:12], 64, workers=2)] == [12]
    assert [len(p) for p in ensemble_packs(points, 64, workers=2)] == [8, 8]
    assert [len(p) for p in ensemble_packs(points, 64, workers=4)] == [8, 8]
    assert [len(p) for p in ensemble_packs(points[:7], 64, workers=2)] == [1] * 7
    assert [len(p) for p in ensemble_packs(points[:12], 5, workers=2)] == [1] * 12


def test_ctrl_c_during_the_check_runs_nothing_and_still_reports(tmp_path, monkeypatch):
    from drake_contact.app import campaign

    def interrupted(points):
        raise KeyboardInterrupt
    monkeypatch.setattr(campaign, "check_configurations", interrupted)
    result = run_campaign(Stiffness(), tmp_path, workers=1)
    assert result.interrupted and (result.ran, result.workers) == (0, 0)
    assert (tmp_path / "report.md").read_text() == "0 completed\n"
    assert not any((tmp_path / "runs").iterdir())
