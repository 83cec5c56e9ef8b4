"""Measures the vector environment's throughput against the single
environment, back to back in one process (one core): environment steps per
second over whole episodes of the training distribution (zero action,
resets included), and what a reset costs (building the stations, or
re-initialising them for the same draws).

    python examples/learned_force_policy/bench_vector.py [--sizes 1,16,64] [--duration 12]
        [--episodes 2] [--out bench_vector.json]
"""
import argparse
import json
import platform
import time

import numpy as np

from drake_contact.gym import ForceTrackingEnv, ForceTrackingVectorEnv


def single_env(duration, episodes, seed):
    env = ForceTrackingEnv(task="random", duration_s=duration)
    steps, start = 0, time.perf_counter()
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        while True:
            _, _, terminated, truncated, _ = env.step(np.zeros(4))
            steps += 1
            if terminated or truncated:
                break
    return steps, time.perf_counter() - start


def vector_env(n, duration, episodes, seed):
    envs = ForceTrackingVectorEnv(num_envs=n, task="random", duration_s=duration)
    steps, resets, start = 0, [], time.perf_counter()
    for episode in range(episodes):
        envs.reset(seed=seed + episode * n)
        resets.append(envs.reset_cost)
        while True:
            _, _, _, _, info = envs.step(np.zeros((n, 4)))
            steps += int(info["stepped"].sum())
            if not info["active"].any():
                break
    wall = time.perf_counter() - start
    # A reset that keeps the stations: the same draws again.
    envs.reset(seed=seed + (episodes - 1) * n)
    kept = envs.reset_cost
    return steps, wall, resets, kept


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1,16,64")
    parser.add_argument("--duration", type=float, default=12.0)
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    rows = []
    steps, wall = single_env(args.duration, args.episodes * 2, seed=1000)
    single = steps / wall
    rows.append({"env": "ForceTrackingEnv", "num_envs": 1, "steps": steps, "wall_s": wall,
                 "steps_per_s": single, "ratio": 1.0})
    print(json.dumps(rows[-1]), flush=True)
    for n in [int(s) for s in args.sizes.split(",")]:
        steps, wall, resets, kept = vector_env(n, args.duration, args.episodes, seed=2000)
        rows.append({"env": "ForceTrackingVectorEnv", "num_envs": n, "steps": steps,
                     "wall_s": wall, "steps_per_s": steps / wall, "ratio": steps / wall / single,
                     "reset_build_s": [r["wall_s"] for r in resets],
                     "reset_kept_s": kept["wall_s"], "kept_rebuilt": kept["rebuilt"]})
        print(json.dumps(rows[-1]), flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"machine": platform.processor() or platform.machine(),
                       "duration_s": args.duration, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
