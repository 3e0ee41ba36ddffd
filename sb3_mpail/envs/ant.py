"""
MuJoCo Ant for MPAIL-OM. MuJoCo is an optional dependency (the ``scenarios`` extra); making the environment without it
raises an ImportError that says what to install.

``sb3_mpail/Ant-v0`` is gymnasium's ``Ant-v4`` with its default 27-D observation (torso height and orientation, joint
angles, then velocities: index 13 is the torso's forward (x) velocity; no contact forces, no x-y position) and reward
(forward velocity + 1 while healthy - control cost), registered with 200-step episodes instead of 1000 so that a CPU
budget covers many episodes, and with float32 observations (MPAIL's networks and planner are float32; Ant-v4's are
float64).
"""

from typing import Any, Dict

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_mpail.envs import SCENARIOS_INSTALL_HINT
from sb3_mpail.envs.locomotion import evaluate_locomotion

ANT_FORWARD_VELOCITY_INDEX = 13


def require_mujoco() -> None:
    """
    Imports MuJoCo's Python bindings.

    :raises ImportError: naming the extra to install when mujoco is missing
    """
    try:
        import mujoco  # noqa: F401
    except ImportError as error:
        raise ImportError(f"This scenario needs mujoco, which is not installed: {SCENARIOS_INSTALL_HINT}") from error


class Float32Observation(gym.ObservationWrapper):
    """
    Casts a ``Box`` observation (and its space) to float32.

    :param env: environment with a ``Box`` observation space
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        space = env.observation_space
        self.observation_space = spaces.Box(space.low.astype(np.float32), space.high.astype(np.float32), dtype=np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return observation.astype(np.float32)


def make_ant(**kwargs: Any) -> gym.Env:
    """
    gymnasium's ``Ant-v4`` environment with float32 observations (the registration adds the time limit).

    :param kwargs: ``Ant-v4``'s keyword arguments (``ctrl_cost_weight``, ``render_mode``, ...)
    :return: the environment
    """
    require_mujoco()
    # Imported here: gymnasium's MuJoCo module needs mujoco at import time
    from gymnasium.envs.mujoco.ant_v4 import AntEnv

    return Float32Observation(AntEnv(**kwargs))


def evaluate_ant(model: Any, n_episodes: int, seed: int, n_envs: int = 1) -> Dict[str, float]:
    """
    Evaluates a deterministic policy on ``sb3_mpail/Ant-v0``: its return and its forward speed, the paper's measure of
    how well MPAIL's Ant walks next to the expert (:func:`sb3_mpail.envs.locomotion.evaluate_locomotion`).

    :param model: anything with SB3's ``predict`` (an SB3 expert, MPAIL)
    :param n_episodes: number of evaluation episodes
    :param seed: seed of the evaluation environments
    :param n_envs: environments stepped together (the episodes are split between them)
    :return: ``return`` and ``return_std`` over the episodes, ``length``, and ``forward_speed``: the torso's x velocity
        (m/s) averaged over every step of every episode
    """
    return evaluate_locomotion(model, "sb3_mpail/Ant-v0", n_episodes, seed, n_envs)
