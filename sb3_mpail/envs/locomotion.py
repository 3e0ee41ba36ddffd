"""
gymnasium's MuJoCo locomotion tasks as MPAIL-OM meets them: stock ``Hopper-v4``, ``Walker2d-v4``,
``HalfCheetah-v4`` and ``Ant-v4`` (their own rewards, terminations and 1,000-step episodes; v4 is the version both
supported gymnasium releases register), scored by return and forward speed. MuJoCo is the ``scenarios`` extra.
"""

from typing import Any, Dict, List, Optional

import numpy as np

from sb3_mpail.evaluation import evaluate_episodes

#: the locomotion tasks and the name of their shipped demo set (``sb3_mpail/data/<name>_<n>.npz`` and ``<name>.json``)
#: (``ant`` is the 200-step ``sb3_mpail/Ant-v0``'s set, hence ``ant_v4``)
LOCOMOTION_TASKS = {"Hopper-v4": "hopper", "Walker2d-v4": "walker2d", "HalfCheetah-v4": "halfcheetah", "Ant-v4": "ant_v4"}


def evaluate_locomotion(
    model: Any, env_id: str, n_episodes: int, seed: int, n_envs: int = 1, env_kwargs: Optional[Dict[str, Any]] = None
) -> Dict[str, float]:
    """
    Evaluates a deterministic policy on a MuJoCo locomotion env: its return and its forward speed (the ``x_velocity``
    every one of them reports in ``info``), the measure of how well a learner moves next to the expert.

    :param model: anything with SB3's ``predict`` (an SB3 expert, MPAIL)
    :param env_id: gymnasium id of the env
    :param n_episodes: number of evaluation episodes
    :param seed: seed of the evaluation environments
    :param n_envs: environments stepped together (the episodes are split between them)
    :param env_kwargs: keyword arguments of the env
    :return: ``return`` and ``return_std`` over the episodes, ``length`` (mean episode length), and ``forward_speed``:
        the x velocity (m/s) averaged over every step of every episode
    """
    forward_velocities: List[float] = []

    def record_forward_velocity(info: Dict[str, Any], _: bool) -> None:
        forward_velocities.append(float(info["x_velocity"]))

    episodes = evaluate_episodes(model, env_id, n_episodes, seed, n_envs, env_kwargs, on_step=record_forward_velocity)
    return {
        "return": episodes.mean_return,
        "return_std": episodes.std_return,
        "length": float(np.mean(episodes.lengths)),
        "forward_speed": float(np.mean(forward_velocities)),
    }
