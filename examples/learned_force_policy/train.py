"""Trains a policy on the vector environment with CMA-ES (pycma): a linear
policy through tanh (observation 10 -> action 4, 44 weights) from the zero
action (the hybrid law unmodified). Each generation is one reset of the
vector environment (:class:`drake_contact.gym.ForceTrackingVectorEnv`,
task ``random``, the default training distribution): candidate j runs in
environments j K .. j K + K - 1, and every candidate sees the same K
episodes (common random numbers), scored by its mean return.

    pip install './examples/learned_force_policy[train]'
    python examples/learned_force_policy/train.py --seed 0 [--budget 600000]
        [--popsize 8] [--episodes 2] [--duration 16] [--sigma 0.1]
        [--out .../policies/cmaes_seed0.json]

``budget``: the environment steps simulated (popsize x episodes per
generation step, held environments included), the same budget
``train_ppo.py`` spends. Writes the CMA-ES mean of the last generation with
how it was trained and every generation's returns (the learning curve).
"""
import argparse
import json
import sys
import time
from pathlib import Path

import cma
import numpy as np

from drake_contact.control.policy import NumpyPolicy
from drake_contact.control.policy_spaces import ACTION, OBSERVATION
from drake_contact.gym import ForceTrackingVectorEnv, TrainingDistribution

HERE = Path(__file__).resolve().parent
SHAPE = (ACTION.size, OBSERVATION.size)


def policy_of(theta):
    theta = np.asarray(theta, dtype=float)
    w = theta[:SHAPE[0] * SHAPE[1]].reshape(SHAPE)
    return NumpyPolicy([(w, theta[SHAPE[0] * SHAPE[1]:])])


def run_generation(envs, policies, seeds):
    """One synchronised episode of every environment, environment i acting
    with ``policies[i]``: (returns, whether it ended early, steps simulated,
    of which held)."""
    observations, _ = envs.reset(seed=seeds)
    returns = np.zeros(envs.num_envs)
    simulated = held = 0
    while True:
        actions = np.array([p(o) for p, o in zip(policies, observations)])
        observations, rewards, terminated, _, info = envs.step(actions)
        returns += rewards
        simulated += envs.num_envs
        held += int((~info["stepped"]).sum())
        if not info["active"].any():
            return returns, terminated, simulated, held


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--budget", type=int, default=600_000)
    parser.add_argument("--popsize", type=int, default=8)
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--duration", type=float, default=16.0)
    parser.add_argument("--sigma", type=float, default=0.1)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    out = args.out or HERE / "drake_contact_learned_policy" / "policies" / \
        f"cmaes_seed{args.seed}.json"
    n = args.popsize * args.episodes
    envs = ForceTrackingVectorEnv(num_envs=n, task="random", duration_s=args.duration,
                                  training=TrainingDistribution())
    size = SHAPE[0] * SHAPE[1] + SHAPE[0]
    es = cma.CMAEvolutionStrategy(np.zeros(size), args.sigma,
                                  {"popsize": args.popsize, "seed": args.seed + 1,
                                   "verbose": -9})
    start = time.perf_counter()
    history, simulated, held, generation = [], 0, 0, 0
    while simulated < args.budget:
        candidates = es.ask()
        # Common random numbers: every candidate sees the same K episodes.
        episode_seeds = [1_000_000 * args.seed + 100 * generation + e
                         for e in range(args.episodes)]
        seeds = [s for _ in candidates for s in episode_seeds]
        policies = [policy_of(c) for c in candidates for _ in episode_seeds]
        returns, ended, steps, idle = run_generation(envs, policies, seeds)
        simulated += steps
        held += idle
        scores = returns.reshape(args.popsize, args.episodes).mean(axis=1)
        es.tell(candidates, [-float(r) for r in scores])
        history.append({"generation": generation, "steps_simulated": simulated,
                        "best": float(scores.max()), "median": float(np.median(scores)),
                        "mean": float(scores.mean()), "ended_early": int(ended.sum()),
                        "wall_s": round(time.perf_counter() - start, 1)})
        print(json.dumps(history[-1]), flush=True)
        generation += 1
    wall = time.perf_counter() - start
    out.parent.mkdir(parents=True, exist_ok=True)
    policy_of(es.mean).save(out, trainer="CMA-ES (pycma %s)" % cma.__version__,
                            seed=args.seed, budget_steps=args.budget, num_envs=n,
                            popsize=args.popsize, episodes_per_candidate=args.episodes,
                            episode_s=args.duration, task="random", sigma0=args.sigma,
                            wall_clock_s=round(wall, 1), steps_simulated=simulated,
                            held_steps=held,
                            generations=history)
    print(f"wrote {out}")


if __name__ == "__main__":
    sys.exit(main())
