"""``drake-contact reproduce``: the quick reproduction scores every thesis
result (the thesis's chapter 6) and passes; a Ctrl-C leaves logs and a partial report;
scoring marks missing runs instead of failing on them; each claim's text
lives once; the report embeds every figure and draws the diagram."""

import dataclasses as dc
import inspect
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import matplotlib.pyplot as plt
import numpy as np
import pytest

from conftest import ON_QUICK_REPRODUCTION, needs_tool
from drake_contact.app import reproduce
from drake_contact.app.claims import CLAIMS
from drake_contact.app.reproduce import JOBS, RESULTS, score, write_report

SCENARIOS = [job.scenario for job in JOBS]


def _status(seeds=(0,)):
    """write_report's status of runs that were never started."""
    return {(name, seed): None for name in SCENARIOS for seed in seeds}


def _table_rows(markdown, section="## Beyond the thesis"):
    """The cells of the first table after ``section``'s heading."""
    after = markdown.split(section + "\n", 1)[1].splitlines()
    start = next(i for i, line in enumerate(after) if line.startswith("| "))
    lines = []
    for line in after[start:]:
        if not line.startswith("|"):
            break
        lines.append(line)
    return [re.split(r"(?<!\\)\|", line.strip())[1:-1] for line in lines[2:]]


@ON_QUICK_REPRODUCTION
def test_quick_reproduction_fills_every_row_and_every_row_is_as_expected(quick_reproduction):
    out, result = quick_reproduction
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.count("0 not as expected") == 2  # the claims and the rows beyond
    markdown = (out / "report.md").read_text()
    # The claims first: every claim is scored on seed 0 or marked for the full run.
    assert markdown.index("## The thesis's claims") < markdown.index("## Beyond the thesis")
    claim_rows = _table_rows(markdown, "## The thesis's claims")
    assert [cells[0].strip() for cells in claim_rows] == [c.id for c in CLAIMS]
    for cells, claim in zip(claim_rows, CLAIMS):
        verdict = cells[-1].strip()
        if not claim.quick:
            assert verdict == "not scored in --quick", cells
        elif claim.calibration:
            assert verdict.startswith("calibration"), cells
        elif claim.deviation:
            assert verdict.startswith(("documented deviation", "holds on these seeds")), cells
        else:
            assert verdict == "reproduced", cells
    assert (out / "claims.csv").read_text().count("\n") == len(CLAIMS) + 1
    rows = _table_rows(markdown)
    assert len(rows) == len(RESULTS)
    for cells, result in zip(rows, RESULTS):
        assert len(cells) == 7
        assert all(cell.strip() for cell in cells), cells
        if result.expectation(quick=True):
            assert cells[-1].strip() == "PASS", cells
        else:
            assert "documented deviation" in cells[-1], cells
    report_html = (out / "report.html").read_text()
    reproduced = sum(result.expectation(quick=True) for result in RESULTS)
    assert report_html.count("class='pass'") == reproduced + sum(
        "reproduced" == cells[-1].strip() for cells in claim_rows)
    assert "Documented deviations" in report_html


@ON_QUICK_REPRODUCTION
def test_quick_reproduction_writes_the_figures_and_embeds_them(quick_reproduction):
    out, _ = quick_reproduction
    expected = {
        "identify_styrofoam": ["fig4_2_switch.png", "fig6_1_identification.png",
                               "fig6_2_identification.png", "fig6_3_identification.png",
                               "fig6_6_identification.png", "fig6_7_identification.png",
                               "fig6_8_nn_output_error.png"],
        "identify_rubber": ["fig6_4_identification.png", "fig6_5_identification.png",
                            "fig6_9_identification.png"],
        "sensor_spectrum": ["fig3_5_psd.png", "fig3_7_rc_gain.png", "fig4_4_raw_force.png"],
        "hybrid_p_only_styrofoam": ["fig6_10_force_tracking.png"],
        "nn_styrofoam": ["fig6_11_force_tracking.png", "fig6_11_nn_output.png"],
        "nn_small_lr": ["fig6_13_force_tracking.png"],
        "nn_rubber_sine": ["fig6_17_force_tracking.png"],
    }
    report = (out / "report.md").read_text()
    for name, figures in expected.items():
        for figure in figures:
            assert (out / name / "seed_0" / figure).stat().st_size > 10_000, (name, figure)
    for figure in ("fig6_1_identification.png", "fig6_9_identification.png",
                   "fig6_11_force_tracking.png", "fig3_5_psd.png"):
        assert f"{figure})" in report
    for material in ("styrofoam", "rubber"):
        assert (out / f"identify_{material}" / "seed_0" / "playback.html").stat().st_size > 100_000


def test_the_neural_controller_is_reported_window_by_window(tmp_path):
    """Seed 0's RMSE per 5 s window, its baseline and adaptation; over the
    seeds the 10-20 s range and each seed's first contact loss."""
    for seed, (rmse, loss) in enumerate([(1.52, 22.6), (1.49, None)]):
        folder = tmp_path / "nn_styrofoam" / f"seed_{seed}"
        folder.mkdir(parents=True)
        (folder / "metrics.json").write_text(json.dumps({
            "force_rmse_windows_n": [1.86, 1.62, 1.63, 1.40, 9.01, 3.0], "force_rmse_n": rmse,
            "baseline_force_rmse_n": 3.22, "adaptation_time_s": 18.0,
            "contact_losses": 0 if loss is None else 11, "first_contact_loss_s": loss}))
    table = reproduce.nn_window_table(tmp_path, (0, 1))
    assert table[0] == "## The neural controller, window by window"
    assert ("| `nn_styrofoam` | 1.86 | 1.62 | 1.63 | 1.40 | 9.01 | 1.52 | 3.22 | 18.0 | "
            "1.49 to 1.52 | 22.6, none |") in table
    assert not any("nn_rubber" in line for line in table)  # not run: no row
    assert reproduce.nn_window_table(tmp_path / "none", (0,)) == []


def test_scoring_marks_missing_runs_as_not_run(tmp_path):
    rows = score(tmp_path)
    assert [r.passed for r in rows] == [None] * len(RESULTS)
    path = write_report(tmp_path, rows, quick=True, status=_status(), interrupted=True)
    text = path.read_text()
    assert "INTERRUPTED" in text and text.count("not run") >= len(RESULTS)


def test_a_run_too_short_for_a_result_fails_that_row_without_crashing(tmp_path):
    for name in ("identify_styrofoam", "identify_rubber"):
        run_dir = tmp_path / name / "seed_0"
        run_dir.mkdir(parents=True)
        (run_dir / "metrics.json").write_text(json.dumps({"status": "completed"}))
    rows = {r.experiment: r for r in score(tmp_path, seeds=(0,))}
    assert rows["switch from approach to hybrid"].passed is False
    assert "mode_switches" in rows["switch from approach to hybrid"].measured
    assert rows["NN controller, + 4 sin(pi t)"].passed is None  # its runs are missing


def _default_sigint():
    """A shell starts background jobs with SIGINT ignored, and an ignored
    signal stays ignored across exec (CI may run the suite that way). A
    terminal's Ctrl-C reaches a foreground process: give the child the
    default disposition so Python turns SIGINT into KeyboardInterrupt."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_leaves_logs_and_a_partial_report(tmp_path):
    """SIGINT to the whole process group, as a terminal's Ctrl-C: the running
    scenarios stop and write their logs, the report is written, exit 130."""
    process = subprocess.Popen(
        [sys.executable, "-m", "drake_contact", "reproduce", "--quick", "--out", str(tmp_path),
         "--jobs", "2", "--seeds", "0"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True, preexec_fn=_default_sigint)
    # Wait until the first two scenarios are simulating: they start at once
    # and write scenario.yaml just before building their diagrams (about a
    # second); the longest, nn_small_lr, then simulates for its 85 s.
    first = [tmp_path / name / "seed_0" / "scenario.yaml" for name in SCENARIOS[:2]]
    deadline = time.monotonic() + 60
    while not all(p.exists() for p in first):
        assert time.monotonic() < deadline, "the first scenarios did not start"
        time.sleep(0.2)
    time.sleep(4.0)
    os.killpg(process.pid, signal.SIGINT)
    output, _ = process.communicate(timeout=120)
    assert process.returncode == 130, output
    report = (tmp_path / "report.md").read_text()
    assert "INTERRUPTED" in report
    statuses = {}
    for name in SCENARIOS[:2]:
        run = tmp_path / name / "seed_0"
        statuses[name] = json.loads((run / "metrics.json").read_text())["status"]
        assert (run / "log.npz").stat().st_size > 0
    # The long one was cut short; the other may have finished first.
    assert statuses[SCENARIOS[0]] == "interrupted", statuses
    assert statuses[SCENARIOS[1]] in ("interrupted", "completed"), statuses
    assert not (tmp_path / SCENARIOS[-1] / "seed_0" / "metrics.json").exists()


def test_results_keep_the_thesis_order():
    assert [result.claim.figures for result in RESULTS] == [
        "4.2", "6.1-6.3", "6.4-6.5", "6.6-6.8", "6.9", "6.11, 6.16", "6.12, 6.17"]


SENSOR_SPECTRUM_METRICS = {
    "status": "completed", "rest_noise_p99_n": 2.0, "rest_noise_std_n": 0.8,
    "psd_max_difference_below_100hz_db": 0.4, "line_480hz_above_floor_db": 12.0}


def _fake_runs(out):
    """A sensor_spectrum run that completed, with figures, and some PNGs of
    other runs that no row names (one in a baseline folder)."""
    figures = ["sensor_spectrum/seed_0/fig3_5_psd.png", "sensor_spectrum/seed_0/fig3_7_rc_gain.png",
               "sensor_spectrum/seed_0/fig4_4_raw_force.png",
               "sensor_spectrum/seed_0/main_signals.png",
               "identify_rubber/seed_0/fig6_5_identification.png",
               "identify_styrofoam/seed_0/fig6_2_identification.png",
               "identify_styrofoam/seed_0/fig6_12_extra.png",
               "nn_styrofoam/seed_0/fig6_11_nn_output.png",
               "nn_styrofoam/seed_0/baseline/fig6_11_force_tracking.png",
               "not_a_job/seed_0/fig9_9_other.png"]
    for figure in figures:
        (out / figure).parent.mkdir(parents=True, exist_ok=True)
        plt.imsave(out / figure, np.zeros((2, 2, 3)))
    (out / "sensor_spectrum" / "seed_0" / "metrics.json").write_text(
        json.dumps(SENSOR_SPECTRUM_METRICS))
    return figures


def test_every_row_states_its_claim_and_each_claim_is_written_once(tmp_path):
    _fake_runs(tmp_path)
    rows = score(tmp_path, seeds=(0,))
    assert [r.passed for r in rows] == [None] * len(RESULTS)  # their runs are missing
    for row, result in zip(rows, RESULTS, strict=True):
        assert (row.experiment, row.figures, row.thesis) == dc.astuple(result.claim)
    source = inspect.getsource(reproduce)
    for result in RESULTS:
        assert source.count(repr(result.claim.thesis)) + source.count(
            f"\"{result.claim.thesis}\"") == 1, result.claim
    assert len({result.claim.experiment for result in RESULTS}) == len(RESULTS)


@pytest.mark.parametrize("have_dot", [True, False])
def test_report_embeds_every_figure_and_draws_the_diagram(tmp_path, monkeypatch, have_dot):
    if have_dot:
        needs_tool("dot", "the report's diagram drawn by Graphviz")
    if not have_dot:
        monkeypatch.setattr(shutil, "which", lambda name: None)
        (tmp_path / "diagram.svg").write_text("stale")
    figures = _fake_runs(tmp_path)
    path = write_report(tmp_path, score(tmp_path, seeds=(0,)), quick=True, status=_status(),
                        seeds=(0,))
    markdown, page = path.read_text(), (tmp_path / "report.html").read_text()
    for figure in figures:
        assert markdown.count(f"]({figure})") == 1, figure
        assert page.count(f"<img src='{figure}'") == 1, figure
    assert ("![Fig 6.5: identification](identify_rubber/seed_0/fig6_5_identification.png)"
            in markdown)
    assert "Fig 6.11: force tracking (hybrid-only baseline)" in page
    # Runs in JOBS order; in a run, figures in number order (6.2 before 6.12).
    assert (page.index("fig6_2_identification") < page.index("fig6_12_extra")
            < page.index("fig6_5_identification") < page.index("fig9_9_other"))
    assert "name=force_sensor" in (tmp_path / "diagram.dot").read_text()
    assert "[diagram.dot](diagram.dot)" in markdown
    if have_dot:
        assert (tmp_path / "diagram.svg").read_text().lstrip().startswith("<?xml")
        assert "[diagram.svg](diagram.svg)" in markdown
        # The results first, then the drawing.
        assert page.index("<table>") < page.index("<img src='diagram.svg'")
    else:
        # A link to the DOT text, never the text itself.
        assert not (tmp_path / "diagram.svg").exists()
        assert "apt-get install graphviz" in markdown and "apt-get install graphviz" in page
        assert "<a href='diagram.dot'>" in page and "digraph" not in page
        assert page.index("<table>") < page.index("diagram.dot")


def test_the_long_run_scores_its_baseline_in_the_window_only():
    """nn_small_lr's hybrid-only baseline runs to 1 s past the scoring
    window (no row reads the rest); --quick shortens the long runs and runs
    no baselines; the first seed's identification runs record a playback."""
    jobs = {job.scenario: job for job in JOBS}
    full = reproduce.job_point(jobs["nn_small_lr"], 0, quick=False, first_seed=0)
    assert full.baseline == "window" and full.overrides == () and full.figures
    assert reproduce.job_point(jobs["nn_styrofoam"], 0, quick=False, first_seed=0).baseline \
        is None  # the runner's default: the whole baseline for the neural controller
    quick = reproduce.job_point(jobs["nn_small_lr"], 1, quick=True, first_seed=1)
    assert quick.baseline is False and quick.overrides == ("simulation.duration=85.0",)
    assert quick.name == "nn_small_lr/seed_1"
    assert reproduce.job_point(jobs["identify_rubber"], 1, quick=True, first_seed=1).record
    assert not reproduce.job_point(jobs["identify_rubber"], 2, quick=True, first_seed=1).record


def _switch_row(out, peaks_by_seed):
    """The switch row over seeds whose styrofoam switch peaked at ``peaks_by_seed``."""
    for seed, peak in enumerate(peaks_by_seed):
        for name in ("identify_styrofoam", "identify_rubber"):
            run = out / name / f"seed_{seed}"
            run.mkdir(parents=True)
            (run / "metrics.json").write_text(json.dumps({
                "status": "completed", "mode_switches": 1, "force_mean_n": 20.0,
                "impact_peak_force_n": peak if name == "identify_styrofoam" else 30.0}))
    rows = score(out, seeds=tuple(range(len(peaks_by_seed))))
    return {r.experiment: r for r in rows}["switch from approach to hybrid"]


def test_a_row_passes_only_when_every_seed_meets_every_bound_by_its_margin(tmp_path):
    row = _switch_row(tmp_path / "a", [30.0, 28.0, 33.0])
    assert row.passed is True and row.as_expected
    assert "peak force, styrofoam (N) 28 to 33" in row.measured
    assert "peak force, styrofoam (N) <= 40 by 4" in row.tolerance
    # One seed inside the margin: every seed meets the bound, not its margin.
    row = _switch_row(tmp_path / "b", [30.0, 37.0, 33.0])
    assert row.passed is False and row.marginal and not row.as_expected
    assert row.verdict() == "MARGINAL"
    # One seed beyond the bound.
    row = _switch_row(tmp_path / "c", [30.0, 41.0, 33.0])
    assert row.passed is False and not row.marginal and row.verdict() == "FAIL"


def test_a_documented_deviation_is_as_expected_while_it_deviates_and_not_when_it_passes():
    deviation = reproduce.Row("x", "1", "claim", "m", "t", "b", passed=False, expected=False,
                              deviation="the cause")
    assert deviation.as_expected and deviation.verdict() == "FAIL (documented deviation)"
    deviation.passed = True
    assert not deviation.as_expected
    assert deviation.verdict() == "PASS (a documented deviation now passes)"
    assert "1 not as expected (x)" in reproduce.summary_line([deviation])


def test_every_documented_deviation_states_its_cause_and_quick_expectations_are_explicit():
    for result in RESULTS:
        assert result.expected or len(result.deviation) > 40, result.claim
        assert result.expected_quick in (None, True, False)


@pytest.mark.parametrize("text, seeds", [("0-2", (0, 1, 2)), ("4", (4,)), ("0,5, 7", (0, 5, 7)),
                                         ("1-2,9", (1, 2, 9))])
def test_seeds_parse(text, seeds):
    assert reproduce.parse_seeds(text) == seeds


@pytest.mark.parametrize("text", ["", "a", "-1", "0,0", "3-1x"])
def test_bad_seeds_are_refused(text):
    with pytest.raises(ValueError):
        reproduce.parse_seeds(text)


def test_bad_seeds_exit_2_with_one_line(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "drake_contact", "reproduce", "--out", str(tmp_path / "o"),
         "--seeds", "0,x"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "--seeds = 0,x is out of range" in result.stderr
    assert not (tmp_path / "o").exists()
