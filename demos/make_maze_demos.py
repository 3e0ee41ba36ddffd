"""Generate observation-only expert demonstrations for a flat PointMaze with a scripted planner.

This script:

1. builds the maze's cell graph (free cells, 4-connected) and, by breadth-first search from each goal cell
   (``sb3_mpail.mppi.costs.maze_shortest_paths``), each cell's next cell on a shortest path to it; the scripted
   expert steers the ball with a PD controller towards the centre of the next cell, and towards the observed goal
   once in the goal cell;
2. evaluates the expert (``sb3_mpail.envs.maze.point_maze_figures``, as the benchmark evaluates MPAIL) and a
   uniform-random policy (``demos/expert_rollouts.py``) on 100 seeded episodes each;
3. records ``--n-demos`` episodes with the expert (episode ``i`` starts from ``env.reset(seed=1000 + i)``) and keeps
   only the observations: ``<out-dir>/<name>_<n>.npz`` with key ``obs`` of shape ``(n, T + 1, 6)`` (float32);
4. writes the metadata file ``<out-dir>/<name>.json`` (same schema as ``cartpole.json``, plus the expert's
   success rate and wall contacts on the evaluation episodes).

``<name>`` is ``pointmaze`` for ``sb3_mpail/PointMaze-v0`` (the U-maze, fixed cells) and ``pointmaze_medium`` for
``sb3_mpail/PointMazeMedium-v0`` (random cells). Needs the ``scenarios`` extra. Deterministic (no learning). Run
from the repository root::

    python demos/make_maze_demos.py
    python demos/make_maze_demos.py --env sb3_mpail/PointMazeMedium-v0 --n-demos 32
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Dict, Optional, Tuple

import gymnasium as gym
import numpy as np
from expert_rollouts import SHIPPED_DEMO_DIR, evaluate_random, record_demos, save_demos, save_metadata

from sb3_mpail.envs.maze import POINT_MAZE_ID, POINT_MAZE_MEDIUM_ID, point_maze_figures
from sb3_mpail.mppi.costs import maze_shortest_paths

#: each maze env's demo set name
DEMO_NAMES = {POINT_MAZE_ID: "pointmaze", POINT_MAZE_MEDIUM_ID: "pointmaze_medium"}
N_EVAL_EPISODES = 100
DEFAULT_OUT_DIR = SHIPPED_DEMO_DIR


class MazeGraphExpert:
    """
    Scripted expert on the maze's cell graph: a PD controller towards the centre of the next cell on a shortest
    path to the goal's cell (breadth-first search over free, 4-connected cells), then towards the observed goal. It is
    stateless (the next cell follows from the ball's and the goal's positions) and has SB3's ``predict``, so SB3's
    evaluation and ``expert_rollouts.record_demos`` can run it.

    :param env: a flat PointMaze environment, for its maze map and cell geometry
    :param position_gain: force per metre of position error
    :param velocity_gain: force per m/s of velocity (the damping term)
    """

    def __init__(self, env: gym.Env, position_gain: float = 6.0, velocity_gain: float = 0.6):
        self.maze = env.unwrapped.maze
        self.position_gain = position_gain
        self.velocity_gain = velocity_gain
        self.next_cell, _ = maze_shortest_paths(self.maze.maze_map)
        self.n_columns = len(self.maze.maze_map[0])

    def action(self, observation: np.ndarray) -> np.ndarray:
        """The force for one ``[x, y, vx, vy, goal_x, goal_y]`` observation."""
        position, velocity, goal = observation[:2], observation[2:4], observation[4:6]
        cell, goal_cell = (int(np.dot(self.maze.cell_xy_to_rowcol(xy), (self.n_columns, 1))) for xy in (position, goal))
        next_cell = np.array(divmod(int(self.next_cell[cell, goal_cell]), self.n_columns))
        target = goal if cell == goal_cell else self.maze.cell_rowcol_to_xy(next_cell)
        force = self.position_gain * (target - position) - self.velocity_gain * velocity
        return np.clip(force, -1.0, 1.0).astype(np.float32)

    def predict(
        self,
        observation: np.ndarray,
        state: Optional[Any] = None,
        episode_start: Optional[np.ndarray] = None,
        deterministic: bool = True,
    ) -> Tuple[np.ndarray, None]:
        """SB3's ``predict`` on one observation or a batch."""
        if observation.ndim == 1:
            return self.action(observation), None
        return np.stack([self.action(row) for row in observation]), None


def parse_args() -> argparse.Namespace:
    """Parse the command-line arguments.

    :return: The parsed arguments (``env``, ``seed``, ``out_dir``, ``n_demos``).
    """
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", choices=sorted(DEMO_NAMES), default=POINT_MAZE_ID, help="the maze env")
    parser.add_argument("--seed", type=int, default=0, help="Seed of the evaluation episodes")
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT_DIR, help="Output folder for the .npz and .json files")
    parser.add_argument("--n-demos", type=int, default=4, help="Number of observation-only demonstrations to record")
    return parser.parse_args()


def main() -> None:
    """Evaluate the scripted expert and a random policy, record the demos and write the metadata."""
    args = parse_args()
    out_dir: Path = args.out_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    expert, name = MazeGraphExpert(gym.make(args.env)), DEMO_NAMES[args.env]

    # the benchmark's evaluation (benchmarks/scenarios.py) on the expert: return, success, wall contacts
    expert_figures = point_maze_figures(expert, N_EVAL_EPISODES, seed=args.seed + 1, env_id=args.env)
    random_mean, random_std = evaluate_random(args.env, seed=args.seed + 2, n_episodes=N_EVAL_EPISODES)
    print(f"expert: {expert_figures}")
    print(f"random return: {random_mean:.2f} +/- {random_std:.2f}")

    episodes, demo_returns = record_demos(expert, args.env, args.n_demos)
    npz_path = out_dir / f"{name}_{args.n_demos}.npz"
    shape = save_demos(episodes, npz_path)
    print(f"saved demos {shape} to {npz_path}; demo returns: {demo_returns}")

    meta: Dict[str, Any] = {
        "env_id": args.env,
        "expert_algo": "scripted: BFS on the maze's cell graph + PD controller",
        "expert_gains": {"position": expert.position_gain, "velocity": expert.velocity_gain},
        "seed": args.seed,
        "expert_return_mean": expert_figures["return"],
        "expert_success_rate": expert_figures["success"],
        "expert_wall_steps": expert_figures["wall_steps"],
        "random_return_mean": random_mean,
        "random_return_std": random_std,
        "n_eval_episodes": N_EVAL_EPISODES,
        "demo_returns": demo_returns,
        "command": "python demos/make_maze_demos.py"
        + ("" if args.env == POINT_MAZE_ID else f" --env {args.env} --n-demos {args.n_demos}"),
    }
    save_metadata(meta, out_dir / f"{name}.json")


if __name__ == "__main__":
    main()
