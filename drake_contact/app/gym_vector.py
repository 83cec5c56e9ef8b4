"""N environments of ``drake_contact/ForceTracking-v0`` in one ensemble
diagram, as a Gymnasium vector environment::

    import gymnasium, drake_contact.gym
    envs = gymnasium.make_vec("drake_contact/ForceTracking-v0", num_envs=16, task="random")
    observations, info = envs.reset(seed=0)          # (16, 10)
    observations, rewards, terminated, truncated, info = envs.step(actions)  # actions (16, 4)

Environment i is the single environment (:class:`~drake_contact.app.gym_env.ForceTrackingEnv`,
the same constructor arguments) seeded with ``seed + i`` (or ``seed[i]``
for a list): it draws its episodes with its own ``np_random`` by the same
code, and every one of its episodes is, bit for bit, the single
environment's (observations, rewards, flags) under the same actions. The N
stations are one :func:`drake_contact.diagram.MakeEnsembleDiagram` (5-7x
the throughput of N single environments at N = 64-256).

**Episodes are synchronised** (Gymnasium's ``AutoresetMode.DISABLED``):
:meth:`reset` starts all N at t = 0, and a reset of only some of them is
refused (``reset_mask`` must be all true). Every episode of the task has
the same length (``duration_s``), so the N episodes end together, unless
one ends early (contact lost, or diverged): that environment is held until
the next reset (its later steps return its final observation, reward 0
and its flags again, ``info["active"]`` false; its station runs on with
the zero action, its state unread). Restarting one environment alone
would need its own clock: the approach, the tare and the force reference
run on the diagram's time, which the N share.

**Divergence**: an environment whose state stops being finite or whose
contact force exceeds its ``simulation.force_limit`` is terminated alone,
with the single environment's penalty and message, and the others run on.
An error the simulator raises cannot be told to one environment: it ends
every episode still running in that station (``info["diverged"]``).

**Structure**: the draws of one reset are built as one station per
ensemble structure (:func:`drake_contact.structure.ensemble_structure`: a
drawn fault, for example, changes it), each group stepped in turn. The
wall's K_e, B_e, law and friction and joint 2's drive are compiled into
the station's systems, so a reset that draws new ones builds the
stations again; a reset whose draws differ from the last ones only in
the noise seed (the ``walls`` evaluation mode once every wall has been
drawn in each slot, or equal draws) keeps them and re-initialises their
Context. ``reset_cost`` holds the wall time of the last reset and
whether it rebuilt.
"""

import dataclasses as dc
import time

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from drake_contact.app.gym_env import (
    LOWEST_REWARD, ForceTrackingEnv, divergence, gym_simulator, step_reward)
from drake_contact.control.hybrid_controller import APPROACH
from drake_contact.control.policy_spaces import ACTION, OBSERVATION, check_action
from drake_contact.diagram import SeedNoise
from drake_contact.errors import ScenarioError
from drake_contact.structure import ensemble_structure


@dc.dataclass
class _Group:
    """The environments of one station: their indices and its simulator."""

    envs: list
    simulator: object
    key: tuple


def _unseeded(scenario):
    """``scenario`` without its noise seed: two draws that differ only there
    share a station."""
    return dc.replace(scenario, simulation=dc.replace(scenario.simulation, seed=0))


class ForceTrackingVectorEnv(VectorEnv):
    """``num_envs`` force-tracking environments in one ensemble diagram (see
    :mod:`drake_contact.app.gym_vector`); the other arguments are
    :class:`~drake_contact.app.gym_env.ForceTrackingEnv`'s. With ``walls``,
    environment i's k-th episode runs wall ``(i + k num_envs) mod
    len(walls)`` with noise seed that index, so a reset covers num_envs
    consecutive walls."""

    metadata = {"autoreset_mode": AutoresetMode.DISABLED, "render_modes": []}

    def __init__(self, num_envs=1, task="square", duration_s=16.0, period_ms=10, training=None,
                 supervisor=False, walls=None, render_mode=None):
        if not (isinstance(num_envs, int) and 1 <= num_envs <= 4096):
            raise ScenarioError(f"num_envs = {num_envs} is out of range: must be an integer in "
                                "[1, 4096]")
        if render_mode is not None:
            raise ScenarioError(f"render_mode = '{render_mode}': the vector environment does "
                                "not render (choose None)")
        self.num_envs = num_envs
        # One single environment per slot draws its episodes (never simulated).
        self.envs = [ForceTrackingEnv(task=task, duration_s=duration_s, period_ms=period_ms,
                                      training=training, supervisor=supervisor, walls=walls)
                     for _ in range(num_envs)]
        for i, env in enumerate(self.envs):
            env._episode = i
            env._stride = num_envs
        first = self.envs[0]
        self.time_step = first.time_step
        self.steps = first.steps
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.render_mode = None
        self.groups = []
        self.scenarios = [None] * num_envs
        self.reset_cost = {}
        self._step = 0
        self._active = np.zeros(num_envs, dtype=bool)

    # -- Gymnasium ---------------------------------------------------------

    def reset(self, *, seed=None, options=None):
        """Starts every environment's next episode at t = 0: environment i
        seeded with ``seed + i`` (an int), ``seed[i]`` (a list), or going on
        with its own ``np_random`` (None). ``options`` may hold only a
        ``reset_mask`` that is all true."""
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if options:
            raise ValueError(f"reset options {sorted(options)} are not supported: pass the "
                             "task and walls to the constructor")
        if mask is not None and not np.all(mask):
            raise ValueError("reset_mask: the episodes are synchronised (autoreset mode "
                             "DISABLED): reset all environments together")
        seeds = self._seeds(seed)
        start = time.perf_counter()
        drawn = []
        for env, s in zip(self.envs, seeds):
            if s is not None:
                gym.Env.reset(env, seed=s)
            d, task = env._draw()
            env._episode += env._stride - 1
            env.drawn, env.episode_task = d, task
            env.episode_scenario = env.scenario(d, task)
            drawn.append(env.episode_scenario)
        rebuilt = self._stations(drawn)
        self.reset_cost = {"wall_s": time.perf_counter() - start, "rebuilt": rebuilt,
                           "stations": len(self.groups)}
        self.scenarios = drawn
        # Each episode's ground truth, for every step's info.
        facts = [env._facts() for env in self.envs]
        self._episode_facts = {}
        for key in ("task", "stiffness", "damping", "law", "friction_coefficient",
                    "drive_scale", "seed"):
            values = [f[key] for f in facts]
            self._episode_facts[key] = np.array(
                values, dtype=object if isinstance(values[0], str) else None)
        self._step = 0
        self._active[:] = True
        self._had_contact = np.zeros(self.num_envs, dtype=bool)
        self._terminated = np.zeros(self.num_envs, dtype=bool)
        self._truncated = np.zeros(self.num_envs, dtype=bool)
        self._observations = np.zeros((self.num_envs, OBSERVATION.size))
        self._final = [{} for _ in range(self.num_envs)]
        for group in self.groups:
            context = group.simulator.get_context()
            system = group.simulator.get_system()
            self._observations[group.envs] = system.GetOutputPort(
                "policy_observation").Eval(context).reshape(len(group.envs), -1)
        return self._observations.copy(), self._infos()

    def step(self, actions):
        """Advances every running environment one period with its row of
        ``actions`` (num_envs x 4; each row checked as the single
        environment checks it: ValueError naming the environment)."""
        if not self.groups:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, dtype=float)
        if actions.shape != (self.num_envs, ACTION.size):
            raise ValueError(f"actions: shape {actions.shape}, expected "
                             f"({self.num_envs}, {ACTION.size})")
        checked = np.zeros_like(actions)
        for i in np.flatnonzero(self._active):
            checked[i] = check_action(actions[i], f"actions[{i}]")
        running = self._active.copy()
        rewards = np.zeros(self.num_envs)
        if not running.any():
            return self._results(rewards, running)
        self._step += 1
        left = self.steps - self._step
        t_next = self._step * self.time_step
        for group in self.groups:
            if running[group.envs].any():
                self._advance(group, checked, t_next, left, rewards)
        return self._results(rewards, running)

    # -- stations ----------------------------------------------------------

    def _seeds(self, seed):
        if seed is None:
            return [None] * self.num_envs
        if np.ndim(seed) == 0:
            return [int(seed) + i for i in range(self.num_envs)]
        seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(f"seed: {len(seeds)} seeds for {self.num_envs} environments")
        return seeds

    def _stations(self, scenarios) -> bool:
        """Builds one station per structure, or keeps the last ones when the
        draws differ from theirs only in the noise seed; returns whether it
        built."""
        key = [_unseeded(s) for s in scenarios]
        if self.groups and key == [_unseeded(s) for s in self.scenarios]:
            for group in self.groups:
                simulator = group.simulator
                context = simulator.get_mutable_context()
                context.SetTime(0.0)
                simulator.get_system().SetDefaultContext(context)
                SeedNoise(simulator.get_system(), context,
                          [scenarios[i].simulation.seed for i in group.envs])
                simulator.Initialize()
            return False
        structures = {}
        for i, scenario in enumerate(scenarios):
            structures.setdefault(ensemble_structure(scenario), []).append(i)
        self.groups = []
        for structure, envs in structures.items():
            simulator = gym_simulator([scenarios[i] for i in envs])
            simulator.Initialize()
            self.groups.append(_Group(envs, simulator, structure))
        return True

    def _advance(self, group, actions, t_next, left, rewards):
        simulator = group.simulator
        system = simulator.get_system()
        context = simulator.get_mutable_context()
        system.get_input_port().FixValue(context, actions[group.envs].reshape(-1))
        try:
            simulator.AdvanceTo(t_next)
        except RuntimeError as e:  # SimulationDiverged and Drake's own checks
            failure = str(e).splitlines()[0]
            for i in group.envs:
                if self._active[i]:
                    self._end(i, LOWEST_REWARD * (left + 1), rewards, terminated=True,
                              diverged=failure, time_s=context.get_time())
            return
        count = len(group.envs)
        outputs = {name: system.GetOutputPort(name).Eval(context).reshape(count, -1)
                   for name in ("policy_observation", "joint_state_true", "contact_force_true")}
        t = context.get_time()
        for k, i in enumerate(group.envs):
            if not self._active[i]:
                continue
            failure = divergence(outputs["joint_state_true"][k],
                                 outputs["contact_force_true"][k][0],
                                 self.scenarios[i].simulation.force_limit, t)
            if failure:
                self._end(i, LOWEST_REWARD * (left + 1), rewards, terminated=True,
                          diverged=failure, time_s=t)
                continue
            observation = outputs["policy_observation"][k].copy()
            self._observations[i] = observation
            reward, lost, self._had_contact[i] = step_reward(observation, self._had_contact[i],
                                                             left)
            if lost:
                self._end(i, reward, rewards, terminated=True, contact_lost=True, time_s=t)
            elif left <= 0:
                self._end(i, reward, rewards, terminated=False, time_s=t)
            else:
                rewards[i] = reward

    def _end(self, i, reward, rewards, *, terminated, **final):
        rewards[i] = reward
        self._active[i] = False
        self._terminated[i] = terminated
        self._truncated[i] = not terminated
        self._final[i] = final

    # -- results -----------------------------------------------------------

    def _results(self, rewards, running):
        """(observations, rewards, terminated, truncated, info) of a step;
        an environment that had ended before it gives its last ones, reward 0."""
        return (self._observations.copy(), rewards, self._terminated.copy(),
                self._truncated.copy(), self._infos(running))

    def _infos(self, running=None) -> dict:
        """Gymnasium's vector info: arrays with a mask ``_<key>`` of the
        environments that have the key. Always: ``time_s``, ``active``
        (still in its episode), ``stepped`` (this step advanced it), the
        ground truth of each episode (``force_true``, ``force_desired``,
        ``in_contact``, ``stiffness``, ``damping``, ``law``, ``task``,
        ``drive_scale``, ``seed``); where it happened, ``diverged`` (the
        message) and ``contact_lost``."""
        n = self.num_envs
        force_true, force_desired, in_contact = np.zeros(n), np.zeros(n), np.zeros(n, bool)
        times = np.zeros(n)
        for group in self.groups:
            system, context = group.simulator.get_system(), group.simulator.get_context()
            times[group.envs] = context.get_time()
            force_true[group.envs] = system.GetOutputPort("contact_force_true").Eval(context)
            force_desired[group.envs] = system.GetOutputPort("force_desired").Eval(context)
            in_contact[group.envs] = system.GetOutputPort("mode").Eval(context) != APPROACH
        info = {"time_s": times, "active": self._active.copy(),
                "stepped": self._active.copy() if running is None else running.copy(),
                "force_true": force_true, "force_desired": force_desired,
                "in_contact": in_contact}
        info |= {key: value.copy() for key, value in self._episode_facts.items()}
        for key in ("diverged", "contact_lost"):
            has = np.array([key in f for f in self._final])
            if has.any():
                info[key] = np.array([f.get(key, "" if key == "diverged" else False)
                                      for f in self._final],
                                     dtype=object if key == "diverged" else bool)
                info[f"_{key}"] = has
        for key in list(info):
            if not key.startswith("_") and f"_{key}" not in info:
                info[f"_{key}"] = np.ones(n, dtype=bool)
        return info

    def close_extras(self, **kwargs):
        self.groups = []
