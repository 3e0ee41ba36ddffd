"""MuJoCo Ant scenario: the missing-dependency error, the env's SB3 compatibility and its forward-speed evaluation."""

import sys

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env

import sb3_mpail.envs  # noqa: F401  (registers the environments)
from sb3_mpail.envs.ant import ANT_FORWARD_VELOCITY_INDEX, evaluate_ant

ANT_ID = "sb3_mpail/Ant-v0"


class FixedAction:
    """An untrained policy with SB3's ``predict`` signature: the same action (legs spread) at every step."""

    def predict(self, observations, state=None, episode_start=None, deterministic=True):
        return np.tile([0.0, 1.0, 0.0, -1.0, 0.0, -1.0, 0.0, 1.0], (len(observations), 1)).astype(np.float32), state


def test_ant_without_mujoco_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # import mujoco now fails as if it were not installed
    with pytest.raises(ImportError, match=r'pip install -e "\.\[scenarios\]"'):
        gym.make(ANT_ID)


def test_ant_passes_sb3_check_env_with_float32_observations_and_200_step_episodes():
    pytest.importorskip("mujoco", reason="the Ant needs mujoco (the scenarios extra)")
    env = gym.make(ANT_ID)
    check_env(env, warn=True)
    assert env.observation_space.shape == (27,) and env.observation_space.dtype == np.float32
    assert env.spec.max_episode_steps == 200


def test_ant_evaluation_reports_the_forward_speed_the_observation_carries():
    pytest.importorskip("mujoco", reason="the Ant needs mujoco (the scenarios extra)")
    figures = evaluate_ant(FixedAction(), n_episodes=1, seed=0)
    # the mean of the torso's x velocity over an episode in the observation matches the env's reported x velocity
    env = gym.make(ANT_ID)
    observation, _ = env.reset(seed=0)
    velocities, done = [], False
    while not done:
        observation, _, terminated, truncated, _ = env.step(FixedAction().predict(observation[None])[0][0])
        velocities.append(observation[ANT_FORWARD_VELOCITY_INDEX])
        done = terminated or truncated
    assert figures["forward_speed"] == pytest.approx(np.mean(velocities), abs=0.05)
    assert np.isfinite(figures["return"]) and figures["return_std"] == 0.0
