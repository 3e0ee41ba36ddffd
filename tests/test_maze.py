"""gymnasium-robotics PointMaze: the missing-dependency error, the flat env, its point-mass model and the demos."""

import sys

import gymnasium as gym
import numpy as np
import pytest
import torch as th

import sb3_mpail.envs  # noqa: F401  (registers the environments)
from sb3_mpail.demos import SHIPPED_DEMO_DIR, load_demos, shipped_demo_info
from sb3_mpail.mppi.dynamics import DEFAULT_DYNAMICS, PointMassDynamics, make_dynamics

POINT_MAZE_ID = "sb3_mpail/PointMaze-v0"


def skip_without_point_maze() -> None:
    """Skips the test when gymnasium-robotics or mujoco is missing (the former can fail on the latter's absence)."""
    pytest.importorskip("mujoco", reason="PointMaze needs mujoco (the scenarios extra)")
    pytest.importorskip("gymnasium_robotics", reason="PointMaze needs gymnasium-robotics (the scenarios extra)")


@pytest.mark.parametrize("missing", ["gymnasium_robotics", "mujoco"])
def test_point_maze_without_gymnasium_robotics_says_what_to_install(monkeypatch, missing):
    monkeypatch.setitem(sys.modules, missing, None)  # importing it now fails as if it were not installed
    with pytest.raises(ImportError, match=r'pip install -e "\.\[scenarios\]"'):
        gym.make(POINT_MAZE_ID)


def test_point_mass_model_is_the_default_for_the_point_maze():
    assert DEFAULT_DYNAMICS[POINT_MAZE_ID] == "point_mass"
    space = gym.spaces.Box(-np.inf, np.inf, shape=(6,), dtype=np.float32)
    actions = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
    assert isinstance(make_dynamics("point_mass", space, actions), PointMassDynamics)


def test_point_mass_model_clips_speed_and_actions_and_holds_the_goal():
    model = PointMassDynamics(substeps=1)
    # 6 m/s is clipped to 5 before the step; an action of 3 pushes as 1
    states = th.tensor([[0.0, 0.0, 6.0, 0.0, 1.0, -1.0]], dtype=th.float64)
    next_states = model(states, th.tensor([[0.0, 3.0]], dtype=th.float64))
    damping_factor = 1 / (1 + 0.01 / model.mass)
    expected_velocity = [5.0 * damping_factor, 0.01 * 100 / model.mass * damping_factor]
    assert next_states[0, 2:4].tolist() == pytest.approx(expected_velocity)
    assert next_states[0, :2].tolist() == pytest.approx([0.01 * velocity for velocity in expected_velocity])
    assert next_states[0, 4:].tolist() == [1.0, -1.0]


def test_point_maze_env_passes_check_env():
    skip_without_point_maze()
    from gymnasium.utils.env_checker import check_env as gymnasium_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(POINT_MAZE_ID)
    assert env.observation_space.shape == (6,)
    sb3_check_env(env)
    gymnasium_check_env(env.unwrapped, skip_render_check=True)  # its render check opens a MuJoCo window


def test_point_maze_starts_in_the_bottom_left_cell_with_the_goal_top_left():
    skip_without_point_maze()
    env = gym.make(POINT_MAZE_ID)
    for seed in range(5):
        observation, _ = env.reset(seed=seed)
        # cell centres (-1, -1) and (-1, 1), plus PointMaze's +-0.25 m noise
        assert np.abs(observation[:2] - [-1.0, -1.0]).max() <= 0.25
        assert np.abs(observation[4:] - [-1.0, 1.0]).max() <= 0.25
        assert observation[2:4].tolist() == [0.0, 0.0]


def test_point_mass_model_predicts_mujoco_off_the_walls_and_not_on_them():
    skip_without_point_maze()
    env = gym.make(POINT_MAZE_ID).unwrapped
    model = PointMassDynamics()
    rng = np.random.default_rng(0)
    errors = {False: [], True: []}
    observation, _ = env.reset(seed=0)
    for _ in range(400):
        action = rng.uniform(-1, 1, size=2)
        # the env's float64 state, so the check is not limited by the float32 observation
        state = np.concatenate((env.maze_env.point_env.data.qpos, env.maze_env.point_env.data.qvel, observation[4:]))
        with th.no_grad():
            predicted = model(th.as_tensor(state[None]), th.as_tensor(action[None]))[0, :4].numpy()
        observation, _, _, _, info = env.step(action.astype(np.float32))
        actual = np.concatenate((env.maze_env.point_env.data.qpos, env.maze_env.point_env.data.qvel))
        errors[info["wall_contact"]].append(np.abs(predicted - actual).max())
    assert len(errors[False]) > 100 and len(errors[True]) > 10  # random forces reach the walls
    assert max(errors[False]) < 1e-6
    assert np.median(errors[True]) > 0.1  # the walls are not in the model


def test_shipped_maze_demos_reach_the_goal_without_touching_the_walls():
    skip_without_point_maze()
    demos = SHIPPED_DEMO_DIR / "pointmaze_4.npz"
    with np.load(demos) as data:
        episodes = data["obs"]
    assert episodes.shape == (4, 101, 6)
    for episode in episodes:
        assert np.linalg.norm(episode[-1, :2] - episode[-1, 4:]) < 0.45  # PointMaze's success distance
        # the path goes round the inner wall (cells (2, 1) and (2, 2), x < 0.5, -0.5 < y < 0.5) on the right
        crossing = np.abs(episode[:, 1]) < 0.5
        assert episode[crossing, 0].min() > 0.5
    load_demos(demos, gym.make(POINT_MAZE_ID).observation_space)
    stats = shipped_demo_info("pointmaze")
    assert stats["expert_success_rate"] == 1.0 and stats["expert_return_mean"] > 3 * stats["random_return_mean"]


def test_the_point_maze_walls_cost_is_paid_in_wall_cells_and_near_them_not_in_the_corridors():
    skip_without_point_maze()
    from sb3_mpail.envs.maze import U_MAZE_FIXED_START_GOAL
    from sb3_mpail.mppi.constraints import make_constraint_cost, maze_walls

    walls = make_constraint_cost("point_maze_walls", state_dim=6)
    assert walls.centres.shape == (sum(row.count(1) for row in U_MAZE_FIXED_START_GOAL), 2)
    # cell (row, column) centres are x = column - 2, y = 2 - row (1 m cells, the maze centred on the origin)
    free = th.tensor([[-1.0, -1.0], [1.0, -1.0], [1.0, 0.0], [1.0, 1.0], [-1.0, 1.0], [0.0, 1.0]])
    inner_wall, near_inner_wall = th.tensor([[-1.0, 0.0], [0.0, 0.0]]), th.tensor([[-1.0, -0.45], [0.0, 0.45]])
    states = th.zeros(len(free) + 4, 6)
    states[:, :2] = th.cat((free, inner_wall, near_inner_wall))
    costs = walls(states)
    assert (costs[: len(free)] == 0).all()  # every corridor cell's centre is free
    assert (costs[len(free):] > 0).all()  # in the inner wall, and within the ball's 0.1 m radius of it
    with pytest.raises(ValueError, match="maze_walls needs a gymnasium-robotics maze env"):
        maze_walls(gym.make("Pendulum-v1"))


def test_shortest_paths_step_through_free_cells_and_lead_out_of_walls():
    from sb3_mpail.envs.maze import U_MAZE_FIXED_START_GOAL
    from sb3_mpail.mppi.costs import maze_shortest_paths

    next_cell, steps = maze_shortest_paths(U_MAZE_FIXED_START_GOAL)
    start, goal = 3 * 5 + 1, 1 * 5 + 1  # the reset and goal cells, (row, column) flattened over 5 columns
    path = [start]
    while path[-1] != goal:
        path.append(int(next_cell[path[-1], goal]))
    # round the inner wall: right along the bottom corridor, up the right-hand one, back left along the top
    assert [divmod(cell, 5) for cell in path] == [(3, 1), (3, 2), (3, 3), (2, 3), (1, 3), (1, 2), (1, 1)]
    assert steps[start, goal] == 6 and steps[goal, goal] == 0
    # a state imagined in the inner wall (2, 1) steps out to a free neighbour next to the goal, not through walls
    assert divmod(int(next_cell[2 * 5 + 1, goal]), 5) == (1, 1) and steps[2 * 5 + 1, goal] == 1
    # a free cell is never entered from a wall: the bottom corridor's path to the goal does not cross the inner wall
    assert steps[3 * 5 + 2, goal] == 5


def test_maze_frame_features_point_to_the_next_cell_and_measure_the_path_left():
    from sb3_mpail.envs.maze import U_MAZE_FIXED_START_GOAL
    from sb3_mpail.mppi.costs import FeatureMap, MazeFrameFeatures

    features = FeatureMap.wrap(
        {"maze_frame": dict(maze_map=U_MAZE_FIXED_START_GOAL, position=[0, 1], goal_position=[4, 5], velocity=[2, 3])}
    )
    assert isinstance(features, MazeFrameFeatures)
    # cell (row, column) centres are x = column - 2, y = 2 - row; the goal (1, 1) is at (-1, 1) plus noise
    states = th.tensor([
        [-1.0, -1.0, 0.5, 0.0, -1.1, 1.2],  # in the start cell (3, 1): next is (3, 2), at (0, -1), 5 cells from the goal's
        [0.0, 1.0, -0.5, 0.0, -1.1, 1.2],  # next to the goal's cell: make for the goal itself
    ])
    expected = th.tensor([
        [1.0, 0.0, 1.0 + 5.0, 0.5, 0.0],
        [-1.1, 0.2, float(np.hypot(1.1, 0.2)), -0.5, 0.0],
    ])
    assert th.allclose(features(states), expected)


def test_maze_frame_features_refuse_a_ragged_map_and_an_unknown_name():
    from sb3_mpail.mppi.costs import MazeFrameFeatures

    with pytest.raises(ValueError, match=r"maze_frame\['maze_map'\] must be rows of cells of one length"):
        MazeFrameFeatures([[1, 1, 1], [1, 0]], position=[0, 1], goal_position=[4, 5])
    with pytest.raises(ValueError, match="No maze map is named 'large'"):
        MazeFrameFeatures("large", position=[0, 1], goal_position=[4, 5])


def test_medium_maze_draws_its_start_and_goal_cells_at_random_and_passes_check_env():
    skip_without_point_maze()
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make("sb3_mpail/PointMazeMedium-v0")
    assert env.spec.max_episode_steps == 200
    sb3_check_env(env)
    maze = env.unwrapped.maze
    cells = set()
    for seed in range(20):
        observation, _ = env.reset(seed=seed)
        start, goal = (tuple(maze.cell_xy_to_rowcol(xy)) for xy in (observation[:2], observation[4:]))
        assert maze.maze_map[start[0]][start[1]] != 1 and maze.maze_map[goal[0]][goal[1]] != 1 and start != goal
        cells |= {start, goal}
    assert len(cells) > 10  # of its 26 free cells


def test_shipped_medium_maze_demos_reach_their_goals_from_many_cells_without_touching_the_walls():
    skip_without_point_maze()
    from sb3_mpail.mppi.constraints import make_constraint_cost

    demos = SHIPPED_DEMO_DIR / "pointmaze_medium_32.npz"
    with np.load(demos) as data:
        episodes = data["obs"]
    assert episodes.shape == (32, 201, 6)
    assert (np.linalg.norm(episodes[:, -1, :2] - episodes[:, -1, 4:], axis=1) < 0.45).all()  # PointMaze's success
    assert len({tuple(np.floor(episode[0, :2]).astype(int)) for episode in episodes}) > 10  # starts in many cells
    walls = make_constraint_cost("point_maze_medium_walls", state_dim=6)
    assert float(walls(th.as_tensor(episodes.reshape(-1, 6))).max()) == 0  # never within the ball's radius of a wall
    load_demos(demos, gym.make("sb3_mpail/PointMazeMedium-v0").observation_space)
    stats = shipped_demo_info("pointmaze_medium")
    assert stats["expert_success_rate"] == 1.0 and stats["expert_return_mean"] > 3 * stats["random_return_mean"]
