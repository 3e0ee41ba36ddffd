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
