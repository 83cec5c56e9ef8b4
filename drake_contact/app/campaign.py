"""Campaigns: many runs, planned, run on Dask, scored into tables.

A sweep, the benchmark, the fault study and the reproduction are each a
:class:`Campaign`: a short declaration of

* its :class:`Point` s (one ``run`` each: a scenario, overrides, a seed);
* how a finished run folder is scored (:meth:`Campaign.score`: rows per
  table);
* the tables aggregated from those rows (:meth:`Campaign.aggregate`);
* its report (:meth:`Campaign.report`: Markdown, HTML, figures) and what
  it ran (:meth:`Campaign.resolved`, written as ``<name>.yaml``).

:func:`run_campaign` does the rest, the same way for all: it skips the
points whose folder holds a finished ``metrics.json`` (so a campaign resumes
where it stopped), runs the others as tasks on a Dask cluster (a
``LocalCluster`` of ``workers`` processes, one thread each, or the cluster
at ``scheduler``; a task may hold several points, run one after the other
on its worker), scores every point from its folder, writes each table as
``<table>.csv`` and calls the report.

Before any run, :func:`check_configurations` loads every point's scenario
and builds the run diagram of each distinct structure once, as ``drake-contact
run`` would: a configuration that cannot be built (a plug-in whose ports do
not fit, a value out of range) raises the ScenarioError ``run`` raises, and
nothing runs. A point that diverges or raises while running is a row with
its status, never a crashed campaign: a raising run (or one whose worker
died each time Dask tried it) writes ``failure.json`` in its folder, and
:attr:`CampaignResult.failed` names it; a diverged run is a result, named
apart in :attr:`CampaignResult.diverged`. Every run
writes ``task.json`` (when and where it ran) and ``run.log`` (its outcome in
one line). Ctrl-C stops the campaign: points not started are not started,
running ones stop at their next check (every 0.1 s simulated) and write
their logs and ``metrics.json`` with status ``interrupted`` (run again next
time), then the tables and report are written from what finished, and
:attr:`CampaignResult.interrupted` says so.
"""

import csv
import dataclasses as dc
import json
import os
import signal
import sys
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import yaml

#: How long the workers get to write the logs of their interrupted runs (s).
STOP_GRACE_S = 120.0
#: On a worker: the batches stopped by their client (see :func:`run_points`).
_STOPPED = set()


@dc.dataclass(frozen=True)
class Point:
    """One run of a campaign."""

    # Unique in the campaign: the run folder's path under the runs folder.
    name: str
    # A bundled scenario's name, a path, YAML text or a mapping.
    scenario: object
    # ``dotted.key=value`` overrides, and the run's seed.
    overrides: tuple = ()
    seed: int = 0
    # The hybrid-only baseline: False, True (the whole run) or "window".
    baseline: object = False
    # Figures in the run folder, and a Meshcat playback (playback.html).
    figures: bool = False
    record: bool = False


def finished_metrics(run_dir: Path):
    """The metrics of a finished run folder (completed or diverged), else None."""
    try:
        metrics = json.loads((Path(run_dir) / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    return metrics if metrics.get("status") in ("completed", "diverged") else None


def run_outcome(run_dir: Path) -> str:
    """A run folder's outcome: metrics.json's status when it has one
    (``completed``, ``diverged``, ``interrupted``), ``failed`` when the run
    raised or its worker died (failure.json), else ``not_run``."""
    try:
        return json.loads((Path(run_dir) / "metrics.json").read_text())["status"]
    except (OSError, ValueError, KeyError):
        return "failed" if failure_message(run_dir) is not None else "not_run"


def failure_message(run_dir: Path):
    """The message a raising run left in ``failure.json``, else None."""
    path = Path(run_dir) / "failure.json"
    return json.loads(path.read_text())["message"] if path.exists() else None


#: The fields of a scenario that a build only passes on as numbers and never
#: checks against another field (their ranges are checked when the scenario
#: loads), as paths into ``dataclasses.asdict(scenario)``: the wall a
#: campaign varies per run, the run's seed and length, the scoring window,
#: the text. Configurations that differ only in these share a structure, and
#: one build checks them all (:func:`configuration_structure`).
PER_RUN_FIELDS = (("description",), ("thesis_figures",), ("simulation", "seed"),
                  ("simulation", "duration"), ("environment", "stiffness"),
                  ("environment", "damping"), ("scoring",))


def configuration_structure(scenario) -> str:
    """What a build of ``scenario`` depends on: the scenario as a mapping
    without :data:`PER_RUN_FIELDS`, as JSON text (equal for two scenarios
    that one build checks alike). Finer than the ensemble's structure key
    (:func:`drake_contact.structure.ensemble_structure`), which packs
    configurations whose numbers differ: a build also checks numbers (the
    friction's stability at the plant step), so each is built once."""
    data = dc.asdict(scenario)
    for path in PER_RUN_FIELDS:
        parent = data
        for key in path[:-1]:
            parent = parent[key]
        parent.pop(path[-1])
    # default=repr: a plug-in's options may hold values JSON has no form for.
    return json.dumps(data, sort_keys=True, default=repr)


def check_configurations(points) -> int:
    """Loads the scenario of every Point of ``points`` and builds the run
    diagram (:func:`drake_contact.simulation.MakeRunDiagram`, as
    ``drake-contact run`` builds it) of each distinct structure
    (:func:`configuration_structure`) once, in the points' order. Raises the
    ScenarioError of the first that does not load or build, the one line
    ``run`` prints; returns the number of builds."""
    from drake_contact.scenario import load_scenario
    from drake_contact.simulation import MakeRunDiagram
    built = set()
    for point in points:
        scenario = load_scenario(point.scenario, point.overrides, seed=point.seed)
        structure = configuration_structure(scenario)
        if structure not in built:
            MakeRunDiagram(scenario)
            built.add(structure)
    return len(built)


def run_status(metrics) -> str:
    """A finished run's status for a table: ``lost_contact`` for a completed
    run that lost contact, else metrics.json's own."""
    status = metrics["status"]
    if status == "completed" and metrics.get("contact_losses"):
        return "lost_contact"
    return status


def _warm_up():
    """On each worker before its first point: import the simulation once."""
    import drake_contact.app.runner  # noqa: F401 - pydrake and the systems


def _leave_ctrl_c_to_the_client():
    """On the workers of our own LocalCluster: a terminal's Ctrl-C reaches the
    whole process group, and the client stops the points so that they keep
    their logs."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _stop_batch(batch):
    _STOPPED.add(batch)


def _stop_check(batch):
    """The runs' progress callback: raising KeyboardInterrupt inside the
    simulation loop ends the run as ``interrupted``, logs kept."""
    def check(t, duration, wall_s):
        if batch in _STOPPED:
            raise KeyboardInterrupt
    return check


def run_point(point: Point, out_dir, batch="") -> dict:
    """Runs ``point`` (on a worker) into ``out_dir``; returns its timing
    (``started``, ``finished``, ``failure`` or None, ``host``, ``pid``;
    ``started`` 0: its batch was stopped before it began)."""
    from drake_contact.app.runner import run
    from drake_contact.scenario import load_scenario
    if batch in _STOPPED:
        return {"started": 0.0, "finished": 0.0, "failure": None}
    started = time.time()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "failure.json").unlink(missing_ok=True)
    try:
        result = run(load_scenario(point.scenario, point.overrides, seed=point.seed), out,
                     figures=point.figures, baseline=point.baseline, progress=_stop_check(batch),
                     record=out / "playback.html" if point.record else None)
        failure, line = None, f"{result.status}: {result.message}".rstrip(": ")
    except Exception as e:  # noqa: BLE001 - any failure of a point is its row
        failure = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
        (out / "failure.json").write_text(json.dumps({"message": failure}) + "\n")
        line = f"failed: {failure}"
    timing = {"started": started, "finished": time.time(), "failure": failure,
              "host": os.uname().nodename, "pid": os.getpid()}
    (out / "task.json").write_text(json.dumps(timing) + "\n")
    (out / "run.log").write_text(f"{line} ({timing['finished'] - started:.1f} s on "
                                 f"{timing['host']}, pid {timing['pid']})\n")
    return timing


def run_task(task, batch="", ensemble=False) -> dict:
    """Runs a task's ``(name, point, out_dir)`` triples: one after the
    other, or with ``ensemble`` as one ensemble (:func:`run_pack`); returns
    {name: timing}."""
    if ensemble and len(task) > 1:
        return run_pack(task, batch)
    return {name: run_point(point, out_dir, batch) for name, point, out_dir in task}


def run_pack(task, batch="") -> dict:
    """Runs a task's points as one ensemble (on a worker): each point's
    folder gets what :func:`run_point` writes, its log bit for bit the one
    it gets alone; a point whose scenario does not load fails alone. If the
    points cannot share an ensemble after all (ScenarioError while building
    it), each runs alone. Returns {name: timing}."""
    from drake_contact.app.runner import run_ensemble
    from drake_contact.errors import ScenarioError
    from drake_contact.scenario import load_scenario
    if batch in _STOPPED:
        return {name: {"started": 0.0, "finished": 0.0, "failure": None} for name, _, _ in task}
    started = time.time()
    loaded, timings = [], {}
    for name, point, out_dir in task:
        try:
            loaded.append((name, point, out_dir, load_scenario(point.scenario, point.overrides,
                                                               seed=point.seed)))
        except Exception:  # noqa: BLE001 - run alone, it writes its failure
            timings[name] = run_point(point, out_dir, batch)
    if len(loaded) < 2:
        return timings | {name: run_point(point, out_dir, batch)
                          for name, point, out_dir, _ in loaded}
    outs = [Path(out_dir) for _, _, out_dir, _ in loaded]
    for out in outs:
        out.mkdir(parents=True, exist_ok=True)
        (out / "failure.json").unlink(missing_ok=True)
    try:
        results = run_ensemble([s for *_, s in loaded], outs, progress=_stop_check(batch),
                               figures=[p.figures for _, p, _, _ in loaded],
                               baselines=[p.baseline for _, p, _, _ in loaded],
                               pack_baselines=MIN_ENSEMBLE)
    except ScenarioError:
        return timings | {name: run_point(point, out_dir, batch)
                          for name, point, out_dir, _ in loaded}
    finished = time.time()
    size = len(loaded)
    for (name, _, _, _), result, out in zip(loaded, results, outs):
        timing = {"started": started, "finished": finished, "failure": None,
                  "host": os.uname().nodename, "pid": os.getpid(), "ensemble": size}
        (out / "task.json").write_text(json.dumps(timing) + "\n")
        line = f"{result.status}: {result.message}".rstrip(": ")
        (out / "run.log").write_text(
            f"{line} ({finished - started:.1f} s for an ensemble of {size} on "
            f"{timing['host']}, pid {timing['pid']})\n")
        timings[name] = timing
    return timings


@dc.dataclass
class PointsRun:
    """What :func:`run_points` returns."""

    # Point name -> its timing (run_point's dict, or a failure).
    timings: dict
    interrupted: bool
    workers: int
    # Cluster start and the workers' first import (s); the points' wall time (s).
    startup_s: float
    wall_s: float


def run_points(points, *, workers=None, scheduler=None, progress=None,
               points_per_task=1, ensemble=1) -> PointsRun:
    """Runs ``points`` (pairs ``(Point, out_dir)``) as tasks on a Dask
    cluster: a LocalCluster of ``workers`` processes (default one per core)
    or the running cluster at ``scheduler``. With ``ensemble`` > 1, the
    points that can share an ensemble (:func:`ensemble_packs`) run as
    ensembles of up to ``ensemble`` environments, one per task; else each
    task runs up to ``points_per_task`` points one after the other.
    ``progress(done, failed, total, eta_s, name)`` is called as each point
    finishes. Ctrl-C stops the batch (``interrupted``): the running points
    write their logs, and what finished is kept."""
    from distributed import Client, LocalCluster

    timings, interrupted, startup, n_workers = {}, False, 0.0, 0
    start = time.perf_counter()
    if not points:
        return PointsRun(timings, interrupted, n_workers, startup, 0.0)
    tasks = [[(point.name, point, str(out)) for point, out in points[i:i + points_per_task]]
             for i in range(0, len(points), points_per_task)]
    cluster = client = None
    try:
        if scheduler:
            client = Client(scheduler)
        else:
            cluster = LocalCluster(n_workers=workers or os.cpu_count(), threads_per_worker=1,
                                   processes=True, dashboard_address=":0")
            client = Client(cluster)
        n_workers = len(client.scheduler_info()["workers"])
        # Import the simulation on every worker first, so that the per-point
        # overhead is the batch's own (start-up is reported apart).
        client.run(_warm_up)
        if cluster is not None:
            client.run(_leave_ctrl_c_to_the_client)
        startup = time.perf_counter() - start
        start = time.perf_counter()
        batch = uuid.uuid4().hex
        if ensemble > 1:
            tasks = [[(point.name, point, str(out)) for point, out in pack]
                     for pack in ensemble_packs(points, ensemble, n_workers)]
        futures = {client.submit(run_task, task, batch, ensemble > 1,
                                 key=f"task-{task[0][0]}-{batch}", pure=False): task
                   for task in tasks}
        try:
            _gather(futures, timings, len(points), start, progress)
        except KeyboardInterrupt:
            interrupted = True
            client.run(_stop_batch, batch)
            _gather(futures, timings, len(points), start, None, timeout=STOP_GRACE_S)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    timings = {name: t for name, t in timings.items() if t["started"] or t["failure"]}
    return PointsRun(timings, interrupted, n_workers, startup, time.perf_counter() - start)


#: Environments per ensemble in campaigns by default (``--ensemble``), and
#: at most. Packing pays from a few environments on and most at 64-256 (the
#: ensembles user guide page measures it); 64 keeps a 20 s ensemble's logs
#: near 1 GB.
DEFAULT_ENSEMBLE = 64
#: Fewer points than this run alone: below about 8 environments an
#: ensemble's fixed per-step cost (its numpy systems) exceeds what it saves
#: (measured: 0.77x at N = 4, 2.2x at N = 16 on nn_styrofoam).
MIN_ENSEMBLE = 8
MAX_ENSEMBLE = 256


def ensemble_packs(points, size, workers=1) -> list:
    """``points`` (pairs ``(Point, out_dir)``) in packs that run as one
    ensemble each: points whose scenarios share a structure
    (:func:`drake_contact.structure.ensemble_structure`: the plant step, the
    controller and what it switches on, the identifiers, the safety
    supervisor, the signal of each fault, ...) and a duration (an ensemble runs
    as long as its longest), in their order, at most ``size`` a pack, the packs of a group of even sizes and
    a whole number of them per worker where the group allows without a pack
    below MIN_ENSEMBLE (so that every worker gets the same work); a group
    smaller than MIN_ENSEMBLE runs point by point. A point that records a playback, or whose scenario does not
    load, is a pack of its own."""
    from drake_contact.scenario import load_scenario
    from drake_contact.structure import ensemble_structure
    groups = {}
    for point, out in points:
        key = ("alone", point.name)
        if not point.record:
            try:
                scenario = load_scenario(point.scenario, point.overrides, seed=point.seed)
                key = (ensemble_structure(scenario), scenario.simulation.duration)
            except Exception:  # noqa: BLE001 - its run writes the failure
                pass
        groups.setdefault(key, []).append((point, out))
    packs = []
    for group in groups.values():
        # As few packs as the size allows, of even sizes, and a whole
        # number of them per worker (every worker finishes at about one
        # time) as far as each stays at least MIN_ENSEMBLE: 12 points on 2
        # workers are one ensemble of 12, not two of 6 (which would run
        # point by point); 16 on 4 workers are two of 8.
        count = -(-len(group) // size)
        if workers > 1:
            balanced = min(len(group), -(-count // workers) * workers)
            count = max(count, min(balanced, len(group) // MIN_ENSEMBLE))
        share = -(-len(group) // count)
        if share < MIN_ENSEMBLE:
            share = 1
        packs += [group[i:i + share] for i in range(0, len(group), share)]
    return packs


def _gather(futures, timings, total, start, progress, timeout=None):
    """Collects the timings of the tasks not collected yet as they finish (a
    task that raised, e.g. its worker died, gives each of its points that
    failure)."""
    from distributed import as_completed
    pending = [f for f, task in futures.items()
               if not all(name in timings for name, _, _ in task)]
    failed = sum(t["failure"] is not None for t in timings.values())
    try:
        for future in as_completed(pending, timeout=timeout):
            task = futures[future]
            try:
                found = future.result()
            except Exception as e:  # noqa: BLE001 - e.g. KilledWorker: the rows say so
                found = {name: {"failure": f"{type(e).__name__}: {e}", "started": 0.0,
                                "finished": 0.0} for name, _, _ in task}
            for name, timing in found.items():
                timings[name] = timing
                failed += timing["failure"] is not None
                if progress is not None:
                    done = len(timings)
                    elapsed = time.perf_counter() - start
                    progress(done, failed, total, elapsed / done * (total - done), name)
    except TimeoutError:
        pass


def write_csv(rows, path: Path, first=()) -> Path:
    """A table as CSV: the columns ``first``, then every other column seen
    (sorted); None as an empty cell. Written atomically."""
    columns = list(first) + sorted({k for r in rows for k in r} - set(first))
    partial = path.with_name(path.name + ".partial")
    with partial.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: "" if row.get(k) is None else row.get(k) for k in columns})
    partial.replace(path)
    return path


@dc.dataclass
class CampaignResult:
    """What :func:`run_campaign` returns."""

    # Table name -> its rows (each written as <name>.csv).
    tables: dict
    # Points run now, and skipped (finished in an earlier call).
    ran: int
    skipped: int
    # The points' wall time, and the cluster's start (s).
    wall_s: float
    startup_s: float
    workers: int
    interrupted: bool
    # Point name -> timing, for the points run now.
    timings: dict = dc.field(default_factory=dict)
    # The table of one row per point (the campaign's first in ``columns``).
    main: str = ""
    # The points whose run raised or whose worker died each time Dask tried
    # it (failure.json, no metrics.json): name -> the failure's line; and the
    # names of those that diverged (a result, not a failure). Points skipped
    # as finished before included.
    failed: dict = dc.field(default_factory=dict)
    diverged: list = dc.field(default_factory=list)
    # Distinct structures built by the pre-check, and its time (s).
    checked: int = 0
    check_s: float = 0.0

    @property
    def rows(self) -> list:
        return self.tables.get(self.main, [])

    @property
    def mean_task_s(self) -> float:
        """Mean time per point run now on its worker (s; a point of an
        ensemble of n: its n-th of the ensemble's time)."""
        durations = self._durations()
        return float(np.mean(durations)) if durations else 0.0

    @property
    def overhead_per_point_s(self) -> float:
        """(wall x workers - sum of point times) / points run now: scheduling,
        gathering and idle workers at the end (s)."""
        durations = self._durations()
        return ((self.wall_s * self.workers - sum(durations)) / len(durations)
                if durations else 0.0)

    def _durations(self):
        return [(t["finished"] - t["started"]) / t.get("ensemble", 1)
                for t in self.timings.values() if t["started"]]


class Campaign:
    """A campaign's declaration; subclasses fill in what differs.

    ``name``: the resolved file ``<name>.yaml``; ``runs_folder``: where the
    run folders go under the output folder (``""``: the output folder
    itself); ``columns``: table name -> its first CSV columns (tables not
    named there are not written as CSV)."""

    name = "campaign"
    runs_folder = "runs"
    columns: dict = {}

    def points(self) -> list[Point]:
        raise NotImplementedError

    def score(self, point: Point, run_dir: Path) -> dict:
        """{table: rows} scored from one point's folder (finished or not)."""
        raise NotImplementedError

    def aggregate(self, tables: dict) -> dict:
        """More tables from the scored ones (e.g. medians over walls, ranks)."""
        return {}

    def resolved(self) -> dict:
        """What the campaign runs, written as ``<name>.yaml`` before it runs."""
        return {}

    def report(self, out: Path, result: CampaignResult):
        """Writes the campaign's Markdown, HTML and figures."""


def run_campaign(campaign: Campaign, out_dir, *, workers=None, scheduler=None, progress=None,
                 points_per_task=1, ensemble=DEFAULT_ENSEMBLE) -> CampaignResult:
    """Runs the points of ``campaign`` not finished in ``out_dir`` before
    (as ensembles of up to ``ensemble`` environments; 1: each alone), then
    scores, aggregates, writes the tables and the report (also after
    Ctrl-C, from what finished)."""
    out = Path(out_dir)
    runs = out / campaign.runs_folder
    points = campaign.points()
    names = [p.name for p in points]
    if len(set(names)) != len(names):
        raise ValueError(f"{campaign.name}: two points share a name")
    todo = [(p, runs / p.name) for p in points if finished_metrics(runs / p.name) is None]
    # Every configuration still to run is checked before the first runs (and
    # before anything is written): a bad one stops the campaign in one line
    # instead of failing run after run on the workers.
    started, interrupted = time.perf_counter(), False
    try:
        checked = check_configurations([p for p, _ in todo])
    except KeyboardInterrupt:
        # Ctrl-C while checking: nothing runs; the tables and report are
        # still written, from the runs finished before.
        checked, interrupted = 0, True
    check_s = time.perf_counter() - started
    runs.mkdir(parents=True, exist_ok=True)
    resolved = campaign.resolved()
    if resolved:
        (out / f"{campaign.name}.yaml").write_text(yaml.safe_dump(resolved, sort_keys=False))
    batch = (PointsRun({}, True, 0, 0.0, 0.0) if interrupted else
             run_points(todo, workers=workers, scheduler=scheduler, progress=progress,
                        points_per_task=points_per_task, ensemble=ensemble))
    for point, run_dir in todo:
        failure = (batch.timings.get(point.name) or {}).get("failure")
        if failure and failure_message(run_dir) is None:  # e.g. its worker died each time
            run_dir.mkdir(parents=True, exist_ok=True)
            (run_dir / "failure.json").write_text(json.dumps({"message": failure}) + "\n")
    tables = {}
    for point in points:
        for table, rows in campaign.score(point, runs / point.name).items():
            tables.setdefault(table, []).extend(rows)
    tables |= campaign.aggregate(tables)
    for table, first in campaign.columns.items():
        if table in tables:
            write_csv(tables[table], out / f"{table}.csv", first)
    outcomes = {p.name: run_outcome(runs / p.name) for p in points}
    result = CampaignResult(tables, ran=len(batch.timings), skipped=len(points) - len(todo),
                            wall_s=batch.wall_s, startup_s=batch.startup_s,
                            workers=batch.workers, interrupted=batch.interrupted,
                            timings=batch.timings, main=next(iter(campaign.columns), ""),
                            failed={n: failure_message(runs / n) for n, o in outcomes.items()
                                    if o == "failed"},
                            diverged=[n for n, o in outcomes.items() if o == "diverged"],
                            checked=checked, check_s=check_s)
    campaign.report(out, result)
    return result


def points_progress(stream=sys.stderr):
    """A progress line (points done, failed, ETA) on a terminal; None off one."""
    if not stream.isatty():
        return None

    def report(done, failed, total, eta_s, name=""):
        end = "\n" if done == total else ""
        stream.write(f"\r  {done}/{total} points done, {failed} failed, ETA {eta_s:6.0f} s  {end}")
        stream.flush()
    return report
