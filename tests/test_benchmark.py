"""drake-contact benchmark: contenders, the ranking, and a quick suite end to
end with the example plug-in (pip-installed by the README's test command)."""

import csv
import subprocess
import sys

import numpy as np
import pytest

from drake_contact import ScenarioError, load_scenario
from drake_contact.app.benchmark import (
    SCENARIO_CONTENDERS, SUITES, TASKS, Run, aggregate, contender_names, contender_scenario,
    markdown, seed_families)
from drake_contact.scoring.metrics import step_metrics


def test_default_contenders_are_the_thesis_robust_and_installed_ones_but_push():
    names = contender_names()
    assert names[:len(SCENARIO_CONTENDERS)] == list(SCENARIO_CONTENDERS)
    assert {"impedance", "admittance", "parallel_force", "jt_pi", "learned_residual"} <= set(names)
    # Harnesses, and the policy controller without a policy, are not.
    assert "push" not in names and "policy" not in names
    with pytest.raises(ScenarioError, match="--controllers: 'pid' is neither"):
        contender_names("hybrid,pid")


def test_a_contender_brings_its_controller_and_nothing_of_the_task():
    data = contender_scenario("nn_robust")
    assert data["controller"]["nn"]["leakage"] == 2.0
    assert data["arm"]["motor_torque_scale"] == [1.0, 1.2, 1.0]  # the suite's plant
    run = Run("nn_robust", "drift", 3, 12000.0, 150.0)
    scenario = load_scenario(data, run.overrides(SUITES["standard"]), seed=run.seed)
    assert scenario.environment.stiffness == 12000.0
    assert scenario.environment.stiffness_drift_per_s == 0.01
    assert scenario.simulation.seed == 3
    assert scenario.force_reference.levels == [20.0, 10.0]
    plugin = load_scenario(contender_scenario("admittance"))
    assert plugin.controller.name == "admittance" and plugin.controller.options == {}
    assert contender_scenario("adaptive_hybrid")["identifiers"]


def _row(contender, task, rmse, status="completed"):
    return {"contender": contender, "task": task, "status": status, "force_rmse_n": rmse}


def test_a_contact_loss_ranks_below_any_rmse_and_the_overall_rank_is_the_mean():
    rows = [_row("a", "hold", 0.1, "lost_contact"), _row("a", "hold", 0.1),
            _row("b", "hold", 3.0), _row("b", "hold", 4.0),
            _row("a", "square", 1.0), _row("a", "square", 1.0),
            _row("b", "square", 2.0), _row("b", "square", 2.0)]
    board = aggregate(rows, ["a", "b"], ["hold", "square"])
    rank = {(e["contender"], e["task"]): e["rank"] for e in board}
    assert rank[("b", "hold")] == 1 and rank[("a", "hold")] == 2
    assert rank[("a", "square")] == 1
    overall = {e["contender"]: e for e in board if e["task"] == "all"}
    assert overall["a"]["mean_rank"] == overall["b"]["mean_rank"] == 1.5
    assert overall["a"]["runs_losing_contact"] == 1
    hold_b = next(e for e in board if e["contender"] == "b" and e["task"] == "hold")
    assert hold_b["force_rmse_n_median"] == 3.5 and hold_b["force_rmse_n_worst"] == 4.0


def test_contenders_of_one_method_by_training_seed_are_summarized_over_seeds():
    rows = ([_row("ppo_s0", "hold", 1.0), _row("ppo_s0", "hold", 3.0, "lost_contact"),
             _row("ppo_s1", "hold", 2.0), _row("ppo_s1", "hold", 2.0),
             _row("ppo_s2", "hold", 4.0), _row("ppo_s2", "hold", 5.0),
             _row("lone_s0", "hold", 1.0), _row("lone_s0", "hold", 1.0),
             _row("hybrid", "hold", 0.5), _row("hybrid", "hold", 0.5)])
    contenders = ["ppo_s0", "ppo_s1", "ppo_s2", "lone_s0", "hybrid"]
    board = aggregate(rows, contenders, ["hold"])
    families = seed_families(board)
    assert [method for method, _ in families] == ["ppo"]  # one seed is no spread
    assert [e["contender"] for e in families[0][1]] == ["ppo_s0", "ppo_s1", "ppo_s2"]
    text = markdown(board, "quick", SUITES["quick"])
    line = next(line for line in text.splitlines() if line.startswith("| ppo |"))
    # Ranks: hybrid 1, lone_s0 2, ppo_s1 3 (2.0), ppo_s2 4 (4.5), ppo_s0 5 (a loss).
    # Median RMSE per seed: 2.0, 2.0, 4.5 -> median 2.0, worst 4.5.
    assert line == "| ppo | 3 | 5, 3, 4 | 1/2, 0/2, 0/2 | 2.00 | 4.50 |"
    assert "## Over training seeds" in text


def test_step_metrics_of_a_first_order_response_by_hand():
    t = np.arange(0, 10, 0.001)
    desired = np.where(t % 5 < 2.5, 20.0, 10.0)
    force = np.empty_like(t)
    force[0] = 20.0
    for i in range(1, len(t)):  # tau = 0.1 s: within 1 N of a 10 N step after 0.1 ln 10 s
        force[i] = force[i - 1] + (desired[i] - force[i - 1]) * 0.001 / 0.1
    force[5800] += 3.0  # 3 N past the 20 N level once, 0.8 s after the step up at 5 s
    out = step_metrics({"t": t, "contact_force_true": force, "force_desired": desired}, t >= 1.0)
    assert out["step_count"] == 3
    assert out["step_overshoot_max_pct"] == pytest.approx(
        100 * (force[5800] - 20.0) / 10.0)
    assert out["step_overshoot_pct"] == 0.0  # the median of the three steps
    assert out["step_settling_s"] == pytest.approx(0.1 * np.log(10), abs=0.002)
    assert out["step_unsettled"] == 0


#: The quick suite's contenders below.
CONTENDERS = ("hybrid", "jt_pi", "learned_residual")


def test_quick_suite_ranks_the_example_plugins_beside_the_thesis_controller(tmp_path):
    """jt_pi and the trained policy learned_residual (examples/), both
    installed by the README's test command, ranked beside hybrid."""
    out = tmp_path / "bench"
    result = subprocess.run(
        [sys.executable, "-m", "drake_contact", "benchmark", "--suite", "quick", "--out",
         str(out), "--controllers", ",".join(CONTENDERS), "--identifiers", "rls,rls_matched",
         "--workers", "2"],
        cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    with (out / "leaderboard.csv").open() as f:
        board = list(csv.DictReader(f))
    quick = SUITES["quick"]
    assert {(e["contender"], e["task"]) for e in board} == {
        (c, t) for c in CONTENDERS for t in (*quick.tasks, "all")}
    with (out / "runs.csv").open() as f:
        runs = list(csv.DictReader(f))
    assert len(runs) == len(CONTENDERS) * len(quick.tasks) * len(quick.walls)
    assert all(r["status"] in ("completed", "lost_contact") for r in runs)
    assert all(float(r["force_rmse_n"]) > 0 for r in runs)
    text = (out / "leaderboard.md").read_text()
    assert "| jt_pi |" in text and f"## square: {TASKS['square'][0]}" in text
    assert "| learned_residual |" in text
    html = (out / "leaderboard.html").read_text()
    assert html.count("data:image/png;base64,") == len(quick.tasks)
    # The identifiers: one run per task and wall, both side by side, scored
    # on the true wall; the matched RLS (ours) settles within 5 % on both
    # walls of the square wave, and on both of `hold` too (a held force
    # excites little beyond the impact, so that is the harder task).
    with (out / "identifier_leaderboard.csv").open() as f:
        ids = {(e["identifier"], e["task"]): e for e in csv.DictReader(f)}
    assert ids[("rls_matched", "square")]["runs_settled_5pct"] == "2"
    assert ids[("rls_matched", "all")]["runs_settled_5pct"] == "4"
    assert float(ids[("rls_matched", "all")]["stiffness_abs_error_pct_median"]) < 5.0
    assert "# Identifiers" in text
    # Rerunning the command runs nothing again.
    again = subprocess.run(
        [sys.executable, "-m", "drake_contact", "benchmark", "--suite", "quick", "--out",
         str(out), "--controllers", ",".join(CONTENDERS), "--identifiers", "rls,rls_matched"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and "16 runs (0 now, 16 from before)" in again.stdout


def test_bad_benchmark_input_exits_2_in_one_line(tmp_path):
    for args, message in [(["--controllers", "pid"], "--controllers: 'pid' is neither"),
                          (["--suite", "huge"], "--suite = huge is unknown"),
                          (["--identifiers", "ols"], "--identifiers: 'ols' is not an"),
                          (["--workers", "0"], "--workers = 0 is out of range")]:
        result = subprocess.run(
            [sys.executable, "-m", "drake_contact", "benchmark", "--out", str(tmp_path / "o"),
             *args], cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert result.returncode == 2 and message in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_an_identifier_with_a_failed_run_is_not_ranked():
    """As the controllers' board: an identifier contender whose run failed
    (no metrics: it raised, or its worker died) is shown ``failed k/n``,
    after every ranked one, never ranked above one that completed."""
    from drake_contact.app.benchmark import aggregate_identifiers, identifier_markdown

    def row(name, wall, status, error):
        return {"identifier": name, "task": "hold", "wall": wall, "status": status,
                "stiffness_error_pct": error, "stiffness_error_1s_pct": error,
                "damping_error_pct": None, "mass_kg": None,
                "settling_s": None if error is None else 0.1}
    # a is better where it ran, but one of its runs failed.
    rows = [row("a", 0, "completed", 1.0), row("a", 1, "failed", None),
            row("b", 0, "completed", 4.0), row("b", 1, "completed", 4.0)]
    board = aggregate_identifiers(rows, ["a", "b"], ["hold"])
    by = {(e["identifier"], e["task"]): e for e in board}
    assert by["b", "hold"]["rank"] == 1 and by["a", "hold"]["rank"] is None
    assert by["b", "all"]["rank"] == 1 and by["a", "all"]["rank"] is None
    assert by["a", "all"]["runs_failed"] == 1 and by["b", "all"]["runs_failed"] == 0
    text = identifier_markdown(board, ["hold"])
    assert text.index("| 1 | b |") < text.index("| failed 1/2 | a |")
