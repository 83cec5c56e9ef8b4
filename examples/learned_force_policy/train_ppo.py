"""Trains a policy on the vector environment with Stable-Baselines3's PPO
(the ``sb3`` extra: torch's CPU build) and exports it to numpy.

    pip install './examples/learned_force_policy[sb3]'
    python examples/learned_force_policy/train_ppo.py --seed 0 [--budget 600000]
        [--num-envs 16] [--duration 16] [--out .../policies/ppo_seed0.json]

The environments: ``num_envs`` of ForceTracking-v0 in one ensemble
(:class:`drake_contact.gym.ForceTrackingVectorEnv`, task ``random``, the
default training distribution, which keeps away from every benchmark
wall), through :class:`sb3_vec.ForceTrackingSb3VecEnv`. ``budget``: the
environment steps simulated (SB3's timesteps: num_envs per step, held
environments included), the same budget ``train.py`` (CMA-ES) spends.

The policy: SB3's MlpPolicy (tanh, 64-64 for the actor and the critic, a
Gaussian of state-independent std from ``--log-std-init``), its rewards
normalized by SB3's VecNormalize (``--no-normalize-reward``: raw). Exported as a
:class:`NumpyPolicy` (output ``clip``): the deterministic action, the
Gaussian's mean clipped to [-1, 1] as SB3 clips it, so the benchmark, its
pre-run check and the published results run it without torch. The export
is checked against ``model.predict(deterministic=True)`` on the rollouts'
observations. The JSON keeps how it was trained and every finished
episode (the learning curve).
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

from drake_contact.control.policy import NumpyPolicy
from drake_contact.gym import ForceTrackingVectorEnv, TrainingDistribution

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sb3_vec import ForceTrackingSb3VecEnv  # noqa: E402

HERE = Path(__file__).resolve().parent


def export(model) -> NumpyPolicy:
    """The deterministic policy of ``model`` (SB3's ActorCriticPolicy with
    tanh layers) as a NumpyPolicy."""
    policy = model.policy
    linears = [m for m in policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    acts = [m for m in policy.mlp_extractor.policy_net if not isinstance(m, torch.nn.Linear)]
    if not all(isinstance(a, torch.nn.Tanh) for a in acts):
        raise ValueError("the export takes tanh hidden layers only")
    layers = [(m.weight.detach().double().numpy(), m.bias.detach().double().numpy())
              for m in linears + [policy.action_net]]
    return NumpyPolicy(layers, output="clip")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--budget", type=int, default=600_000)
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--duration", type=float, default=16.0)
    parser.add_argument("--n-steps", type=int, default=400)
    parser.add_argument("--log-std-init", type=float, default=-1.0)
    parser.add_argument("--learning-rate", type=float, default=3e-4)
    parser.add_argument("--no-normalize-reward", dest="normalize_reward", action="store_false")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    out = args.out or HERE / "drake_contact_learned_policy" / "policies" / \
        f"ppo_seed{args.seed}.json"
    torch.set_num_threads(1)
    envs = ForceTrackingVectorEnv(num_envs=args.num_envs, task="random",
                                  duration_s=args.duration, training=TrainingDistribution())
    adapter = ForceTrackingSb3VecEnv(envs)
    # Training seed s: environment i's episodes drawn from seed 1_000_000 s + i.
    adapter.seed(1_000_000 * args.seed)
    # The rewards scaled by a running estimate of the discounted return's
    # spread (SB3's VecNormalize, as its zoo trains continuous control): a
    # lost contact's penalty reaches -2 per step left, hundreds at once. The
    # observation is not normalized: the exported policy reads it as is.
    venv = (VecNormalize(adapter, norm_obs=False, norm_reward=True, gamma=0.99)
            if args.normalize_reward else adapter)
    hyper = {"n_steps": args.n_steps, "batch_size": args.n_steps * args.num_envs // 8,
             "n_epochs": 10, "learning_rate": args.learning_rate, "gamma": 0.99,
             "gae_lambda": 0.95, "clip_range": 0.2, "ent_coef": 0.0}
    model = PPO("MlpPolicy", venv, seed=args.seed, device="cpu", verbose=0,
                policy_kwargs={"log_std_init": args.log_std_init}, **hyper)
    start = time.perf_counter()
    model.learn(total_timesteps=args.budget)
    wall = time.perf_counter() - start
    policy = export(model)
    # The export against SB3's own deterministic action.
    rng = np.random.default_rng(args.seed)
    observations = envs.observation_space.sample() * 0.05 + rng.normal(0, 0.5, (
        args.num_envs, envs.single_observation_space.shape[0]))
    expected, _ = model.predict(observations.astype(np.float32), deterministic=True)
    error = float(np.abs(policy(observations) - expected).max())
    if error > 1e-5:
        raise SystemExit(f"the export differs from SB3's action by {error:.3g}")
    out.parent.mkdir(parents=True, exist_ok=True)
    history = adapter.history
    policy.save(out, trainer=f"PPO (stable-baselines3 {stable_baselines3.__version__}, "
                             f"torch {torch.__version__})",
                seed=args.seed, budget_steps=args.budget, num_envs=args.num_envs,
                episode_s=args.duration, task="random", log_std_init=args.log_std_init,
                normalize_reward=args.normalize_reward,
                hyperparameters=hyper, wall_clock_s=round(wall, 1),
                steps_simulated=adapter.steps_simulated, held_steps=adapter.held_steps,
                export_max_error=error, episodes=history)
    returns = [e["r"] for e in history]
    print(json.dumps({"seed": args.seed, "wall_s": round(wall, 1),
                      "steps": adapter.steps_simulated, "held": adapter.held_steps,
                      "episodes": len(history),
                      "first_returns": float(np.mean(returns[:args.num_envs])),
                      "last_returns": float(np.mean(returns[-args.num_envs:]))}))
    print(f"wrote {out}")


if __name__ == "__main__":
    sys.exit(main())
