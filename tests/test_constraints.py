"""A known constraint cost (walls, obstacles) added to the learned costs: where it is paid and what the planner does."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from test_planner_equivalence import NAVIGATION, assert_same_plans, make_policy, navigation_states, plan_both_ways

from sb3_mpail.mppi.constraints import RectangleObstacles, highway_env_obstacles
from sb3_mpail.mppi.planner import rollout
from sb3_mpail.policies import MPPIPolicy

#: a wall 2 m thick across the x axis at x = 5, from y = -10 to 10
WALL = dict(centres=[[5.0, 0.0]], half_sizes=[[1.0, 10.0]], margin=0.5, weight=100.0)


def positions(*points) -> th.Tensor:
    states = th.zeros(len(points), 12)
    states[:, :2] = th.tensor(points, dtype=th.float32)
    return states


def test_the_cost_is_paid_inside_the_inflated_rectangle_only_and_grows_with_depth():
    wall = RectangleObstacles(**WALL)
    costs = wall(positions((0.0, 0.0), (3.4, 0.0), (4.0, 0.0), (5.0, 0.0), (5.0, 10.4), (5.0, 10.6)))
    assert costs[0] == 0 and costs[1] == 0 and costs[5] == 0  # beyond the 0.5 m margin
    assert 100 < costs[2] < costs[3] and costs[4] > 100  # inside: at least the weight, more deeper in
    assert costs[3] == pytest.approx(100 * (1 + 1.5 / 0.5))  # the centre is 1.5 m inside the inflated wall


def test_a_rotated_rectangle_is_scored_along_its_own_axes():
    diagonal = RectangleObstacles(centres=[[0.0, 0.0]], half_sizes=[[5.0, 0.5]], headings=[np.pi / 4], margin=0.1)
    on_it, beside_it = diagonal(positions((3.0, 3.0), (3.0, -3.0)))
    assert on_it > 0 and beside_it == 0


def test_costs_keep_any_leading_shape():
    wall = RectangleObstacles(**WALL)
    states = navigation_states(6).float().reshape(2, 3, 12)
    assert wall(states).shape == (2, 3)


@pytest.mark.parametrize("settings", [dict(margin=0.0), dict(weight=-1.0), dict(half_sizes=[[1.0, -1.0]])])
def test_bad_rectangles_are_refused_naming_the_setting(settings):
    with pytest.raises(ValueError, match="RectangleObstacles"):
        RectangleObstacles(**{**WALL, **settings})


def test_the_planner_with_a_constraint_cost_matches_the_reference_and_avoids_the_wall():
    # drive towards a goal behind the wall: the true reward as the step cost, so only the wall differs
    class GoalDistance(th.nn.Module):
        def forward(self, states, next_states):
            return th.linalg.vector_norm(next_states[..., :2] - next_states.new_tensor([10.0, 0.0]), dim=-1)

    wall = RectangleObstacles(**WALL).double()
    free = make_policy(NAVIGATION, "bicycle", n_samples=256, horizon=10, step_cost=GoalDistance(), use_terminal_value=False)
    walled = make_policy(NAVIGATION, "bicycle", n_samples=256, horizon=10, step_cost=GoalDistance(), use_terminal_value=False,
                         constraint_cost=wall)  # fmt: skip
    states = navigation_states(2) * 0
    states[:, 0] = 2.0  # 2 m before the wall, heading at the goal
    optimised, reference = plan_both_ways(walled, states)
    assert_same_plans(optimised, reference)

    def wall_cost_of(policy):
        plan = plan_both_ways(policy, states, n_steps=3)[0][-1][0]
        with th.no_grad():
            visited = rollout(policy.planner.dynamics, states, plan.transpose(0, 1).unsqueeze(2))
        return wall(visited).sum().item()

    assert wall_cost_of(free) > 0  # straight at the goal goes through the wall
    assert wall_cost_of(walled) == 0  # the walled planner's plan does not


def test_parking_walls_are_read_from_highway_env():
    pytest.importorskip("highway_env", reason="parking needs highway-env (the scenarios extra)")
    import gymnasium as gym

    env = gym.make("sb3_mpail/Parking-v0")
    env.reset(seed=0)
    walls = highway_env_obstacles(env, position_scale=100.0)
    assert walls.centres.shape == (4, 2)  # parking-v0's four walls, no parked cars by default
    inside, centre = th.zeros(2, 12), th.zeros(1, 12)
    inside[:, :2] = th.tensor([[0.0, 0.21], [-0.35, 0.0]])  # on the top and left walls (observation units: m / 100)
    assert (walls(inside) > 0).all() and walls(centre).item() == 0


def test_a_constraint_cost_is_saved_with_the_model_and_one_of_the_wrong_shape_is_named(tmp_path):
    from sb3_mpail import MPAIL
    from sb3_mpail.train_navigation import make_model

    model = make_model(n_envs=1, policy_kwargs=dict(n_samples=8, horizon=3, n_iterations=1,
                                                    constraint_cost=RectangleObstacles(**WALL)))  # fmt: skip
    model.save(tmp_path / "walled")
    loaded = MPAIL.load(tmp_path / "walled")
    th.testing.assert_close(loaded.policy.planner.constraint_cost.centres, th.tensor([[5.0, 0.0]]))
    obs = np.zeros((1, 12), np.float32)
    assert np.array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])

    def one_per_env(states):
        return states[..., 0].sum(-1)  # summed over samples: the wrong shape

    wrong = make_model(n_envs=1, policy_kwargs=dict(n_samples=8, horizon=3, n_iterations=1, constraint_cost=one_per_env))
    with pytest.raises(ValueError, match="constraint_cost must return"):
        wrong.predict(obs, deterministic=True)


def test_parking_walls_leave_every_slot_free_and_keep_a_car_at_any_heading_off_them():
    pytest.importorskip("highway_env", reason="parking needs highway-env (the scenarios extra)")
    import gymnasium as gym

    from sb3_mpail.mppi.constraints import parking_walls

    env = gym.make("sb3_mpail/Parking-v0")
    env.reset(seed=0)
    lanes = env.unwrapped.road.network.lanes_list()
    slots = th.zeros(len(lanes), 12)
    slots[:, :2] = th.tensor(np.array([lane.position(lane.length / 2, 0) for lane in lanes]) / 100, dtype=th.float32)
    walls = parking_walls()
    assert len(lanes) == 28 and (walls(slots) == 0).all()
    # a car whose corner (2.5 m along, 1 m across from its centre) touches the right wall's face (x = 34.5 m) pays
    corner_on_wall = th.zeros(1, 12)
    corner_on_wall[0, 0] = (34.5 - np.hypot(2.5, 1.0) + 0.05) / 100
    assert walls(corner_on_wall).item() > 0


def test_parking_walls_are_named_for_a_yaml_file_and_an_unknown_name_is_refused():
    pytest.importorskip("highway_env", reason="parking needs highway-env (the scenarios extra)")
    from sb3_mpail.mppi.constraints import make_constraint_cost

    walls = make_constraint_cost("parking_walls")
    assert isinstance(walls, RectangleObstacles) and walls.centres.shape == (4, 2)
    with pytest.raises(ValueError, match="Unknown constraint_cost 'walls'.*parking_walls"):
        make_constraint_cost("walls")
    with pytest.raises(ValueError, match="constraint_cost must be"):
        make_constraint_cost(3.0)


#: Pendulum's spaces, for planners built without an env
PENDULUM_SPACES = (spaces.Box(-8.0, 8.0, (3,), np.float32), spaces.Box(-2.0, 2.0, (1,), np.float32))


def pendulum_policy(constraint_cost) -> MPPIPolicy:
    return MPPIPolicy(*PENDULUM_SPACES, dynamics="pendulum", n_samples=16, horizon=3, n_iterations=2,
                      constraint_cost=constraint_cost)  # fmt: skip


def test_a_constraint_cost_returning_nan_is_named_as_the_source_of_a_non_finite_plan():
    policy = pendulum_policy(lambda states: states[..., 0] * float("nan"))
    with pytest.raises(ValueError, match=r"The plan made from a finite observation and state holds NaN .* for envs \[0, 1\] "
                                         r".*constraint_cost returned NaN for envs \[0, 1\]"):  # fmt: skip
        policy.predict(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], np.float32))


def test_a_constraint_infinite_for_every_sample_of_an_env_is_reported_as_leaving_no_feasible_sample():
    policy = pendulum_policy(lambda states: th.where(states[..., 2] > 1.0, float("inf"), 0.0))
    upright, spinning = [1.0, 0.0, 0.0], [1.0, 0.0, 5.0]  # every sample of the spinning pendulum keeps w > 1
    actions, _ = policy.predict(np.array([upright], np.float32), deterministic=True)  # some samples are feasible
    assert np.isfinite(actions).all()
    with pytest.raises(ValueError, match=r"for env 1: .*every sampled sequence of env 1 has an infinite cost \(no feasible "
                                         r"sample\): constraint_cost is infinite on each"):  # fmt: skip
        policy.predict(np.array([upright, spinning], np.float32), deterministic=True)


def test_rectangle_indices_out_of_range_for_the_state_are_refused_naming_them_and_the_state_size():
    obstacles = RectangleObstacles(**WALL, x_index=5)
    expected = r"RectangleObstacles' x_index=5 is out of range for the 3-D state \(indices in \[-3, 3\)\)"
    with pytest.raises(ValueError, match=expected):  # when the planner is built
        pendulum_policy(obstacles)
    with pytest.raises(ValueError, match=expected):  # used on its own: at its first call
        obstacles(th.zeros(4, 3))
