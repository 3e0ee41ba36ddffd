"""The highway in traffic: the env's observation, its planning model, the collision cost, the demos and MPAIL on it."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import yaml
from stable_baselines3.common.env_util import make_vec_env

import sb3_mpail.envs  # noqa: F401  (registers the environments)
from sb3_mpail import MPAIL
from sb3_mpail.demos import SHIPPED_DEMO_DIR, shipped_demo_info
from sb3_mpail.envs.highway_roads import EGO_SCALES
from sb3_mpail.envs.highway_traffic import TRAFFIC_STATE_DIM, VEHICLE_FEATURES, traffic_vehicles, vehicle_dims
from sb3_mpail.mppi import DEFAULT_DYNAMICS, HighwayKinematics, HighwayTrafficKinematics, make_dynamics
from sb3_mpail.mppi.constraints import TrafficCollisions, make_constraint_cost
from sb3_mpail.mppi.reference import rollout as rollout_step_by_step
from sb3_mpail.zoo import HYPERPARAMS

TRAFFIC_ID = "sb3_mpail/HighwayTraffic-v0"
DENSE_ID = "sb3_mpail/HighwayTrafficDense-v0"


def gentle_action(step: int) -> np.ndarray:
    """Slow speed changes and a steering small enough to stay near the lane for a few dozen steps."""
    return np.array([0.5 * np.sin(step / 5), 0.02 * np.sin(step / 3)], dtype=np.float32)


def traffic_state(ego_xy=(10.0, 4.0), vehicles=(), dtype=th.float64) -> th.Tensor:
    """A traffic state (metres, m/s) with the ego at ``ego_xy`` driving at 25 m/s and ``vehicles`` as ``(x, y, vx)``."""
    state = th.zeros(TRAFFIC_STATE_DIM, dtype=dtype)
    state[:6] = th.tensor([ego_xy[0] / 10, ego_xy[1] / 10, 2.5, 0.0, 1.0, 0.0], dtype=dtype)
    for slot, (x, y, vx) in enumerate(vehicles):
        state[vehicle_dims("presence")[slot]] = 1.0
        dims = [vehicle_dims(name)[slot] for name in ("x", "y", "vx")]
        state[dims] = th.tensor([x, y, vx], dtype=dtype) / 10
    return state


@pytest.mark.parametrize("env_id, lanes, vehicles", [(TRAFFIC_ID, 3, 20), (DENSE_ID, 4, 50)])
def test_observation_is_highway_envs_absolute_kinematics_of_the_ego_and_its_five_nearest_vehicles(env_id, lanes, vehicles):
    pytest.importorskip("highway_env")
    from highway_env.envs.common.observation import KinematicObservation

    env = gym.make(env_id, dtype=np.float64)
    observation, _ = env.reset(seed=3)
    road_env = env.unwrapped.road_env
    assert road_env.config["lanes_count"] == lanes and len(road_env.road.vehicles) == vehicles + 1
    assert env.observation_space.shape == (TRAFFIC_STATE_DIM,)
    assert env.observation_space.contains(observation.astype(np.float32))
    # highway-env's own observation of the same scene: the ego's row, then the 5 nearest vehicles' (behind included)
    kinematics = KinematicObservation(
        road_env, features=VEHICLE_FEATURES, vehicles_count=6, absolute=True, normalize=False, see_behind=True
    )
    ego_kinematics = KinematicObservation(road_env, features=["cos_h", "sin_h"], vehicles_count=1, absolute=True)
    present_slots = 0
    for step in range(25):
        expected = kinematics.observe()
        ours = np.concatenate(([1.0], observation[:4] * EGO_SCALES[:4], observation[6:] * np.tile([1, 10, 10, 10, 10], 5)))
        # highway-env's observation is float32; ours in float64 rounds to the same values
        np.testing.assert_array_equal(ours.astype(np.float32), expected.ravel())
        np.testing.assert_array_equal(observation[4:6].astype(np.float32), ego_kinematics.observe()[0])
        present_slots += int(observation[vehicle_dims("presence")].sum())
        observation, _, terminated, truncated, info = env.step(gentle_action(step))
        assert isinstance(info["crashed"], bool) and info["speed"] == pytest.approx(10 * np.hypot(*observation[2:4]))
        if terminated or truncated:
            break
    assert present_slots > 0  # the scene had traffic to compare


def test_traffic_env_passes_the_gymnasium_and_sb3_env_checks():
    pytest.importorskip("highway_env")
    from gymnasium.utils.env_checker import check_env as gymnasium_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(TRAFFIC_ID)
    sb3_check_env(env)
    gymnasium_check_env(env.unwrapped)


def test_model_predicts_the_ego_as_highway_kinematics_and_lane_keeping_vehicles_at_constant_velocity():
    pytest.importorskip("highway_env")
    env = gym.make(TRAFFIC_ID, dtype=np.float64)
    road_env = env.unwrapped.road_env
    model = make_dynamics(DEFAULT_DYNAMICS[TRAFFIC_ID], env.observation_space, env.action_space)
    assert isinstance(model, HighwayTrafficKinematics)
    assert (model.dt, model.substeps) == (env.unwrapped.simulation_dt, env.unwrapped.substeps) == (0.2, 1)
    ego_model = HighwayKinematics(dt=0.2, substeps=1)
    observation, _ = env.reset(seed=0)
    errors = []
    for step in range(40):
        # the shown vehicles driving straight along their lane (not changing lanes, nor steering back to its centre)
        shown = traffic_vehicles(road_env.vehicle, road_env.road.vehicles, road_env.PERCEPTION_DISTANCE)
        straight = [
            (slot, vehicle, vehicle.lane_index)
            for slot, vehicle in enumerate(shown)
            if vehicle.lane_index == vehicle.target_lane_index and abs(vehicle.heading) < 1e-3
        ]
        action = gentle_action(step)
        with th.no_grad():
            states, actions = th.as_tensor(observation[None]), th.as_tensor(action[None], dtype=th.float64)
            predicted, predicted_ego = model(states, actions)[0].numpy(), ego_model(states[:, :6], actions)[0].numpy()
        observation, _, terminated, _, _ = env.step(action)
        if terminated:  # a crash moves the cars involved
            break
        np.testing.assert_array_equal(predicted[:6], predicted_ego)
        np.testing.assert_allclose(predicted[:6], observation[:6], rtol=0, atol=1e-12)
        # each vehicle where it went, found by identity (the slots may reorder as vehicles pass each other), unless it
        # decided to change lanes in this step, which it starts at once
        errors += [
            np.abs(10 * predicted[[vehicle_dims("x")[slot], vehicle_dims("y")[slot]]] - vehicle.position)
            for slot, vehicle, lane in straight
            if vehicle.target_lane_index == lane
        ]
    errors = np.array(errors)
    assert len(errors) > 100
    # one 0.2 s simulation step of a vehicle that keeps its lane: only its small steering and the float rounding
    assert errors.max() < 0.01, errors.max(axis=0)


def test_traffic_model_rolls_out_as_its_steps_over_any_leading_shape_holding_absent_vehicles():
    model = HighwayTrafficKinematics()
    held = list(model.held_state_dims)
    initial = th.stack((traffic_state(vehicles=[(30.0, 4.0, 20.0), (-12.0, 8.0, 28.0)]), traffic_state((50.0, 0.0))))
    actions = th.rand(6, 2, 8, 2, generator=th.Generator().manual_seed(0), dtype=th.float64) * 2 - 1
    with th.no_grad():
        states = model.rollout(initial, actions)
        np.testing.assert_allclose(states, rollout_step_by_step(model, initial, actions), rtol=0, atol=1e-12)
        # the first vehicle of env 0 moves at 20 m/s for 6 steps of 0.2 s; the empty slots stay zero
        expected_x = (30.0 + 4.0 * th.arange(7.0))[:, None].expand(7, 8)
        np.testing.assert_allclose(10 * states[:, 0, :, vehicle_dims("x")[0]], expected_x)
        assert (states[:, 1, :, 6:] == 0).all()
        assert (states[..., held] == initial[None, :, None, held]).all()
        batch = initial[:, None].expand(2, 3, TRAFFIC_STATE_DIM)
        flat = model(batch.reshape(6, -1), actions[0, :, :3].reshape(6, 2))
        np.testing.assert_array_equal(model(batch, actions[0, :, :3]), flat.reshape(2, 3, -1))


def test_dense_traffic_env_plans_with_its_own_15_hz_simulation_step():
    pytest.importorskip("highway_env")
    model = MPAIL(
        "MlpMPPI", make_vec_env(DENSE_ID, n_envs=1), demos="highway_traffic_16", policy_kwargs=dict(n_samples=4, horizon=2)
    )
    dynamics = model.policy.dynamics
    assert isinstance(dynamics, HighwayTrafficKinematics) and (dynamics.dt, dynamics.substeps) == (1 / 15, 3)


def test_collision_cost_is_large_inside_a_vehicles_rectangle_and_zero_away_from_it_over_any_leading_shape():
    cost = make_constraint_cost("highway_traffic_vehicles", TRAFFIC_STATE_DIM)
    assert isinstance(cost, TrafficCollisions)
    # one vehicle at x = 40 m in the middle lane (y = 4 m): the ego behind it, beside it, on it, in the next lane
    ego_positions = [(20.0, 4.0), (32.0, 4.0), (37.0, 4.0), (40.0, 4.5), (40.0, 8.0), (40.0, 6.5), (60.0, 4.0)]
    states = th.stack([traffic_state(xy, [(40.0, 4.0, 25.0)]) for xy in ego_positions])
    costs = cost(states)
    # 20 m and 8 m behind (3 m between the bumpers, beyond the 2 m margin), centred in the next lane, 20 m ahead
    assert costs[[0, 1, 4, 6]].tolist() == [0, 0, 0, 0]
    assert costs[2] >= 1000 and costs[3] > costs[2] and costs[5] >= 1000  # 3 m behind, on it, 2.5 m beside it
    # an absent vehicle costs nothing, wherever its zero row puts it
    assert cost(traffic_state((0.0, 0.0))).item() == 0
    # the road's edges: 3 lanes centred on 0, 4, 8 m, 4 m wide; the car's body (2 m wide) must stay on it
    edges = cost(th.stack([traffic_state((20.0, y)) for y in (-0.9, -1.5, 8.9, 9.5)]))
    assert edges[0] == 0 and edges[1] >= 1000 and edges[2] == 0 and edges[3] >= 1000
    # any leading shape, as the planner scores every rolled-out state
    batched = cost(states.reshape(1, 7, 1, -1).expand(2, 7, 3, -1))
    np.testing.assert_array_equal(batched, costs.reshape(1, 7, 1).expand(2, 7, 3))
    assert make_constraint_cost("highway_traffic_dense_vehicles")(traffic_state((20.0, 12.0))).item() == 0  # 4 lanes


def test_bad_traffic_settings_are_refused_saying_what_is_wrong():
    pytest.importorskip("highway_env")
    with pytest.raises(ValueError, match="computes its own ego observation"):
        gym.make(TRAFFIC_ID, config={"observation": {"type": "Kinematics"}})
    with pytest.raises(ValueError, match=r"continuous \[acceleration, steering\]"):
        gym.make(TRAFFIC_ID, config={"action": {"type": "DiscreteMetaAction"}})
    with pytest.raises(ValueError, match="multiple of the policy frequency"):
        gym.make(TRAFFIC_ID, config={"policy_frequency": 2})
    with pytest.raises(ValueError, match="Unknown traffic base 'merge'"):
        gym.make(TRAFFIC_ID, base="merge")
    with pytest.raises(ValueError, match="31-D states"):
        make_constraint_cost("highway_traffic_vehicles", 6)
    with pytest.raises(ValueError, match="two margins > 0"):
        TrafficCollisions(margin=(0.0, 1.0))


def test_shipped_traffic_demos_are_collision_free_idm_episodes_with_their_expert_figures():
    with np.load(SHIPPED_DEMO_DIR / "highway_traffic_16.npz") as data:
        demos = data["obs"].astype(np.float64)
    info = shipped_demo_info("highway_traffic")
    assert demos.shape == (16, 152, TRAFFIC_STATE_DIM)  # 151 steps: highway-env's 30 s at 0.2 s, float rounding
    assert info["env_id"] == TRAFFIC_ID and len(info["demo_returns"]) == 16
    for key in ("expert_crash_rate", "expert_speed_mean", "random_return_mean", "demo_speed_mean", "failed_demo_seeds"):
        assert key in info
    speeds = 10 * np.hypot(demos[..., 2], demos[..., 3])
    assert 15.0 < speeds.mean() <= 30.0 and (demos[..., vehicle_dims("presence")].sum(axis=-1) > 0).all()


def test_mpail_learns_a_few_steps_on_traffic_with_the_zoo_entrys_cost_and_a_tiny_planner():
    pytest.importorskip("highway_env")
    entry = yaml.safe_load(HYPERPARAMS.read_text())[TRAFFIC_ID]
    policy_kwargs = eval(entry["policy_kwargs"], {"dict": dict})  # rl_zoo3's convention: a Python string
    assert entry["demos"] == "highway_traffic_16" and policy_kwargs["constraint_cost"] == "highway_traffic_vehicles"
    policy_kwargs.update(n_samples=8, horizon=3, n_iterations=1)
    env = make_vec_env(TRAFFIC_ID, n_envs=2, seed=0)
    model = MPAIL("MlpMPPI", env, demos=entry["demos"], n_steps=8, seed=0, policy_kwargs=policy_kwargs)
    model.learn(16)
    assert model.num_timesteps == 16
    assert isinstance(model.policy.dynamics, HighwayTrafficKinematics)
    assert isinstance(model.policy.planner.constraint_cost, TrafficCollisions)
