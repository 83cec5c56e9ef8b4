"""The vector environment (drake_contact.app.gym_vector): N environments
of ForceTracking-v0 in one ensemble diagram. Gymnasium has no checker for
vector environments; these are its checks, named: spaces and shapes,
seeding, the reset mode, bit-identity with single environments, one
diverging environment."""
import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import drake_contact.gym  # noqa: E402  (registers the environment)
from drake_contact.control.policy_spaces import ACTION, OBSERVATION  # noqa: E402
from drake_contact.errors import ScenarioError  # noqa: E402
from drake_contact.gym import (  # noqa: E402
    ENV_ID, LOWEST_REWARD, ForceTrackingEnv, ForceTrackingVectorEnv, TrainingDistribution)

#: Long enough for contact on every drawn wall (the 5 N switch comes at
#: 9.1 s on 7 kN/m), short enough for the suite.
DURATION = 9.6
WALLS = [(9000.0, 60.0), (1e9, 100.0), (20000.0, 30.0)]


def rollout(env, actions, seed):
    """A single environment's episode under ``actions``: observations,
    rewards, (terminated, truncated) flags, last info."""
    observation, _ = env.reset(seed=seed)
    observations, rewards, flags = [observation], [], []
    for action in actions:
        observation, reward, terminated, truncated, info = env.step(action)
        observations.append(observation)
        rewards.append(reward)
        flags.append((terminated, truncated))
        if terminated or truncated:
            return observations, rewards, flags, info
    raise AssertionError("the episode did not end")


def vector_rollout(envs, actions, seed):
    """Each environment's episode as :func:`rollout` gives it, from the
    vector environment's steps where it was ``stepped``."""
    observation, info = envs.reset(seed=seed)
    n = envs.num_envs
    assert info["active"].all()
    observations, rewards, flags = [[observation[i]] for i in range(n)], [[] for _ in range(n)], \
        [[] for _ in range(n)]
    for k in range(envs.steps):
        observation, reward, terminated, truncated, info = envs.step(actions[k])
        for i in np.flatnonzero(info["stepped"]):
            observations[i].append(observation[i])
            rewards[i].append(reward[i])
            flags[i].append((terminated[i], truncated[i]))
        for i in np.flatnonzero(~info["stepped"]):
            # Held: its last observation, reward 0, its flags again.
            assert reward[i] == 0.0 and (terminated[i] or truncated[i])
            np.testing.assert_array_equal(observation[i], observations[i][-1])
        if not info["active"].any():
            return observations, rewards, flags, info
    raise AssertionError("the episodes did not end")


def assert_same_episode(single, vector, i):
    observations, rewards, flags, _ = single
    assert len(observations) == len(vector[0][i])
    for a, b in zip(observations, vector[0][i]):
        np.testing.assert_array_equal(a, b)  # bit for bit
    assert rewards == vector[1][i]
    assert flags == vector[2][i]


def test_make_vec_gives_the_ensemble_with_batched_spaces_and_shapes():
    envs = gymnasium.make_vec(ENV_ID, num_envs=3, task="hold", duration_s=DURATION)
    assert isinstance(envs, ForceTrackingVectorEnv)
    assert envs.metadata["autoreset_mode"] == gymnasium.vector.AutoresetMode.DISABLED
    assert envs.single_observation_space.shape == (OBSERVATION.size,)
    assert envs.single_action_space.shape == (ACTION.size,)
    assert envs.observation_space.shape == (3, OBSERVATION.size)
    assert envs.action_space.shape == (3, ACTION.size)
    observation, info = envs.reset(seed=0)
    assert observation.shape == (3, OBSERVATION.size)
    assert observation in envs.observation_space
    observation, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert observation.shape == (3, OBSERVATION.size) and reward.shape == (3,)
    assert terminated.dtype == bool and truncated.dtype == bool
    assert info["time_s"].shape == (3,) and info["_time_s"].all()
    assert envs.reset_cost["rebuilt"] and envs.reset_cost["stations"] == 1
    with pytest.raises(ValueError, match=r"actions: shape \(4,\), expected \(3, 4\)"):
        envs.step(np.zeros(4))
    bad = np.zeros((3, 4))
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match=r"actions\[1\]"):
        envs.step(bad)
    with pytest.raises(ScenarioError, match=r"num_envs = 0 is out of range"):
        ForceTrackingVectorEnv(num_envs=0)


def test_seeding_draws_environment_i_with_seed_plus_i():
    envs = ForceTrackingVectorEnv(num_envs=3, task="random", duration_s=DURATION)
    _, info = envs.reset(seed=11)
    _, again = envs.reset(seed=11)
    _, listed = envs.reset(seed=[11, 12, 13])
    for key in ("stiffness", "damping", "task", "seed", "drive_scale"):
        np.testing.assert_array_equal(info[key], again[key])
        np.testing.assert_array_equal(info[key], listed[key])
    for i in range(3):
        single = ForceTrackingEnv(task="random", duration_s=DURATION)
        _, facts = single.reset(seed=11 + i)
        assert (facts["stiffness"], facts["task"]) == (info["stiffness"][i], info["task"][i])
    assert len(set(info["stiffness"])) == 3
    _, other = envs.reset(seed=12)
    assert other["stiffness"][0] == info["stiffness"][1]


def test_the_reset_mode_is_synchronised_and_a_reset_of_the_same_draws_keeps_the_stations():
    envs = ForceTrackingVectorEnv(num_envs=2, task="hold", duration_s=DURATION,
                                  walls=[(9000.0, 60.0), (20000.0, 30.0)])
    first, _ = envs.reset(seed=0)
    stations = [group.simulator for group in envs.groups]
    envs.step(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="reset_mask: the episodes are synchronised"):
        envs.reset(options={"reset_mask": np.array([True, False])})
    again, info = envs.reset(options={"reset_mask": np.array([True, True])})
    # The same walls again (two slots, two walls): the stations are kept,
    # re-initialised at t = 0.
    assert not envs.reset_cost["rebuilt"]
    assert [group.simulator for group in envs.groups] == stations
    assert info["time_s"].tolist() == [0.0, 0.0]
    np.testing.assert_array_equal(first, again)
    with pytest.raises(ValueError, match="reset options"):
        envs.reset(options={"task": "hold"})


def test_every_episode_is_its_single_environments_bit_for_bit():
    """Two episodes of three environments on randomized walls (one of them
    lost contact on a stiff wall in the first episode, and ended early),
    against three single environments under the same actions."""
    n = 3
    envs = ForceTrackingVectorEnv(num_envs=n, task="random", duration_s=DURATION)
    rng = np.random.default_rng(5)
    actions = rng.uniform(-1.0, 1.0, (2, envs.steps, n, ACTION.size))
    vector = [vector_rollout(envs, actions[0], seed=7),
              vector_rollout(envs, actions[1], seed=None)]
    ended_early = 0
    for i in range(n):
        single = ForceTrackingEnv(task="random", duration_s=DURATION)
        for episode in range(2):
            found = rollout(single, actions[episode, :, i], seed=7 + i if episode == 0 else None)
            assert_same_episode(found, vector[episode], i)
            ended_early += found[2][-1][0]
    assert ended_early >= 1  # a lost contact is in the comparison


def test_a_diverging_environment_is_terminated_alone_and_the_others_run_on():
    n = len(WALLS)
    envs = ForceTrackingVectorEnv(num_envs=n, task="hold", duration_s=DURATION, walls=WALLS)
    actions = np.random.default_rng(1).uniform(-1.0, 1.0, (envs.steps, n, ACTION.size))
    vector = vector_rollout(envs, actions, seed=0)
    info = vector[3]
    assert info["_diverged"].tolist() == [False, True, False]
    assert info["diverged"][1].startswith("diverged at t = ")
    assert "exceeds simulation.force_limit = 500.0 N" in info["diverged"][1]
    assert [flags[-1] for flags in vector[2]] == [(False, True), (True, False), (False, True)]
    for i in range(n):
        single = ForceTrackingEnv(task="hold", duration_s=DURATION, walls=WALLS)
        single._episode = i  # the vector environment's slot i takes wall i
        found = rollout(single, actions[:, i], seed=0)
        assert_same_episode(found, vector, i)
        if i == 1:
            assert found[3]["diverged"] == info["diverged"][1]
            assert found[1][-1] == LOWEST_REWARD * (envs.steps - len(found[1]) + 1)


def test_a_drawn_fault_that_changes_the_structure_gets_its_own_station():
    training = TrainingDistribution(fault_probability=0.5, faults=(
        {"kind": "force_dropout_zero", "start_s": 0.5, "duration_s": 0.05},))
    envs = ForceTrackingVectorEnv(num_envs=4, task="hold", duration_s=2.0, training=training)
    envs.reset(seed=3)
    faulted = [env.drawn["fault"] is not None for env in envs.envs]
    assert any(faulted) and not all(faulted)
    assert envs.reset_cost["stations"] == 2
    assert sorted(sorted(group.envs) for group in envs.groups) == sorted(
        [[i for i in range(4) if faulted[i]], [i for i in range(4) if not faulted[i]]])
    observation, reward, terminated, truncated, info = envs.step(np.zeros((4, 4)))
    assert info["stepped"].all() and info["time_s"].tolist() == [0.01] * 4
