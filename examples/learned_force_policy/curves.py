"""Learning curves and the training table of the policies trained on the
vector environment, from the records their JSON files keep (no training,
no torch): for each method, against the environment steps simulated, its
median over the training seeds and their range.

    python examples/learned_force_policy/curves.py [--out docs/results/learning]

Writes ``learning_curves.png`` (the median episode return, and the
fraction of episodes that ended early, per bin of steps) and
``training.md`` (per method and seed: the wall time, the steps simulated,
the held steps, the first and the last bin). CMA-ES's points are its
generations: the median candidate's mean return, and the fraction of its
environments that ended early.
"""
import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

HERE = Path(__file__).resolve().parent
POLICIES = HERE / "drake_contact_learned_policy" / "policies"
METHODS = {"ppo": "PPO (Stable-Baselines3)", "cmaes": "CMA-ES (pycma)"}
#: The curves' points: the episodes that ended in each bin of this many
#: simulated steps (two CMA-ES generations).
BIN_STEPS = 51_200


def episodes(about: dict):
    """(steps simulated when it ended, return, ended early) of each
    training episode in a policy's record (CMA-ES: each generation's
    candidates, their mean return and its environments that ended early)."""
    if "generations" in about:
        rows = []
        for g in about["generations"]:
            n = about["num_envs"]
            early = g["ended_early"] / n
            rows.append((g["steps_simulated"], g["median"], early))
        return rows
    return [(e["steps_simulated"], e["r"], float(e["ended_early"])) for e in about["episodes"]]


def curve(about: dict):
    """(bin ends, median return, fraction ending early) per bin."""
    rows = np.array(episodes(about))
    edges = np.arange(BIN_STEPS, rows[:, 0].max() + BIN_STEPS, BIN_STEPS)
    bins = np.searchsorted(edges, rows[:, 0])
    x, median, early = [], [], []
    for b in range(len(edges)):
        inside = rows[bins == b]
        if len(inside):
            x.append(edges[b])
            median.append(np.median(inside[:, 1]))
            early.append(np.mean(inside[:, 2]))
    return np.array(x), np.array(median), np.array(early)


def start_and_end(about: dict):
    """The median return and the fraction ending early over the first and
    the last bin."""
    _, median, early = curve(about)
    return median[0], median[-1], early[0], early[-1]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/results/learning"))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    fig, (ax, ax_early) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    rows = []
    for (method, label), color in zip(METHODS.items(), ("tab:blue", "tab:orange")):
        curves = []
        for path in sorted(POLICIES.glob(f"{method}_seed*.json")):
            about = json.loads(path.read_text())["about"]
            curves.append(curve(about))
            rows.append((label, about["seed"], about["wall_clock_s"], about["steps_simulated"],
                         about.get("held_steps"), *start_and_end(about)))
        if not curves:
            continue
        for axis, k in ((ax, 1), (ax_early, 2)):
            for c in curves:
                axis.plot(c[0], c[k], color=color, alpha=0.3, linewidth=0.8)
            grid = np.linspace(max(c[0][0] for c in curves), min(c[0][-1] for c in curves), 60)
            ys = np.array([np.interp(grid, c[0], c[k]) for c in curves])
            axis.fill_between(grid, ys.min(axis=0), ys.max(axis=0), color=color, alpha=0.2)
            axis.plot(grid, np.median(ys, axis=0), color=color,
                      label=f"{label}: median of {len(curves)} seeds, range shaded")
    ax.set_ylabel("median episode return")
    ax.set_ylim(-1500, 0)
    ax_early.set_ylabel("episodes ending early\n(contact lost)")
    ax_early.set_ylim(0, 1)
    ax_early.set_xlabel(f"environment steps simulated (10 ms each), bins of {BIN_STEPS:,}")
    for axis in (ax, ax_early):
        axis.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title("Training on ForceTracking-v0's vector environment (16 environments)")
    fig.tight_layout()
    figure = args.out / "learning_curves.png"
    fig.savefig(figure, dpi=100)
    # 256 colours, as the docs' snapshots keep their figures.
    with Image.open(figure) as image:
        image.convert("RGB").quantize(256).save(figure, optimize=True)
    lines = ["| method | seed | wall time (min) | steps simulated | held steps | "
             "median return: first bin, last bin | ending early: first bin, last bin |",
             "|---|---|---|---|---|---|---|"]
    for label, seed, wall, steps, held, first, last, early_first, early_last in rows:
        held = "not recorded" if held is None else f"{held:,}"
        lines.append(f"| {label} | {seed} | {wall / 60:.1f} | {steps:,} | {held} | "
                     f"{first:.0f}, {last:.0f} | {early_first:.0%}, {early_last:.0%} |")
    (args.out / "training.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out / 'learning_curves.png'} and {args.out / 'training.md'}")


if __name__ == "__main__":
    main()
