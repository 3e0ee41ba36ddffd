"""
How far :class:`sb3_mpail.mppi.dynamics.PointMassDynamics`'s one-step predictions are from MuJoCo on
``sb3_mpail/PointMaze-v0`` under uniformly random forces (a new episode every 100 steps), split by whether the ball
touched a wall during the step (the model has no walls). The model runs in float64 on the simulator's float64 state
(the model's own error) and in float32 on the float32 observation MPAIL plans on; errors are the largest absolute
error over position (m) and over velocity (m/s).

Run: ``python -m benchmarks.maze_model_error`` (``--steps 3000 --seed 0``; needs the ``scenarios`` extra); prints a
table, writes nothing.
"""

import argparse
from typing import Dict, List

import gymnasium as gym
import numpy as np
import torch as th

from sb3_mpail.envs.maze import POINT_MAZE_ID
from sb3_mpail.mppi.dynamics import PointMassDynamics


def one_step_errors(n_steps: int, seed: int) -> Dict[str, np.ndarray]:
    """
    :param n_steps: number of environment steps
    :param seed: seed of the resets and of the forces
    :return: per step, ``wall_contact`` and the position and velocity errors ``position64``, ``velocity64`` (float64
        state) and ``position32``, ``velocity32`` (float32 observation, against the float64 truth)
    """
    env = gym.make(POINT_MAZE_ID).unwrapped
    model = PointMassDynamics()
    rng = np.random.default_rng(seed)
    results: Dict[str, List] = {key: [] for key in ("wall_contact", "position64", "velocity64", "position32", "velocity32")}
    for step in range(n_steps):
        if step % 100 == 0:
            observation, _ = env.reset(seed=seed + step)
        action = rng.uniform(-1, 1, size=(1, 2))
        data = env.maze_env.point_env.data
        state = np.concatenate((data.qpos, data.qvel, observation[4:]))[None]
        with th.no_grad():
            predicted64 = model(th.as_tensor(state), th.as_tensor(action))[0, :4].numpy()
            predicted32 = model(th.as_tensor(observation[None]), th.as_tensor(action, dtype=th.float32))[0, :4].numpy()
        observation, _, _, _, info = env.step(action[0].astype(np.float32))
        truth = np.concatenate((data.qpos, data.qvel))
        results["wall_contact"].append(info["wall_contact"])
        for name, predicted in (("64", predicted64), ("32", predicted32.astype(np.float64))):
            results["position" + name].append(np.abs(predicted[:2] - truth[:2]).max())
            results["velocity" + name].append(np.abs(predicted[2:] - truth[2:]).max())
    env.close()
    return {key: np.array(values) for key, values in results.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    errors = one_step_errors(args.steps, args.seed)
    print("| steps | n | position error, median / max (m) | velocity error, median / max (m/s) | precision |")
    print("|---|---|---|---|---|")
    for label, selected in (("off the walls", ~errors["wall_contact"]), ("touching a wall", errors["wall_contact"])):
        for precision in ("64", "32"):
            position, velocity = errors["position" + precision][selected], errors["velocity" + precision][selected]
            print(
                f"| {label} | {selected.sum()} | {np.median(position):.2e} / {position.max():.2e} | "
                f"{np.median(velocity):.2e} / {velocity.max():.2e} | float{precision} |"
            )


if __name__ == "__main__":
    main()
