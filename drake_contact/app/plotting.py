"""Figures of a run's log.

Two layers:

- Helpers that draw on Axes the caller owns and return the artists they
  drew, for users who plot a run's log themselves (a notebook, a GUI, a
  figure of their own): :func:`plot_force_tracking`, :func:`plot_tip_errors`,
  :func:`plot_impedance`, :func:`plot_signal`. They never create figures,
  show them or choose a backend.
- The runner's figure writers (:func:`plot_main_signals`,
  :func:`plot_sensor_figures`, :func:`plot_contact_figures`,
  :func:`plot_identification_figures`), which draw with those helpers on
  ``matplotlib.figure.Figure`` objects and write PNGs. No pyplot is involved:
  no window opens, no backend is needed or changed (a headless machine
  writes the same files), and a figure is freed when it goes out of scope.

A log is a mapping from signal names to arrays sampled at ``log["t"]`` (s),
one row per sample: the runner's ``RunResult.log``, or
``dict(np.load("log.npz"))``. Signals in SI units; the helpers scale lengths
to mm, angles to mrad and stiffness to kN/m where they say so.
"""

import dataclasses as dc
import functools
import gc
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

#: Thesis units of the impedance columns M_e, B_e, K_e: axis label, scale
#: from SI (kg, N s/m, N/m).
_IMPEDANCE_UNITS = (("M_e (kg)", 1.0), ("B_e (N s/m)", 1.0), ("K_e (kN/m)", 1e-3))

#: The runner's figures draw a line of more samples than this from its
#: min-max envelope (:func:`min_max_envelope`): a 600 s run's lines are
#: 600,000 samples each, which matplotlib would hold several times over
#: (hundreds of MB) to draw 880 pixels. Every thesis run is shorter (20 s).
FIGURE_MAX_POINTS = 50_000


def min_max_envelope(t, y, max_points):
    """The samples of the line (t, y) that keep its look: ``y`` cut into
    ``max_points // 2`` runs of consecutive samples, and of each run its
    lowest and highest sample, in time order. Peaks of one sample survive;
    a run holding a NaN gives that NaN (numpy's argmin and argmax pick it),
    so gaps stay gaps. Lines of ``max_points`` samples or fewer are
    returned as they are. No copy of the line is made."""
    t, y = np.asarray(t), np.asarray(y)
    if len(y) <= max_points:
        return t, y
    picks = _envelope_picks(y, max_points)
    return t[picks], y[picks]


def _envelope_picks(y, max_points):
    """The indices (sorted) of the samples :func:`min_max_envelope` keeps
    of a line longer than ``max_points``."""
    n = len(y)
    size = -(-n // max(max_points // 2, 1))
    whole = n // size * size
    runs = y[:whole].reshape(-1, size)  # a view
    start = np.arange(len(runs)) * size
    picks = [start + runs.argmin(axis=1), start + runs.argmax(axis=1)]
    if whole < n:
        tail = y[whole:]
        picks.append(whole + np.array([tail.argmin(), tail.argmax()]))
    return np.unique(np.concatenate(picks))


@dc.dataclass
class ForceTrackingLines:
    """The lines :func:`plot_force_tracking` drew; None where the log lacks
    the signal (or no scenario was given, for ``threshold``)."""

    # True normal contact force (N), ``log["contact_force_true"]``.
    true: Line2D
    # Raw sensor force after tare (N), ``log["force_measured"]``.
    measured: Line2D | None = None
    # Filtered force the controller sees (N), ``log["force_filtered"]``.
    filtered: Line2D | None = None
    # Desired force f_d (N), ``log["force_desired"]``.
    desired: Line2D | None = None
    # The hybrid controller's contact switch threshold (N), horizontal.
    threshold: Line2D | None = None


@dc.dataclass
class TipErrorLines:
    """The lines :func:`plot_tip_errors` drew."""

    # y - y_d (mm).
    y: Line2D
    # phi - phi_d (mrad).
    phi: Line2D


@dc.dataclass
class ImpedanceLines:
    """The lines :func:`plot_impedance` drew, in the order M_e, B_e, K_e."""

    # An identifier's estimates: M_e (kg), B_e (N s/m), K_e (kN/m).
    estimates: list[Line2D]
    # The environment's true M_e, B_e, K_e, dashed; None when not drawn.
    truth: list[Line2D] | None = None


def plot_signal(ax, log, key, *, column=None, scale=1.0, label=None, max_points=None,
                **line_kw) -> Line2D:
    """Draw one logged signal against time.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Axes to draw on.
    log : mapping of str to numpy.ndarray
        A run's log; ``log["t"]`` is the time (s), one row per sample.
    key : str
        Name of the signal, e.g. ``"contact_force_true"`` (N).
    column : int, optional
        Column of a vector signal (e.g. 1 for y of ``"tip_pose_true"``,
        which is (x, y, phi) in m, m, rad). Required for a vector signal,
        unused for a scalar one.
    scale : float, optional
        Factor applied to the signal's SI values (1e3 for mm or mrad).
    label : str, optional
        Legend label; default ``key`` (with ``[column]`` when given).
    max_points : int, optional
        Draw a longer line from its min-max envelope of this many points
        (:func:`min_max_envelope`); default: every sample.
    **line_kw
        Passed to ``ax.plot`` (``color``, ``lw``, ``ls``, ...).

    Returns
    -------
    matplotlib.lines.Line2D
        The line; its x data is ``log["t"]``, its y data the signal times
        ``scale`` (with ``max_points``, the envelope's samples of them).
    """
    values = np.asarray(log[key])
    if column is not None:
        values = values[:, column]
    elif values.ndim != 1:
        raise ValueError(f"log['{key}'] has {values.shape[1]} columns: choose one with column=")
    if label is None:
        label = key if column is None else f"{key}[{column}]"
    t = log["t"]
    if max_points is not None:
        # The same samples as the envelope of values * scale (scaling keeps
        # which sample is a run's lowest and highest), without that copy.
        t, values = min_max_envelope(t, values, max_points)
    (line,) = ax.plot(t, values * scale, label=label, **line_kw)
    return line


def plot_force_tracking(ax, log, *, scenario=None, label=None,
                        max_points=None) -> ForceTrackingLines:
    """Draw the contact force against time: the true force, the sensor's
    raw and filtered forces and the desired force, each when in the log.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Axes to draw on; its y label is set to ``force (N)``.
    log : mapping of str to numpy.ndarray
        A run's log: ``t`` (s) and ``contact_force_true`` (N); optionally
        ``force_measured``, ``force_filtered`` and ``force_desired`` (N).
    scenario : drake_contact.scenario.Scenario, optional
        When given, the hybrid controller's contact threshold
        (``controller.hybrid.contact_threshold_n``, N) is drawn dotted.
    label : str, optional
        Legend label of the true force; default ``"true"``.
    max_points : int, optional
        As for :func:`plot_signal`.

    Returns
    -------
    ForceTrackingLines
        The lines drawn (None for a signal not in the log).
    """
    measured = filtered = desired = threshold = None
    if "force_measured" in log:
        measured = plot_signal(ax, log, "force_measured", label="measured (raw)", lw=0.7,
                               alpha=0.6, max_points=max_points)
    if "force_filtered" in log:
        filtered = plot_signal(ax, log, "force_filtered", label="filtered (controller)", lw=1.2,
                               max_points=max_points)
    true = plot_signal(ax, log, "contact_force_true", label=label or "true", color="k", lw=1.2,
                       max_points=max_points)
    if "force_desired" in log:
        desired = plot_signal(ax, log, "force_desired", label="desired", color="r", ls="--",
                              lw=1, max_points=max_points)
    if scenario is not None:
        threshold = ax.axhline(scenario.controller.hybrid.contact_threshold_n, color="grey",
                               ls=":", lw=1)
    ax.set_ylabel("force (N)")
    return ForceTrackingLines(true=true, measured=measured, filtered=filtered, desired=desired,
                              threshold=threshold)


def plot_tip_errors(ax, log, scenario, *, max_points=None) -> TipErrorLines:
    """Draw the tip's errors from the position the hybrid controller holds,
    y - y_d (mm) and phi - phi_d (mrad), against time.

    Parameters
    ----------
    ax : matplotlib.axes.Axes or pair of them
        One Axes for both errors, or (Axes for y, Axes for phi). The y
        labels are set.
    log : mapping of str to numpy.ndarray
        A run's log: ``t`` (s) and ``tip_pose_true`` (N x 3: x, y in m,
        phi in rad).
    scenario : drake_contact.scenario.Scenario
        Gives y_d and phi_d (``controller.hybrid.y_desired``, m, and
        ``.phi_desired``, rad).
    max_points : int, optional
        As for :func:`plot_signal`.

    Returns
    -------
    TipErrorLines
        The y and phi lines.
    """
    ax_y, ax_phi = (ax, ax) if not np.iterable(ax) else ax
    hybrid = scenario.controller.hybrid
    pose = np.asarray(log["tip_pose_true"])
    errors = {"t": log["t"], "y": pose[:, 1] - hybrid.y_desired,
              "phi": pose[:, 2] - hybrid.phi_desired}
    lines = TipErrorLines(y=plot_signal(ax_y, errors, "y", scale=1e3, label="y error (mm)",
                                        max_points=max_points),
                          phi=plot_signal(ax_phi, errors, "phi", scale=1e3,
                                          label="phi error (mrad)", max_points=max_points))
    if ax_y is ax_phi:
        ax_y.set_ylabel("tip error (mm, mrad)")
    else:
        ax_y.set_ylabel("y error (mm)")
        ax_phi.set_ylabel("phi error (mrad)")
    return lines


def plot_impedance(axes, log, name, *, truth=True, max_points=None,
                   **line_kw) -> ImpedanceLines:
    """Draw an online identifier's estimates of the environment's impedance
    M_e (kg), B_e (N s/m) and K_e (kN/m) against time, on three Axes.

    Parameters
    ----------
    axes : sequence of three matplotlib.axes.Axes
        Axes for M_e, B_e and K_e; their y labels are set.
    log : mapping of str to numpy.ndarray
        A run's log: ``t`` (s), ``impedance_{name}`` (N x 3: M, B, K in kg,
        N s/m, N/m) and, for ``truth``, ``true_impedance`` (the same columns).
    name : str
        The identifier's name in the scenario (e.g. ``"rls"``).
    truth : bool, optional
        Also draw the true impedance, dashed black (default True).
    max_points : int, optional
        As for :func:`plot_signal`.
    **line_kw
        Passed to ``ax.plot`` for the estimates (``color``, ``lw``, ...).

    Returns
    -------
    ImpedanceLines
        The estimate lines (label ``name``) and the truth lines (label
        ``"truth"``), each in the order M_e, B_e, K_e.
    """
    lines = ImpedanceLines(estimates=[], truth=[] if truth else None)
    for k, (ax, (ylabel, scale)) in enumerate(zip(axes, _IMPEDANCE_UNITS, strict=True)):
        lines.estimates.append(plot_signal(ax, log, f"impedance_{name}", column=k,
                                           scale=scale, label=name, max_points=max_points,
                                           **line_kw))
        if truth:
            lines.truth.append(plot_signal(ax, log, "true_impedance", column=k, scale=scale,
                                           label="truth", color="k", ls="--", lw=1,
                                           max_points=max_points))
        ax.set_ylabel(ylabel)
    return lines


# The runner's figures draw through these: long lines as their envelopes.
_signal = functools.partial(plot_signal, max_points=FIGURE_MAX_POINTS)
_force_tracking = functools.partial(plot_force_tracking, max_points=FIGURE_MAX_POINTS)
_tip_errors = functools.partial(plot_tip_errors, max_points=FIGURE_MAX_POINTS)
_impedance = functools.partial(plot_impedance, max_points=FIGURE_MAX_POINTS)


def _plot(ax, t, y, *args, **kw):
    """``ax.plot(t, y, ...)`` of a line drawn as its envelope when long."""
    return ax.plot(*min_max_envelope(t, y, FIGURE_MAX_POINTS), *args, **kw)


def _new_figure(figsize, nrows=1, ncols=1, **subplots_kw):
    """A figure outside pyplot (nothing to close, no backend) and its axes."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **subplots_kw)


def _save(fig, axes, path, *, legend=True, collect=False) -> Path:
    """Grid (and legend) on every axis, tight layout, write the PNG, then
    empty the figure (its lines and rendered canvas are not kept until the
    cyclic garbage collector comes by). ``collect``: run that collector now
    (about 0.1 s): a long run's figures are drawn one after another within
    the run's peak memory (a 600 s run stays under 300 MB)."""
    for ax in np.ravel(axes):
        ax.grid(True, which="both", alpha=0.3)
        if legend and ax.get_legend_handles_labels()[0]:
            ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    fig.clear()
    if collect:
        gc.collect()
    return Path(path)


def _window(log, keep, *, t0=0.0, keys=None) -> dict:
    """The samples of ``log`` where ``keep`` is true, with time counted from
    ``t0``; only ``keys`` (and ``t``) when given."""
    keys = log.keys() if keys is None else [key for key in keys if key in log]
    inside = np.flatnonzero(keep)
    if len(inside) and inside[-1] - inside[0] + 1 == len(inside) and 2 * len(inside) >= len(keep):
        # One long span: views, not copies. (A short one is copied, so the
        # whole signal a log read for it is not kept alive by the view.)
        keep = slice(inside[0], inside[-1] + 1)
    out = {key: np.asarray(log[key])[keep] for key in keys}
    out["t"] = np.asarray(log["t"])[keep] - t0
    return out


def _envelope_window(log, start, *, t0, keys, max_points=FIGURE_MAX_POINTS) -> dict:
    """As :func:`_window` for the samples from index ``start`` on, but of
    a long window only the samples some line's envelope needs: the union,
    over ``keys`` and their columns, of each column's
    :func:`min_max_envelope` picks. Each key is read once to pick and once
    to take the picks, so at most one full-length signal is held at a time
    (a 600 s run's ``tip_pose_true`` is 14 MB)."""
    keys = [key for key in keys if key in log]
    t = np.asarray(log["t"])
    if len(t) - start <= max_points:
        return _window(log, np.arange(len(t)) >= start, t0=t0, keys=keys)
    t = t[start:]
    picks = []
    for key in keys:
        signal = np.asarray(log[key])[start:]
        columns = signal.reshape(len(signal), -1)
        picks += [_envelope_picks(columns[:, k], max_points) for k in range(columns.shape[1])]
        del signal, columns
    picks = np.unique(np.concatenate(picks))
    out = {key: np.asarray(log[key])[start:][picks] for key in keys}
    out["t"] = t[picks] - t0
    return out


def _switch_time(log) -> float:
    """Time (s) of the first switch to hybrid control (``mode`` > 0)."""
    return log["t"][np.argmax(log["mode"] > 0)]


def plot_main_signals(log: dict, scenario, out_dir) -> Path:
    """Contact force, penetration, tip pose and joint torques over time."""
    t = log["t"]
    fig, axes = _new_figure((8, 9), 4, 1, sharex=True)
    _signal(axes[0], log, "contact_force_true", label="true normal force")
    if "force_desired" in log:
        _signal(axes[0], log, "force_desired", label="desired f_d", color="r", ls="--")
    elif scenario.controller.name == "push":
        # The push's command: open loop, so the wall gets what the joints'
        # friction leaves of it.
        push = scenario.controller.push
        axes[0].hlines(push.force, push.start_time, t[-1], color="r", ls="--", lw=1,
                       label=f"commanded push ({push.force:g} N, open loop)")
    axes[0].set_ylabel("force (N)")
    _signal(axes[1], log, "penetration_true", scale=1e3, label="true penetration")
    axes[1].set_ylabel("penetration (mm)")
    _plot(axes[2], t, (log["tip_pose_true"][:, 0] - scenario.environment.surface_x) * 1e3,
          label="x - surface (mm)")
    _signal(axes[2], log, "tip_pose_true", column=1, scale=1e3, label="y (mm)")
    _signal(axes[2], log, "tip_pose_true", column=2, scale=1e3, label="phi (mrad)")
    axes[2].set_ylabel("tip pose (mm, mrad)")
    for i in range(3):
        _signal(axes[3], log, "joint_torque_applied", column=i, label=f"joint {i + 1}")
    axes[3].set_ylabel("applied torque (N m)")
    axes[3].set_xlabel("time (s)")
    env = scenario.environment
    fig.suptitle(f"{scenario.description or 'run'}\n"
                 f"K_e = {env.stiffness:.4g} N/m, B_e = {env.damping:.4g} N s/m, "
                 f"M_e = {env.mass:.4g} kg", fontsize=10)
    return _save(fig, axes, Path(out_dir) / "main_signals.png")


def plot_sensor_figures(log: dict, scenario, out_dir) -> list[Path]:
    """Fig 4.4 (a raw force sample) always; Figs 3.5 and 3.7 when the log has
    the 190 Hz RC probe channel."""
    from scipy import signal as sps

    from drake_contact.sensing.filters import rc_lowpass_analog
    from drake_contact.scoring.spectra import welch_psd, windows

    out_dir = Path(out_dir)
    paths = []
    t = log["t"]
    rest, pressing = windows(log, scenario.dsp.tare_window_s)
    # Fig 4.4: one second of the raw DSP force, at rest if there is rest.
    pick = rest if rest.sum() >= 1000 else np.ones_like(rest)
    start = t[pick][0]
    sample = _window(log, (t >= start) & (t < start + 1.0),
                     keys=("force_measured", "force_filtered", "contact_force_true"))
    fig, ax = _new_figure((8, 3.5))
    _force_tracking(ax, sample)
    ax.set_xlabel("time (s)")
    ax.set_title("Fig 4.4: signal from the force sensor")
    paths.append(_save(fig, ax, out_dir / "fig4_4_raw_force.png"))

    if "force_measured_antialiased" in log and pressing.sum() >= 2048:
        f, p_raw = welch_psd(log["force_measured"][pressing])
        _, p_rc = welch_psd(log["force_measured_antialiased"][pressing])
        fig, ax = _new_figure((8, 4))
        ax.semilogy(f, p_raw, lw=0.9, label="unfiltered")
        ax.semilogy(f, p_rc, lw=0.9, label="190 Hz RC filtered")
        ax.axvline(120, color="grey", ls=":", lw=1)
        ax.axvline(480, color="grey", ls=":", lw=1)
        ax.set_xlim(0, 500)
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("PSD (N$^2$/Hz)")
        ax.set_title("Fig 3.5: PSD of the raw force, unfiltered and 190 Hz filtered")
        paths.append(_save(fig, ax, out_dir / "fig3_5_psd.png"))

        aa = scenario.dsp.anti_aliasing
        num, den = rc_lowpass_analog(aa.R1, aa.R2, aa.C1, aa.C2)
        freqs = np.logspace(0, 4, 400)
        _, h = sps.freqs(num, den, worN=2 * np.pi * freqs)
        fig, ax = _new_figure((7, 4))
        ax.semilogx(freqs, 20 * np.log10(np.abs(h)))
        fn = np.sqrt(den[2]) / (2 * np.pi)
        ax.axvline(fn, color="grey", ls=":", lw=1, label=f"natural frequency {fn:.1f} Hz")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("gain (dB)")
        ax.set_title("Fig 3.7: gain of the 2nd-order RC low-pass (190 Hz)")
        paths.append(_save(fig, ax, out_dir / "fig3_7_rc_gain.png"))
    return paths


def _figure_label(scenario, default):
    """("6.11, 6.15", "6_11") from the scenario's thesis_figures."""
    label = scenario.thesis_figures or default
    return label, label.split(",")[0].strip().replace(".", "_")


def plot_contact_figures(log: dict, scenario, out_dir, *, baseline_log=None) -> list[Path]:
    """Fig 4.2 (the force through the 5 N switch); the force tracking against
    f_d with y and phi errors (Figs 6.10-6.17), with the hybrid part alone on
    the same axes when ``baseline_log`` is given; the compensator's output."""
    if "mode" not in log or not np.any(log["mode"] > 0):
        return []
    out_dir = Path(out_dir)
    t = log["t"]
    t_c = _switch_time(log)
    long = len(t) > FIGURE_MAX_POINTS
    paths = []
    fig, ax = _new_figure((8, 4))
    _force_tracking(ax, _window(log, (t >= t_c - 0.3) & (t <= t_c + 0.7), t0=t_c,
                                keys=("force_measured", "force_filtered",
                                      "contact_force_true", "force_desired")),
                    scenario=scenario)
    ax.axvline(0, color="grey", ls=":", lw=1)
    ax.set_xlabel("time from the switch (s)")
    ax.set_title("Fig 4.2: force from position control to hybrid control")
    paths.append(_save(fig, ax, out_dir / "fig4_2_switch.png", collect=long))

    if scenario.identifiers:
        # The identification runs' thesis figures are the six-panel ones.
        label, stem = "", "force_tracking"
    else:
        label, stem = _figure_label(scenario, "6.10, 6.15")
        label, stem = f"Fig {label}: ", f"fig{stem}_force_tracking"
    fig, axes = _new_figure((9, 7.5), 3, 1, sharex=True)
    runs = [("neural controller" if baseline_log is not None else "true force", log, "k")]
    if baseline_log is not None and np.any(baseline_log["mode"] > 0):
        runs.append(("hybrid part alone", baseline_log, "tab:orange"))
    for name, run_log, colour in reversed(runs):
        run_t_c = _switch_time(run_log)
        # Only the run drawn last (this one) carries f_d.
        keys = ("contact_force_true", "tip_pose_true") + (("force_desired",)
                                                          if run_log is log else ())
        start = int(np.searchsorted(run_log["t"], run_t_c - 0.5))
        after = _envelope_window(run_log, start, t0=run_t_c, keys=keys)
        _force_tracking(axes[0], after, label=name).true.set(color=colour, lw=0.9)
        tip = _tip_errors(axes[1:], after, scenario)
        for line in (tip.y, tip.phi):
            line.set(color=colour, lw=0.9, label=name)
        del after  # before the next run's window is read (a long run's are tens of MB)
    axes[0].set_ylabel("true normal force (N)")
    axes[2].set_xlabel("time from the first contact (s)")
    fig.suptitle(f"{label}force tracking; {scenario.description}", fontsize=9)
    paths.append(_save(fig, axes, out_dir / f"{stem}.png", collect=long))

    if "nn_output" in log:
        after = _envelope_window(log, int(np.searchsorted(t, t_c - 0.5)), t0=t_c,
                                 keys=("nn_output",))
        fig, axes = _new_figure((8, 6), 3, 1, sharex=True)
        for k, (name, unit) in enumerate([("n_x", "N"), ("n_y", "N"), ("n_phi", "N m")]):
            _signal(axes[k], after, "nn_output", column=k, label=name, lw=0.8)
            axes[k].set_ylabel(f"{name} ({unit})")
        axes[2].set_xlabel("time from the first contact (s)")
        fig.suptitle(f"{label}the compensator's output n (J^T n is added to tau_h)",
                     fontsize=9)
        paths.append(_save(fig, axes, out_dir / f"{stem.replace('force_tracking', 'nn_output')}.png",
                           legend=False, collect=long))
    paths.extend(plot_identification_figures(log, scenario, out_dir))
    return paths


#: Line colours of the identifiers in one figure, in scenario order.
_IDENTIFIER_COLOURS = ("tab:blue", "tab:green", "tab:purple", "tab:orange", "tab:brown")


def plot_identification_figures(log: dict, scenario, out_dir) -> list[Path]:
    """Figs 6.1-6.9: per thesis figure, six panels over the first 4 s after
    the switch (force, displacement xe, f / xe, M_e, B_e, K_e), with every
    identifier that names the figure and the ground truth dashed; then each
    group's second figure: the whole run (RLS, Figs 6.2, 6.5) or the
    network's output error f - f_hat (NN, Fig 6.8)."""
    if not scenario.identifiers or "contact_info" not in log:
        return []
    info = log["contact_info"][:, 0]
    if not np.any(info >= 0):
        return []
    out_dir = Path(out_dir)
    t = log["t"]
    t_c = info[-1]
    groups = {}
    for config in scenario.identifiers:
        key = config.figures[0] if config.figures else f"_{config.name}"
        groups.setdefault(key, []).append(config)
    paths = []
    for key, configs in groups.items():
        label = key if not key.startswith("_") else ""
        stem = f"fig{label.replace('.', '_')}" if label else f"identification{key}"
        title = (f"Fig {label}: " if label else "") + \
            f"identification ({', '.join(c.name for c in configs)}), {scenario.description}"
        paths.append(_plot_identification(log, t, t_c, configs, 4.0, title,
                                          out_dir / f"{stem}_identification.png"))
        second = {c.figures[1] for c in configs if len(c.figures) > 1}
        for number in sorted(second):
            stem2 = f"fig{number.replace('.', '_')}"
            # A network's second figure is its output error; another's, the whole run.
            if log.get(f"force_estimate_{configs[0].name}") is None:
                paths.append(_plot_identification(
                    log, t, t_c, configs, t[-1] - t_c,
                    f"Fig {number}: identification over the whole run, {scenario.description}",
                    out_dir / f"{stem2}_identification.png"))
            else:
                paths.append(_plot_network_error(log, t, t_c, configs, number, scenario,
                                                 out_dir / f"{stem2}_nn_output_error.png"))
    return paths


def _plot_identification(log, t, t_c, configs, span_s, title, path) -> Path:
    keep = (t >= t_c - 0.05) & (t <= t_c + span_s)
    window = _window(log, keep, t0=t_c)
    true_k = window["true_impedance"][:, 2] / 1e3
    fig, axes = _new_figure((11, 8), 3, 2, sharex=True)
    _force_tracking(axes[0, 0], _window(log, keep, t0=t_c,
                                        keys=("force_filtered", "contact_force_true")))
    axes[0, 0].set_ylabel("force f (N)")
    ax = axes[1, 0]
    _signal(ax, window, "displacement_measured", scale=1e3, lw=0.8,
            label="xe measured (from the switch point)")
    pen = log["penetration_true"]
    _plot(ax, window["t"], (window["penetration_true"] - pen[np.argmax(t >= t_c)]) * 1e3, "k--",
          lw=0.8, label="true, from the switch point")
    ax.set_ylabel("displacement xe (mm)")
    ax = axes[2, 0]
    _signal(ax, window, "stiffness_ratio", scale=1e-3, lw=0.8, label="f / xe (measured)")
    _signal(ax, window, "true_impedance", column=2, scale=1e-3, color="k", ls="--", lw=1,
            label="true K_e")
    ax.set_ylabel("f / xe (kN/m)")
    ax.set_xlabel("time from the switch (s)")
    for i, (colour, config) in enumerate(zip(_IDENTIFIER_COLOURS, configs)):
        _impedance(axes[:, 1], window, config.name, truth=i == len(configs) - 1,
                   color=colour, lw=0.9)
    for ax in axes[2]:
        _clip_to_truth(ax, true_k)
    axes[2, 1].set_xlabel("time from the switch (s)")
    fig.suptitle(title, fontsize=9)
    return _save(fig, axes, path)


def _clip_to_truth(ax, truth):
    """K_e and f / xe start far off (theta0 = 2e5 N/m, xe ~ 0): show 0 to
    twice the truth."""
    ax.set_ylim(0, 2 * float(np.max(truth)))


def _plot_network_error(log, t, t_c, configs, number, scenario, path) -> Path:
    window = (t >= t_c) & (t <= t_c + 4.0)
    fig, ax = _new_figure((8, 4))
    for colour, config in zip(_IDENTIFIER_COLOURS, configs):
        estimate = log.get(f"force_estimate_{config.name}")
        if estimate is None:
            continue
        _plot(ax, t[window] - t_c, log["force_filtered"][window] - estimate[window],
              color=colour, lw=0.8, label=config.name)
    ax.set_xlabel("time from the switch (s)")
    ax.set_ylabel("output error f - f_hat (N)")
    ax.set_title(f"Fig {number}: error of the network's output, {scenario.description}",
                 fontsize=9)
    return _save(fig, ax, path)
