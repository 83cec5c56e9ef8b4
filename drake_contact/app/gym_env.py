"""The contact station as a Gymnasium environment, on Drake's
:class:`pydrake.gym.DrakeGymEnv`: ``drake_contact/ForceTracking-v0``.

    import gymnasium, drake_contact.gym
    env = gymnasium.make("drake_contact/ForceTracking-v0", task="square")
    observation, info = env.reset(seed=0)
    observation, reward, terminated, truncated, info = env.step(env.action_space.sample())

**The task.** The benchmark's (:data:`drake_contact.app.benchmark.TASKS`:
hold, square, square_sine, drift, hunt_crossley, friction; or ``random``,
one per reset) on the benchmark's base scenario (the arm, sensor and DSP of
``nn_styrofoam``), driven by the ``policy`` controller
(:mod:`drake_contact.control.policy`) with its hybrid law as the benchmark's
``hybrid_pi`` contender has it (K_fp 1, K_fi 0.003, joint 2's drive
calibrated). An episode runs from the start of the approach through contact
for ``duration_s`` (default 16 s: the quick suite's; contact comes at about
9.1 s on styrofoam), one step per ``period_ms`` (default 10 ms, ten 1 ms samples of the
law).

**Observation and action**: :mod:`drake_contact.control.policy_spaces`, the
same code the ``policy`` controller runs in a scenario and in the
benchmark. The action is a ``Box(-1, 1, (4,))``; a value outside is clipped
there; a NaN or a wrong shape raises ValueError in one line before
anything is simulated.

**Reward**, per step: 0 before the first contact, then minus the mean
|f_d - f| over the step's samples in units of 10 N, at most 2 (the measured
filtered force; no ground truth). **Termination**: losing contact after
the first contact (the law's switch back to the approach) or a divergence
(a non-finite state, a contact force above ``simulation.force_limit``, or an
error inside the simulator) ends the episode with ``terminated`` and a
penalty of the lowest reward, -2, for every step the episode had left, so
ending an episode never pays. The end of ``duration_s`` is ``truncated``.
``info`` holds the ground truth for scoring: the true contact force, the
wall's parameters and law, the noise seed, the drive's scale, the time.

**Domain randomization** (:class:`TrainingDistribution`): at each reset the
wall's K_e and B_e (log-uniform, away from every benchmark wall), the
contact law, wall friction, joint 2's drive scale (the model error the
controller does not know), the noise seed and optionally a fault, drawn
from the environment's ``np_random`` (the seed given to reset): the same
seed gives the same episode.

**Safety**: ``supervisor=True`` puts the station's safety supervisor
(``safety.enabled``) behind the policy.
"""

import dataclasses as dc
import math

import gymnasium as gym
import numpy as np
from pydrake.gym import DrakeGymEnv
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from drake_contact.app.benchmark import SUITES, TASKS, contender_scenario
from drake_contact.control.hybrid_controller import APPROACH
from drake_contact.control.policy import EXTERNAL
from drake_contact.control.policy_spaces import (
    ACTION, ACTION_HIGH, ACTION_LOW, OBSERVATION, OBSERVATION_BOUND, check_action)
from drake_contact.diagram import MakeEnsembleDiagram, SeedNoise
from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import CONTROL_PERIOD
from drake_contact.scenario import Scenario, load_scenario

#: The environment's id in Gymnasium's registry.
ENV_ID = "drake_contact/ForceTracking-v0"
#: The contender whose hybrid law the policy drives.
BASE_CONTENDER = "hybrid_pi"
#: The lowest reward of a step (an error of 20 N or more).
LOWEST_REWARD = -2.0


@dc.dataclass(frozen=True)
class TrainingDistribution:
    """What each reset draws (log-uniform K_e and B_e; the rest uniform)."""

    # Wall stiffness K_e (N/m) and damping B_e (N s/m): log-uniform.
    stiffness_range: tuple = (2000.0, 200000.0)
    damping_range: tuple = (5.0, 400.0)
    # A draw within this relative distance of a benchmark wall's K_e and B_e
    # (both) is drawn again, so no training wall is an evaluation wall.
    exclusion: float = 0.15
    # Chance of the Hunt-Crossley law (else linear), and of wall friction
    # with mu uniform in friction_range.
    hunt_crossley_probability: float = 0.2
    friction_probability: float = 0.2
    friction_range: tuple = (0.1, 0.4)
    # Joint 2's drive delivers this times its command (the suite: 1.2).
    drive_scale_range: tuple = (1.0, 1.4)
    # Chance of one fault, drawn from ``faults`` (scenario fault mappings).
    fault_probability: float = 0.0
    faults: tuple = ()

    def draw(self, rng: np.random.Generator) -> dict:
        """One environment: overrides of the base scenario and its facts."""
        walls = [wall for suite in SUITES.values() for wall in suite.walls]
        while True:
            k = math.exp(rng.uniform(*np.log(self.stiffness_range)))
            b = math.exp(rng.uniform(*np.log(self.damping_range)))
            if not any(abs(k / wk - 1) < self.exclusion and abs(b / wb - 1) < self.exclusion
                       for wk, wb in walls):
                break
        law = "hunt_crossley" if rng.uniform() < self.hunt_crossley_probability else "linear"
        mu = (rng.uniform(*self.friction_range) if rng.uniform() < self.friction_probability
              else 0.0)
        drive = rng.uniform(*self.drive_scale_range)
        seed = int(rng.integers(0, 2**31))
        fault = None
        if self.faults and rng.uniform() < self.fault_probability:
            fault = dict(self.faults[int(rng.integers(len(self.faults)))])
        return {"stiffness": k, "damping": b, "law": law, "friction_coefficient": mu,
                "drive_scale": drive, "seed": seed, "fault": fault}


class ForceTrackingEnv(DrakeGymEnv):
    """The station's force-tracking task as a Gymnasium environment (see
    :mod:`drake_contact.app.gym_env`).

    ``task``: a benchmark task or ``random``; ``duration_s``: the episode's
    simulated time; ``period_ms``: the control period (a multiple of the
    1 ms sample); ``training``: the :class:`TrainingDistribution`;
    ``supervisor``: the safety supervisor behind the policy; ``walls``:
    instead of drawing, cycle through these (K_e, B_e) with noise seed i
    for wall i (evaluation on fixed walls)."""

    metadata = {"render_modes": ["ansi"]}

    def __init__(self, task="square", duration_s=16.0, period_ms=10,
                 training: TrainingDistribution | None = None, supervisor=False, walls=None,
                 render_mode=None):
        if task != "random" and task not in TASKS:
            raise ScenarioError(f"task = '{task}' is unknown: choose one of "
                                f"{', '.join(TASKS)}, random")
        if not (isinstance(period_ms, int) and 1 <= period_ms <= 1000):
            raise ScenarioError(f"period_ms = {period_ms} is out of range: must be an integer "
                                "in [1, 1000] (ms)")
        if not (0.0 < duration_s <= 600.0):
            raise ScenarioError(f"duration_s = {duration_s} is out of range: must be in "
                                "(0, 600] s")
        self.task = task
        self.duration_s = float(duration_s)
        self.period_ms = period_ms
        self.training = training or TrainingDistribution()
        self.supervisor = supervisor
        self.walls = list(walls) if walls else None
        self._episode = 0
        super().__init__(
            simulator=self._make_simulator,
            time_step=period_ms * CONTROL_PERIOD,
            action_space=gym.spaces.Box(ACTION_LOW, ACTION_HIGH, (ACTION.size,), np.float32),
            observation_space=gym.spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND,
                                             (OBSERVATION.size,), np.float64),
            reward=lambda system, context: 0.0,
            action_port_id="policy_action", observation_port_id="policy_observation",
            render_mode="ansi" if render_mode is None else render_mode)
        # DrakeGymEnv lists its own render modes (human, ascii) in the class's
        # metadata; this environment renders a line of text (ansi).
        self.metadata = {"render_modes": ["ansi"]}
        if render_mode not in (None, "ansi"):
            raise ScenarioError(f"render_mode = '{render_mode}' is unknown: choose ansi or None")
        self.render_mode = render_mode
        self.steps = int(round(self.duration_s / self.time_step))

    # -- building ----------------------------------------------------------

    def scenario(self, drawn: dict, task: str, source: str = EXTERNAL) -> Scenario:
        """The scenario of one episode: the benchmark's base scenario with
        the policy controller, the task and the drawn environment. With a
        ``source`` (see :class:`drake_contact.control.policy.PolicyConfig`)
        instead of ``external``, the same episode with that policy in the
        controller, to run as any scenario."""
        data = contender_scenario(BASE_CONTENDER)
        data["controller"] = {"name": "policy", "hybrid": data["controller"]["hybrid"],
                              "policy": {"source": source, "period_ms": self.period_ms}}
        arm = data.setdefault("arm", {})
        arm["motor_torque_scale"] = [1.0, drive_scale(drawn), 1.0]
        if drawn.get("fault"):
            data["faults"] = [drawn["fault"]]
        if self.supervisor:
            data.setdefault("safety", {})["enabled"] = True
        overrides = TASKS[task][1] + [
            f"environment.stiffness={drawn['stiffness']!r}",
            f"environment.damping={drawn['damping']!r}",
            f"simulation.duration={self.duration_s!r}", f"simulation.seed={drawn['seed']}",
            # The final-window metrics' window, within a short episode.
            f"simulation.settle_window={min(0.5, self.duration_s)!r}"]
        if drawn.get("law", "linear") != "linear":
            overrides.append(f"environment.law={drawn['law']}")
        if drawn.get("friction_coefficient"):
            overrides.append(f"environment.friction_coefficient={drawn['friction_coefficient']!r}")
        return load_scenario(data, overrides)

    def _draw(self):
        rng = self.np_random
        task = self.task if self.task != "random" else list(TASKS)[int(rng.integers(len(TASKS)))]
        if self.walls:
            i = self._episode % len(self.walls)
            k, b = self.walls[i]
            drawn = {"stiffness": float(k), "damping": float(b), "seed": i,
                     "drive_scale": 1.2}
        else:
            drawn = self.training.draw(rng)
        self._episode += 1
        return drawn, task

    def _make_simulator(self, generator=None):
        drawn, task = self._draw()
        scenario = self.scenario(drawn, task)
        simulator = gym_simulator([scenario])
        self.drawn, self.episode_task, self.episode_scenario = drawn, task, scenario
        return simulator

    # -- Gymnasium ---------------------------------------------------------

    def reset(self, *, seed=None, options=None):
        """Draws an environment with the env's ``np_random`` (seeded by
        ``seed``), builds its diagram and returns the observation at t = 0.
        Replaces DrakeGymEnv.reset, which would re-randomize the Context
        after seeding it (SetRandomContext) and call Initialize before."""
        gym.Env.reset(self, seed=seed)
        if options:
            raise ValueError(f"reset options {options!r} are not supported: pass the "
                             "task and walls to the constructor")
        self.simulator = self._make_simulator()
        self._setup()
        self.simulator.Initialize()
        self._had_contact = False
        self._step = 0
        context = self.simulator.get_context()
        self._observation = self.observation_port.Eval(context).copy()
        return self._observation, self._info(context)

    def step(self, action):
        """Advances ``period_ms`` with ``action`` (checked: ValueError for a
        wrong shape or a non-finite entry; clipped to [-1, 1] by the law).
        Replaces DrakeGymEnv.step, which returns reward 0 and truncates on a
        simulator error: here it is a termination with the penalty."""
        if self.simulator is None:
            raise RuntimeError("call reset() before step()")
        action = check_action(action)
        context = self.simulator.get_mutable_context()
        self.action_port.FixValue(context, action)
        self._step += 1
        t_next = self._step * self.time_step
        system = self.simulator.get_system()
        failure = ""
        try:
            self.simulator.AdvanceTo(t_next)
        except RuntimeError as e:  # SimulationDiverged and Drake's own checks
            failure = str(e).splitlines()[0]
        if not failure:
            failure = self._diverged(system, context)
        left = self.steps - self._step
        if failure:
            # The state may not be finite: the last good observation, and
            # what is known without evaluating the diagram.
            info = self._facts() | {"time_s": context.get_time(), "diverged": failure}
            return self._observation, LOWEST_REWARD * (left + 1), True, False, info
        observation = self.observation_port.Eval(context).copy()
        self._observation = observation
        info = self._info(context)
        reward, lost, self._had_contact = step_reward(observation, self._had_contact, left)
        if lost:
            info["contact_lost"] = True
            return observation, reward, True, False, info
        return observation, reward, False, left <= 0, info

    def _diverged(self, system, context) -> str:
        return divergence(system.GetOutputPort("joint_state_true").Eval(context),
                          system.GetOutputPort("contact_force_true").Eval(context)[0],
                          self.episode_scenario.simulation.force_limit, context.get_time())

    def _info(self, context) -> dict:
        system = self.simulator.get_system()
        return {"time_s": context.get_time(),
                "force_true": float(system.GetOutputPort("contact_force_true").Eval(context)[0]),
                "force_desired": float(system.GetOutputPort("force_desired").Eval(context)[0]),
                "in_contact": bool(system.GetOutputPort("mode").Eval(context)[0] != APPROACH),
                } | self._facts()

    def _facts(self) -> dict:
        """The episode's environment: the ground truth for scoring."""
        return {"task": self.episode_task, "stiffness": self.drawn["stiffness"],
                "damping": self.drawn["damping"], "law": self.drawn.get("law", "linear"),
                "friction_coefficient": self.drawn.get("friction_coefficient", 0.0),
                "drive_scale": drive_scale(self.drawn), "seed": self.drawn["seed"],
                "fault": self.drawn.get("fault")}

    def render(self):
        if self.simulator is None:
            return ""
        info = self._info(self.simulator.get_context())
        return (f"t = {info['time_s']:.3f} s  f_true = {info['force_true']:.2f} N  "
                f"f_d = {info['force_desired']:.2f} N  K_e = {info['stiffness']:.0f} N/m")


#: The station's outputs an environment reads.
GYM_OUTPUTS = ("policy_observation", "contact_force_true", "joint_state_true", "force_desired",
               "mode")


def gym_simulator(scenarios) -> Simulator:
    """A Simulator of the station of ``scenarios`` (one environment, or an
    ensemble: :func:`drake_contact.diagram.MakeEnsembleDiagram`) with its
    input ``policy_action`` and the outputs :data:`GYM_OUTPUTS` exported,
    its noise seeded by each scenario's seed."""
    builder = DiagramBuilder()
    station = builder.AddSystem(MakeEnsembleDiagram(scenarios))
    builder.ExportInput(station.GetInputPort("policy_action"), "policy_action")
    for name in GYM_OUTPUTS:
        builder.ExportOutput(station.GetOutputPort(name), name)
    diagram = builder.Build()
    diagram.set_name("gym")
    simulator = Simulator(diagram)
    SeedNoise(diagram, simulator.get_mutable_context())
    return simulator


def step_reward(observation, had_contact: bool, left: int):
    """(reward, contact lost, had contact since) of a step that ended in
    ``observation`` with ``left`` steps of the episode after it: 0 before
    the first contact, then minus the step's mean |f_d - f| in units of
    10 N, at most 2; losing contact adds the lowest reward for every step
    left."""
    in_contact = observation[OBSERVATION.in_contact] == 1.0
    reward = 0.0
    if had_contact or in_contact:
        reward = -min(observation[OBSERVATION.mean_abs_force_error], -LOWEST_REWARD)
    lost = had_contact and not in_contact
    if lost:
        reward += LOWEST_REWARD * left
    return reward, lost, had_contact or in_contact


def divergence(state, force: float, limit: float, t: float) -> str:
    """Why the arm's state [q; v] and the true contact force at ``t`` end
    the episode ('' if they do not): not finite, or above ``limit``."""
    if not (np.all(np.isfinite(state)) and math.isfinite(force)):
        return f"diverged at t = {t:.3f} s: the arm's state is not finite"
    if force > limit:
        return (f"diverged at t = {t:.3f} s: the contact force {force:.4g} N "
                f"exceeds simulation.force_limit = {limit} N")
    return ""


def drive_scale(drawn: dict) -> float:
    return float(drawn.get("drive_scale", 1.2))


def register():
    """Registers :data:`ENV_ID` with Gymnasium (once), with its vector
    environment (:class:`drake_contact.app.gym_vector.ForceTrackingVectorEnv`)
    as the entry point of ``gymnasium.make_vec``."""
    if ENV_ID not in gym.registry:
        gym.register(ENV_ID, entry_point="drake_contact.app.gym_env:ForceTrackingEnv",
                     vector_entry_point="drake_contact.app.gym_vector:ForceTrackingVectorEnv",
                     disable_env_checker=False)
