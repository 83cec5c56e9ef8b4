"""Running a scenario into an output folder.

:func:`run` simulates a scenario (:func:`drake_contact.simulation.simulate_scenario`)
and writes what the run produced:

* ``scenario.yaml``: the fully resolved scenario, overrides applied;
* ``log.npz``: 1 kHz signals keyed by name (each station signal's log keys),
  plus ``t``;
* ``metrics.json``: :func:`drake_contact.scoring.metrics.compute_metrics`;
* ``*.png``: figures of the main signals.

A run that diverges or is interrupted (Ctrl-C) still writes all of these up
to the last logged sample; ``metrics.json`` says why it stopped.
"""

import json
import shutil
import sys
from pathlib import Path

import numpy as np

from drake_contact.scenario import Scenario, dump_scenario
from drake_contact.scoring.metrics import baseline_scenario
from drake_contact.simulation import (
    NpzLog, RunResult, save_log, simulate_ensemble, simulate_scenario)
from drake_contact.visualization import check_record_path


def run(scenario: Scenario, out_dir, *, progress=None, figures=True,
        baseline=None, meshcat=None, record=None, realtime_rate=0.0) -> RunResult:
    """Simulates ``scenario`` and writes scenario.yaml, log.npz, metrics.json
    and figures into ``out_dir`` (created if needed).

    ``baseline`` (default: with figures, for the neural controller) also runs
    :func:`baseline_scenario` into ``out_dir/baseline``, adds its force RMSE
    to the metrics as ``baseline_*`` and draws both runs on the same axes.
    ``baseline="window"`` runs it only to 1 s past the end of the scoring
    window (the contact time is the run's: the compensator acts only in
    contact, so both runs are the same until then), enough for
    ``baseline_force_rmse_n``; sweeps use it (its per-window RMSE then stops
    there too).
    ``meshcat``, ``record`` (an HTML playback file) and ``realtime_rate``
    are passed to :func:`simulate_scenario` (the baseline is not drawn).
    """
    if record is not None:
        check_record_path(record)  # before writing anything
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scenario.yaml").write_text(dump_scenario(scenario))
    spool = out / ".log_spool"
    shutil.rmtree(spool, ignore_errors=True)
    try:
        result = simulate_scenario(scenario, progress=progress, meshcat=meshcat, record=record,
                                   realtime_rate=realtime_rate, spool=spool)
    except KeyboardInterrupt:
        # Ctrl-C while the diagram was being built: nothing was simulated,
        # but the folder still says what happened.
        np.savez(out / "log.npz", t=np.empty(0))
        _write_metrics(out, {"status": "interrupted",
                             "message": "interrupted before the simulation started"})
        raise
    _finish(scenario, result, out, figures=figures, baseline=baseline)
    shutil.rmtree(spool, ignore_errors=True)
    return result


def _baseline_to_run(scenario: Scenario, result: RunResult, *, figures, baseline):
    """The baseline scenario a finished run asks for (see :func:`run`), or
    None: the hybrid part alone, to 1 s past the scoring window for
    ``baseline="window"``."""
    if baseline is None:
        baseline = figures and scenario.controller.name == "nn"
    if not baseline or result.status != "completed":
        return None
    base_scenario = baseline_scenario(scenario)
    window_end = scenario.scoring.window_end_s
    contact = result.metrics.get("contact_time_s")
    if baseline == "window" and window_end > 0 and contact is not None:
        base_scenario.simulation.duration = min(scenario.simulation.duration,
                                                contact + window_end + 1.0)
    return base_scenario


def _finish(scenario: Scenario, result: RunResult, out: Path, *, figures, baseline,
            base=None):
    """Writes a simulated run's log.npz, its baseline run (see :func:`run`;
    ``base``: that baseline's RunResult when it was already run, into
    ``out/baseline``), metrics.json and figures into ``out``;
    ``result.log`` then reads log.npz."""
    save_log(out / "log.npz", result.log)
    # The log now lives in log.npz: read from there, key by key.
    result.log = NpzLog(out / "log.npz")
    log, metrics = result.log, result.metrics
    baseline_log = None
    if base is None:
        base_scenario = _baseline_to_run(scenario, result, figures=figures, baseline=baseline)
        if base_scenario is not None:
            base = run(base_scenario, out / "baseline", figures=False, baseline=False)
    if base is not None:
        baseline_log = base.log
        for key in ("force_rmse_n", "force_rmse_windows_n", "force_mean_abs_error_n",
                    "adaptation_time_s"):
            if key in base.metrics:
                metrics[f"baseline_{key}"] = base.metrics[key]
        del base  # its diagram and simulator: nothing reads them again
    _write_metrics(out, metrics)
    if figures and len(log["t"]) > 1:
        from drake_contact.app.plotting import (
            plot_contact_figures, plot_main_signals, plot_sensor_figures)
        plot_main_signals(log, scenario, out)
        plot_sensor_figures(log, scenario, out)
        plot_contact_figures(log, scenario, out, baseline_log=baseline_log)


def run_ensemble(scenarios, out_dirs, *, progress=None, figures=None, baselines=None,
                 pack_baselines=0) -> list:
    """Simulates ``scenarios`` as one ensemble (:func:`simulate_ensemble`)
    and writes each one's folder of ``out_dirs`` as :func:`run` does: the
    same files, the same log bit for bit. ``figures`` and ``baselines``:
    each run's (see :func:`run`; default none). The baselines the runs ask
    for run after it: as ensembles of their own where at least
    ``pack_baselines`` (> 1; 0: never) share a structure (each log bit for
    bit its run alone), else alone. Returns the RunResults, in order."""
    outs = [Path(o) for o in out_dirs]
    for scenario, out in zip(scenarios, outs):
        out.mkdir(parents=True, exist_ok=True)
        (out / "scenario.yaml").write_text(dump_scenario(scenario))
    results = simulate_ensemble(scenarios, progress=progress)
    figures = figures or [False] * len(scenarios)
    baselines = baselines or [None] * len(scenarios)
    asked = {i: _baseline_to_run(s, r, figures=f, baseline=b)
             for i, (s, r, f, b) in enumerate(zip(scenarios, results, figures, baselines))}
    from drake_contact.structure import ensemble_structure
    groups = {}
    for i, base in asked.items():
        if base is not None:
            groups.setdefault(ensemble_structure(base), []).append(i)
    bases = {}
    for members in groups.values():
        if pack_baselines > 1 and len(members) >= pack_baselines:  # else alone, in _finish
            bases |= dict(zip(members, run_ensemble(
                [asked[i] for i in members], [outs[i] / "baseline" for i in members],
                baselines=[False] * len(members))))
    for i, (scenario, result, out, drawn, baseline) in enumerate(
            zip(scenarios, results, outs, figures, baselines)):
        _finish(scenario, result, out, figures=drawn, baseline=baseline, base=bases.get(i))
        result.simulator = None
    return results


def _write_metrics(out: Path, metrics: dict):
    """Writes metrics.json last and atomically: a run folder whose
    metrics.json parses is a finished run (the sweep's resume relies on it)."""
    partial = out / "metrics.json.partial"
    partial.write_text(json.dumps(metrics, indent=2, sort_keys=True) + "\n")
    partial.replace(out / "metrics.json")


def terminal_progress(stream=sys.stderr):
    """A progress callback printing simulated time and ETA on a terminal,
    or None when ``stream`` is not one (runs stay quiet in logs and CI)."""
    if not stream.isatty():
        return None

    def report(t, duration, wall_s):
        eta = wall_s * (duration - t) / t if t > 0 else float("nan")
        end = "\n" if t >= duration else ""
        stream.write(f"\r  t = {t:7.2f} / {duration:.2f} s   ETA {eta:6.1f} s  {end}")
        stream.flush()
    return report
