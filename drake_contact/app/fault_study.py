"""Every fault kind against the thesis's and the robust controllers, with and
without the safety supervisor: ``drake-contact faults``.

    drake-contact faults --out DIR [--controllers A,B,...] [--suite quick|standard]
                         [--workers N | --scheduler ADDRESS]

Each run is one benchmark contender (:mod:`drake_contact.app.benchmark`:
the suite's arm, sensor and DSP, the contender's controller) tracking the
thesis's 20/10 N square wave on one wall, with one fault of :func:`fault_cases`
starting :data:`FAULT_START_S` after the first contact, once with the
supervisor off and once on (``safety.enabled``, the limit
:data:`FORCE_LIMIT_N`; the same limit says whether a run ended safe either
way). The walls are points no controller was tuned on; each runs with
every noise seed of the suite. Each run is one point of a campaign
(:func:`drake_contact.app.campaign.run_campaign`, on Dask), into
``DIR/runs/<contender>/<safety>/<fault>/<wall>_seed<seed>/``.

Per run (``runs.csv``): the peak true force from the fault's start to the
end of the run, whether it went past the limit by more than 10 %, the
fault's contact losses, the time to recover tracking (the 100 ms mean true
force back within 1 N of f_d for 0.5 s; ``-`` if never), whether the run
ended safe and the supervisor's stop, if any. ``faults.md`` (and
``faults.csv``) has, per fault and contender, off and on: the worst peak
over the walls, the runs past the limit, the runs recovered and the median
recovery time, the runs that ended safe, with the spread of the peaks
and recovery times over the walls and seeds.
"""

import dataclasses as dc
from pathlib import Path

import numpy as np
import yaml

from drake_contact.app.benchmark import contender_names, contender_scenario
from drake_contact.app.campaign import (
    DEFAULT_ENSEMBLE,
    Campaign, CampaignResult, Point, failure_message, finished_metrics, run_campaign)
from drake_contact.errors import ScenarioError
from drake_contact.faults import FAULT_KINDS, NULL_CASE

#: The supervisor's limit in every run (N): twice the square wave's top level.
FORCE_LIMIT_N = 40.0
#: Faults start this long after the first contact (s): on the square wave's
#: second 20 N level (5-7.5 s), 0.5 s after its step, so that a short
#: fault's recovery is measured on 2 s of constant f_d, not on a step.
FAULT_START_S = 5.5
def fault_cases() -> dict:
    """Fault case name -> (what it is, the fault's fields but its start): a
    null case, then each registered kind's own case (its ``study_case``)."""
    cases = {NULL_CASE: ("no fault: the sensor's gain 1 for 2 s, an identity, scored as a fault is",
                      {"kind": "force_gain", "duration_s": 2.0, "magnitude": 1.0})}
    for kind in FAULT_KINDS.values():
        if kind.study_case is not None:
            cases[kind.study_case.name] = (kind.study_case.description,
                                           {"kind": kind.name} | kind.study_case.fields)
    return cases

#: The contenders by default: the thesis's hybrid (P only) and neural
#: controllers and the robust ones.
DEFAULT_CONTENDERS = ("hybrid", "nn", "nn_robust", "adaptive_hybrid")
SAFETY = ("off", "on")


@dc.dataclass(frozen=True)
class Suite:
    # [K_e (N/m), B_e (N s/m)] per wall.
    walls: tuple
    # The fault cases by name; None: every case of fault_cases().
    cases: tuple | None
    # Simulated time per run (s): the slowest approach touches at about
    # 9.5 s, then FAULT_START_S, the longest fault (2 s) and 2.5 s more.
    duration_s: float
    # The noise seeds every wall runs with.
    seeds: tuple = (0,)

    @property
    def case_names(self) -> tuple:
        return tuple(fault_cases()) if self.cases is None else self.cases


SUITES = {
    "quick": Suite(walls=((6000.0, 12.0),), cases=("none", "dropout_zero_50ms"),
                   duration_s=17.5),
    "standard": Suite(walls=((6000.0, 12.0), (25000.0, 90.0), (80000.0, 45.0)),
                      cases=None, duration_s=19.5, seeds=(0, 1, 2, 3, 4)),
}


@dc.dataclass(frozen=True)
class Run:
    contender: str
    safety: str
    case: str
    wall: int
    stiffness: float
    damping: float
    seed: int = 0

    @property
    def path(self) -> str:
        return (f"{self.contender}/{self.safety}/{self.case}/"
                f"wall{self.wall}_K{self.stiffness:g}_B{self.damping:g}_seed{self.seed}")

    def overrides(self, suite: Suite) -> list:
        fault = {"start_s": FAULT_START_S, "start_from": "contact"} | fault_cases()[self.case][1]
        return ["force_reference.levels=[20.0, 10.0]", "force_reference.half_period_s=2.5",
                f"environment.stiffness={self.stiffness}",
                f"environment.damping={self.damping}",
                f"simulation.duration={suite.duration_s}",
                "faults=" + yaml.safe_dump([fault], default_flow_style=True).strip(),
                f"safety.enabled={'true' if self.safety == 'on' else 'false'}",
                f"safety.force_limit_n={FORCE_LIMIT_N}"]


def plan(contenders, suite: Suite) -> list:
    return [Run(c, s, case, i, k, b, seed) for c in contenders for s in SAFETY
            for case in suite.case_names for i, (k, b) in enumerate(suite.walls)
            for seed in suite.seeds]


def score_run(run: Run, run_dir: Path) -> dict:
    """One row of runs.csv."""
    row = {"contender": run.contender, "safety": run.safety, "fault": run.case,
           "wall": run.wall, "stiffness_n_per_m": run.stiffness,
           "damping_n_s_per_m": run.damping, "seed": run.seed}
    metrics = finished_metrics(run_dir)
    if metrics is None:
        failure = failure_message(run_dir)
        return row | {"status": "failed" if failure else "interrupted",
                      "message": failure or "not run to the end"}
    fault = (metrics.get("faults") or [{}])[0]
    peaks = [fault.get("peak_force_during_n"), fault.get("peak_force_after_n")]
    peaks = [p for p in peaks if p is not None]
    peak = max(peaks) if peaks else None
    return row | {
        "status": metrics["status"], "message": metrics.get("message", ""),
        "fault_start_s": fault.get("start_s"),
        "peak_force_n": peak,
        "past_limit": bool(peak is not None and peak > 1.1 * FORCE_LIMIT_N
                           or metrics["status"] == "diverged"),
        "peak_tip_speed_m_s": max([s for s in (fault.get("peak_tip_speed_during_m_s"),
                                               fault.get("peak_tip_speed_after_m_s"))
                                   if s is not None], default=None),
        "contact_losses": fault.get("contact_losses"),
        "recovery_s": fault.get("recovery_s"),
        "ended_safe": metrics.get("ended_safe"),
        "safety_events": metrics.get("safety_event_count"),
        "safety_stop": metrics.get("safety_stop_reason"),
    }


def aggregate(rows, contenders, cases) -> list:
    """Per fault, contender and safety: worst peak, runs past the limit,
    recovered, median recovery, contact losses, ended safe, stops."""
    table = []
    for case in cases:
        for contender in contenders:
            for safety in SAFETY:
                runs = [r for r in rows if (r["fault"], r["contender"], r["safety"])
                        == (case, contender, safety)]
                # Scored: the runs that finished (a diverged run is a result:
                # past the limit); a failed or unfinished one has no scores.
                done = [r for r in runs if r["status"] not in ("failed", "interrupted")]
                recovered = [r["recovery_s"] for r in done if r.get("recovery_s") is not None]
                peaks = [r["peak_force_n"] for r in done if r.get("peak_force_n") is not None]
                table.append({
                    "fault": case, "contender": contender, "safety": safety,
                    "runs": len(runs),
                    "runs_failed": sum(r["status"] == "failed" for r in runs),
                    "runs_diverged": sum(r["status"] == "diverged" for r in runs),
                    "runs_not_finished": sum(r["status"] == "interrupted" for r in runs),
                    "peak_force_n_median": float(np.median(peaks)) if peaks else None,
                    "peak_force_n_worst": max(peaks) if peaks else None,
                    "runs_past_limit": sum(bool(r["past_limit"]) for r in done),
                    "runs_recovered": len(recovered),
                    "runs_recovered_within_1s": sum(r <= 1.0 for r in recovered),
                    "recovery_s_median": float(np.median(recovered)) if recovered else None,
                    "recovery_s_worst": max(recovered) if recovered else None,
                    "contact_losses": sum(r.get("contact_losses") or 0 for r in done),
                    "runs_with_contact_loss": sum(bool(r.get("contact_losses")) for r in done),
                    "runs_ended_safe": sum(bool(r.get("ended_safe")) for r in done),
                    "runs_stopped": sum(bool(r.get("safety_stop")) for r in done)})
    return table


def _cell(e) -> str:
    peak = ("-" if e["peak_force_n_worst"] is None
            else f"{e['peak_force_n_median']:.0f}-{e['peak_force_n_worst']:.0f}")
    rec = ("-" if e["recovery_s_median"] is None
           else f"{e['recovery_s_median']:.2f}, worst {e['recovery_s_worst']:.2f} s")
    done = e["runs"] - e["runs_failed"] - e["runs_not_finished"]
    text = f"{peak} N, rec {e['runs_recovered']}/{done} ({rec})"
    if e["runs_failed"]:
        text = f"**failed {e['runs_failed']}/{e['runs']}**, " + text
    if e["runs_diverged"]:
        text += f", {e['runs_diverged']} diverged"
    if e["runs_past_limit"]:
        text += f", **{e['runs_past_limit']} over**"
    if e["contact_losses"]:
        text += f", {e['contact_losses']} lost in {e['runs_with_contact_loss']}"
    if e["runs_stopped"]:
        text += f", {e['runs_stopped']} stopped"
    if e["runs_ended_safe"] < done:
        text += f", {done - e['runs_ended_safe']} unsafe end"
    return text


def markdown(table, contenders, suite: Suite, wall_s=None, resumed=0) -> str:
    walls = ", ".join(f"{k / 1000:g} kN/m & {b:g} N s/m" for k, b in suite.walls)
    lines = [
        "# Faults", "",
        f"Each fault starts {FAULT_START_S:g} s after the first contact (true force > 5 N), "
        f"on the 20/10 N square wave; walls {walls}; limit {FORCE_LIMIT_N:g} N. Per cell, over "
        f"the walls and noise seeds {', '.join(map(str, suite.seeds))}: the true force from "
        "the fault's start to the end (median-worst of the runs' peaks), the runs whose "
        "tracking recovered (100 ms mean within 1 N of f_d for 0.5 s) and their median "
        "and worst time from the fault's end, runs more than 10 % over the limit, contact "
        "losses (and the runs that had one), "
        "supervisor stops, runs that did not end safe. A failed run (it raised, or its worker "
        "died) has no scores and is counted as failed; a diverged one is scored (past the "
        "limit) and counted apart.", ""]
    if wall_s is not None:
        lines += [f"Ran in {wall_s:.0f} s" + (f", resuming a study that had {resumed} runs "
                                             "finished before" if resumed else "") + ".", ""]
    header = "| fault | " + " | ".join(f"{c} off | {c} on" for c in contenders) + " |"
    lines += [header, "|---|" + "---|" * (2 * len(contenders))]
    cases = fault_cases()
    for case in suite.case_names:
        cells = []
        for contender in contenders:
            for safety in SAFETY:
                e = next(e for e in table if (e["fault"], e["contender"], e["safety"])
                         == (case, contender, safety))
                cells.append(_cell(e))
        lines.append(f"| {case}: {cases[case][0]} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def check_contenders(requested):
    """The contenders (comma-separated, checked), DEFAULT_CONTENDERS if None."""
    return contender_names(requested) if requested else list(DEFAULT_CONTENDERS)


class FaultStudy(Campaign):
    """The study as a campaign: a point per contender, supervisor off / on,
    fault case and wall, scored into runs.csv, aggregated into faults.csv;
    the report is faults.md."""

    name = "faults"
    columns = {"runs": ["contender", "safety", "fault", "wall", "status"],
               "faults": ["fault", "contender", "safety", "runs", "runs_failed",
                          "runs_diverged"]}

    def __init__(self, suite="standard", contenders=None):
        if suite not in SUITES:
            raise ScenarioError(f"--suite = {suite} is unknown: choose one of "
                                f"{', '.join(SUITES)}")
        self.suite_name, self.suite = suite, SUITES[suite]
        self.contenders = check_contenders(contenders)
        self.scenarios = {name: contender_scenario(name) for name in self.contenders}
        self.runs = {r.path: r for r in plan(self.contenders, self.suite)}

    def points(self):
        return [Point(r.path, self.scenarios[r.contender], tuple(r.overrides(self.suite)),
                      r.seed) for r in self.runs.values()]

    def score(self, point, run_dir):
        return {"runs": [score_run(self.runs[point.name], run_dir)]}

    def aggregate(self, tables):
        return {"faults": aggregate(tables["runs"], self.contenders, self.suite.case_names)}

    def resolved(self):
        return {"suite": self.suite_name, "force_limit_n": FORCE_LIMIT_N,
                "fault_start_s": FAULT_START_S,
                "cases": {c: fault_cases()[c][1] for c in self.suite.case_names},
                "contenders": self.scenarios, "walls": [list(w) for w in self.suite.walls],
                "seeds": list(self.suite.seeds)}

    def report(self, out, result):
        wall_s = result.startup_s + result.wall_s
        (out / "faults.md").write_text(markdown(
            result.tables["faults"], self.contenders, self.suite,
            wall_s=wall_s if result.ran and not result.interrupted else None,
            resumed=result.skipped))


def run_fault_study(out_dir, *, contenders=None, suite="standard", workers=None,
                    scheduler=None, progress=None, ensemble=DEFAULT_ENSEMBLE) -> CampaignResult:
    """Runs the study (the points not finished in ``out_dir`` before) and
    writes runs.csv, faults.csv, faults.md and faults.yaml (what ran). The
    result's tables: ``runs`` and ``faults``."""
    return run_campaign(FaultStudy(suite, contenders), out_dir, workers=workers,
                        scheduler=scheduler, progress=progress, ensemble=ensemble)
