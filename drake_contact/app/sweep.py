"""Parameter sweeps on a Dask cluster: many runs of one scenario, a table and
maps of where a scheme works.

    drake-contact sweep SWEEP --out DIR [--workers N | --scheduler ADDRESS] [--quick]

SWEEP is a YAML file, or the name of a bundled sweep (``models/sweeps/``)::

    description: "what it maps"
    scenario: nn_styrofoam            # the base: a bundled name or a file
    set: ["simulation.duration=38"]   # overrides of the base, for every point
    grid:                             # fields varied as a full grid (dotted paths)
      controller.nn.learning_rate: {log: [1.0e-5, 1.0e-3, 5]}    # 5 values, log spaced
      environment.stiffness: {linear: [3000, 12000, 4]}         # 4 values, evenly spaced
      environment.damping: [20, 50, 100, 200]                   # a list
    paired:                           # fields varied together (equal lengths), crossed with grid
      controller.hybrid.force_gain: [1.0, 0.25]
      controller.hybrid.force_integral_gain: [0.02, 0.005]
    seeds: [0, 1, 2]                  # every point runs once per seed
    baseline: false                   # neural controller: also run its hybrid part alone,
                                      # to the scoring window's end (baseline_force_rmse_n)
    maps:                             # figures: a heat map (x and y), a line plot (x only)
      - {metric: force_rmse_n, x: environment.stiffness, y: controller.nn.learning_rate,
         facet: environment.damping}
    quick: {grid: {...}, seeds: [0], set: [...]}   # what --quick replaces (CI's short version)

Every point and seed is one ``run`` into ``DIR/runs/<field>=<value>__...__seed=<s>/``
(logs, ``metrics.json``; no figures), executed as a task on ``dask.distributed``:
a ``LocalCluster`` of ``--workers`` processes (one thread each; default one per
core), or the cluster at ``--scheduler`` (``dask scheduler`` / ``dask worker``, or
dask-jobqueue; the workers need this package installed and ``DIR`` on a shared
file system). The sweep writes:

* ``DIR/results.csv``: a row per point and seed: the varied fields (columns
  named by their dotted paths), ``seed``, ``status`` (completed, lost_contact,
  diverged, failed, interrupted), ``message``, ``wall_time_s`` (the point's
  task, start to end on its worker) and every scalar metric of the run
  (nested ones flattened with dots, e.g. ``identified_impedance_rls.stiffness``);
* the maps (PNG) and ``DIR/sweep.html`` (the maps and the table), and the
  heat maps as Markdown tables in ``DIR/maps.md``;
* ``DIR/sweep.yaml``: the resolved sweep.

A point that diverges or raises is a row with its status and message, never a
crashed sweep. Rerunning the same command skips every point whose folder
holds a finished ``metrics.json`` (written last and atomically by the run) and
runs only the rest. A worker that dies mid-point has its point rescheduled on
another by Dask (``distributed.scheduler.allowed-failures`` times); the table
is built from the run folders, so nothing is counted twice.
"""

import dataclasses as dc
import itertools
import json
from pathlib import Path

import numpy as np
import yaml

from drake_contact.app.campaign import (
    DEFAULT_ENSEMBLE,
    Campaign, CampaignResult, Point, failure_message, finished_metrics, run_campaign, run_status)
from drake_contact.app.sweep_figures import STATUSES
from drake_contact.errors import ScenarioError, did_you_mean
from drake_contact.resources import models_dir
from drake_contact.scenario import _yaml_load, load_scenario

def sweeps_dir() -> Path:
    """The bundled sweep files, one ``NAME.yaml`` per sweep."""
    return models_dir() / "sweeps"


def bundled_sweep_names() -> list[str]:
    return sorted(p.stem for p in sweeps_dir().glob("*.yaml"))


@dc.dataclass
class MapSpec:
    """One figure of the sweep."""

    # The metric (a results.csv column) drawn.
    metric: str
    # The varied field along x; along y for a heat map (empty: a line plot).
    x: str
    y: str = ""
    # A varied field with one panel per value (empty: one panel).
    facet: str = ""
    title: str = ""


@dc.dataclass
class Sweep:
    """A resolved sweep: the base scenario, its points and maps."""

    description: str
    scenario: str
    overrides: list
    # Field -> its values (grid: crossed; paired: zipped, then crossed with the grid).
    grid: dict
    paired: dict
    seeds: list
    maps: list
    # Run the neural controller's hybrid-only baseline at every point too.
    baseline: bool = False

    @property
    def fields(self) -> list[str]:
        return list(self.grid) + list(self.paired)

    def points(self) -> list[dict]:
        """Every point as {field: value}, grid order (the last field fastest)."""
        grid = [dict(zip(self.grid, values))
                for values in itertools.product(*self.grid.values())]
        paired = [dict(zip(self.paired, values)) for values in zip(*self.paired.values())]
        return [g | p for g in grid for p in (paired or [{}])]

    def tasks(self) -> list["Task"]:
        return [Task(point, seed) for point in self.points() for seed in self.seeds]


@dc.dataclass(frozen=True)
class Task:
    """One run: a point's values and a seed."""

    values: dict
    seed: int

    @property
    def name(self) -> str:
        """The run folder's name: ``field=value__...__seed=s``."""
        parts = [f"{field}={_format(value)}" for field, value in self.values.items()]
        return "__".join(parts + [f"seed={self.seed}"])

    def overrides(self) -> list[str]:
        return [f"{field}={json.dumps(value)}" for field, value in self.values.items()]


def _format(value) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def load_sweep(source, *, quick=False) -> Sweep:
    """Reads and checks a sweep (a bundled name or a YAML file); ``quick``
    applies its ``quick:`` replacements. Every point's scenario is loaded
    once here, so a bad field or value fails before anything runs, with
    one line naming it."""
    path = Path(source)
    if not path.is_file():
        bundled = sweeps_dir() / f"{source}.yaml"
        if not bundled.is_file():
            names = bundled_sweep_names()
            raise ScenarioError(f"sweep '{source}' is neither a file nor a bundled sweep"
                                f"{did_you_mean(source, names)}: choose a path or one of "
                                f"{', '.join(names)}")
        path = bundled
    try:
        data = _yaml_load(path.read_text()) or {}
    except yaml.YAMLError as e:
        raise ScenarioError(f"{path}: malformed YAML: {str(e).splitlines()[0]}") from None
    known = {"description", "scenario", "set", "duration", "grid", "paired", "seeds", "maps",
             "baseline", "quick"}
    _check_keys(data, known, "sweep")
    if quick and "quick" in data:
        _check_keys(data["quick"], known - {"quick", "description", "scenario", "maps"},
                    "quick")
        data = data | data["quick"]
    if "scenario" not in data:
        raise ScenarioError("sweep.scenario is missing: name the base scenario")
    overrides = list(data.get("set") or [])
    if not all(isinstance(o, str) for o in overrides):
        raise ScenarioError(f"sweep.set = {overrides!r} must be a list of 'dotted.key=value'")
    if data.get("duration") is not None:
        overrides.append(f"simulation.duration={data['duration']}")
    grid = {field: _values(spec, f"grid.{field}")
            for field, spec in (data.get("grid") or {}).items()}
    paired = {field: _values(spec, f"paired.{field}")
              for field, spec in (data.get("paired") or {}).items()}
    if len({len(v) for v in paired.values()}) > 1:
        raise ScenarioError("sweep.paired: every field needs the same number of values, got "
                            + ", ".join(f"{f}: {len(v)}" for f, v in paired.items()))
    if not grid and not paired:
        raise ScenarioError("sweep.grid is empty: vary at least one field")
    seeds = data.get("seeds", [0])
    if not (isinstance(seeds, list) and seeds
            and all(isinstance(s, int) and s >= 0 for s in seeds)):
        raise ScenarioError(f"sweep.seeds = {seeds!r} is out of range: must be a list of "
                            "whole numbers >= 0")
    baseline = data.get("baseline", False)
    if not isinstance(baseline, bool):
        raise ScenarioError(f"sweep.baseline = {baseline!r} must be true or false")
    sweep = Sweep(description=str(data.get("description", "")), scenario=str(data["scenario"]),
                  overrides=overrides, grid=grid, paired=paired, seeds=seeds,
                  maps=[_map(m, i, grid | paired) for i, m in enumerate(data.get("maps") or [])],
                  baseline=baseline)
    check_points(sweep)
    return sweep


def check_points(sweep: Sweep):
    """Loads every point's scenario once (not per seed): a bad field or
    value raises ScenarioError naming it, before anything runs."""
    for task in sweep.tasks()[:: len(sweep.seeds)]:
        load_scenario(sweep.scenario, sweep.overrides + task.overrides())


def _check_keys(data, known, where):
    if not isinstance(data, dict):
        raise ScenarioError(f"{where} must be a mapping of keys, got {data!r}")
    for key in data:
        if key not in known:
            raise ScenarioError(f"{where}.{key} is not a sweep key: known keys are "
                                f"{', '.join(sorted(known))}")


def _values(spec, where) -> list:
    """A list of values from a list, {linear: [a, b, n]} or {log: [a, b, n]}."""
    if isinstance(spec, list) and spec:
        return spec
    if isinstance(spec, dict) and len(spec) == 1:
        ((kind, args),) = spec.items()
        ok = (kind in ("linear", "log") and isinstance(args, list) and len(args) == 3
              and all(isinstance(a, (int, float)) for a in args)
              and isinstance(args[2], int) and args[2] >= 1)
        if ok and kind == "log" and not (args[0] > 0 and args[1] > 0):
            ok = False
        if ok:
            a, b, n = args
            values = np.geomspace(a, b, n) if kind == "log" else np.linspace(a, b, n)
            return [float(f"{v:.6g}") for v in values]
    raise ScenarioError(f"sweep.{where} = {spec!r} is out of range: give a list of values, "
                        "{linear: [start, stop, count]} or {log: [start, stop, count]} "
                        "(log: start, stop > 0)")


def _map(spec, i, fields) -> MapSpec:
    where = f"sweep.maps[{i}]"
    _check_keys(spec, {f.name for f in dc.fields(MapSpec)}, where)
    if "metric" not in spec or "x" not in spec:
        raise ScenarioError(f"{where} needs a metric and an x field")
    m = MapSpec(**{k: str(v) for k, v in spec.items()})
    for axis in ("x", "y", "facet"):
        field = getattr(m, axis)
        if field and field not in fields:
            raise ScenarioError(f"{where}.{axis} = '{field}' is not a varied field: choose one "
                                f"of {', '.join(fields)}")
    return m


def row_of(sweep: Sweep, task: Task, run_dir: Path) -> dict:
    """The results.csv row of a task from its run folder."""
    row = {"point": task.name} | dict(task.values) | {"seed": task.seed}
    metrics = finished_metrics(run_dir)
    timing = None
    if (run_dir / "task.json").exists():
        timing = json.loads((run_dir / "task.json").read_text())
    if metrics is None:
        failure = failure_message(run_dir)
        status = "failed" if failure else "interrupted"
        return row | {"status": status, "message": failure or "not run to the end",
                      "wall_time_s": None}
    wall = (timing["finished"] - timing["started"]) if timing else None
    row |= {"status": run_status(metrics), "message": metrics.get("message", ""),
            "wall_time_s": wall}
    for key, value in _flatten(metrics):
        if key not in row and key not in ("status", "message"):
            row[key] = value
    return row


def _flatten(metrics, prefix=""):
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _flatten(value, f"{name}.")
        elif isinstance(value, bool) or value is None or isinstance(value, (int, float, str)):
            yield name, value


class SweepCampaign(Campaign):
    """A sweep as a campaign: a point per task, scored into results.csv; the
    report is the maps, maps.md and sweep.html."""

    name = "sweep"

    def __init__(self, sweep: Sweep, figures=True):
        self.sweep, self.figures = sweep, figures
        self.columns = {"results": ["point", *sweep.fields, "seed", "status", "message",
                                    "wall_time_s"]}
        self._tasks = {t.name: t for t in sweep.tasks()}

    def points(self):
        return [Point(t.name, self.sweep.scenario, tuple(self.sweep.overrides + t.overrides()),
                      t.seed, baseline="window" if self.sweep.baseline else False)
                for t in self._tasks.values()]

    def score(self, point, run_dir):
        return {"results": [row_of(self.sweep, self._tasks[point.name], run_dir)]}

    def resolved(self):
        return _resolved(self.sweep)

    def report(self, out, result):
        if self.figures:
            _write_figures(self.sweep, result, out)


def run_sweep(sweep: Sweep, out_dir, *, workers=None, scheduler=None, progress=None,
              figures=True, ensemble=DEFAULT_ENSEMBLE) -> CampaignResult:
    """Runs every task of ``sweep`` not already finished in ``out_dir`` on a
    Dask cluster (:func:`drake_contact.app.campaign.run_campaign`), then
    writes results.csv, the maps and sweep.html.

    ``workers``: the LocalCluster's worker processes (default: one per
    core); ``scheduler``: an address of a running cluster instead;
    ``ensemble``: environments per ensemble (1: each point alone).
    ``progress(done, failed, total, eta_s, name)`` is called as tasks finish."""
    return run_campaign(SweepCampaign(sweep, figures), out_dir, workers=workers,
                        scheduler=scheduler, progress=progress, ensemble=ensemble)


def _resolved(sweep: Sweep) -> dict:
    return {"description": sweep.description, "scenario": sweep.scenario,
            "set": sweep.overrides, "grid": sweep.grid, "paired": sweep.paired,
            "seeds": sweep.seeds, "maps": [dc.asdict(m) for m in sweep.maps]}


def summary_lines(sweep: Sweep, result: CampaignResult) -> list[str]:
    counts = {s: sum(r["status"] == s for r in result.rows) for s in STATUSES}
    lines = [f"{len(result.rows)} runs ({len(result.rows) // len(sweep.seeds)} points x "
             f"{len(sweep.seeds)} seeds): "
             + ", ".join(f"{n} {s}" for s, n in counts.items() if n),
             f"ran {result.ran} now, skipped {result.skipped} already finished; "
             f"{result.wall_s:.1f} s wall on {result.workers} workers (and "
             f"{result.startup_s:.1f} s to start them)"]
    if result.ran:
        share = result.overhead_per_point_s / result.mean_task_s if result.mean_task_s else 0.0
        lines.append(f"mean task {result.mean_task_s:.2f} s; overhead per point "
                     f"{result.overhead_per_point_s:.3f} s ({100 * share:.1f} % of a task: "
                     "scheduling, gathering, idle workers at the end)")
    if result.interrupted:
        lines.append("INTERRUPTED: rerun the same command to finish the rest")
    return lines


def _write_figures(sweep: Sweep, result: CampaignResult, out: Path):
    from drake_contact.app.sweep_figures import (
        markdown_map, write_sweep_figures, write_sweep_html)
    figures = write_sweep_figures(result.rows, sweep.maps, out) if sweep.maps else []
    tables = [markdown_map(result.rows, m.metric, m.x, m.y, facet=m.facet, title=m.title)
              for m in sweep.maps]
    (out / "maps.md").write_text("\n".join(summary_lines(sweep, result) + [""] + tables))
    write_sweep_html(out, result.rows, figures, title=sweep.description or "sweep",
                     summary_lines=summary_lines(sweep, result))
