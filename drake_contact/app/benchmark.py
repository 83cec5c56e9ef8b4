"""Every controller on the same force-control tasks, on walls none was tuned
on, ranked: ``drake-contact benchmark``.

    drake-contact benchmark --out DIR [--controllers A,B,...] [--identifiers all|A,B,...]
                            [--suite quick|standard] [--workers N | --scheduler ADDRESS]

A **contender** is a controller with one set of options for the whole
suite: an installed controller by name (its default options), or one of the
project's scenarios whose ``controller`` section (and, for
``adaptive_hybrid``, its identifiers and estimator) it takes
(:data:`SCENARIO_CONTENDERS`: the thesis's ``hybrid`` (P only and PI)
and ``nn`` as tuned on styrofoam, the robust ``nn_robust`` and
``adaptive_hybrid``). Everything else is the suite's: the arm with the
model errors of the thesis's styrofoam runs (``nn_styrofoam``: joint 2's
drive 1.2 times its command), the sensor and DSP, the wall and the task.

A **task** (:data:`TASKS`) is a force reference and an environment law: a
20 N hold, the thesis's 20/10 N square wave, the square wave plus 4 sin(pi
t), K_e drifting +1 %/s during contact, Hunt-Crossley contact, and
tangential (Coulomb) friction at the wall. Each runs on every wall of the
suite (:data:`SUITES`), one noise seed per wall. The walls of ``standard``
spread over K_e 3.5-145 kN/m and B_e 11-280 N s/m, and none is a point the
baselines or the robust schemes were tuned on.

Each run is one point of a campaign
(:func:`drake_contact.app.campaign.run_campaign`, on Dask), into
``DIR/runs/<contender>/<task>/<wall>/``. Scores per run come from
``metrics.json`` (force RMSE in the scoring window, the worst 5 s window,
overshoot and settling after each step of f_d, contact losses, y and phi
errors, torque effort); per contender and task they are the median and the
worst over the walls. A contender ranks by the runs in which it lost
contact, then by its median force RMSE; its overall rank is by its mean
rank over the tasks. Writes ``runs.csv`` (every run), ``leaderboard.csv``
(per contender and task, with the ranks), ``leaderboard.md`` and
``leaderboard.html`` (the tables and one figure per task), ``figures/``.
Contenders named ``<method>_s<k>`` are training seed k of one method (the
learned policies): the leaderboard's "Over training seeds" section gives
each method's spread over its seeds (:func:`seed_families`).

With ``--identifiers``, the identifiers (:func:`identifier_entries`: the
thesis's and ours from ``identify_styrofoam``, and every installed plug-in
kind) also run, all side by side in one run per task and wall under
``nn_robust`` (:data:`IDENTIFIER_CONTROLLER`), scored on K_e at the end and 1 s after
contact, B_e, M_e and the time to settle within 5 % of K_e
(``identifiers.csv``, ``identifier_leaderboard.csv``, a section of
``leaderboard.md``).
"""

import base64
import dataclasses as dc
import html
import re
from pathlib import Path

import numpy as np

from drake_contact.app.campaign import (
    DEFAULT_ENSEMBLE,
    Campaign, CampaignResult, Point, failure_message, finished_metrics, run_campaign, run_status)
from drake_contact.errors import ScenarioError
from drake_contact.scoring.metrics import SCORES
from drake_contact.plugins import (
    controller_declaration, identifier_declaration, installed_controllers, installed_identifiers)
from drake_contact.resources import scenarios_dir
from drake_contact.scenario import yaml_load

#: The suite's plant, sensor and DSP (and the scenario every run starts from).
BASE_SCENARIO = "nn_styrofoam"

#: The sections a contender from a scenario may bring (the rest is the suite's).
CONTENDER_SECTIONS = ("controller", "identifiers", "estimator")
#: Contenders taken from a bundled scenario: name -> (scenario, the
#: sections taken from it). The thesis's hybrid controller as its neural
#: runs use it (P only, K_fp 0.25) and as its identification runs do (PI,
#: K_fp 1, K_fi 0.003, without their seven identifiers); the thesis's
#: neural controller; ours: nn_robust and adaptive_hybrid (its RLS with it).
SCENARIO_CONTENDERS = {
    "hybrid": ("hybrid_p_only_styrofoam", ("controller",)),
    "hybrid_pi": ("identify_styrofoam", ("controller",)),
    "nn": ("nn_styrofoam", ("controller",)),
    "nn_robust": ("nn_robust", ("controller",)),
    "adaptive_hybrid": ("adaptive_hybrid", CONTENDER_SECTIONS),
}

_SQUARE = ["force_reference.levels=[20.0, 10.0]", "force_reference.half_period_s=2.5"]
#: Task name -> (what it is, overrides of the base scenario).
TASKS = {
    "hold": ("20 N held", ["force_reference.levels=[20.0]"]),
    "square": ("20/10 N square wave, 2.5 s per level (the thesis's)", _SQUARE),
    "square_sine": ("the square wave plus 4 sin(pi t) N (the thesis's)",
                    _SQUARE + ["force_reference.sine_amplitude_n=4.0",
                               "force_reference.sine_frequency_hz=0.5"]),
    "drift": ("the square wave on a wall whose K_e grows 1 %/s",
              _SQUARE + ["environment.stiffness_drift_per_s=0.01"]),
    "hunt_crossley": ("the square wave on a Hunt-Crossley wall (exponent 1.5)",
                      _SQUARE + ["environment.law=hunt_crossley"]),
    "friction": ("the square wave with wall friction mu = 0.3",
                 _SQUARE + ["environment.friction_coefficient=0.3"]),
}


@dc.dataclass(frozen=True)
class Suite:
    """Walls, tasks and run length of a benchmark suite."""

    # [K_e (N/m), B_e (N s/m)] per wall; wall i runs with noise seed i.
    walls: tuple
    tasks: tuple
    # Simulated time per run (s) and the scoring window after the first
    # contact switch (s): the window ends inside the run on every wall (the
    # 5 N switch comes at 9.1 s on 7 kN/m and 10.0 s on 3 kN/m).
    duration_s: float
    window_s: tuple


SUITES = {
    "quick": Suite(walls=((5000.0, 30.0), (60000.0, 200.0)), tasks=("hold", "square"),
                   duration_s=16.0, window_s=(1.0, 6.0)),
    # Eight walls over the whole range, K_e log-spaced 3.5-145 kN/m with B_e
    # alternately low and high (11-280 N s/m), none on a tuning grid.
    "standard": Suite(
        walls=((3500.0, 250.0), (6000.0, 12.0), (12000.0, 90.0), (25000.0, 20.0),
               (50000.0, 280.0), (80000.0, 45.0), (120000.0, 150.0), (145000.0, 11.0)),
        tasks=tuple(TASKS), duration_s=32.0, window_s=(2.0, 20.0)),
}

def contender_names(requested=None) -> list:
    """The contenders: ``requested`` (comma-separated names, checked), or
    every scenario contender and installed controller but the harnesses."""
    installed = installed_controllers()
    known = list(SCENARIO_CONTENDERS) + sorted(set(installed) - set(SCENARIO_CONTENDERS))
    if not requested:
        return [name for name in known if name in SCENARIO_CONTENDERS
                or controller_declaration(name).contender]
    names = [name.strip() for name in requested.split(",") if name.strip()]
    for name in names:
        if name not in known:
            raise ScenarioError(f"--controllers: '{name}' is neither an installed controller "
                                f"nor a scenario contender: choose from {', '.join(known)}")
    if len(set(names)) != len(names):
        raise ScenarioError(f"--controllers = {requested}: a name is given twice")
    return names


def contender_scenario(name: str) -> dict:
    """The base scenario (a mapping) with contender ``name``'s sections."""
    data = yaml_load((scenarios_dir() / f"{BASE_SCENARIO}.yaml").read_text())
    for section in CONTENDER_SECTIONS:
        data.pop(section, None)
    if name in SCENARIO_CONTENDERS:
        scenario, sections = SCENARIO_CONTENDERS[name]
        own = yaml_load((scenarios_dir() / f"{scenario}.yaml").read_text())
        data |= {section: own[section] for section in sections if section in own}
    else:
        data["controller"] = {"name": name}
    return data


@dc.dataclass(frozen=True)
class Run:
    """One run of the suite: a contender (or ``identifiers``: the identifier
    contenders' shared run) on a task and a wall."""

    contender: str
    task: str
    wall: int
    stiffness: float
    damping: float

    @property
    def seed(self) -> int:
        return self.wall

    @property
    def path(self) -> str:
        return (f"{self.contender}/{self.task}/"
                f"wall{self.wall}_K{self.stiffness:g}_B{self.damping:g}")

    def overrides(self, suite: Suite) -> list:
        return TASKS[self.task][1] + [
            f"environment.stiffness={self.stiffness}", f"environment.damping={self.damping}",
            f"simulation.duration={suite.duration_s}",
            f"scoring.window_start_s={suite.window_s[0]}",
            f"scoring.window_end_s={suite.window_s[1]}"]


#: The identifiers' contenders: the thesis's and ours as configured in this
#: scenario's ``identifiers`` list, and every installed plug-in kind (with
#: its default options); all run side by side, on every task and wall, under
#: :data:`IDENTIFIER_CONTROLLER`: nn_robust, which keeps contact on every wall
#: of the suite (the thesis's hybrid PI loses it on almost half, and an
#: identifier cannot be scored across a lost contact).
IDENTIFIER_SCENARIO = "identify_styrofoam"
IDENTIFIER_CONTROLLER = "nn_robust"
#: A K_e estimate has settled once it stays within this of the truth.
IDENTIFIER_SETTLE = 0.05


def identifier_entries() -> dict:
    """{name: the scenario's identifiers entry} of every identifier contender."""
    own = yaml_load((scenarios_dir() / f"{IDENTIFIER_SCENARIO}.yaml").read_text())
    entries = {entry["name"]: entry for entry in own["identifiers"]}
    for kind in sorted(installed_identifiers()):
        # The thesis's kinds (configured by sections) are there as the scenario has them.
        if not identifier_declaration(kind).sections and kind not in entries:
            entries[kind] = {"name": kind, "kind": kind}
    for entry in entries.values():
        entry.pop("figures", None)
    return entries


def identifier_names(requested) -> list:
    """``requested`` ('all' or comma-separated names), checked; [] if None."""
    if not requested:
        return []
    known = list(identifier_entries())
    if requested.strip() == "all":
        return known
    names = [name.strip() for name in requested.split(",") if name.strip()]
    for name in names:
        if name not in known:
            raise ScenarioError(f"--identifiers: '{name}' is not an identifier contender: "
                                f"choose from {', '.join(known)}, or all")
    return names


def identifier_scenario(names) -> dict:
    data = contender_scenario(IDENTIFIER_CONTROLLER)
    entries = identifier_entries()
    data["identifiers"] = [entries[name] for name in names]
    return data


def score_identifiers(run: Run, run_dir: Path, names) -> list:
    """One identifiers.csv row per identifier of a run."""
    metrics = finished_metrics(run_dir) or {}
    rows = []
    for name in names:
        row = {"identifier": name, "task": run.task, "wall": run.wall,
               "stiffness_n_per_m": run.stiffness, "damping_n_s_per_m": run.damping,
               "seed": run.seed, "status": metrics.get("status", "failed")}
        error = metrics.get(f"identification_error_{name}") or {}
        early = metrics.get(f"identification_error_1s_{name}") or {}
        found = metrics.get(f"identified_impedance_{name}") or {}
        for key, value in (("stiffness_error_pct", error.get("stiffness")),
                           ("stiffness_error_1s_pct", early.get("stiffness")),
                           ("damping_error_pct", error.get("damping"))):
            row[key] = None if value is None else 100 * value
        row["mass_kg"] = found.get("mass")
        row["settling_s"] = metrics.get(f"identification_time_{name}_s")
        rows.append(row)
    return rows


def aggregate_identifiers(rows, names, tasks) -> list:
    """Per identifier and task: median and worst |K_e error| at the end and
    1 s after contact, median |B_e error|, median M_e, runs whose K_e
    settled within 5 %, median settling time; ranked by the runs that did
    not settle, then the median |K_e error|; then one overall row each."""
    board = []
    for task in tasks:
        entries = []
        for name in names:
            runs = [r for r in rows if r["identifier"] == name and r["task"] == task]
            k = [abs(r["stiffness_error_pct"]) for r in runs
                 if r["stiffness_error_pct"] is not None]
            k1 = [abs(r["stiffness_error_1s_pct"]) for r in runs
                  if r["stiffness_error_1s_pct"] is not None]
            settled = [r["settling_s"] for r in runs if r["settling_s"] is not None]
            entries.append({
                "identifier": name, "task": task, "runs": len(runs),
                "runs_failed": sum(r["status"] == "failed" for r in runs),
                "runs_settled_5pct": len(settled),
                "stiffness_abs_error_pct_median": _median(k),
                "stiffness_abs_error_pct_worst": _max(k),
                "stiffness_abs_error_1s_pct_median": _median(k1),
                "damping_abs_error_pct_median": _median(
                    [abs(r["damping_error_pct"]) for r in runs
                     if r["damping_error_pct"] is not None]),
                "mass_kg_median": _median([r["mass_kg"] for r in runs]),
                "settling_s_median": _median(settled)})
        board += _ranked_completed(entries, lambda e: e["runs"] - e["runs_settled_5pct"],
                                   "stiffness_abs_error_pct_median")
    for name in names:
        mine = [e for e in board if e["identifier"] == name]
        ranks = [e["rank"] for e in mine]
        board.append({"identifier": name, "task": "all",
                      "mean_rank": None if None in ranks else float(np.mean(ranks)),
                      "runs": sum(e["runs"] for e in mine),
                      "runs_failed": sum(e["runs_failed"] for e in mine),
                      "runs_settled_5pct": sum(e["runs_settled_5pct"] for e in mine),
                      "stiffness_abs_error_pct_median": _median(
                          [abs(r["stiffness_error_pct"]) for r in rows
                           if r["identifier"] == name and r["stiffness_error_pct"] is not None])})
    overall = [e for e in board if e["task"] == "all"]
    ranked = sorted([e for e in overall if e["mean_rank"] is not None],
                    key=lambda e: e["mean_rank"])
    for rank, entry in enumerate(ranked, start=1):
        entry["rank"] = rank
    for entry in overall:
        entry.setdefault("rank", None)
    return board


def identifier_markdown(board, tasks) -> str:
    lines = ["", "# Identifiers", "",
             f"All side by side in one run per task and wall, under `{IDENTIFIER_CONTROLLER}`; "
             "true M_e is 0.01 kg. Ranked by the runs whose K_e estimate did not settle within "
             "5 % of the truth, then by the median |K_e error| at the end. An identifier with a "
             "failed run (the run raised, or its worker died) is not ranked: `failed k/n`.", "",
             "| rank | identifier | mean task rank | K_e settled within 5 % | median abs K_e "
             "error at the end (%) |", "|---|---|---|---|---|"]
    for e in sorted([e for e in board if e["task"] == "all"],
                    key=lambda e: (e["rank"] is None, e["rank"] or e["runs_failed"])):
        lines.append(f"| {_rank_cell(e)} | {e['identifier']} | {_fmt(e['mean_rank'])} | "
                     f"{e['runs_settled_5pct']}/{e['runs']} | "
                     f"{_fmt(e['stiffness_abs_error_pct_median'])} |")
    for task in tasks:
        lines += ["", f"## identifiers, {task}: {TASKS[task][0]}", "",
                  "| rank | identifier | K_e settled within 5 % | abs K_e error median / worst "
                  "(%) | at 1 s (%) | abs B_e error (%) | M_e (kg) | settling (s) |",
                  "|---|---|---|---|---|---|---|---|"]
        for e in [e for e in board if e["task"] == task]:
            lines.append(
                f"| {_rank_cell(e)} | {e['identifier']} | {e['runs_settled_5pct']}/{e['runs']} | "
                f"{_fmt(e['stiffness_abs_error_pct_median'])} / "
                f"{_fmt(e['stiffness_abs_error_pct_worst'])} | "
                f"{_fmt(e['stiffness_abs_error_1s_pct_median'])} | "
                f"{_fmt(e['damping_abs_error_pct_median'], 0)} | {_fmt(e['mass_kg_median'], 3)} "
                f"| {_fmt(e['settling_s_median'])} |")
    return "\n".join(lines) + "\n"


def plan(contenders, suite: Suite) -> list:
    return [Run(c, task, i, k, b) for c in contenders for task in suite.tasks
            for i, (k, b) in enumerate(suite.walls)]


def score_run(run: Run, run_dir: Path) -> dict:
    """One row of runs.csv."""
    row = {"contender": run.contender, "task": run.task, "wall": run.wall,
           "stiffness_n_per_m": run.stiffness, "damping_n_s_per_m": run.damping,
           "seed": run.seed}
    metrics = finished_metrics(run_dir)
    if metrics is None:
        failure = failure_message(run_dir)
        return row | {"status": "failed" if failure else "interrupted",
                      "message": failure or "not run to the end"}
    status = run_status(metrics)
    if status == "completed" and metrics.get("contact_time_s") is None:
        status = "no_contact"
    row |= {"status": status, "message": metrics.get("message", "")}
    for score in SCORES:
        value = metrics.get(score.key)
        row[score.column] = None if value is None else value * score.scale
    return row


def _ranked(entries, failures, score):
    """``entries`` sorted by ``failures(entry)``, then by ``entry[score]``
    (None last), each given its ``rank`` from 1."""
    order = sorted(entries, key=lambda e: (failures(e), np.inf if e[score] is None
                                           else e[score]))
    for rank, entry in enumerate(order, start=1):
        entry["rank"] = rank
    return order


def _median(values):
    values = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.median(values)) if values else None


def _max(values):
    values = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.max(values)) if values else None


#: Outcomes of a run that rank a contender down: a result, but not the task
#: done (a lost contact, a diverged run, never touching, not run to the end).
_BAD = ("lost_contact", "diverged", "no_contact", "interrupted")
#: Counts per contender and task: column -> the run statuses it counts. A
#: failed run (it raised, or its worker died) is no result at all, apart
#: from a diverged one.
_COUNTS = {"runs_losing_contact": ("lost_contact",), "runs_diverged": ("diverged",),
           "runs_no_contact": ("no_contact",), "runs_failed": ("failed",)}


def aggregate(rows, contenders, tasks) -> list:
    """leaderboard.csv rows: per contender and task, the median and worst of
    each score over the walls, the runs that lost contact, diverged, never
    touched or failed, and the task rank; then one overall row per
    contender. A contender with a failed run in a task is not ranked on it
    (``rank`` None), nor overall, and comes after every ranked one."""
    board = []
    for task in tasks:
        entries = []
        for contender in contenders:
            runs = [r for r in rows if r["contender"] == contender and r["task"] == task]
            entry = {"contender": contender, "task": task, "runs": len(runs),
                     "_bad": sum(r["status"] in _BAD for r in runs)}
            entry |= {column: sum(r["status"] in statuses for r in runs)
                      for column, statuses in _COUNTS.items()}
            for score in SCORES:
                values = [r.get(score.column) for r in runs]
                entry[f"{score.column}_median"] = _median(values)
                entry[f"{score.column}_worst"] = _max(values)
            entries.append(entry)
        board += _ranked_completed(entries, lambda e: e["_bad"], "force_rmse_n_median")
    for contender in contenders:
        mine = [e for e in board if e["contender"] == contender]
        ranks = [e["rank"] for e in mine]
        entry = {"contender": contender, "task": "all",
                 "mean_rank": None if None in ranks else float(np.mean(ranks)),
                 "runs": sum(e["runs"] for e in mine),
                 "force_rmse_n_median": _median([r.get("force_rmse_n") for r in rows
                                                 if r["contender"] == contender])}
        board.append(entry | {column: sum(e[column] for e in mine) for column in _COUNTS})
    overall = [e for e in board if e["task"] == "all"]
    ranked = sorted([e for e in overall if e["mean_rank"] is not None],
                    key=lambda e: e["mean_rank"])
    for rank, entry in enumerate(ranked, start=1):
        entry["rank"] = rank
    for entry in overall:
        entry.setdefault("rank", None)
    for entry in board:
        entry.pop("_bad", None)
    return board


def _ranked_completed(entries, bad, score):
    """:func:`_ranked` over the entries without a failed run; then the
    others, unranked (``rank`` None), fewest failures first."""
    ranked = _ranked([e for e in entries if not e["runs_failed"]], bad, score)
    failed = sorted([e for e in entries if e["runs_failed"]], key=lambda e: e["runs_failed"])
    for entry in failed:
        entry["rank"] = None
    return ranked + failed


def _rank_cell(entry) -> str:
    """A board's rank cell: the rank, or ``failed k/n`` for an unranked
    contender."""
    if entry["rank"] is None:
        return f"failed {entry['runs_failed']}/{entry['runs']}"
    return str(entry["rank"])


def _fmt(value, digits=2):
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


#: A contender ``<method>_s<k>``: training seed k of ``method``.
SEED_NAME = re.compile(r"^(?P<method>.+)_s(?P<seed>\d+)$")


def seed_families(board) -> list:
    """Each method with two or more training seeds among the contenders:
    (method, its overall entries by seed). Its spread over seeds: the
    ranks, the runs losing contact, the median force RMSE of each seed."""
    families = {}
    for e in board:
        match = SEED_NAME.match(e["contender"]) if e["task"] == "all" else None
        if match:
            families.setdefault(match["method"], []).append((int(match["seed"]), e))
    return [(method, [e for _, e in sorted(entries, key=lambda x: x[0])])
            for method, entries in families.items() if len(entries) >= 2]


def _seed_lines(board) -> list:
    families = seed_families(board)
    if not families:
        return []
    lines = ["", "## Over training seeds", "",
             "Each learned method's contenders, one per training seed (`<method>_s<k>`): "
             "their overall ranks, runs losing contact, and median force RMSE (the median "
             "and the worst over the seeds).", "",
             "| method | seeds | overall ranks | runs losing contact | "
             "median force RMSE (N): median over seeds | worst seed |",
             "|---|---|---|---|---|---|"]
    for method, entries in families:
        ranks = ", ".join(_fmt(e["rank"]) for e in entries)
        lost = ", ".join(f"{e['runs_losing_contact']}/{e['runs']}" for e in entries)
        rmse = [e["force_rmse_n_median"] for e in entries]
        known = [v for v in rmse if v is not None]
        lines.append(f"| {method} | {len(entries)} | {ranks} | {lost} | "
                     f"{_fmt(_median(rmse))} | {_fmt(max(known) if known else None)} |")
    return lines


def markdown(board, suite_name, suite: Suite, wall_s=None, rows=None) -> str:
    walls = ", ".join(f"{k / 1000:g} kN/m & {b:g} N s/m" for k, b in suite.walls)
    lines = [f"# Leaderboard: suite `{suite_name}`", "",
             f"Walls (one noise seed each): {walls}. Every run {suite.duration_s:g} s; scored "
             f"{suite.window_s[0]:g}-{suite.window_s[1]:g} s after the first contact switch, "
             "on the true contact force."
             + (f" Wall time of the suite: {wall_s / 60:.1f} min." if wall_s else ""), "",
             "## Overall", "",
             "A contender with a failed run (it raised, or its worker died) is not ranked: "
             "it shows `failed k/n` and comes last. A diverged run is a result, counted apart.",
             "",
             "| rank | contender | mean task rank | runs losing contact | runs diverged "
             "| runs never in contact | runs failed | median force RMSE (N) |",
             "|---|---|---|---|---|---|---|---|"]
    overall = [e for e in board if e["task"] == "all"]
    for e in sorted(overall, key=lambda e: (e["rank"] is None, e["rank"] or e["runs_failed"])):
        lines.append(f"| {_rank_cell(e)} | {e['contender']} | {_fmt(e['mean_rank'])} | "
                     f"{e['runs_losing_contact']}/{e['runs']} | {e['runs_diverged']} | "
                     f"{e['runs_no_contact']} | {e['runs_failed']}/{e['runs']} | "
                     f"{_fmt(e['force_rmse_n_median'])} |")
    lines += _seed_lines(board)
    for task in suite.tasks:
        shown = [score for score in SCORES if score.show]
        lines += ["", f"## {task}: {TASKS[task][0]}", "",
                  "| rank | contender | lost contact | diverged | "
                  + " | ".join(score.header for score in shown) + " |",
                  "|---|---|---|---|" + "---|" * len(shown)]
        for e in [e for e in board if e["task"] == task]:
            cells = [" / ".join(_fmt(e[f"{score.column}_{aggregate}"], score.digits)
                                for aggregate in score.show) for score in shown]
            lines.append(f"| {_rank_cell(e)} | {e['contender']} | {e['runs_losing_contact']}/"
                         f"{e['runs']} | {e['runs_diverged']}/{e['runs']} | "
                         + " | ".join(cells) + " |")
        if rows is not None:
            contenders = [e["contender"] for e in board if e["task"] == task]
            lines += ["", "Each run's force RMSE (o; x: lost contact):", "", "```",
                      *strip_chart(rows, contenders, task), "```"]
    return "\n".join(lines) + "\n"


#: The text strip charts' log axis (N) and width (characters).
STRIP_RANGE_N = (0.1, 30.0)
STRIP_WIDTH = 60


def strip_chart(rows, contenders, task) -> list:
    """A text figure for Markdown: per contender, each run's force RMSE on a
    log axis (``o``; ``x`` a run that lost contact, ``!`` failed)."""
    low, high = np.log10(STRIP_RANGE_N[0]), np.log10(STRIP_RANGE_N[1])
    width = max(len(c) for c in contenders)
    lines = []
    for contender in contenders:
        strip = [" "] * STRIP_WIDTH
        for r in rows:
            if r["contender"] != contender or r["task"] != task:
                continue
            rmse = r.get("force_rmse_n")
            mark = "o" if r["status"] == "completed" else "x"
            if rmse is None:
                rmse, mark = STRIP_RANGE_N[1], "!"
            at = (np.log10(min(max(rmse, STRIP_RANGE_N[0]), STRIP_RANGE_N[1])) - low) / (high - low)
            i = min(int(at * (STRIP_WIDTH - 1) + 0.5), STRIP_WIDTH - 1)
            strip[i] = "x" if "x" in (strip[i], mark) else ("!" if "!" in (strip[i], mark)
                                                             else mark)
        lines.append(f"{contender:>{width}} |{''.join(strip)}|")
    ticks = [0.1, 0.3, 1, 3, 10, 30]
    axis = [" "] * (STRIP_WIDTH + 8)
    for tick in ticks:
        i = int((np.log10(tick) - low) / (high - low) * (STRIP_WIDTH - 1) + 0.5)
        for k, ch in enumerate(f"{tick:g}"):
            if i + k < len(axis):
                axis[i + k] = ch
    lines.append(" " * (width + 2) + "".join(axis).rstrip() + "  force RMSE (N), log")
    return lines


def task_figure(rows, contenders, task, path: Path):
    """Force RMSE of every run of ``task``, per contender (log scale);
    a red cross is a run that lost contact."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(1.2 * len(contenders) + 2, 3.6))
    for i, contender in enumerate(contenders):
        runs = [r for r in rows if r["contender"] == contender and r["task"] == task
                and r.get("force_rmse_n") is not None]
        for r in runs:
            lost = r["status"] != "completed"
            ax.scatter(i + 0.08 * (r["wall"] - len(runs) / 2), r["force_rmse_n"],
                       marker="x" if lost else "o", color="tab:red" if lost else "tab:blue",
                       s=22)
    ax.set_yscale("log")
    ax.set_xticks(range(len(contenders)), contenders, rotation=30, ha="right")
    ax.set_ylabel("force RMSE (N)")
    ax.set_title(f"{task}: {TASKS[task][0]} (x: lost contact)", fontsize=9)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_html(text_md: str, figures, path: Path):
    body = [f"<pre>{html.escape(text_md)}</pre>"]
    for figure in figures:
        data = base64.b64encode(figure.read_bytes()).decode()
        body.append(f'<p><img alt="{figure.stem}" src="data:image/png;base64,{data}"></p>')
    path.write_text("<!doctype html><html><head><meta charset='utf-8'><title>drake_contact "
                    "leaderboard</title></head><body>" + "\n".join(body) + "</body></html>\n")


class BenchmarkCampaign(Campaign):
    """The benchmark as a campaign: a point per contender, task and wall (and
    per task and wall for the identifiers' shared runs), scored into
    runs.csv (identifiers.csv), ranked into leaderboard.csv
    (identifier_leaderboard.csv); the report is leaderboard.md, .html and a
    figure per task."""

    name = "benchmark"
    columns = {
        "runs": ["contender", "task", "wall", "stiffness_n_per_m", "damping_n_s_per_m", "seed",
                 "status", "message"],
        "leaderboard": ["rank", "contender", "task", "runs", "runs_failed", "runs_diverged",
                        "runs_losing_contact", "runs_no_contact", "mean_rank",
                        "force_rmse_n_median"],
        "identifiers": ["identifier", "task", "wall", "stiffness_n_per_m", "damping_n_s_per_m",
                        "seed", "status"],
        "identifier_leaderboard": ["rank", "identifier", "task", "runs", "runs_failed",
                                   "runs_settled_5pct", "mean_rank"],
    }

    def __init__(self, suite="standard", contenders=None, identifiers=None):
        if suite not in SUITES:
            raise ScenarioError(f"--suite = {suite} is unknown: choose one of "
                                f"{', '.join(SUITES)}")
        self.suite_name, self.suite = suite, SUITES[suite]
        self.contenders = contender_names(contenders)
        self.identifiers = identifier_names(identifiers)
        self.scenarios = {name: contender_scenario(name) for name in self.contenders}
        self.runs = {r.path: r for r in plan(self.contenders, self.suite)}
        self.id_runs = ({r.path: r for r in plan(["identifiers"], self.suite)}
                        if self.identifiers else {})

    def points(self):
        points = [Point(r.path, self.scenarios[r.contender], tuple(r.overrides(self.suite)),
                        r.seed) for r in self.runs.values()]
        if self.identifiers:
            scenario = identifier_scenario(self.identifiers)
            points += [Point(r.path, scenario, tuple(r.overrides(self.suite)), r.seed)
                       for r in self.id_runs.values()]
        return points

    def score(self, point, run_dir):
        if point.name in self.id_runs:
            return {"identifiers": score_identifiers(self.id_runs[point.name], run_dir,
                                                     self.identifiers)}
        return {"runs": [score_run(self.runs[point.name], run_dir)]}

    def aggregate(self, tables):
        found = {"leaderboard": aggregate(tables["runs"], self.contenders, self.suite.tasks)}
        if self.identifiers:
            found["identifier_leaderboard"] = aggregate_identifiers(
                tables["identifiers"], self.identifiers, self.suite.tasks)
        return found

    def resolved(self):
        return {"suite": self.suite_name, "contenders": self.scenarios,
                "tasks": {t: TASKS[t][1] for t in self.suite.tasks},
                "walls": [list(w) for w in self.suite.walls]}

    def report(self, out, result):
        tables = result.tables
        wall_s = result.startup_s + result.wall_s
        text = markdown(tables["leaderboard"], self.suite_name, self.suite,
                        wall_s=wall_s if result.ran and not result.interrupted else None,
                        rows=tables["runs"])
        if self.identifiers:
            text += identifier_markdown(tables["identifier_leaderboard"], self.suite.tasks)
        (out / "leaderboard.md").write_text(text)
        figures = out / "figures"
        figures.mkdir(exist_ok=True)
        paths = []
        for task in self.suite.tasks:
            paths.append(figures / f"{task}.png")
            task_figure(tables["runs"], self.contenders, task, paths[-1])
        write_html(text, paths, out / "leaderboard.html")


def run_benchmark(out_dir, *, contenders=None, identifiers=None, suite="standard", workers=None,
                  scheduler=None, progress=None, ensemble=DEFAULT_ENSEMBLE) -> CampaignResult:
    """Runs the suite (the points not finished in ``out_dir`` before) and
    writes the leaderboard; ``identifiers`` ('all' or names) adds the
    identifiers' runs and board. The result's tables: ``runs``,
    ``leaderboard`` (and ``identifiers``, ``identifier_leaderboard``)."""
    return run_campaign(BenchmarkCampaign(suite, contenders, identifiers), out_dir,
                        workers=workers, scheduler=scheduler, progress=progress,
                        ensemble=ensemble)
