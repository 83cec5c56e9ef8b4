"""A campaign never hides a failure: a configuration that cannot be built is
refused before any run, in run's one line, exit 2; a run that raises or
whose worker dies is counted as failed in the summary, left unranked on the
leaderboard and makes the command exit 1 (unless --allow-failures); a
diverged run is a result (exit 0). The plug-ins are test_plugins.py's
broken ones."""

import csv
import os
import subprocess
import sys
import time

import pytest

from drake_contact import MakeContactDiagram, ScenarioError, load_scenario
from drake_contact.app import benchmark
from drake_contact.app.benchmark import Suite
from drake_contact.app.campaign import Point, check_configurations
from drake_contact.app.cli import EXIT_BAD_INPUT, EXIT_FAILED, main
from drake_contact.app.fault_study import (
    Suite as FaultSuite, aggregate as fault_table, markdown as fault_markdown)
from drake_contact.app.sweep import load_sweep
from test_plugins import broken_plugins  # noqa: F401 - a fixture

#: Dask workers are new processes: they find the plug-ins on PYTHONPATH.
pytestmark = pytest.mark.xdist_group("test_campaign_failures")

#: A refusal is a build or two, not a run: it must come well within this (s),
#: interpreter start and imports included.
REFUSAL_S = 30.0


def _env(site):
    return dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(site), os.environ.get("PYTHONPATH", "")]))


def _read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("command", ["benchmark", "sweep", "faults"])
def test_a_plugin_with_a_former_port_name_is_refused_before_any_run(
        broken_plugins, tmp_path, command):
    """The issue's new user: a plug-in written against the earlier port names
    (an input ``force``) exits 2 with the line ``run`` prints, before the
    cluster starts or any folder is made."""
    with pytest.raises(ScenarioError) as refused:
        MakeContactDiagram(load_scenario("nn_styrofoam", ["controller.name=former_name"]))
    expected = f"drake-contact: {refused.value}"
    assert "input port 'force'" in expected
    sweep = tmp_path / "former.yaml"
    sweep.write_text("scenario: nn_styrofoam\nset: [controller.name=former_name]\n"
                     "grid: {environment.stiffness: [7000.0, 20000.0]}\n")
    args = {"benchmark": ["benchmark", "--suite", "quick", "--controllers",
                          "former_name,hybrid"],
            "sweep": ["sweep", str(sweep)],
            "faults": ["faults", "--suite", "quick", "--controllers", "hybrid,former_name"]}
    out = tmp_path / "out"
    started = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "drake_contact", *args[command], "--out",
                             str(out), "--workers", "1"], env=_env(broken_plugins),
                            capture_output=True, text=True, timeout=300)
    elapsed = time.perf_counter() - started
    assert result.returncode == EXIT_BAD_INPUT, result.stderr
    assert result.stderr.splitlines() == [expected]
    assert result.stdout == ""
    assert not any(out.rglob("*")), "a run or its folder was made before the refusal"
    assert elapsed < REFUSAL_S
    print(f"{command}: refused in {elapsed:.1f} s")


@pytest.mark.parametrize("campaign", ["standard benchmark", "stability_nn sweep"])
def test_the_pre_check_builds_each_structure_once_and_quickly(campaign):
    """Timed on the campaigns' own points, without running them: the
    standard benchmark (every wall of a contender's task shares one build)
    and the full stability_nn map (one build per learning rate)."""
    if campaign == "standard benchmark":
        standard = benchmark.BenchmarkCampaign("standard")
        points = standard.points()
        builds = len(standard.contenders) * len(standard.suite.tasks)
    else:
        from drake_contact.app.sweep import SweepCampaign
        sweep = load_sweep("stability_nn")
        points = SweepCampaign(sweep).points()
        builds = len(sweep.grid["controller.nn.learning_rate"])
    started = time.perf_counter()
    assert check_configurations(points) == builds
    elapsed = time.perf_counter() - started
    print(f"{campaign}: {len(points)} points, {builds} builds in {elapsed:.1f} s")
    # Far below one run of either (a minute or more), and linear in builds.
    assert elapsed < 0.2 * len(points)


def test_a_configuration_that_loads_but_does_not_build_names_its_port(broken_plugins):
    good = Point("good", "push_constant")
    bad = Point("bad", "push_constant", ("controller.name=no_torque",))
    assert check_configurations([good, good]) == 1
    with pytest.raises(ScenarioError, match="has no output port 'joint_torque_commanded'"):
        check_configurations([good, bad])


#: Two walls the tripwire plug-in tells apart (it raises on the soft one
#: only), 20 N held, 2.6 s: the push touches at about 2.15 s.
TINY = Suite(walls=((5000.0, 30.0), (60000.0, 200.0)), tasks=("hold",), duration_s=2.6,
             window_s=(0.1, 0.4))


def test_a_contender_raising_on_one_wall_is_failed_unranked_and_exits_1(
        broken_plugins, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PYTHONPATH", _env(broken_plugins)["PYTHONPATH"])
    monkeypatch.setitem(benchmark.SUITES, "tiny", TINY)
    out = tmp_path / "bench"
    args = ["benchmark", "--suite", "tiny", "--controllers", "trips,hybrid", "--out", str(out),
            "--workers", "1"]
    assert main(args) == EXIT_FAILED
    stdout, stderr = capsys.readouterr()
    runs = {(r["contender"], r["wall"]): r for r in _read(out / "runs.csv")}
    assert runs[("trips", "0")]["status"] == "failed"
    assert "RuntimeError: tripped at t = 2." in runs[("trips", "0")]["message"]
    # On the stiff wall the plug-in held 20 N: by the runs alone it would
    # rank first, hybrid never touching the wall in 2.6 s.
    assert runs[("trips", "1")]["status"] == "completed"
    assert {runs[("hybrid", w)]["status"] for w in "01"} == {"no_contact"}
    board = {(e["contender"], e["task"]): e for e in _read(out / "leaderboard.csv")}
    assert board[("hybrid", "hold")]["rank"] == "1" and board[("hybrid", "all")]["rank"] == "1"
    assert board[("trips", "hold")]["rank"] == "" and board[("trips", "all")]["rank"] == ""
    assert board[("trips", "all")]["runs_failed"] == "1"
    assert board[("trips", "all")]["runs_diverged"] == "0"
    text = (out / "leaderboard.md").read_text()
    assert "| failed 1/2 | trips |" in text
    assert text.index("| 1 | hybrid |") < text.index("| failed 1/2 | trips |")
    assert "4 runs (4 now, 0 from before)" in stdout and "1 failed, 0 diverged" in stdout
    assert "  -. trips              FAILED 1/2 runs, not ranked" in stdout
    assert stdout.index(". hybrid") < stdout.index(". trips")
    assert stderr.splitlines()[-1].startswith(
        "drake-contact: 1 of 4 runs failed, first trips/hold/wall0_K5000_B30: RuntimeError")
    # --allow-failures: the failed run is tried again, fails again, and is
    # still shown as failed; the command exits 0.
    assert main(args + ["--allow-failures"]) == 0
    stdout, _ = capsys.readouterr()
    assert "4 runs (1 now, 3 from before)" in stdout and "1 failed" in stdout


def test_a_point_whose_worker_dies_each_time_is_failed_and_exits_1(
        broken_plugins, tmp_path, monkeypatch, capsys):
    """Dask gives up on a task after ``allowed-failures`` worker deaths; 0
    here, to give up at the first (the engine's handling is the same). The
    point that lives runs first: Dask counts a death against every task the
    worker held, queued ones too."""
    import dask
    # distributed's defaults must be in dask.config before the set below, or
    # leaving it removes them all.
    import distributed  # noqa: F401
    monkeypatch.setenv("PYTHONPATH", _env(broken_plugins)["PYTHONPATH"])
    (tmp_path / "dies.yaml").write_text(
        "scenario: push_constant\nset: [controller.name=dies]\nduration: 0.5\n"
        "grid: {controller.options.die_at_s: [10.0, 0.2]}\n")
    out = tmp_path / "out"
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        status = main(["sweep", str(tmp_path / "dies.yaml"), "--out", str(out),
                       "--workers", "1"])
    assert status == EXIT_FAILED
    stdout, stderr = capsys.readouterr()
    rows = {r["controller.options.die_at_s"]: r for r in _read(out / "results.csv")}
    assert rows["0.2"]["status"] == "failed" and "KilledWorker" in rows["0.2"]["message"]
    assert rows["10.0"]["status"] == "completed"
    assert "2 runs (2 points x 1 seeds): 1 completed, 1 failed" in stdout
    assert "KilledWorker" in stderr.splitlines()[-1]


def test_a_diverging_wall_is_a_result_not_a_failure(tmp_path, capsys):
    """push_constant on a 1e9 N/m wall diverges within milliseconds of the
    touch (2.15 s): a diverged row, exit 0."""
    (tmp_path / "stiff.yaml").write_text(
        "scenario: push_constant\nduration: 2.3\n"
        "grid: {environment.stiffness: [7000.0, 1.0e+9]}\n")
    out = tmp_path / "out"
    assert main(["sweep", str(tmp_path / "stiff.yaml"), "--out", str(out),
                 "--workers", "1"]) == 0
    stdout, stderr = capsys.readouterr()
    statuses = sorted(r["status"] for r in _read(out / "results.csv"))
    assert statuses == ["completed", "diverged"]
    assert "1 completed, 1 diverged" in stdout and "failed" not in stdout
    assert stderr == ""


def test_the_fault_table_shows_failed_and_diverged_runs_apart():
    def row(status, wall):
        return {"contender": "nn", "safety": "off", "fault": "gain", "wall": wall,
                "status": status, "peak_force_n": 60.0 if status == "diverged" else None,
                "past_limit": status == "diverged", "recovery_s": None, "contact_losses": 0,
                "ended_safe": False, "safety_stop": None}
    table = fault_table([row("failed", 0), row("diverged", 1), row("completed", 2)],
                        ["nn"], ["gain"])
    off = table[0]
    assert (off["runs"], off["runs_failed"], off["runs_diverged"]) == (3, 1, 1)
    assert off["runs_past_limit"] == 1  # the diverged run is scored
    text = fault_markdown([off, off | {"safety": "on"}], ["nn"],
                          FaultSuite(walls=((1.0, 1.0),), cases=("gain",), duration_s=1.0))
    assert "**failed 1/3**" in text and "1 diverged" in text and "rec 0/2" in text
