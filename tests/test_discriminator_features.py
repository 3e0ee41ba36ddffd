"""The discriminator and the value can each see chosen features of the state while the planner and dynamics use all of it."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from imitation.data.types import Trajectory
from stable_baselines3.common.env_util import make_vec_env
from torch import nn

from sb3_mpail import MPAIL
from sb3_mpail.mppi import AngleFeatures, GoalFrameFeatures, LaneFrameFeatures
from sb3_mpail.mppi.costs import FeatureMap, squared_segment_distances
from sb3_mpail.mppi.fused import Workspace

TINY_PLANNER = dict(n_samples=16, horizon=3, n_iterations=2)


def pendulum_angle(states: th.Tensor) -> th.Tensor:
    """Pendulum features without the angular velocity: ``[cos(theta), sin(theta)]``."""
    return states[:, :2]


class ScaledAngle(nn.Module):
    """A feature module with a saved (untrained) parameter."""

    def __init__(self):
        super().__init__()
        self.scale = nn.Parameter(th.tensor([2.0, -3.0]))

    def forward(self, states: th.Tensor) -> th.Tensor:
        return states[:, :2] * self.scale


@pytest.fixture(scope="module")
def demo_observations():
    env = gym.make("Pendulum-v1")
    env.action_space.seed(0)
    episodes = []
    for index in range(2):
        observations = [env.reset(seed=index)[0]]
        for _ in range(30):
            observations.append(env.step(env.action_space.sample())[0])
        episodes.append(np.array(observations, np.float32))
    return episodes


def trajectories(episodes):
    return [Trajectory(obs=obs, acts=np.zeros((len(obs) - 1, 1), np.float32), infos=None, terminal=False) for obs in episodes]


def make_model(demos, features=pendulum_angle, seed=0, **kwargs):
    return MPAIL(
        "MlpMPPI",
        make_vec_env("Pendulum-v1", n_envs=1, seed=seed),
        demos,
        n_steps=16,
        seed=seed,
        policy_kwargs=dict(TINY_PLANNER, discriminator_features=features),
        **kwargs,
    )


def first_layer_inputs(model: MPAIL) -> int:
    return next(layer for layer in model.policy.discriminator.mlp.modules() if isinstance(layer, nn.Linear)).in_features


def test_discriminator_is_built_on_the_feature_size_and_demos_are_mapped(demo_observations):
    model = make_model(trajectories(demo_observations))
    assert first_layer_inputs(model) == 4  # (phi(s), phi(s')) with 2 features each, not 2 x 3 observations
    assert model.policy.value_net[0].in_features == 3  # the value still sees the full state
    expected = np.concatenate([episode[:-1, :2] for episode in demo_observations])
    np.testing.assert_array_equal(model.expert.observations, expected)


def test_rewards_and_planner_costs_see_only_the_features(demo_observations):
    model = make_model(trajectories(demo_observations)).learn(32)
    buffer = model.rollout_buffer
    observations = th.as_tensor(buffer.flat("observations"))
    next_observations = th.as_tensor(buffer.flat("next_observations"))
    with th.no_grad():
        logits = model.policy.discriminator(observations[:, :2], None, next_observations[:, :2], None)
    kept = buffer.flat("timeouts") == 0  # time-limit steps also hold the bootstrapped value
    np.testing.assert_allclose(buffer.flat("rewards")[kept], logits.numpy()[kept])
    # states differing only in the unseen velocity cost the same, on the module path and on the fused one
    cost = model.policy.planner.step_cost
    model.policy.set_training_mode(False)
    with th.no_grad():
        states = th.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 5.0]])
        next_states = th.tensor([[0.9, 0.1, 1.0], [0.9, 0.1, -4.0]])
        costs = cost(states, next_states)
        expected = -model.policy.discriminator(states[:, :2], None, next_states[:, :2], None)
        fused = cost.planning_view(3)
        roll_out = th.stack((states, next_states)).view(2, 1, 2, 3)  # (horizon + 1, envs, samples, state)
        fused_costs = fused(roll_out, th.ones(1), Workspace())
    assert th.allclose(costs, expected)
    assert costs[0].item() == pytest.approx(costs[1].item())
    assert th.allclose(fused_costs.view(2), costs, atol=1e-6)


def test_a_list_of_indices_selects_state_dimensions(demo_observations):
    model = make_model(trajectories(demo_observations), features=[0, 1])
    states = th.as_tensor(demo_observations[0])
    assert th.equal(model.policy.features(states), states[:, :2])
    np.testing.assert_array_equal(model.expert.observations[:5], demo_observations[0][:5, :2])


def test_demos_can_already_be_features(demo_observations):
    partial = [episode[:, :2] for episode in demo_observations]
    model = make_model(trajectories(partial), demos_are_features=True).learn(32)
    np.testing.assert_array_equal(model.expert.observations, np.concatenate([episode[:-1] for episode in partial]))
    with pytest.raises(ValueError, match=r"shape \(3,\) but the discriminator's feature space has shape \(2,\)"):
        make_model(trajectories(demo_observations), demos_are_features=True)
    with pytest.raises(ValueError, match=r"shape \(2,\) but the environment's observation space has shape \(3,\)"):
        make_model(trajectories(partial))


@pytest.mark.parametrize(
    "features",
    [pendulum_angle, lambda states: states[:, 1:] * 2.0, ScaledAngle(), [2, 0]],
    ids=["function", "lambda", "module", "indices"],
)
def test_feature_map_survives_save_and_load(demo_observations, tmp_path, features):
    model = make_model(trajectories(demo_observations), features=features).learn(32)
    model.save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model")
    states = th.as_tensor(np.random.default_rng(0).normal(size=(5, 3)).astype(np.float32))
    assert th.equal(loaded.policy.features(states), model.policy.features(states))
    for (name, a), (_, b) in zip(model.policy.state_dict().items(), loaded.policy.state_dict().items()):
        assert th.equal(a, b), name
    model.set_random_seed(1)
    loaded.set_random_seed(1)
    np.testing.assert_array_equal(
        model.predict(states.numpy(), deterministic=True)[0], loaded.predict(states.numpy(), deterministic=True)[0]
    )
    # a loaded model maps new full-observation demos through the same features
    loaded.set_demos(trajectories(demo_observations))
    np.testing.assert_array_equal(loaded.expert.observations, model.expert.observations)


def test_feature_map_of_the_wrong_shape_is_refused(demo_observations):
    with pytest.raises(ValueError, match=r"\(batch, n_features\) tensor; for a batch of 2 it gave \(2,\)"):
        make_model(trajectories(demo_observations), features=lambda states: states[:, 0])
    with pytest.raises(TypeError, match="discriminator_features must be an nn.Module, a callable or a list of state"):
        make_model(trajectories(demo_observations), features="angle")


def test_angle_features_put_each_angle_as_its_cosine_and_sine_in_its_place():
    states = th.tensor([[0.5, np.pi - 0.01, 2.0, -np.pi + 0.01, 7.0]])
    features = AngleFeatures([3, 1])(states)
    expected = [0.5, np.cos(np.pi - 0.01), np.sin(np.pi - 0.01), 2.0, np.cos(-np.pi + 0.01), np.sin(-np.pi + 0.01), 7.0]
    assert th.allclose(features, th.tensor([expected], dtype=th.float32))
    # headings on either side of the wrap are neighbours
    assert th.allclose(features[0, 1:3], features[0, 4:6] * th.tensor([1.0, -1.0]), atol=1e-6)
    with pytest.raises(ValueError, match="distinct angle indices"):
        AngleFeatures([1, 1])


def test_the_value_plans_and_learns_on_its_own_features_and_is_saved_with_them(demo_observations, tmp_path):
    model = MPAIL(
        "MlpMPPI", make_vec_env("Pendulum-v1", n_envs=2, seed=0), trajectories(demo_observations), n_steps=16, seed=0,
        policy_kwargs=dict(TINY_PLANNER, value_features=pendulum_angle),
    )  # fmt: skip
    assert model.policy.value_net.network[0].in_features == 2  # the value sees [cos, sin] only
    model.learn(32)
    states = th.tensor([[1.0, 0.0, 5.0], [1.0, 0.0, -5.0]])
    with th.no_grad():
        values = model.policy.planner.terminal_value(states)
    assert values[0] == values[1], "the angular velocity is not among the value's features"
    model.save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model")
    with th.no_grad():
        assert th.equal(loaded.policy.planner.terminal_value(states), values)


def test_a_dict_of_angles_names_angle_features_as_a_yaml_file_can():
    features = FeatureMap.wrap({"angles": [5]})
    assert isinstance(features, AngleFeatures) and features.angle_indices == [5]
    with pytest.raises(ValueError, match="one key, 'angles'"):
        FeatureMap.wrap({"angle": [5]})


#: parking's state: ego [x, y, vx, vy, cos h, sin h], then the goal's
PARKING_GOAL_FRAME = dict(position=[0, 1], velocity=[2, 3], heading=[4, 5], goal_position=[6, 7], goal_heading=[10, 11])


def parking_state(x, y, vx, vy, heading, goal_x, goal_y, goal_heading):
    return [x, y, vx, vy, np.cos(heading), np.sin(heading), goal_x, goal_y, 0.0, 0.0, np.cos(goal_heading),
            np.sin(goal_heading)]  # fmt: skip


def test_goal_frame_features_are_the_same_for_the_same_approach_to_any_goal():
    features = FeatureMap.wrap({"goal_frame": dict(PARKING_GOAL_FRAME, position_scale=10.0)})
    assert isinstance(features, GoalFrameFeatures)
    # 2 m short of a goal facing +y, moving towards it at 1 unit, heading 0.1 rad left of the goal's
    towards_north = parking_state(3.0, 8.0, 0.0, 1.0, np.pi / 2 + 0.1, 3.0, 10.0, np.pi / 2)
    # the same approach to a goal facing -x elsewhere
    towards_west = parking_state(-3.0, -1.0, -1.0, 0.0, np.pi + 0.1, -5.0, -1.0, np.pi)
    mapped = features(th.tensor([towards_north, towards_west], dtype=th.float32))
    expected = [-20.0, 0.0, 1.0, 0.0, np.cos(0.1), np.sin(0.1)]  # along, across (x 10), velocity, relative heading
    assert th.allclose(mapped, th.tensor([expected, expected], dtype=th.float32), atol=1e-5)
    without_velocity = GoalFrameFeatures(**{k: v for k, v in PARKING_GOAL_FRAME.items() if k != "velocity"})
    assert without_velocity(th.tensor([towards_north], dtype=th.float32)).shape == (1, 4)


def test_goal_frame_features_of_a_goal_without_heading_are_the_offset_from_it_and_the_velocity():
    # the point maze's state [x, y, vx, vy, goal_x, goal_y]: the same approach to two goals looks the same
    features = FeatureMap.wrap({"goal_frame": dict(position=[0, 1], goal_position=[4, 5], velocity=[2, 3])})
    states = th.tensor([[1.0, 2.0, 0.5, -0.5, 1.5, 1.0], [-1.5, 0.0, 0.5, -0.5, -1.0, -1.0]])
    assert th.allclose(features(states), th.tensor([[-0.5, 1.0, 0.5, -0.5], [-0.5, 1.0, 0.5, -0.5]]))


@pytest.mark.parametrize(
    "settings, message",
    [
        (dict(PARKING_GOAL_FRAME, heading=None), r"both heading and goal_heading .* or neither"),
        (dict(PARKING_GOAL_FRAME, position=[0]), r"two state indices for each of \['position'\]"),
        (dict(PARKING_GOAL_FRAME, position_scale=0), r"position_scale'\] must be a number > 0"),
        (dict(PARKING_GOAL_FRAME, goal_heading=[10, 12]), r"goal_frame'\]\['goal_heading'\] holds state indices \[12\]"),
    ],
)
def test_bad_goal_frame_settings_are_refused_naming_them(settings, message):
    with pytest.raises(ValueError, match=message):
        features = FeatureMap.wrap({"goal_frame": settings}, "discriminator_features")
        FeatureMap.space(features, spaces.Box(-1, 1, (12,)), "discriminator_features")


def ring_road(radius: float = 10.0, lane_width: float = 0.5, n_points: int = 64):
    """Two concentric lanes driven anticlockwise round (0, 0), and a straight one along y = 30: polylines."""
    angles = np.linspace(0.0, 2 * np.pi, n_points)
    ring = [np.stack((r * np.cos(angles), r * np.sin(angles)), axis=1) for r in (radius, radius + lane_width)]
    return ring + [np.array([[-20.0, 30.0], [0.0, 30.0], [20.0, 30.0]])]


def test_lane_frame_features_give_the_offset_and_heading_from_the_nearest_lane():
    # two square lanes 0.5 apart driven anticlockwise round (0, 0), and a straight one along y = 30
    squares = [np.array([[-r, -r], [r, -r], [r, r], [-r, r], [-r, -r]]) for r in (10.0, 10.5)]
    road = squares + [np.array([[-20.0, 30.0], [0.0, 30.0], [20.0, 30.0]])]
    settings = dict(centrelines=road, position=[0, 1], heading=[2, 3], lateral_scale=10.0, cell_size=0.25)
    features = FeatureMap.wrap({"lane_frame": settings})
    assert isinstance(features, LaneFrameFeatures)
    states = th.tensor(
        [
            [5.0, 30.1, np.cos(0.2), np.sin(0.2)],  # 0.1 left of the straight lane, heading 0.2 rad left of it
            [0.0, -10.05, 1.0, 0.0],  # 0.05 outside (right of) the inner lane at its bottom, heading along it
            [0.0, 10.45, -1.0, 0.0],  # 0.05 inside (left of) the outer lane at its top, along it (anticlockwise)
            [10.1, 3.0, np.cos(2.0), np.sin(2.0)],  # 0.1 right of the inner lane's right side, heading 2 rad
        ],
        dtype=th.float32,
    )
    expected = [[1.0, np.cos(0.2), np.sin(0.2)], [-0.5, 1.0, 0.0], [0.5, 1.0, 0.0], [-1.0, np.cos(2.0 - np.pi / 2),
                np.sin(2.0 - np.pi / 2)]]  # fmt: skip
    assert th.allclose(features(states), th.tensor(expected, dtype=th.float32), atol=1e-5)


def test_lane_frame_grid_lookup_finds_the_nearest_segment_near_the_road_as_measuring_every_segment_does():
    features = LaneFrameFeatures(ring_road(), position=[0, 1], heading=[2, 3])
    generator = th.Generator().manual_seed(0)
    positions = th.rand((20000, 2), generator=generator) * th.tensor([50.0, 60.0]) - th.tensor([25.0, 20.0])
    headings = th.rand(20000, generator=generator) * 2 * np.pi
    states = th.cat((positions, th.cos(headings)[:, None], th.sin(headings)[:, None]), dim=1)
    segments = features.segment_starts, features.segment_directions, features.segment_lengths
    squared_distances, nearest = squared_segment_distances(positions, *segments).min(dim=1)
    direction, offset = features.segment_directions[nearest], positions - features.segment_starts[nearest]
    lateral = th.sign(direction[:, 0] * offset[:, 1] - direction[:, 1] * offset[:, 0]) * squared_distances.sqrt()
    near = squared_distances < 2.0**2  # four lane widths
    assert near.sum() > 2000
    assert th.allclose(features(states)[near, 0], lateral[near], atol=1e-5)


def test_lane_frame_features_without_a_heading_give_the_offset_and_pass_on_the_dimensions_kept():
    squares = [np.array([[-r, -r], [r, -r], [r, r], [-r, r], [-r, -r]]) for r in (10.0, 10.5)]
    features = LaneFrameFeatures(squares, position=[0, 1], keep=[3, 2], lateral_scale=10.0, cell_size=0.25)
    states = th.tensor([[0.0, -10.05, 7.0, 8.0], [10.1, 3.0, -1.0, 2.0]])  # 0.05 and 0.1 right of the inner lane
    assert th.allclose(features(states), th.tensor([[-0.5, 8.0, 7.0], [-1.0, 2.0, -1.0]]), atol=1e-5)


def test_a_chain_applies_its_maps_in_turn_and_feature_demos_pass_through_its_later_maps(demo_observations):
    chain = {"chain": [[2, 0, 1], [1, 2]]}  # the demos hold (thdot, cos, sin); the discriminator sees (cos, sin)
    partial = [episode[:, [2, 0, 1]] for episode in demo_observations]
    model = make_model(trajectories(partial), features=chain, demos_are_features=True).learn(32)
    assert model.policy.feature_space.shape == (2,) and model.policy.demo_feature_space.shape == (3,)
    states = th.as_tensor(demo_observations[0])
    assert th.equal(model.policy.features(states), states[:, :2])
    expected = np.concatenate([episode[:-1, :2] for episode in demo_observations])
    np.testing.assert_array_equal(model.expert.observations, expected)
    with pytest.raises(ValueError, match=r"shape \(2,\) but the discriminator's feature space has shape \(3,\)"):
        make_model(trajectories([episode[:, :2] for episode in demo_observations]), features=chain, demos_are_features=True)


@pytest.mark.parametrize(
    "chain, message",
    [
        ([[0, 1]], r"discriminator_features\['chain'\] must be a list of two or more feature maps"),
        ("01", r"discriminator_features\['chain'\] must be a list of two or more feature maps"),
        ([[0, 2], [2]], r"discriminator_features\['chain'\]\[1\] holds state indices \[2\] out of range for the 2-D state"),
    ],
)
def test_bad_chains_are_refused_naming_the_map(chain, message):
    with pytest.raises(ValueError, match=message):
        features = FeatureMap.wrap({"chain": chain}, "discriminator_features")
        FeatureMap.space(features, spaces.Box(-1, 1, (3,)), "discriminator_features")


def test_the_lap_demo_path_is_its_recorded_positions_closed_into_a_loop():
    from sb3_mpail.demos import shipped_demos

    positions = shipped_demos("lap", 1)[0].obs[:, :2]
    features = LaneFrameFeatures("lap_demo", position=[0, 1])
    assert th.allclose(features(th.as_tensor(positions)), th.zeros(len(positions), 1), atol=1e-5)
    # the track is a circle through the origin centred at (0, 3.82 m): its centre is about a radius off the path
    assert features(th.tensor([[0.0, 3.82]])).abs().item() == pytest.approx(3.82, abs=0.3)


@pytest.mark.parametrize(
    "settings, message",
    [
        (dict(centrelines="nowhere"), r"names no known road: 'nowhere'"),
        (dict(centrelines=[[[0.0, 0.0]]]), r"polylines of \(n_points >= 2, 2\) positions; got 1 lines, lines \[0\]"),
        (dict(centrelines=[[[0.0, 0.0], [0.0, 0.0]]]), r"no point repeated consecutively"),
        (dict(lateral_scale=-1), r"lateral_scale'\] must be a number > 0"),
        (dict(cell_size=0), r"cell_size'\] must be a number > 0"),
        (dict(heading=[4, 6]), r"lane_frame'\]\['heading'\] holds state indices \[6\]"),
        (dict(keep=[7]), r"lane_frame'\]\['keep'\] holds state indices \[7\]"),
        (dict(keep=[]), r"lane_frame'\]\['keep'\] must be a non-empty list of state indices"),
    ],
)
def test_bad_lane_frame_settings_are_refused_naming_them(settings, message):
    settings = dict(dict(centrelines=ring_road(), position=[0, 1], heading=[4, 5]), **settings)
    with pytest.raises(ValueError, match=message):
        features = FeatureMap.wrap({"lane_frame": settings}, "discriminator_features")
        FeatureMap.space(features, spaces.Box(-1, 1, (6,)), "discriminator_features")


def test_racetrack_lanes_are_read_from_highway_env():
    pytest.importorskip("highway_env", reason="the racetrack needs highway-env (the scenarios extra)")
    features = LaneFrameFeatures("racetrack", position=[0, 1], heading=[4, 5], lateral_scale=10.0)
    # racetrack-v0's first straight: lanes at y = 0 and 5 m from x = 42 m, driven towards +x; observation units of 10 m
    states = th.tensor([[5.0, 0.02, 1.0, 0.0, 1.0, 0.0], [6.0, 0.45, 1.0, 0.0, 1.0, 0.0]])
    assert th.allclose(features(states), th.tensor([[0.2, 1.0, 0.0], [-0.5, 1.0, 0.0]]), atol=1e-4)
