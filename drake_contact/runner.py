"""Simulates one scenario and writes its logs, metrics and figures.

:func:`run` is the library entry point (the ``drake-contact run`` command and
the tests call it). A run writes into its output folder:

* ``scenario.yaml``: the fully resolved scenario, overrides applied;
* ``log.npz``: 1 kHz signals keyed by name (:data:`LOG_SIGNALS`), plus ``t``;
* ``metrics.json``: timing, peak force, ground truth and steady-state numbers;
* ``*.png``: figures of the main signals.

A run that diverges (non-finite state, or a contact force above
``simulation.force_limit``) or is interrupted (Ctrl-C) still writes all of
these up to the last logged sample; ``metrics.json`` says why it stopped.
"""

import copy
import dataclasses as dc
import json
import sys
import time
import zlib
from pathlib import Path

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, RandomSource

from drake_contact.arm import CONTROL_PERIOD
from drake_contact.diagram import MakeContactDiagram
from drake_contact.errors import SimulationDiverged
from drake_contact.identification import add_stiffness_ratio, identification_metrics
from drake_contact.scenario import Scenario, dump_scenario
from drake_contact.spectra import sensor_metrics
from drake_contact.visualization import (
    check_record_path, finish_recording, new_meshcat, start_recording)

#: log.npz key -> (exported output port, columns taken from it). Keys whose
#: port the scenario's diagram does not export are left out of the log.
LOG_SIGNALS = {
    "tip_pose_true": ("tip_state_true", slice(0, 3)),
    "tip_velocity_true": ("tip_state_true", slice(3, 6)),
    "contact_force_true": ("contact_force_true", 0),
    "penetration_true": ("penetration_true", 0),
    "true_impedance": ("true_impedance", slice(0, 3)),
    "joint_positions_true": ("joint_state_true", slice(0, 3)),
    "joint_velocities_true": ("joint_state_true", slice(3, 6)),
    "joint_positions_measured": ("joint_positions_measured", slice(0, 3)),
    "joint_torque_commanded": ("joint_torque_commanded", slice(0, 3)),
    "joint_torque_applied": ("joint_torque_applied", slice(0, 3)),
    "joint_friction_torque": ("joint_friction_torque", slice(0, 3)),
    "force_measured": ("force_measured", 0),
    "force_filtered": ("force_filtered", 0),
    "force_measured_antialiased": ("force_measured_antialiased", 0),
    "tip_pose_measured": ("tip_pose_measured", slice(0, 3)),
    "tip_velocity_measured": ("tip_velocity_measured", slice(0, 3)),
    "tip_acceleration_measured": ("tip_acceleration_measured", slice(0, 3)),
    "joint_positions_estimated": ("joint_positions_estimated", slice(0, 3)),
    "joint_velocities_estimated": ("joint_velocities_estimated", slice(0, 3)),
    "mode": ("mode", 0),
    "force_desired": ("force_desired", 0),
    "contact_info": ("contact_info", slice(0, 4)),
    "nn_output": ("nn_output", slice(0, 3)),
    "hybrid_torque": ("hybrid_torque", slice(0, 3)),
}

#: Exported ports logged under their own name when the scenario has them
#: (one per identifier).
DYNAMIC_LOG_PREFIXES = ("impedance_", "force_estimate_")

#: Simulated seconds between divergence checks and progress reports.
CHUNK_S = 0.1


@dc.dataclass
class RunResult:
    """What :func:`run` returns: the logs, the metrics, and how it ended."""

    log: dict
    metrics: dict
    status: str  # "completed", "diverged" or "interrupted"
    message: str = ""


def simulate(scenario: Scenario, *, progress=None, meshcat=None, record=None,
             realtime_rate=0.0):
    """Simulates ``scenario``; returns (log dict, status, message, wall time).

    ``progress(t, duration, wall_s)`` is called after every chunk if given.
    ``meshcat``: show the run live there (arm, wall, contact force; see
    :mod:`drake_contact.visualization`). ``record``: write a standalone HTML
    playback to this file (checked before simulating; a headless Meshcat is
    made if none is given), also for a diverged or interrupted run.
    ``realtime_rate`` > 0 paces the simulation (simulated s per wall s), for
    watching live. Without ``meshcat`` and ``record`` nothing is drawn.
    """
    live = meshcat is not None
    if record is not None:
        record = check_record_path(record)
        if meshcat is None:
            meshcat = new_meshcat()
    builder = DiagramBuilder()
    station = builder.AddNamedSystem("station", MakeContactDiagram(scenario, meshcat=meshcat))
    loggers = {}
    dynamic = [station.get_output_port(i).get_name() for i in range(station.num_output_ports())
               if station.get_output_port(i).get_name().startswith(DYNAMIC_LOG_PREFIXES)]
    for port_name in dict.fromkeys([v[0] for v in LOG_SIGNALS.values()] + dynamic):
        if not station.HasOutputPort(port_name):
            continue
        loggers[port_name] = LogVectorOutput(
            station.GetOutputPort(port_name), builder, CONTROL_PERIOD)
        loggers[port_name].set_name(f"log_{port_name}")
    diagram = builder.Build()
    diagram.set_name("run")

    simulator = Simulator(diagram)
    simulator.set_target_realtime_rate(realtime_rate)
    context = simulator.get_mutable_context()
    # Recording is on whenever something is drawn: a live browser can
    # replay the run once it is sent at the end.
    visualizers = start_recording(diagram, live=live) if meshcat is not None else []
    SeedRandomSources(diagram, context, scenario.simulation.seed)
    duration = scenario.simulation.duration
    force_limit = scenario.simulation.force_limit
    status, message = "completed", ""
    start = time.perf_counter()
    try:
        simulator.Initialize()
        chunks = int(np.ceil(duration / CHUNK_S - 1e-9))
        for k in range(1, chunks + 1):
            # Whole multiples of the chunk (no accumulated rounding), ending
            # exactly at the duration.
            t = duration if k == chunks else k * CHUNK_S
            simulator.AdvanceTo(t)
            _check_divergence(loggers, context, force_limit)
            if progress is not None:
                progress(t, duration, time.perf_counter() - start)
    except SimulationDiverged as e:
        status, message = "diverged", str(e)
    except KeyboardInterrupt:
        status, message = "interrupted", f"interrupted at t = {context.get_time():.3f} s"
    except RuntimeError as e:
        status = "diverged"
        message = (f"simulation failed at t = {context.get_time():.3f} s: "
                   f"{str(e).splitlines()[0]}")
    wall_s = time.perf_counter() - start
    finish_recording(visualizers, meshcat, record)
    log = _collect(loggers, context)
    if status == "diverged":
        log = _truncate_at_divergence(log, force_limit)
    return log, status, message, wall_s


def SeedRandomSources(diagram, context, seed):
    """Seeds every RandomSource from the scenario seed and its own name.

    Drake's SetRandomContext draws every subsystem's random state from one
    generator in diagram order (LinearSystems draw too), so adding any system
    would change the noise. Seeding each source by name keeps the same noise
    whatever controller or identifier a user wires in."""
    diagram.SetRandomContext(context, RandomGenerator(seed))
    for system in leaf_systems(diagram):
        if isinstance(system, RandomSource):
            name_hash = zlib.crc32(system.GetSystemPathname().encode())
            system.SetRandomContext(system.GetMyMutableContextFromRoot(context),
                                    RandomGenerator((seed * 1_000_003 + name_hash) % 2**31))


def leaf_systems(diagram):
    """Every leaf system of ``diagram``, depth first, in diagram order."""
    for system in diagram.GetSystems():
        if isinstance(system, Diagram):
            yield from leaf_systems(system)
        else:
            yield system


def _check_divergence(loggers, context, force_limit):
    """Raises SimulationDiverged at the first bad sample of the last chunk."""
    chunk = int(round(CHUNK_S / CONTROL_PERIOD)) + 1
    state_log = loggers["joint_state_true"].FindLog(context)
    force_log = loggers["contact_force_true"].FindLog(context)
    times = state_log.sample_times()[-chunk:]
    state = state_log.data()[:, -chunk:]
    force = force_log.data()[0, -chunk:]
    bad_state = ~np.all(np.isfinite(state), axis=0)
    bad_force = ~np.isfinite(force) | (force > force_limit)
    if bad_state.any() or bad_force.any():
        i = int(np.argmax(bad_state | bad_force))
        if bad_state[i]:
            where = "joint_state_true"
            what = "the arm's state is not finite"
        elif not np.isfinite(force[i]):
            where = "contact_force_true"
            what = "the contact force is not finite"
        else:
            where = "contact_force_true"
            what = f"the contact force {force[i]:.4g} N exceeds simulation.force_limit = {force_limit} N"
        raise SimulationDiverged(
            f"diverged at t = {times[i]:.3f} s: {what} ({where})", time_s=times[i], where=where)


def _truncate_at_divergence(log, force_limit):
    """Keeps the samples up to and including the first bad one."""
    bad = ~np.isfinite(log["contact_force_true"]) | (log["contact_force_true"] > force_limit)
    bad |= ~np.all(np.isfinite(log["joint_positions_true"]), axis=1)
    if bad.any():
        stop = int(np.argmax(bad)) + 1
        log = {k: v[:stop] for k, v in log.items()}
    return log


def _collect(loggers, context):
    logs = {name: logger.FindLog(context) for name, logger in loggers.items()}
    n = min(log.num_samples() for log in logs.values())
    out = {"t": logs["joint_state_true"].sample_times()[:n].copy()}
    for key, (port_name, columns) in LOG_SIGNALS.items():
        if port_name in logs:
            out[key] = logs[port_name].data()[columns, :n].T.copy()
    for port_name, log in logs.items():
        if port_name.startswith(DYNAMIC_LOG_PREFIXES):
            data = log.data()[:, :n].T.copy()
            out[port_name] = data[:, 0] if data.shape[1] == 1 else data
    add_stiffness_ratio(out)
    return out


def compute_metrics(scenario: Scenario, log: dict, wall_s: float) -> dict:
    """Timing, peak force, ground truth and steady-state contact numbers."""
    t = log["t"]
    simulated = float(t[-1]) if len(t) else 0.0
    steps = simulated / scenario.arm.time_step
    env = scenario.environment
    force = log["contact_force_true"]
    penetration = log["penetration_true"]
    metrics = {
        "simulated_time_s": simulated,
        "wall_time_s": wall_s,
        "realtime_factor": simulated / wall_s if wall_s > 0 else float("nan"),
        "us_per_step": wall_s / steps * 1e6 if steps > 0 else float("nan"),
        "plant_time_step_s": scenario.arm.time_step,
        "peak_force_n": float(np.max(force)) if len(force) else 0.0,
        "true_impedance": {"mass": env.mass, "damping": env.damping, "stiffness": env.stiffness},
    }
    window = t >= simulated - scenario.simulation.settle_window
    contact = window & (penetration > 0)
    if contact.any():
        f_mean = float(np.mean(force[contact]))
        x_mean = float(np.mean(penetration[contact]))
        K_true = float(np.mean(log["true_impedance"][contact, 2]))
        metrics["steady_force_n"] = f_mean
        metrics["steady_penetration_m"] = x_mean
        metrics["steady_stiffness_ratio_n_per_m"] = f_mean / x_mean
        metrics["steady_stiffness_error"] = f_mean / x_mean / K_true - 1.0
    metrics.update(sensor_metrics(log, scenario.dsp.tare_window_s))
    metrics.update(tracking_metrics(log, scenario))
    metrics.update(identification_metrics(log, scenario.identifiers))
    return metrics


def tracking_metrics(log: dict, scenario: Scenario) -> dict:
    """Contact switch and force/position tracking against ground truth, in
    the scoring window after the first switch (runs with a ``mode`` log)."""
    if "mode" not in log or not np.any(log["mode"] > 0):
        return {"contact_time_s": None} if "mode" in log else {}
    t = log["t"]
    i_contact = int(np.argmax(log["mode"] > 0))
    t_contact = float(t[i_contact])
    s = scenario.scoring
    end = t[-1] + 1.0 if s.window_end_s == 0 else t_contact + s.window_end_s
    window = (t >= t_contact + s.window_start_s) & (t < end)
    out = {
        "contact_time_s": t_contact,
        "mode_switches": int(np.sum(np.abs(np.diff(log["mode"])) > 0)),
        "impact_peak_force_n": float(np.max(log["contact_force_true"][
            (t >= t_contact) & (t < t_contact + s.impact_window_s)])),
        "scoring_window_s": [float(t_contact + s.window_start_s), float(min(end, t[-1]))],
    }
    if window.sum() > 0:
        force = log["contact_force_true"][window]
        error = force - log["force_desired"][window]
        hybrid = scenario.controller.hybrid
        out.update({
            "force_mean_n": float(np.mean(force)),
            "force_desired_mean_n": float(np.mean(log["force_desired"][window])),
            "force_rmse_n": float(np.sqrt(np.mean(error**2))),
            "force_mean_abs_error_n": float(np.mean(np.abs(error))),
            "y_max_abs_error_m": float(np.max(np.abs(log["tip_pose_true"][window, 1]
                                                      - hybrid.y_desired))),
            "phi_max_abs_error_rad": float(np.max(np.abs(log["tip_pose_true"][window, 2]
                                                         - hybrid.phi_desired))),
        })
    out.update(adaptation_metrics(log, t_contact, s))
    return out


#: adaptation_time_s slides its window by this much (s).
ADAPTATION_STEP_S = 0.5


def adaptation_metrics(log: dict, t_contact: float, scoring) -> dict:
    """Force RMSE (true force vs f_d) per ``rmse_window_s`` window from the
    switch, and the time from the switch to the end of the first sliding
    window whose RMSE is below ``adaptation_rmse_n`` (None if none is)."""
    t = log["t"]
    error = log["contact_force_true"] - log["force_desired"]
    width = scoring.rmse_window_s

    def rmse(start):
        window = (t >= t_contact + start - 1e-9) & (t < t_contact + start + width - 1e-9)
        return float(np.sqrt(np.mean(error[window] ** 2)))

    span = t[-1] + CONTROL_PERIOD - t_contact  # logged time after the switch
    whole = int(np.floor(span / width + 1e-9))
    windows = [rmse(k * width) for k in range(whole)]
    adaptation = None
    for k in range(int(np.floor((span - width) / ADAPTATION_STEP_S + 1e-9)) + 1):
        if rmse(k * ADAPTATION_STEP_S) < scoring.adaptation_rmse_n:
            adaptation = k * ADAPTATION_STEP_S + width
            break
    return {"force_rmse_windows_n": windows, "adaptation_time_s": adaptation}


def baseline_scenario(scenario: Scenario) -> Scenario:
    """The hybrid part alone of a neural-controller scenario: the same arm,
    environment, seed and gains with the compensator removed (Fig 6.10)."""
    baseline = copy.deepcopy(scenario)
    baseline.controller.name = "hybrid"
    baseline.description = f"hybrid part alone of: {scenario.description}"
    return baseline


def run(scenario: Scenario, out_dir, *, progress=None, figures=True,
        baseline=None, meshcat=None, record=None, realtime_rate=0.0) -> RunResult:
    """Simulates ``scenario`` and writes scenario.yaml, log.npz, metrics.json
    and figures into ``out_dir`` (created if needed).

    ``baseline`` (default: with figures, for the neural controller) also runs
    :func:`baseline_scenario` into ``out_dir/baseline``, adds its force RMSE
    to the metrics as ``baseline_*`` and draws both runs on the same axes.
    ``meshcat``, ``record`` (an HTML playback file) and ``realtime_rate``
    are passed to :func:`simulate` (the baseline is not drawn).
    """
    if record is not None:
        check_record_path(record)  # before writing anything
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scenario.yaml").write_text(dump_scenario(scenario))
    log, status, message, wall_s = simulate(scenario, progress=progress, meshcat=meshcat,
                                            record=record, realtime_rate=realtime_rate)
    metrics = compute_metrics(scenario, log, wall_s)
    metrics["status"] = status
    if message:
        metrics["message"] = message
    np.savez(out / "log.npz", **log)
    if baseline is None:
        baseline = figures and scenario.controller.name == "nn"
    baseline_log = None
    if baseline and status == "completed":
        base = run(baseline_scenario(scenario), out / "baseline", figures=False, baseline=False)
        baseline_log = base.log
        for key in ("force_rmse_n", "force_rmse_windows_n", "force_mean_abs_error_n",
                    "adaptation_time_s"):
            if key in base.metrics:
                metrics[f"baseline_{key}"] = base.metrics[key]
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2, sort_keys=True) + "\n")
    if figures and len(log["t"]) > 1:
        from drake_contact.plotting import (
            plot_contact_figures, plot_main_signals, plot_sensor_figures)
        plot_main_signals(log, scenario, out)
        plot_sensor_figures(log, scenario, out)
        plot_contact_figures(log, scenario, out, baseline_log=baseline_log)
    return RunResult(log=log, metrics=metrics, status=status, message=message)


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
