"""Tests for the ``sb3_mpail/Navigation-v0`` environment and its demonstration files."""

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Navigation-v0)
from sb3_mpail.demos import shipped_demos
from sb3_mpail.envs.navigation import NavigationEnv

ENV_ID = "sb3_mpail/Navigation-v0"


def bicycle_step(obs: np.ndarray, action: np.ndarray, dt: float = 0.1) -> np.ndarray:
    """The planner's kinematic bicycle model (as in ``sb3_mpail.mppi.dynamics``), on one observation.

    :param obs: 12-D observation.
    :param action: Normalised ``[speed, steering]``.
    :param dt: Step length in seconds.
    :return: Predicted next observation (float64).
    """
    speed = 3.0 * float(np.clip(action[0], -1.0, 1.0))
    steer = 0.488 * float(np.clip(action[1], -1.0, 1.0))
    yaw_rate = speed * math.tan(steer) / 0.325
    pred = obs.astype(np.float64)
    pred[0] += speed * math.cos(pred[5]) * dt
    pred[1] += speed * math.sin(pred[5]) * dt
    pred[5] += yaw_rate * dt
    pred[6], pred[7], pred[11] = speed, 0.0, yaw_rate
    return pred


def test_env_passes_gymnasium_and_sb3_checkers() -> None:
    with warnings.catch_warnings():
        # Any checker warning (bounds, dtype, determinism) is a failure.
        warnings.simplefilter("error")
        gymnasium_check_env(gym.make(ENV_ID).unwrapped)
        sb3_check_env(NavigationEnv())


def test_same_seed_and_actions_give_same_observations() -> None:
    actions = np.random.default_rng(0).uniform(-1.0, 1.0, size=(50, 2)).astype(np.float32)

    def trajectory(seed: int) -> np.ndarray:
        env = NavigationEnv()
        observations = [env.reset(seed=seed)[0]]
        observations += [env.step(action)[0] for action in actions]
        return np.stack(observations)

    np.testing.assert_array_equal(trajectory(3), trajectory(3))
    assert not np.array_equal(trajectory(3), trajectory(4))


def test_reward_is_sqrt200_minus_distance_to_goal() -> None:
    env = NavigationEnv()
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    for _ in range(30):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(-1.0, 1.0, size=2))
        distance = math.hypot(obs[0] - 10.0, obs[1] - 10.0)
        assert reward == pytest.approx(math.sqrt(200.0) - distance, abs=1e-4)
        assert info["distance_to_goal"] == pytest.approx(distance, abs=1e-4)
        assert not terminated and not truncated


def test_custom_goal_from_reset_options_sets_distance() -> None:
    env = NavigationEnv()
    obs, info = env.reset(seed=0, options={"goal": (-5.0, 2.0)})
    assert info["distance_to_goal"] == pytest.approx(math.hypot(obs[0] + 5.0, obs[1] - 2.0), abs=1e-5)


def test_default_start_is_at_rest_within_1m_of_origin_with_small_heading() -> None:
    env = NavigationEnv()
    for seed in range(200):
        obs, _ = env.reset(seed=seed)
        assert np.all(np.abs(obs[:2]) <= 0.5) and math.hypot(obs[0], obs[1]) <= 1.0
        assert abs(obs[5]) <= math.pi / 8
        np.testing.assert_array_equal(obs[6:], 0.0)


def test_ood_start_lies_in_40m_box_with_any_heading() -> None:
    env = NavigationEnv(start_region="ood")
    starts = np.stack([env.reset(seed=seed)[0] for seed in range(300)])
    assert np.all(np.abs(starts[:, :2]) <= 20.0)
    assert np.abs(starts[:, :2]).max() > 10.0  # actually spreads beyond the default region
    assert starts[:, 5].min() < -math.pi / 2 and starts[:, 5].max() > math.pi / 2
    assert all(env.observation_space.contains(obs) for obs in starts)
    # The same region can be requested per episode.
    obs, _ = NavigationEnv().reset(seed=0, options={"start_region": 3.0})
    assert np.all(np.abs(obs[:2]) <= 3.0)


def test_registered_env_truncates_after_100_steps() -> None:
    env = gym.make(ENV_ID)
    env.reset(seed=0)
    for step in range(1, 101):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        assert not terminated
        assert truncated == (step == 100)


def test_bicycle_model_mismatch_is_bounded_and_nonzero() -> None:
    env = NavigationEnv()
    rng = np.random.default_rng(0)
    position_errors, yaw_errors, speed_errors, yaw_rate_errors = [], [], [], []
    for episode in range(10):
        obs, _ = env.reset(seed=episode)
        for _ in range(100):
            action = rng.uniform(-1.0, 1.0, size=2)
            pred = bicycle_step(obs, action)
            obs, *_ = env.step(action)
            position_errors.append(math.hypot(pred[0] - obs[0], pred[1] - obs[1]))
            yaw_errors.append(abs((pred[5] - obs[5] + math.pi) % (2 * math.pi) - math.pi))
            speed_errors.append(abs(pred[6] - obs[6]))
            yaw_rate_errors.append(abs(pred[11] - obs[11]))
    for name, errors in [
        ("position [m]", position_errors),
        ("yaw [rad]", yaw_errors),
        ("vx [m/s]", speed_errors),
        ("wz [rad/s]", yaw_rate_errors),
    ]:
        print(f"one-step bicycle error {name}: mean {np.mean(errors):.4f} max {np.max(errors):.4f}")
    # Lag and slip make the model imperfect, but one step can never be off by more than full-speed travel.
    assert np.mean(position_errors) > 1e-3 and np.max(position_errors) < 0.6
    assert np.mean(yaw_errors) > 1e-3 and np.max(yaw_errors) < 1.0


def test_bicycle_model_matches_at_low_speed_steady_state() -> None:
    env = NavigationEnv()
    env.reset(seed=0)
    action = np.array([0.1, 0.5], dtype=np.float32)
    for _ in range(30):
        obs, *_ = env.step(action)
    pred = bicycle_step(obs, action)
    obs, *_ = env.step(action)
    assert math.hypot(pred[0] - obs[0], pred[1] - obs[1]) < 1e-3
    assert pred[11] == pytest.approx(obs[11], rel=0.01)


@pytest.mark.parametrize("n_demos", [1, 4, 16])
def test_demo_file_holds_finite_in_space_observations(n_demos: int) -> None:
    obs = np.stack([trajectory.obs for trajectory in shipped_demos("navigation", n_demos)])
    assert obs.shape == (n_demos, 101, 12) and obs.dtype == np.float32
    assert np.all(np.isfinite(obs))
    space = NavigationEnv().observation_space
    assert all(space.contains(step_obs) for step_obs in obs.reshape(-1, 12))
