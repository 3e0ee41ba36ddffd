"""highway-env road scenarios (racetrack, highway): the envs' observation, their planning models and shipped demos."""

import sys

import gymnasium as gym
import numpy as np
import pytest
import torch as th

import sb3_mpail.envs  # noqa: F401  (registers the environments)
from sb3_mpail.demos import SHIPPED_DEMO_DIR
from sb3_mpail.envs.highway_roads import EGO_FEATURES, EGO_SCALES
from sb3_mpail.mppi import DEFAULT_DYNAMICS, HighwayKinematics, RacetrackKinematics, make_dynamics
from sb3_mpail.mppi.reference import rollout as rollout_step_by_step

RACETRACK_ID = "sb3_mpail/Racetrack-v0"
HIGHWAY_ID = "sb3_mpail/Highway-v0"
# env id, its planning model, its action size
ROAD_SCENARIOS = [(RACETRACK_ID, RacetrackKinematics, 1), (HIGHWAY_ID, HighwayKinematics, 2)]


@pytest.mark.parametrize("env_id", [RACETRACK_ID, HIGHWAY_ID])
def test_road_env_without_highway_env_says_what_to_install(monkeypatch, env_id):
    monkeypatch.setitem(sys.modules, "highway_env", None)  # import highway_env now fails as if it were not installed
    with pytest.raises(ImportError, match=r'pip install -e "\.\[scenarios\]"'):
        gym.make(env_id)


def test_racetrack_model_holds_the_speed_and_turns_left_for_positive_steering():
    model = RacetrackKinematics()
    states = th.tensor([[5.0, 0.0, 1.0, 0.0, 1.0, 0.0]] * 2, dtype=th.float64)  # x = 50 m, heading 0 at 10 m/s
    next_states = model(states, th.tensor([[0.0], [1.0]], dtype=th.float64))
    assert next_states[0].tolist() == pytest.approx([5.0 + 10.0 * 0.2 / 10, 0.0, 1.0, 0.0, 1.0, 0.0])
    assert 10 * th.hypot(next_states[1, 2], next_states[1, 3]).item() == pytest.approx(10.0)
    assert next_states[1, 1] > 0 and next_states[1, 5] > 0  # moved and turned left


def test_racetrack_model_rollout_matches_its_steps():
    model = RacetrackKinematics()
    generator = th.Generator().manual_seed(0)
    initial_states = th.tensor([[7.0, 0.5, 1.0, 0.0, 1.0, 0.0], [3.0, -2.0, 0.0, -0.9, 0.0, -1.0]], dtype=th.float64)
    actions = th.rand(8, 2, 16, 1, generator=generator, dtype=th.float64) * 2 - 1
    with th.no_grad():
        np.testing.assert_allclose(
            model.rollout(initial_states, actions), rollout_step_by_step(model, initial_states, actions), atol=1e-12
        )
        # beyond highway-env's 40 m/s limit the closed form does not hold; the speeds are integrated substep by substep
        fast_states = initial_states * th.tensor([1.0, 1.0, 5.0, 5.0, 1.0, 1.0], dtype=th.float64)  # 45-50 m/s
        np.testing.assert_allclose(
            model.rollout(fast_states, actions), rollout_step_by_step(model, fast_states, actions), atol=1e-12
        )


@pytest.mark.parametrize("env_id, model_class, action_size", ROAD_SCENARIOS)
def test_road_model_is_the_default_for_its_env(env_id, model_class, action_size):
    space = gym.spaces.Box(-np.inf, np.inf, shape=(6,), dtype=np.float32)
    actions = gym.spaces.Box(-1.0, 1.0, shape=(action_size,), dtype=np.float32)
    assert isinstance(make_dynamics(DEFAULT_DYNAMICS[env_id], space, actions), model_class)


@pytest.mark.parametrize("env_id, model_class, action_size", ROAD_SCENARIOS)
def test_road_env_passes_check_env(env_id, model_class, action_size):
    pytest.importorskip("highway_env")
    from gymnasium.utils.env_checker import check_env as gymnasium_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(env_id)
    assert env.observation_space.shape == (6,) and env.action_space.shape == (action_size,)
    sb3_check_env(env)
    gymnasium_check_env(env.unwrapped)


@pytest.mark.parametrize("env_id, model_class, action_size", ROAD_SCENARIOS)
def test_road_observation_is_highway_envs_absolute_kinematics_observation(env_id, model_class, action_size):
    pytest.importorskip("highway_env")
    from highway_env.envs.common.observation import KinematicObservation

    env = gym.make(env_id, dtype=np.float64)
    observation, _ = env.reset(seed=3)
    kinematics = KinematicObservation(
        env.unwrapped.road_env, features=EGO_FEATURES, vehicles_count=1, absolute=True, normalize=False
    )
    for step in range(30):
        # highway-env's observation is float32; ours in float64 rounds to the same values
        np.testing.assert_array_equal((observation * EGO_SCALES).astype(np.float32), kinematics.observe()[0])
        observation, *_ = env.step(np.full(action_size, 0.5 * np.sin(step / 5), dtype=np.float32))


@pytest.mark.parametrize("env_id, model_class, action_size", ROAD_SCENARIOS)
def test_road_model_predicts_highway_env_to_float_precision(env_id, model_class, action_size):
    pytest.importorskip("highway_env")
    env = gym.make(env_id, dtype=np.float64)
    model = model_class()
    rng = np.random.default_rng(0)
    observation, _ = env.reset(seed=0)
    for _ in range(100):
        action = rng.uniform(-1, 1, size=action_size).astype(np.float32)
        with th.no_grad():
            predicted = model(th.as_tensor(observation[None]), th.as_tensor(action[None], dtype=th.float64))[0].numpy()
        observation, *_ = env.step(action)
        np.testing.assert_allclose(predicted, observation, rtol=0, atol=1e-12)


def test_road_envs_refuse_an_observation_or_action_their_model_cannot_decode():
    pytest.importorskip("highway_env")
    for env_id in (RACETRACK_ID, HIGHWAY_ID):
        with pytest.raises(ValueError, match="computes its own ego observation"):
            gym.make(env_id, config={"observation": {"type": "Kinematics"}})
    with pytest.raises(ValueError, match="steers only"):
        gym.make(RACETRACK_ID, config={"action": {"type": "ContinuousAction", "longitudinal": True, "lateral": True}})


def test_shipped_racetrack_demos_drive_a_lap_on_the_road_at_constant_speed():
    with np.load(SHIPPED_DEMO_DIR / "racetrack_4.npz") as data:
        demos = data["obs"].astype(np.float64)
    assert demos.shape == (4, 201, 6)
    speeds = 10 * np.hypot(demos[..., 2], demos[..., 3])
    np.testing.assert_allclose(speeds, 10.0, atol=1e-4)  # racetrack steers only: the initial 10 m/s is held
    # 200 steps at 10 m/s = 400 m, more than one lap (348 m to 382 m): each demo comes back near its start
    distances_to_start = 10 * np.hypot(*(demos[:, 120:, :2] - demos[:, :1, :2]).transpose(2, 0, 1))
    assert (distances_to_start.min(axis=1) < 5.0).all()


def test_shipped_highway_demos_end_fast_in_the_rightmost_lane():
    with np.load(SHIPPED_DEMO_DIR / "highway_4.npz") as data:
        demos = data["obs"].astype(np.float64)
    assert demos.shape == (4, 201, 6)
    # highway-v0's 4 lanes are 4 m wide, centred on y = 0, 4, 8, 12 (12: the rightmost); its top reward from 30 m/s
    np.testing.assert_allclose(10 * demos[:, -20:, 1], 12.0, atol=0.2)
    np.testing.assert_allclose(10 * demos[:, -20:, 2], 30.0, atol=0.2)


def test_racetrack_episodes_go_on_off_the_road_on_every_highway_env_version():
    env = gym.make("sb3_mpail/Racetrack-v0")
    env.reset(seed=0)
    on_road, terminated, truncated = [], False, False
    while not (terminated or truncated):
        _, _, terminated, truncated, info = env.step(np.array([1.0], dtype=np.float32))  # full left: off the road
        on_road.append(bool(info["rewards"]["on_road_reward"]))
    assert not all(on_road) and len(on_road) == 200 and truncated and not terminated
