"""highway-env scenarios: the missing-dependency error, the parking env's flat observation and its planning model."""

import math
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch as th

import sb3_mpail.envs  # noqa: F401  (registers the environments)
from sb3_mpail.demos import SHIPPED_DEMO_DIR, shipped_demo_info
from sb3_mpail.mppi import DEFAULT_DYNAMICS, ParkingKinematics, make_dynamics
from sb3_mpail.mppi.reference import rollout as rollout_step_by_step

PARKING_ID = "sb3_mpail/Parking-v0"


def test_parking_without_highway_env_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "highway_env", None)  # import highway_env now fails as if it were not installed
    with pytest.raises(ImportError, match=r'pip install -e "\.\[scenarios\]"'):
        gym.make(PARKING_ID)


def test_parking_model_drives_straight_turns_left_and_holds_the_goal():
    model = ParkingKinematics()
    goal = [0.26, 0.14, 0.0, 0.0, 0.0, 1.0]
    # heading 0 at 10 m/s; the second car also brakes fully and steers fully left
    states = th.tensor([[0.0, 0.0, 2.0, 0.0, 1.0, 0.0, *goal]] * 2, dtype=th.float64)
    next_states = model(states, th.tensor([[0.0, 0.0], [-1.0, 1.0]], dtype=th.float64))
    assert next_states[0, :6].tolist() == pytest.approx([10.0 * 0.2 / 100, 0.0, 2.0, 0.0, 1.0, 0.0])
    speeds = 10.0 - 5.0 * np.arange(3) / 15  # speed during each of the 3 substeps
    beta = math.atan(math.tan(math.pi / 4) / 2)
    heading = speeds.sum() * math.sin(beta) / 2.5 / 15
    assert math.atan2(next_states[1, 5], next_states[1, 4]) == pytest.approx(heading)
    assert 5 * math.hypot(next_states[1, 2], next_states[1, 3]) == pytest.approx(10.0 - 5.0 * 3 / 15)
    assert next_states[1, 1] > 0  # turned left
    assert next_states[:, 6:].tolist() == [goal, goal]


def test_parking_model_limits_the_speed_like_highway_env():
    model = ParkingKinematics()
    states = th.zeros(1, 12, dtype=th.float64)
    states[0, 2], states[0, 4] = 41.0 / 5, 1.0  # 41 m/s, above the 40 m/s limit
    next_states = model(states, th.tensor([[1.0, 0.0]], dtype=th.float64))
    # full throttle is replaced by 40 - v in the first substep, which is then held: 41 -> 41 - 3/15
    assert 5 * next_states[0, 2].item() == pytest.approx(41.0 - 3.0 / 15)


def test_parking_model_is_the_default_for_the_parking_env():
    assert DEFAULT_DYNAMICS[PARKING_ID] == "parking"
    space = gym.spaces.Box(-np.inf, np.inf, shape=(12,), dtype=np.float32)
    actions = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
    assert isinstance(make_dynamics("parking", space, actions), ParkingKinematics)


def test_parking_env_passes_check_env():
    pytest.importorskip("highway_env")
    from gymnasium.utils.env_checker import check_env as gymnasium_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(PARKING_ID)
    assert env.observation_space.shape == (12,)
    sb3_check_env(env)
    gymnasium_check_env(env.unwrapped)


def test_parking_model_predicts_highway_env_on_non_crash_steps():
    pytest.importorskip("highway_env")
    env = gym.make(PARKING_ID, dtype=np.float64)
    model = ParkingKinematics()
    rng = np.random.default_rng(0)
    observation, _ = env.reset(seed=0)
    checked = 0
    for _ in range(150):
        action = rng.uniform(-1, 1, size=2).astype(np.float32)
        with th.no_grad():
            predicted = model(th.as_tensor(observation[None]), th.as_tensor(action[None], dtype=th.float64))[0].numpy()
        observation, _, terminated, truncated, info = env.step(action)
        if not info["crashed"]:
            np.testing.assert_allclose(predicted, observation, rtol=0, atol=1e-12)
            checked += 1
        if terminated or truncated:
            observation, _ = env.reset()
    assert checked > 100


def test_parking_env_numpy_observation_equals_parking_v0s_own():
    pytest.importorskip("highway_env")
    ours = gym.make(PARKING_ID, dtype=np.float64)
    theirs = gym.make("parking-v0")
    rng = np.random.default_rng(0)
    observation, _ = ours.reset(seed=0)
    expected, _ = theirs.reset(seed=0)
    episodes = 1
    for _ in range(200):
        assert observation.tolist() == [*expected["observation"], *expected["desired_goal"]]
        action = rng.uniform(-1, 1, size=2).astype(np.float32)
        observation, reward, terminated, truncated, info = ours.step(action)
        # ours steps highway-env with the action in float64 (numpy 2 would keep a float32 action's precision)
        expected, expected_reward, *expected_ends, expected_info = theirs.step(action.astype(np.float64))
        assert (reward, terminated, truncated) == (expected_reward, *expected_ends)
        assert (info["is_success"], info["crashed"]) == (expected_info["is_success"], expected_info["crashed"])
        if terminated or truncated:
            episodes += 1
            observation, _ = ours.reset(seed=episodes)
            expected, _ = theirs.reset(seed=episodes)
    assert episodes > 1  # the comparison went through a reset


def parking_rollout_inputs(speed: float):
    """Three cars at ``speed`` m/s with random positions and headings, and 64 action sequences of 15 steps each."""
    generator = th.Generator().manual_seed(0)
    headings = th.rand(3, generator=generator, dtype=th.float64) * 2 * math.pi
    states = th.zeros(3, 12, dtype=th.float64)
    states[:, :2] = th.rand(3, 2, generator=generator, dtype=th.float64) * 0.6 - 0.3
    states[:, 2], states[:, 3] = speed / 5 * th.cos(headings), speed / 5 * th.sin(headings)
    states[:, 4], states[:, 5] = th.cos(headings), th.sin(headings)
    states[:, 6:] = th.tensor([0.26, 0.14, 0.0, 0.0, 0.0, 1.0], dtype=th.float64)
    # beyond [-1, 1] too: the model clips like highway-env
    actions = th.randn(15, 3, 64, 2, generator=generator, dtype=th.float64) * 1.2
    return states, actions


@pytest.mark.parametrize("speed", [2.0, 39.5], ids=["free", "at-the-speed-limit"])
def test_parking_model_batched_rollout_matches_step_by_step(speed):
    model = ParkingKinematics()
    states, actions = parking_rollout_inputs(speed)
    with th.no_grad():
        batched = model.rollout(states, actions)
    np.testing.assert_allclose(batched, rollout_step_by_step(model, states, actions), rtol=0, atol=1e-12)


def test_compiled_parking_rollout_is_one_graph_and_matches_step_by_step():
    # fullgraph: compiled code never checks the speed limit on the host, so nothing breaks the graph. At 39.5 m/s the
    # limit binds for some sequences and not for others; 4 steps keep the compile short.
    model = ParkingKinematics()
    states, actions = parking_rollout_inputs(39.5)
    actions = actions[:4]
    unlimited_speeds = 39.5 + (model.max_acceleration * model.substeps * model.dt) * actions[..., 0].clamp(-1, 1).cumsum(0)
    assert (unlimited_speeds > model.max_speed).any() and (unlimited_speeds < model.max_speed).any()
    with th.no_grad():
        compiled = th.compile(model.rollout, fullgraph=True, dynamic=False)(states, actions)
    np.testing.assert_allclose(compiled, rollout_step_by_step(model, states, actions), rtol=0, atol=1e-10)


def test_parking_trains_with_the_shipped_zoo_entry(tmp_path):
    pytest.importorskip("highway_env")
    from test_scenarios import zoo_train

    model = zoo_train(PARKING_ID, 400, tmp_path)
    assert isinstance(model.policy.dynamics, ParkingKinematics)


def test_parking_env_refuses_an_observation_its_model_cannot_decode():
    pytest.importorskip("highway_env")
    config = {"observation": {"type": "KinematicsGoal", "features": ["x", "y"], "scales": [100, 100], "normalize": False}}
    with pytest.raises(ValueError, match="keeps parking-v0's observation"):
        gym.make(PARKING_ID, config=config)


def test_shipped_parking_demos_park_stop_and_stay_parked_in_different_slots():
    with np.load(SHIPPED_DEMO_DIR / "parking_16.npz") as data:
        episodes = np.split(data["obs"], np.cumsum(data["episode_lengths"])[:-1])
    hold_steps = shipped_demo_info("parking")["demo_hold_steps"]
    assert len(episodes) == 16 and hold_steps > 0
    for episode in episodes:
        assert episode.shape[1] == 12
        states = episode.astype(np.float64)
        # parking-v0's success test: weighted L1 distance to the goal, to the power 0.5, below 0.12
        parked = (np.abs(states[:, :6] - states[:, 6:]) @ np.array([1, 0.3, 0, 0, 0.02, 0.02])) ** 0.5 < 0.12
        stopped = np.hypot(states[:, 2], states[:, 3]) * 5 < 0.2  # below 0.2 m/s (velocities are in units of 5 m/s)
        arrived = int(np.argmax(parked & stopped))
        assert parked[arrived] and stopped[arrived]
        assert len(episode) - 1 - arrived == hold_steps and parked[arrived:].all()  # then it stays parked
        assert np.abs(episode[0, :2] - episode[0, 6:8]).max() > 0.05  # started more than 5 m from the goal
    assert len({tuple(np.round(episode[0, 6:8], 3)) for episode in episodes}) >= 8  # goal slots drawn at random
