"""Learning curves and the training table of the policies trained on the
vector environment, from the records their JSON files keep (no training,
no torch): for each method, the return against the environment steps
simulated, its median over the training seeds and their range.

    python examples/learned_force_policy/curves.py [--out docs/results/learning]

Writes ``learning_curves.png`` and ``training.md`` (per method and seed:
the wall time, the steps simulated, the held steps, the return at the
start and at the end).
"""
import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
POLICIES = HERE / "drake_contact_learned_policy" / "policies"
METHODS = {"ppo": "PPO (Stable-Baselines3)", "cmaes": "CMA-ES (pycma)"}
#: The curve's points: the mean return of the episodes that ended in each
#: bin of this many simulated steps.
BIN_STEPS = 25_600


def curve(about: dict):
    """(steps, mean return) of a policy's training record."""
    if "generations" in about:  # CMA-ES: each generation's mean candidate return
        rows = about["generations"]
        return (np.array([r["steps_simulated"] for r in rows]),
                np.array([r["mean"] for r in rows]))
    episodes = about["episodes"]
    steps = np.array([e["steps_simulated"] for e in episodes])
    returns = np.array([e["r"] for e in episodes])
    edges = np.arange(BIN_STEPS, steps.max() + BIN_STEPS, BIN_STEPS)
    bins = np.searchsorted(edges, steps)
    x, y = [], []
    for b in range(len(edges)):
        inside = bins == b
        if inside.any():
            x.append(edges[b])
            y.append(returns[inside].mean())
    return np.array(x), np.array(y)


def start_and_end(about: dict):
    """The mean return over the first and the last tenth of training."""
    x, y = curve(about)
    tenth = max(1, len(y) // 10)
    return float(y[:tenth].mean()), float(y[-tenth:].mean())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/results/learning"))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    rows = []
    for (method, label), color in zip(METHODS.items(), ("tab:blue", "tab:orange")):
        curves = []
        for path in sorted(POLICIES.glob(f"{method}_seed*.json")):
            about = json.loads(path.read_text())["about"]
            x, y = curve(about)
            curves.append((x, y))
            ax.plot(x, y, color=color, alpha=0.25, linewidth=0.8)
            first, last = start_and_end(about)
            rows.append((label, about["seed"], about["wall_clock_s"], about["steps_simulated"],
                         about.get("held_steps"), first, last))
        if not curves:
            continue
        grid = np.linspace(max(c[0][0] for c in curves), min(c[0][-1] for c in curves), 60)
        ys = np.array([np.interp(grid, x, y) for x, y in curves])
        ax.fill_between(grid, ys.min(axis=0), ys.max(axis=0), color=color, alpha=0.2)
        ax.plot(grid, np.median(ys, axis=0), color=color,
                label=f"{label}: median of {len(curves)} seeds, range shaded")
    ax.set_xlabel("environment steps simulated (10 ms each)")
    ax.set_ylabel("mean episode return")
    ax.set_ylim(bottom=max(ax.get_ylim()[0], -1200))
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    ax.set_title("Training on ForceTracking-v0's vector environment (16 environments)")
    fig.tight_layout()
    fig.savefig(args.out / "learning_curves.png", dpi=100)
    lines = ["| method | seed | wall time (min) | steps simulated | held steps | "
             "return, first tenth | return, last tenth |", "|---|---|---|---|---|---|---|"]
    for label, seed, wall, steps, held, first, last in rows:
        held = "not recorded" if held is None else f"{held:,}"
        lines.append(f"| {label} | {seed} | {wall / 60:.1f} | {steps:,} | {held} | "
                     f"{first:.1f} | {last:.1f} |")
    (args.out / "training.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out / 'learning_curves.png'} and {args.out / 'training.md'}")


if __name__ == "__main__":
    main()
