"""Draw the landing page's figure, docs/_static/force_tracking.png (the
README shows it too): the thesis's Fig 6.11 task on styrofoam, the true
contact force under the hybrid controller alone and with the neural-network
compensator, seed 0. It is committed (a small curated image); remake it
after a change of physics with ``python docs/make_landing_figure.py``."""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import drake_contact as dc  # noqa: E402

OUT = Path(__file__).resolve().parent / "_static" / "force_tracking.png"


def main():
    scenarios = {name: dc.load_scenario(name, duration=26.0, seed=0)
                 for name in ("hybrid_p_only_styrofoam", "nn_styrofoam")}
    runs = {name: dc.simulate_scenario(scenario) for name, scenario in scenarios.items()}
    wall = scenarios["nn_styrofoam"].environment.stiffness / 1e3
    fig, ax = plt.subplots(figsize=(7.5, 3.0), dpi=100)
    reference = runs["nn_styrofoam"].log
    start = runs["nn_styrofoam"].metrics["contact_time_s"]
    ax.plot(reference["t"] - start, reference["force_desired"], color="0.3", lw=1.2,
            ls="--", label="desired force $f_d$")
    for (name, result), label, color in zip(
            runs.items(), ("hybrid controller alone", "with the neural compensator"),
            ("tab:orange", "tab:blue")):
        log = result.log
        t0 = result.metrics["contact_time_s"]
        ax.plot(log["t"] - t0, log["contact_force_true"], color=color, lw=0.9, label=label)
    ax.set_xlim(0, 17)
    ax.set_ylim(0, 32)
    ax.set_xlabel("time after contact (s)")
    ax.set_ylabel("true contact force (N)")
    ax.set_title(f"Styrofoam ({wall:.1f} kN/m): tracking a 20/10 N square wave "
                 "(thesis Fig 6.11)", fontsize=10)
    ax.legend(loc="upper right", fontsize=8, ncol=3)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(OUT)
    print(f"wrote {OUT} ({OUT.stat().st_size // 1024} kB)")


if __name__ == "__main__":
    main()
