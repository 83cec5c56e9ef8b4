"""Figures of a run's log (matplotlib, written as PNG; never shown)."""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


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
    axes[2].set_ylabel("tip pose")
    for i in range(3):
        axes[3].plot(t, log["joint_torque_applied"][:, i], label=f"joint {i + 1}")
    axes[3].set_ylabel("applied torque (N m)")
    axes[3].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    env = scenario.environment
    fig.suptitle(f"{scenario.description or 'run'}\n"
                 f"K_e = {env.stiffness:.4g} N/m, B_e = {env.damping:.4g} N s/m, "
                 f"M_e = {env.mass:.4g} kg", fontsize=10)
    fig.tight_layout()
    path = Path(out_dir) / "main_signals.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
