"""Deterministic evaluation on fresh, seeded environments, with a look at every step (the scenarios' figures)."""

from typing import Any, Callable, Dict, Optional

import numpy as np
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.type_aliases import PolicyPredictor

#: ``on_step(info, done)``: called for every env and step of the evaluation
StepHook = Callable[[Dict[str, Any], bool], None]


def deterministic_episode_returns(
    model: PolicyPredictor, env_id: str, n_episodes: int, seed: int, n_envs: int = 1, on_step: Optional[StepHook] = None
) -> np.ndarray:
    """
    Runs ``n_episodes`` deterministic episodes with SB3's ``evaluate_policy`` on ``make_vec_env(env_id, n_envs,
    seed)`` (closed afterwards).

    :param model: anything with SB3's ``predict`` (MPAIL, an SB3 expert, a scripted controller)
    :param env_id: registered env id
    :param n_episodes: number of episodes (split between the envs as ``evaluate_policy`` does)
    :param seed: seed of the environments
    :param n_envs: environments stepped together
    :param on_step: sees each env's ``info`` and ``done`` after every step
    :return: the episodes' returns
    """
    env = make_vec_env(env_id, n_envs=n_envs, seed=seed)

    def callback(local_variables: Dict[str, Any], _: Dict[str, Any]) -> None:
        if on_step is not None:
            on_step(local_variables["info"], local_variables["done"])

    returns, _ = evaluate_policy(
        model, env, n_eval_episodes=n_episodes, deterministic=True, return_episode_rewards=True, callback=callback
    )
    env.close()
    return np.asarray(returns, dtype=float)
