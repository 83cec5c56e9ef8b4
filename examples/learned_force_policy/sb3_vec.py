"""Stable-Baselines3's ``VecEnv`` over the vector environment
(:class:`drake_contact.gym.ForceTrackingVectorEnv`), which SB3 cannot take
as it is: SB3 resets each environment in the step that ends its episode
(``terminal_observation`` in its info), where the vector environment's
episodes are synchronised (Gymnasium's autoreset mode DISABLED).

Here the N episodes start together and run one period per step. An
environment whose episode ends early (contact lost, diverged) is done at
that step, with its true reward and final observation; until the others
end it is *held*: each later step gives it reward 0, done, its final
observation again and ``info["held"] = True`` (a one-step episode that
changes nothing: PPO's advantage there is -V(final observation) and nothing
bootstraps from it). When every environment has ended, the step resets
all N and returns the new episodes' first observations. A finished
episode's ``info["episode"]`` (return, length, time) is SB3's Monitor's, so
SB3's ``ep_rew_mean`` counts real episodes only; ``history`` lists them
with the environment steps simulated so far (held ones included: the
budget counts what was simulated).
"""
import time

import numpy as np
from stable_baselines3.common.vec_env import VecEnv


class ForceTrackingSb3VecEnv(VecEnv):
    """SB3's VecEnv over ``envs`` (a ForceTrackingVectorEnv)."""

    def __init__(self, envs):
        self.envs = envs
        self.render_mode = None
        super().__init__(envs.num_envs, envs.single_observation_space, envs.single_action_space)
        self.history = []
        self.steps_simulated = 0
        self.held_steps = 0
        self._actions = None
        self._returns = np.zeros(self.num_envs)
        self._lengths = np.zeros(self.num_envs, dtype=int)
        self._start = time.perf_counter()

    def reset(self):
        seeds = self._seeds
        seed = None if all(s is None for s in seeds) else seeds
        observations, info = self.envs.reset(seed=seed)
        self._reset_seeds()
        self._returns[:] = 0.0
        self._lengths[:] = 0
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return observations.astype(np.float32)

    def step_async(self, actions):
        self._actions = np.asarray(actions, dtype=float).reshape(self.num_envs, -1)

    def step_wait(self):
        observations, rewards, terminated, truncated, info = self.envs.step(self._actions)
        stepped = info["stepped"]  # running before this step
        self.steps_simulated += self.num_envs
        self.held_steps += int((~stepped).sum())
        dones = terminated | truncated
        infos = [{} for _ in range(self.num_envs)]
        self._returns += rewards
        self._lengths += stepped
        for i in range(self.num_envs):
            if not stepped[i]:
                infos[i] = {"held": True, "terminal_observation": observations[i].astype(
                    np.float32), "TimeLimit.truncated": False}
                continue
            if dones[i]:
                episode = {"r": float(self._returns[i]), "l": int(self._lengths[i]),
                           "t": round(time.perf_counter() - self._start, 3)}
                infos[i] = {"episode": episode,
                            "terminal_observation": observations[i].astype(np.float32),
                            # Truncation (the episode's end) bootstraps; a
                            # termination (contact lost, diverged) does not.
                            "TimeLimit.truncated": bool(truncated[i])}
                self.history.append(episode | {
                    "env": i, "steps_simulated": self.steps_simulated,
                    "ended_early": bool(terminated[i]),
                    "stiffness": float(info["stiffness"][i])})
        if not info["active"].any():
            observations = self.reset()
        return observations.astype(np.float32), rewards.astype(np.float32), dones, infos

    def close(self):
        self.envs.close()

    # The rest of SB3's interface: the N environments are one system here.

    def get_attr(self, attr_name, indices=None):
        return [getattr(self.envs, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name, value, indices=None):
        setattr(self.envs, attr_name, value)

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        raise NotImplementedError("the N environments are one ensemble: call the vector "
                                  "environment's methods")

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False for _ in self._get_indices(indices)]
