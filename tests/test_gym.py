"""The Gymnasium environment (drake_contact.gym) and the policy controller
it shares its observation and action with."""
import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import drake_contact.gym  # noqa: E402  (registers the environment)
from drake_contact.app.benchmark import SUITES  # noqa: E402
from drake_contact.control.policy import NumpyPolicy  # noqa: E402
from drake_contact.control.policy_spaces import (  # noqa: E402
    ACTION, OBSERVATION, apply_action)
from drake_contact.errors import ScenarioError  # noqa: E402
from drake_contact.gym import LOWEST_REWARD, ForceTrackingEnv, TrainingDistribution  # noqa: E402
from drake_contact.simulation import simulate_scenario  # noqa: E402

#: A wall of no suite, for the runs that need contact.
WALL = (9000.0, 60.0)


def test_the_registered_environment_passes_gymnasiums_checker():
    env = gymnasium.make(drake_contact.gym.ENV_ID, duration_s=0.2)
    from gymnasium.utils.env_checker import check_env
    check_env(env.unwrapped, skip_render_check=True)
    assert env.action_space.shape == (ACTION.size,)
    assert env.observation_space.shape == (OBSERVATION.size,)


def test_the_same_seed_gives_the_same_episode_and_another_seed_another_wall():
    env = ForceTrackingEnv(duration_s=0.3)
    rollouts = []
    for seed in (4, 4, 5):
        observation, info = env.reset(seed=seed)
        observations = [observation]
        for k in range(30):
            observations.append(env.step(np.full(4, 0.1 * (k % 3), np.float32))[0])
        rollouts.append((np.array(observations), info["stiffness"], info["seed"]))
    assert np.array_equal(rollouts[0][0], rollouts[1][0])
    assert rollouts[0][1:] == rollouts[1][1:]
    assert rollouts[2][1:] != rollouts[0][1:]


def test_the_supervisor_and_a_drawn_fault_sit_in_the_episode():
    fault = {"kind": "force_dropout_zero", "start_s": 0.05, "duration_s": 0.05}
    env = ForceTrackingEnv(duration_s=0.2, supervisor=True, render_mode="ansi",
                           training=TrainingDistribution(fault_probability=1.0, faults=(fault,)))
    observation, info = env.reset(seed=2)
    assert info["fault"] == fault
    scenario = env.episode_scenario
    assert scenario.safety.enabled and [f.kind for f in scenario.faults] == [fault["kind"]]
    assert "safety_state" in env.simulator.get_system().GetSubsystemByName("station").signals
    for _ in range(20):
        observation, reward, terminated, truncated, info = env.step(np.zeros(4))
    assert truncated and not terminated
    assert env.render().startswith("t = 0.200 s")


def test_training_walls_stay_away_from_every_evaluation_wall():
    training = TrainingDistribution()
    rng = np.random.default_rng(0)
    walls = [wall for suite in SUITES.values() for wall in suite.walls]
    for _ in range(300):
        drawn = training.draw(rng)
        assert 2000.0 <= drawn["stiffness"] <= 200000.0
        assert not any(abs(drawn["stiffness"] / k - 1) < training.exclusion
                       and abs(drawn["damping"] / b - 1) < training.exclusion for k, b in walls)


def test_bad_actions_raise_one_line_and_out_of_bounds_actions_are_clipped():
    env = ForceTrackingEnv(duration_s=0.1)
    env.reset(seed=0)
    for bad, says in (([np.nan, 0, 0, 0], "not finite"), ([0.0, 0.0], r"shape \(2,\)"),
                      ("four", "not 4 numbers")):
        with pytest.raises(ValueError, match=says) as error:
            env.step(bad)
        assert "\n" not in str(error.value)
    env.step(np.array([5.0, -7.0, 2.0, -3.0]))  # clipped, no error
    assert apply_action(np.array([5.0, -7.0, 2.0, -3.0]), 1.0, 0.003, 0.0) == \
        apply_action(np.array([1.0, -1.0, 1.0, -1.0]), 1.0, 0.003, 0.0)
    # The zero action leaves the law as it is.
    assert apply_action(np.zeros(4), 1.0, 0.003, 20.0) == (0.0, 1.0, 0.003, 20.0)
    with pytest.raises(ScenarioError, match="task = 'push' is unknown"):
        ForceTrackingEnv(task="push")


def rollout(env, act):
    """Steps ``env`` (reset with seed 0) with ``act`` to the end: the
    observations, the true forces, and the last step's flags and info."""
    observation, _ = env.reset(seed=0)
    observations, forces = [observation], []
    while True:
        observation, reward, terminated, truncated, info = env.step(act(observation))
        observations.append(observation)
        forces.append(info["force_true"])
        if terminated or truncated:
            return np.array(observations), np.array(forces), terminated, truncated, info


def test_the_laws_own_command_holds_the_force_on_a_wall_of_no_suite():
    env = gymnasium.make(drake_contact.gym.ENV_ID, task="hold", duration_s=10.5,
                         walls=[WALL])
    _, forces, terminated, truncated, info = rollout(env, lambda o: np.zeros(4, np.float32))
    assert truncated and not terminated and info["in_contact"]
    # The last second of the 20 N hold, true force (ground truth in info).
    assert abs(np.mean(forces[-100:]) - 20.0) < 1.0
    # The zero action is the hybrid law unmodified: the episode's true
    # force is hybrid_pi's on the same wall and seed, bit for bit.
    scenario = env.unwrapped.scenario(env.unwrapped.drawn, "hold")
    scenario.controller.name = "hybrid"
    hybrid_log = simulate_scenario(scenario).log
    assert "policy_action" not in hybrid_log
    assert np.array_equal(hybrid_log["contact_force_true"][10::10], forces)


def test_a_rollout_equals_the_run_of_the_same_policy_as_the_controller(tmp_path):
    """Stepping the environment with a policy and running the ``policy``
    controller with it in a scenario give the same run, sample for sample."""
    rng = np.random.default_rng(3)
    policy = NumpyPolicy([(0.3 * rng.standard_normal((ACTION.size, OBSERVATION.size)),
                           0.3 * rng.standard_normal(ACTION.size))])
    path = tmp_path / "policy.json"
    policy.save(path)
    env = ForceTrackingEnv(task="square", duration_s=10.5, walls=[WALL])
    observations, forces, terminated, truncated, info = rollout(env, NumpyPolicy.load(path))
    assert truncated and not terminated
    result = simulate_scenario(env.scenario(env.drawn, "square", source=str(path)))
    log = result.log
    assert np.array_equal(log["policy_observation"][::10], observations)
    assert np.array_equal(log["contact_force_true"][10::10], forces)
    assert np.abs(log["policy_action"][-1]).max() > 0.01  # the policy acted


def test_policies_in_an_ensemble_act_as_alone_in_contact(tmp_path):
    """The policy controller serving N environments (one law, observation
    and runner, each environment its own policy, a clipped and a tanh
    output) gives each its run alone, bit for bit, through contact."""
    from drake_contact.simulation import simulate_ensemble
    rng = np.random.default_rng(4)
    env = ForceTrackingEnv(task="square_sine", duration_s=10.2)
    scenarios = []
    for i, (wall, output) in enumerate(((WALL, "clip"), ((40000.0, 15.0), "tanh"))):
        hidden = 0.3 * rng.standard_normal((8, OBSERVATION.size)), np.zeros(8)
        last = 0.5 * rng.standard_normal((ACTION.size, 8)), 0.2 * rng.standard_normal(4)
        path = tmp_path / f"policy{i}.json"
        NumpyPolicy([hidden, last], output=output).save(path)
        drawn = {"stiffness": wall[0], "damping": wall[1], "seed": 5 + i, "drive_scale": 1.1}
        scenarios.append(env.scenario(drawn, "square_sine", source=str(path)))
    for scenario, result in zip(scenarios, simulate_ensemble(scenarios)):
        alone = simulate_scenario(scenario)
        assert result.status == alone.status == "completed"
        assert alone.log["mode"][-1] == 1.0  # in contact at the end
        for key in alone.log:
            np.testing.assert_array_equal(np.asarray(result.log[key]),
                                          np.asarray(alone.log[key]), err_msg=key)


def test_a_wall_of_1e9_n_per_m_diverges_into_a_termination_with_the_penalty():
    env = ForceTrackingEnv(task="hold", duration_s=8.0, walls=[(1e9, 100.0)])
    env.reset(seed=0)
    for step in range(1, env.steps + 1):
        observation, reward, terminated, truncated, info = env.step(np.zeros(4))
        if terminated or truncated:
            break
    assert terminated and not truncated
    assert info["diverged"].startswith(f"diverged at t = {info['time_s']:.3f} s: the contact "
                                       "force")
    assert "exceeds simulation.force_limit = 500.0 N" in info["diverged"]
    assert reward == LOWEST_REWARD * (env.steps - step + 1)
    assert np.all(np.isfinite(observation))


def test_a_simulator_error_terminates_with_the_penalty():
    env = ForceTrackingEnv(task="hold", duration_s=2.0)
    env.reset(seed=1)
    env.step(np.zeros(4))

    class Failing:
        """The simulator, raising as Drake does on a NaN input."""

        def __init__(self, simulator):
            self._simulator = simulator

        def __getattr__(self, name):
            return getattr(self._simulator, name)

        def AdvanceTo(self, t):
            raise RuntimeError("MultibodyPlant: a NaN in the applied forces\nmore lines")
    env.simulator = Failing(env.simulator)
    observation, reward, terminated, truncated, info = env.step(np.zeros(4))
    assert terminated and not truncated
    assert info["diverged"] == "MultibodyPlant: a NaN in the applied forces"
    assert reward == LOWEST_REWARD * (env.steps - 1)


def test_a_numpy_policy_clips_or_squashes_and_takes_a_batch(tmp_path):
    rng = np.random.default_rng(6)
    layers = [(rng.standard_normal((8, OBSERVATION.size)), rng.standard_normal(8)),
              (3.0 * rng.standard_normal((ACTION.size, 8)), rng.standard_normal(ACTION.size))]
    batch = 2.0 * rng.standard_normal((5, OBSERVATION.size))
    for output in ("tanh", "clip"):
        policy = NumpyPolicy(layers, output=output)
        actions = policy(batch)
        assert actions.shape == (5, ACTION.size)
        assert np.abs(actions).max() <= 1.0
        for row, action in zip(batch, actions):
            np.testing.assert_allclose(policy(row), action, rtol=0, atol=1e-12)
        for suffix in (".json", ".npz"):
            path = tmp_path / f"policy_{output}{suffix}"
            policy.save(path)
            loaded = NumpyPolicy.load(path)
            assert loaded.output == output
            np.testing.assert_array_equal(loaded(batch[0]), policy(batch[0]))
    h = np.tanh(layers[0][0] @ batch[0] + layers[0][1])
    mean = layers[1][0] @ h + layers[1][1]
    assert np.array_equal(NumpyPolicy(layers, output="clip")(batch[0]), np.clip(mean, -1, 1))
    assert (np.abs(mean) > 1).any()  # the clip is exercised
    with pytest.raises(ValueError, match="output = 'relu'"):
        NumpyPolicy(layers, output="relu")
