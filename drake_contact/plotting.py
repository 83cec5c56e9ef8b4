"""Figures of a run's log (matplotlib, written as PNG; never shown)."""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _save(fig, axes, path, *, legend=True) -> Path:
    """Grid (and legend) on every axis, tight layout, write the PNG, close."""
    for ax in np.ravel(axes):
        ax.grid(True, which="both", alpha=0.3)
        if legend and ax.get_legend_handles_labels()[0]:
            ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_main_signals(log: dict, scenario, out_dir) -> Path:
    """Contact force, penetration, tip pose and joint torques over time."""
    t = log["t"]
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    axes[0].plot(t, log["contact_force_true"], label="true normal force")
    axes[0].set_ylabel("force (N)")
    axes[1].plot(t, log["penetration_true"] * 1e3, label="true penetration")
    axes[1].set_ylabel("penetration (mm)")
    pose = log["tip_pose_true"]
    axes[2].plot(t, (pose[:, 0] - scenario.environment.surface_x) * 1e3,
                 label="x - surface (mm)")
    axes[2].plot(t, pose[:, 1] * 1e3, label="y (mm)")
    axes[2].plot(t, pose[:, 2] * 1e3, label="phi (mrad)")
    axes[2].set_ylabel("tip pose (mm, mrad)")
    for i in range(3):
        axes[3].plot(t, log["joint_torque_applied"][:, i], label=f"joint {i + 1}")
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

    from drake_contact.filters import rc_lowpass_analog
    from drake_contact.spectra import welch_psd, windows

    out_dir = Path(out_dir)
    paths = []
    t = log["t"]
    rest, pressing = windows(log, scenario.dsp.tare_window_s)
    # Fig 4.4: one second of the raw DSP force, at rest if there is rest.
    pick = rest if rest.sum() >= 1000 else np.ones_like(rest)
    start = t[pick][0]
    sample = (t >= start) & (t < start + 1.0)
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(t[sample], log["force_measured"][sample], lw=0.8, label="raw (after tare)")
    ax.plot(t[sample], log["force_filtered"][sample], lw=1.2, label="120 Hz filtered")
    ax.plot(t[sample], log["contact_force_true"][sample], "k--", lw=1, label="true")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force (N)")
    ax.set_title("Fig 4.4: signal from the force sensor")
    paths.append(_save(fig, ax, out_dir / "fig4_4_raw_force.png"))

    if "force_measured_antialiased" in log and pressing.sum() >= 2048:
        f, p_raw = welch_psd(log["force_measured"][pressing])
        _, p_rc = welch_psd(log["force_measured_antialiased"][pressing])
        fig, ax = plt.subplots(figsize=(8, 4))
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
        fig, ax = plt.subplots(figsize=(7, 4))
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
    t_c = t[np.argmax(log["mode"] > 0)]
    paths = []
    near = (t >= t_c - 0.3) & (t <= t_c + 0.7)
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(t[near] - t_c, log["force_measured"][near], lw=0.7, alpha=0.6, label="measured (raw)")
    ax.plot(t[near] - t_c, log["force_filtered"][near], lw=1.2, label="filtered (controller)")
    ax.plot(t[near] - t_c, log["contact_force_true"][near], "k", lw=1.2, label="true")
    ax.plot(t[near] - t_c, log["force_desired"][near], "r--", lw=1, label="desired")
    ax.axhline(scenario.controller.hybrid.contact_threshold_n, color="grey", ls=":", lw=1)
    ax.axvline(0, color="grey", ls=":", lw=1)
    ax.set_xlabel("time from the switch (s)")
    ax.set_ylabel("force (N)")
    ax.set_title("Fig 4.2: force from position control to hybrid control")
    paths.append(_save(fig, ax, out_dir / "fig4_2_switch.png"))

    if scenario.identifiers:
        # The identification runs' thesis figures are the six-panel ones.
        label, stem = "", "force_tracking"
    else:
        label, stem = _figure_label(scenario, "6.10, 6.15")
        label, stem = f"Fig {label}: ", f"fig{stem}_force_tracking"
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    runs = [("neural controller" if baseline_log is not None else "true force", log, "k")]
    if baseline_log is not None and np.any(baseline_log["mode"] > 0):
        runs.append(("hybrid part alone", baseline_log, "tab:orange"))
    for name, run_log, colour in reversed(runs):
        rt = run_log["t"]
        rc = rt[np.argmax(run_log["mode"] > 0)]
        after = rt >= rc - 0.5
        axes[0].plot(rt[after] - rc, run_log["contact_force_true"][after], color=colour, lw=0.9,
                     label=name)
        axes[1].plot(rt[after] - rc, run_log["tip_pose_true"][after, 1] * 1e3, color=colour,
                     lw=0.9, label=name)
        axes[2].plot(rt[after] - rc, run_log["tip_pose_true"][after, 2] * 1e3, color=colour,
                     lw=0.9, label=name)
    after = t >= t_c - 0.5
    axes[0].plot(t[after] - t_c, log["force_desired"][after], "r--", lw=1, label="desired")
    axes[0].set_ylabel("true normal force (N)")
    axes[1].set_ylabel("y error (mm)")
    axes[2].set_ylabel("phi error (mrad)")
    axes[2].set_xlabel("time from the first contact (s)")
    fig.suptitle(f"{label}force tracking; {scenario.description}", fontsize=9)
    paths.append(_save(fig, axes, out_dir / f"{stem}.png"))

    if "nn_output" in log:
        fig, axes = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
        for k, (name, unit) in enumerate([("n_x", "N"), ("n_y", "N"), ("n_phi", "N m")]):
            axes[k].plot(t[after] - t_c, log["nn_output"][after, k], lw=0.8)
            axes[k].set_ylabel(f"{name} ({unit})")
        axes[2].set_xlabel("time from the first contact (s)")
        fig.suptitle(f"{label}the compensator's output n (J^T n is added to tau_h)",
                     fontsize=9)
        paths.append(_save(fig, axes, out_dir / f"{stem.replace('force_tracking', 'nn_output')}.png",
                           legend=False))
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
            if configs[0].kind == "rls":
                paths.append(_plot_identification(
                    log, t, t_c, configs, t[-1] - t_c,
                    f"Fig {number}: identification over the whole run, {scenario.description}",
                    out_dir / f"{stem2}_identification.png"))
            else:
                paths.append(_plot_network_error(log, t, t_c, configs, number, scenario,
                                                 out_dir / f"{stem2}_nn_output_error.png"))
    return paths


def _plot_identification(log, t, t_c, configs, span_s, title, path) -> Path:
    window = (t >= t_c - 0.05) & (t <= t_c + span_s)
    tw = t[window] - t_c
    truth = log["true_impedance"][window]
    fig, axes = plt.subplots(3, 2, figsize=(11, 8), sharex=True)
    ax = axes[0, 0]
    ax.plot(tw, log["force_filtered"][window], lw=0.8, label="measured, filtered")
    ax.plot(tw, log["contact_force_true"][window], "k--", lw=0.8, label="true")
    ax.set_ylabel("force f (N)")
    ax = axes[1, 0]
    ax.plot(tw, log["displacement_measured"][window] * 1e3, lw=0.8,
            label="xe measured (from the switch point)")
    pen = log["penetration_true"]
    ax.plot(tw, (pen[window] - pen[np.argmax(t >= t_c)]) * 1e3, "k--", lw=0.8,
            label="true, from the switch point")
    ax.set_ylabel("displacement xe (mm)")
    ax = axes[2, 0]
    ax.plot(tw, log["stiffness_ratio"][window] / 1e3, lw=0.8, label="f / xe (measured)")
    ax.plot(tw, truth[:, 2] / 1e3, "k--", lw=1, label="true K_e")
    _clip_to_truth(ax, truth[:, 2] / 1e3)
    ax.set_ylabel("f / xe (kN/m)")
    ax.set_xlabel("time from the switch (s)")
    units = [("M_e (kg)", 1.0, 0), ("B_e (N s/m)", 1.0, 1), ("K_e (kN/m)", 1e-3, 2)]
    for row, (name, scale, k) in enumerate(units):
        ax = axes[row, 1]
        for colour, config in zip(_IDENTIFIER_COLOURS, configs):
            est = log[f"impedance_{config.name}"][window, k] * scale
            ax.plot(tw, est, color=colour, lw=0.9, label=config.name)
        ax.plot(tw, truth[:, k] * scale, "k--", lw=1, label="truth")
        if k == 2:
            _clip_to_truth(ax, truth[:, k] * scale)
        ax.set_ylabel(name)
    axes[2, 1].set_xlabel("time from the switch (s)")
    fig.suptitle(title, fontsize=9)
    return _save(fig, axes, path)


def _clip_to_truth(ax, truth):
    """K_e and f / xe start far off (theta0 = 2e5 N/m, xe ~ 0): show 0 to
    twice the truth."""
    ax.set_ylim(0, 2 * float(np.max(truth)))


def _plot_network_error(log, t, t_c, configs, number, scenario, path) -> Path:
    window = (t >= t_c) & (t <= t_c + 4.0)
    fig, ax = plt.subplots(figsize=(8, 4))
    for colour, config in zip(_IDENTIFIER_COLOURS, configs):
        estimate = log.get(f"force_estimate_{config.name}")
        if estimate is None:
            continue
        ax.plot(t[window] - t_c, log["force_filtered"][window] - estimate[window], color=colour,
                lw=0.8, label=config.name)
    ax.set_xlabel("time from the switch (s)")
    ax.set_ylabel("output error f - f_hat (N)")
    ax.set_title(f"Fig {number}: error of the network's output, {scenario.description}",
                 fontsize=9)
    return _save(fig, ax, path)
