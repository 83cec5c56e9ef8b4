"""Trains the learned_residual policy on the Gymnasium environment with
CMA-ES (pycma): a linear policy through tanh (observation 10 -> action 4,
44 weights) from the zero action (the hybrid law unmodified), each candidate
scored by its mean return over the same few randomized training episodes
per generation, the episodes run on Dask (a LocalCluster by default).

    pip install './examples/learned_force_policy[train]'
    python examples/learned_force_policy/train.py [--generations 12] [--popsize 10]
        [--episodes 2] [--duration 12] [--seed 0] [--workers 2 | --scheduler ADDRESS]
        [--out examples/learned_force_policy/drake_contact_learned_policy/policy.json]

Writes the best mean found (the CMA-ES mean of the last generation, scored
again on fresh episodes beside the zero action) with how it was trained.
"""
import argparse
import json
import sys
import time
from pathlib import Path

import cma
import numpy as np
from dask.distributed import Client, LocalCluster

from drake_contact.control.policy import NumpyPolicy
from drake_contact.control.policy_spaces import ACTION, OBSERVATION

HERE = Path(__file__).resolve().parent
SHAPE = (ACTION.size, OBSERVATION.size)


def policy_of(theta):
    theta = np.asarray(theta, dtype=float)
    w = theta[:SHAPE[0] * SHAPE[1]].reshape(SHAPE)
    return NumpyPolicy([(w, theta[SHAPE[0] * SHAPE[1]:])])


def episode_return(theta, seed, duration, task):
    """One episode of the environment with the policy ``theta``: (return,
    steps, whether it ended early, mean |true force error| in contact)."""
    from drake_contact.gym import ForceTrackingEnv
    env = ForceTrackingEnv(task=task, duration_s=duration)
    policy = policy_of(theta)
    observation, _ = env.reset(seed=seed)
    total, steps, errors = 0.0, 0, []
    while True:
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        total += reward
        steps += 1
        if info["in_contact"]:
            errors.append(abs(info["force_true"] - info["force_desired"]))
        if terminated or truncated:
            return total, steps, terminated, float(np.mean(errors)) if errors else float("nan")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generations", type=int, default=10)
    parser.add_argument("--popsize", type=int, default=10)
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--duration", type=float, default=12.0)
    parser.add_argument("--task", default="random")
    parser.add_argument("--sigma", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--scheduler", default=None)
    parser.add_argument("--out", type=Path,
                        default=HERE / "drake_contact_learned_policy" / "policy.json")
    args = parser.parse_args(argv)
    client = (Client(args.scheduler) if args.scheduler else
              Client(LocalCluster(n_workers=args.workers, threads_per_worker=1,
                                  processes=True, dashboard_address=None)))
    size = SHAPE[0] * SHAPE[1] + SHAPE[0]
    es = cma.CMAEvolutionStrategy(np.zeros(size), args.sigma,
                                  {"popsize": args.popsize, "seed": args.seed + 1,
                                   "verbose": -9})
    start = time.perf_counter()
    history = []
    for generation in range(args.generations):
        candidates = es.ask()
        # Common random numbers: every candidate sees the same episodes.
        seeds = [args.seed * 100_000 + generation * 100 + e for e in range(args.episodes)]
        futures = [[client.submit(episode_return, list(c), s, args.duration, args.task,
                                  pure=False) for s in seeds] for c in candidates]
        results = [[f.result() for f in row] for row in futures]
        returns = [float(np.mean([r[0] for r in row])) for row in results]
        es.tell(candidates, [-r for r in returns])
        history.append({"generation": generation, "best": max(returns),
                        "median": float(np.median(returns)),
                        "wall_s": round(time.perf_counter() - start, 1)})
        print(json.dumps(history[-1]), flush=True)
    mean = es.mean
    # The result against the zero action on fresh episodes.
    check = [args.seed * 100_000 + 90_000 + e for e in range(2 * args.episodes)]
    scored = {name: [client.submit(episode_return, list(theta), s, args.duration, args.task,
                                   pure=False).result() for s in check]
              for name, theta in (("trained", mean), ("zero_action", np.zeros(size)))}
    summary = {name: {"mean_return": float(np.mean([r[0] for r in rows])),
                      "ended_early": int(sum(r[2] for r in rows)),
                      "mean_abs_true_force_error_n": float(np.nanmean([r[3] for r in rows]))}
               for name, rows in scored.items()}
    print(json.dumps(summary), flush=True)
    policy_of(mean).save(args.out, trainer="CMA-ES (pycma %s)" % cma.__version__,
                         generations=args.generations, popsize=args.popsize,
                         episodes_per_candidate=args.episodes, episode_s=args.duration,
                         task=args.task, seed=args.seed, sigma0=args.sigma,
                         wall_clock_s=round(time.perf_counter() - start, 1),
                         workers=len(client.scheduler_info()["workers"]),
                         history=history, check_episodes=check, check=summary)
    print(f"wrote {args.out}")
    client.close()


if __name__ == "__main__":
    sys.exit(main())
