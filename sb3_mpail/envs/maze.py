"""
gymnasium-robotics PointMaze for MPAIL. gymnasium-robotics (with MuJoCo) is an optional dependency (the ``scenarios``
extra); making this environment without it raises an ImportError that says what to install.

``sb3_mpail/PointMaze-v0`` is ``PointMaze_UMaze-v3``'s U-shaped maze with its start and goal cells fixed, so that
the demos and the task agree: the ball starts in the bottom-left cell and must go right, up the right-hand corridor
and back left to the top-left cell, around the inner wall. ``sb3_mpail/PointMazeMedium-v0`` is
``PointMaze_Medium-v3``'s 8 x 8 maze with its stock random start and goal cells. Their planning model is
:class:`sb3_mpail.mppi.dynamics.PointMassDynamics`, which knows nothing of the walls.
"""

from typing import TYPE_CHECKING, Any, Dict, List, Optional, Tuple, Union

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.type_aliases import PolicyPredictor

from sb3_mpail.envs import SCENARIOS_INSTALL_HINT
from sb3_mpail.evaluation import evaluate_episodes

if TYPE_CHECKING:
    from gymnasium_robotics.envs.maze.maze_v4 import Maze


# PointMaze_UMaze-v3's map (1 = wall) with the reset cell "r" and the goal cell "g" fixed, in (row, column) cells
# of 1 m; the walls between them make the shortest path a U of three corridors.
U_MAZE_FIXED_START_GOAL: List[List[Union[int, str]]] = [
    [1, 1, 1, 1, 1],
    [1, "g", 0, 0, 1],
    [1, 1, 1, 0, 1],
    [1, "r", 0, 0, 1],
    [1, 1, 1, 1, 1],
]
POINT_MAZE_ID = "sb3_mpail/PointMaze-v0"
POINT_MAZE_MEDIUM_ID = "sb3_mpail/PointMazeMedium-v0"


def named_maze_map(name: str) -> List[List[Union[int, str]]]:
    """
    A maze map by name: ``"u_maze_fixed"`` (:data:`U_MAZE_FIXED_START_GOAL`) or ``"medium"`` (gymnasium-robotics'
    ``MEDIUM_MAZE``: every free cell a possible start and goal; needs the ``scenarios`` extra).

    :param name: the map's name
    :raises ValueError: an unknown name
    """
    if name == "u_maze_fixed":
        return U_MAZE_FIXED_START_GOAL
    if name == "medium":
        require_gymnasium_robotics()
        from gymnasium_robotics.envs.maze.maps import MEDIUM_MAZE

        return MEDIUM_MAZE
    raise ValueError(f"No maze map is named {name!r}; the names are 'u_maze_fixed' and 'medium'.")


def require_gymnasium_robotics() -> None:
    """
    Imports gymnasium-robotics and MuJoCo (which gymnasium-robotics imports only when a MuJoCo env is made).

    :raises ImportError: naming the extra to install when either is missing
    """
    try:
        import mujoco  # noqa: F401
        import gymnasium_robotics  # noqa: F401  # isort: skip
    # gymnasium-robotics 1.3+ raise gymnasium's DependencyNotInstalled, no ImportError, when mujoco is missing
    except (ImportError, gym.error.DependencyNotInstalled) as error:
        raise ImportError(
            f"This scenario needs gymnasium-robotics and mujoco, which are not installed: {SCENARIOS_INSTALL_HINT}"
        ) from error


class FlatPointMazeEnv(gym.Env):
    """
    A force-actuated ball in a gymnasium-robotics PointMaze with a flat Box observation ``[x, y, vx, vy, goal_x,
    goal_y]`` (m, m/s). The start and goal positions are cells' centres (the map's ``"r"`` and ``"g"`` cells, or
    random free cells where it has none) plus PointMaze's uniform noise of +-0.25 m, so the goal is observed. The task
    is PointMaze's continuing one with the goal held (no termination): the dense reward ``exp(-distance to goal)``
    rewards getting there fast and staying.

    Each action (the force in ``[-1, 1]^2``, x 100 N) is held for ``action_repeat`` MuJoCo steps of 0.01 s and the
    reward is summed over them. PointMaze documents a 10 Hz control rate but steps its 0.01 s simulation once per
    action; at 100 Hz a planner would need hundreds of steps to see a corridor ahead. ``sb3_mpail/PointMaze-v0``
    acts at 20 Hz and truncates after 100 actions, 5 s; ``sb3_mpail/PointMazeMedium-v0`` after 200, 10 s.

    The info dict adds ``wall_contact``: whether the ball touched a wall during the step (the steps where the
    wall-free planning model is wrong). It holds the gymnasium-robotics environment instead of wrapping it, so that
    it is no goal env to SB3.

    :param maze_map: the map (rows of cells, 1 for a wall) or its name (:func:`named_maze_map`)
    :param action_repeat: MuJoCo steps (0.01 s each) per action
    :param render_mode: gymnasium render mode
    """

    metadata = {"render_modes": ["human", "rgb_array", "depth_array"], "render_fps": 20}  # the default action_repeat

    def __init__(
        self,
        maze_map: Union[str, List[List[Union[int, str]]]] = "u_maze_fixed",
        action_repeat: int = 5,
        render_mode: Optional[str] = None,
    ):
        require_gymnasium_robotics()
        from gymnasium_robotics.envs.maze.point_maze import PointMazeEnv

        self.maze_env = PointMazeEnv(
            maze_map=named_maze_map(maze_map) if isinstance(maze_map, str) else maze_map,
            render_mode=render_mode,
            reward_type="dense",
            continuing_task=True,
            reset_target=False,
        )
        self.action_repeat = action_repeat
        self.render_mode = render_mode
        model = self.maze_env.point_env.model
        self.wall_geoms = {index for index in range(model.ngeom) if model.geom(index).name.startswith("block_")}
        # Finite bounds: the maze spans half its cells either side of 0 (1 m each); speeds are clipped to 5 m/s before
        # each MuJoCo step.
        extent = float(max(self.maze.map_length, self.maze.map_width)) / 2 + 0.5
        high = np.array([extent, extent, 10.0, 10.0, extent, extent], dtype=np.float32)
        self.observation_space = spaces.Box(-high, high, dtype=np.float32)
        self.action_space = self.maze_env.action_space

    def _flatten(self, observation: Dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate((observation["observation"], observation["desired_goal"])).astype(np.float32)

    def _touches_wall(self) -> bool:
        data = self.maze_env.point_env.data
        return any({data.contact[index].geom1, data.contact[index].geom2} & self.wall_geoms for index in range(data.ncon))

    @property
    def maze(self) -> "Maze":
        """gymnasium-robotics' :class:`Maze`: the map and its cell <-> position conversions."""
        return self.maze_env.maze

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None
    ) -> Tuple[np.ndarray, Dict[str, Any]]:
        super().reset(seed=seed)
        observation, info = self.maze_env.reset(seed=seed, options=options)
        return self._flatten(observation), info

    def step(self, action: np.ndarray) -> Tuple[np.ndarray, float, bool, bool, Dict[str, Any]]:
        total_reward, wall_contact = 0.0, False
        for _ in range(self.action_repeat):
            observation, reward, _, _, info = self.maze_env.step(action)
            total_reward += float(reward)
            wall_contact = wall_contact or self._touches_wall()
        return self._flatten(observation), total_reward, False, False, {**info, "wall_contact": wall_contact}

    def render(self) -> Optional[np.ndarray]:
        return self.maze_env.render()

    def close(self) -> None:
        self.maze_env.close()


def point_maze_figures(model: PolicyPredictor, n_episodes: int, seed: int, env_id: str = POINT_MAZE_ID) -> Dict[str, float]:
    """
    Evaluates a deterministic policy on a flat PointMaze's episodes (``make_vec_env`` seeded with ``seed``).

    :param model: anything with SB3's ``predict`` (a trained model or a scripted expert)
    :param n_episodes: number of episodes, run one after the other in one environment
    :param seed: seed of the environment
    :param env_id: ``sb3_mpail/PointMaze-v0`` or ``sb3_mpail/PointMazeMedium-v0``
    :return: ``return`` (mean episode return), ``success`` (fraction of episodes ending within PointMaze's 0.45 m
        of the goal) and ``wall_steps`` (fraction of steps in which the ball touched a wall)
    """
    wall_contacts: List[bool] = []

    def record_wall_contact(info: Dict[str, Any], _: bool) -> None:
        wall_contacts.append(info["wall_contact"])

    episodes = evaluate_episodes(model, env_id, n_episodes, seed, n_envs=1, on_step=record_wall_contact)
    return {
        "return": episodes.mean_return,
        "success": float(np.mean([info["success"] for info in episodes.final_infos])),
        "wall_steps": float(np.mean(wall_contacts)),
    }
