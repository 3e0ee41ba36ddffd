"""gymnasium's MuJoCo locomotion tasks: their evaluation (return, length, forward speed) and their shipped demo sets."""

import gymnasium as gym
import numpy as np
import pytest

from sb3_mpail.demos import list_shipped_demos, shipped_demo_info, shipped_demos
from sb3_mpail.envs.locomotion import LOCOMOTION_TASKS, evaluate_locomotion

pytest.importorskip("mujoco", reason="the MuJoCo tasks need mujoco (the scenarios extra)")

#: rl_zoo3's published returns that a shipped expert must come near to be called an expert
EXPERT_RETURNS = {"Hopper-v4": 2500, "Walker2d-v4": 3000, "HalfCheetah-v4": 4000, "Ant-v4": 2000}
#: the tasks whose demos the package ships
SHIPPED_TASKS = ["Hopper-v4", "Walker2d-v4", "HalfCheetah-v4", "Ant-v4"]


class ForwardLean:
    """An untrained policy with SB3's ``predict`` signature: the same small action at every step."""

    def predict(self, observations, state=None, episode_start=None, deterministic=True):
        return np.full((len(observations), 3), 0.3, np.float32), state


def test_locomotion_evaluation_reports_the_mean_x_velocity_over_every_step_and_the_episode_length():
    figures = evaluate_locomotion(ForwardLean(), "Hopper-v4", n_episodes=1, seed=0)
    env = gym.make("Hopper-v4")
    env.reset(seed=0)
    velocities, total, done = [], 0.0, False
    while not done:
        _, reward, terminated, truncated, info = env.step(np.full(3, 0.3, np.float32))
        velocities.append(info["x_velocity"])
        total += reward
        done = terminated or truncated
    assert figures["forward_speed"] == pytest.approx(np.mean(velocities), rel=1e-6)
    assert figures["length"] == len(velocities) and figures["return"] == pytest.approx(total, rel=1e-6)


@pytest.mark.parametrize("env_id", SHIPPED_TASKS)
def test_a_shipped_locomotion_demo_set_comes_from_a_real_expert_and_fits_its_env(env_id):
    name = LOCOMOTION_TASKS[env_id]
    sizes = [int(shipped.rsplit("_", 1)[1]) for shipped in list_shipped_demos() if shipped.rsplit("_", 1)[0] == name]
    info = shipped_demo_info(name)
    assert info["env_id"] == env_id and max(sizes) >= 16
    assert info["expert_return_mean"] >= EXPERT_RETURNS[env_id] > info["random_return_mean"]
    trajectories = shipped_demos(name, max(sizes))
    space = gym.make(env_id).observation_space
    assert all(trajectory.obs.shape[1:] == space.shape for trajectory in trajectories)
