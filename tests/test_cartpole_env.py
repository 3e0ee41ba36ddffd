"""``sb3_mpail/ContinuousCartPole-v0``: gymnasium's CartPole-v1 with a continuous force, and its shipped demos."""


import gymnasium as gym
import numpy as np
import torch as th
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/ContinuousCartPole-v0)
from sb3_mpail import load_demos
from sb3_mpail.demos import SHIPPED_DEMO_DIR, shipped_demo_info
from sb3_mpail.envs.cartpole import ContinuousCartPoleEnv, cartpole_dynamics

ENV_ID = "sb3_mpail/ContinuousCartPole-v0"


def test_env_passes_the_checkers():
    gymnasium_check_env(ContinuousCartPoleEnv(), skip_render_check=True)
    sb3_check_env(ContinuousCartPoleEnv())
    image = ContinuousCartPoleEnv(render_mode="rgb_array")
    image.reset(seed=0)
    assert image.render().shape == (400, 600, 3)


def test_full_pushes_reproduce_cartpole_v1_exactly():
    ours, reference = gym.make(ENV_ID), gym.make("CartPole-v1")
    rng = np.random.default_rng(0)
    for episode in range(3):
        observation, _ = ours.reset(seed=episode)
        expected, _ = reference.reset(seed=episode)
        np.testing.assert_array_equal(observation, expected)
        done = False
        while not done:
            push = int(rng.integers(2))
            observation, reward, terminated, truncated, _ = ours.step(np.array([2.0 * push - 1.0], np.float32))
            expected, expected_reward, expected_terminated, _, _ = reference.step(push)
            np.testing.assert_array_equal(observation, expected)
            assert (reward, terminated) == (expected_reward, expected_terminated)
            done = terminated or truncated


def test_episodes_are_cut_at_200_steps():
    env = gym.make(ENV_ID)
    observation, _ = env.reset(seed=0)
    truncations = []
    for _ in range(200):
        # a linear state feedback that balances the pole and centres the cart
        force = np.clip(np.dot([0.1, 0.3, 5.0, 1.0], observation), -1, 1)
        observation, _, terminated, truncated, _ = env.step(np.array([force], np.float32))
        assert not terminated
        truncations.append(truncated)
    assert truncations[-1] and not any(truncations[:-1])


def test_torch_dynamics_match_the_env_step():
    env = ContinuousCartPoleEnv()
    observation, _ = env.reset(seed=3)
    rng = np.random.default_rng(1)
    for _ in range(50):
        action = rng.uniform(-1.5, 1.5, size=1).astype(np.float32)  # out-of-range forces are clipped by both
        state = th.as_tensor(np.array(env.state), dtype=th.float64)[None]
        predicted = cartpole_dynamics(state, th.as_tensor(action, dtype=th.float64)[None])[0].numpy()
        observation, _, terminated, _, _ = env.step(action)
        np.testing.assert_allclose(predicted, np.array(env.state), rtol=1e-12, atol=1e-12)
        if terminated:
            break


def test_shipped_demos_are_expert_episodes_of_the_env():
    meta = shipped_demo_info("cartpole")
    assert meta["env_id"] == ENV_ID
    assert meta["expert_return_mean"] > meta["random_return_mean"] + 100
    demos = load_demos(SHIPPED_DEMO_DIR / "cartpole_4.npz", gym.make(ENV_ID).observation_space)
    assert len(demos.observations) == sum(int(value) for value in meta["demo_returns"])
    assert np.all(np.abs(demos.observations[:, 2]) < 12 * np.pi / 180)  # the pole stays up throughout
