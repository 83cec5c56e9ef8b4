"""drake-contact faults: the cases, the table, and the quick suite end to end."""

import csv
import subprocess
import sys

import pytest

from drake_contact import ScenarioError, load_scenario
from drake_contact.app.benchmark import contender_scenario
from drake_contact.app.fault_study import (
    FAULT_START_S, FORCE_LIMIT_N, SUITES, Run, Suite, aggregate, check_contenders,
    fault_cases, markdown)
from drake_contact.faults import FAULT_KINDS


def test_the_standard_suite_covers_every_fault_kind_and_a_null_case():
    cases = fault_cases()
    kinds = {cases[c][1]["kind"] for c in SUITES["standard"].case_names if c != "none"}
    assert kinds == set(FAULT_KINDS)
    assert "none" in SUITES["standard"].case_names


@pytest.mark.parametrize("case", list(fault_cases()))
def test_every_case_loads_on_every_contender(case):
    run = Run("nn_robust", "on", case, 1, 25000.0, 90.0)
    scenario = load_scenario(contender_scenario("nn_robust"), run.overrides(SUITES["standard"]))
    fault = scenario.faults[0]
    assert fault.start_from == "contact" and fault.start_s == FAULT_START_S
    assert scenario.safety.enabled and scenario.safety.force_limit_n == FORCE_LIMIT_N
    assert scenario.environment.stiffness == 25000.0


def test_the_table_counts_runs_over_the_limit_and_recoveries():
    def row(safety, peak, recovery, wall):
        return {"contender": "nn", "safety": safety, "fault": "gain", "wall": wall,
                "status": "completed", "peak_force_n": peak, "past_limit": peak > 44.0,
                "recovery_s": recovery, "contact_losses": 0, "ended_safe": True,
                "safety_stop": None}
    rows = [row("off", 50.0, None, 0), row("off", 30.0, 0.4, 1),
            row("on", 35.0, 0.2, 0), row("on", 30.0, 0.6, 1)]
    table = aggregate(rows, ["nn"], ["gain"])
    off, on = table
    assert (off["runs_past_limit"], off["runs_recovered"], off["peak_force_n_worst"]) == (1, 1, 50.0)
    assert (on["runs_past_limit"], on["runs_recovered"], on["recovery_s_median"]) == (0, 2, 0.4)
    assert (on["recovery_s_worst"], on["peak_force_n_median"]) == (0.6, 32.5)
    text = markdown(table, ["nn"], Suite(walls=((1.0, 1.0),), cases=("gain",), duration_s=1.0))
    assert "| gain: " in text and "**1 over**" in text
    assert "32-35 N, rec 2/2 (0.40, worst 0.60 s)" in text


def test_bad_contenders_and_suites_are_refused():
    with pytest.raises(ScenarioError, match="--controllers: 'pid'"):
        check_contenders("nn,pid")
    result = subprocess.run([sys.executable, "-m", "drake_contact", "faults", "--out",
                             "/tmp/never", "--suite", "huge"], capture_output=True, text=True)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "drake-contact: --suite = huge is unknown: choose one of quick, standard"]


def test_the_quick_study_end_to_end(tmp_path):
    out = tmp_path / "faults"
    result = subprocess.run(
        [sys.executable, "-m", "drake_contact", "faults", "--out", str(out), "--suite", "quick",
         "--controllers", "nn_robust", "--workers", "2"],
        capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    rows = list(csv.DictReader((out / "runs.csv").open()))
    assert len(rows) == 4  # one wall, two cases, supervisor off and on
    assert all(r["status"] == "completed" for r in rows)
    by = {(r["fault"], r["safety"]): r for r in rows}
    # nn_robust recovers from the 50 ms dropout with the supervisor, and
    # the null fault's run is the reference
    assert float(by[("dropout_zero_50ms", "on")]["recovery_s"]) <= 1.0
    assert by[("none", "off")]["past_limit"] == "False"
    assert "| none: " in (out / "faults.md").read_text()
