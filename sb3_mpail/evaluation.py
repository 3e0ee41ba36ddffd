"""
Evaluation: episodes of anything with SB3's ``predict`` on fresh, seeded environments, measured episode by episode
(returns, lengths, final infos and, when asked, every observation), and the normalised score against a demo set's
expert and random returns.
"""

from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple

import numpy as np
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.type_aliases import PolicyPredictor

#: ``on_step(info, done)``: called for every env and step of the evaluation
StepHook = Callable[[Dict[str, Any], bool], None]


@dataclass
class Episodes:
    """
    What :func:`evaluate_episodes` measured, one entry per episode, ordered by env index and, within an env, by time.

    :param returns: undiscounted episode returns ``(n,)``
    :param lengths: episode lengths in steps ``(n,)``
    :param final_infos: each episode's ``info`` of its last step (e.g. the navigation env's ``distance_to_goal``)
    :param observations: each episode's observations ``(T_i + 1, *obs_shape)``, its final one included, when recorded
    """

    returns: np.ndarray
    lengths: np.ndarray
    final_infos: List[Dict[str, Any]]
    observations: Optional[List[np.ndarray]] = None

    @property
    def mean_return(self) -> float:
        """The mean episode return."""
        return float(np.mean(self.returns))

    @property
    def std_return(self) -> float:
        """The standard deviation of the episode returns."""
        return float(np.std(self.returns))


def evaluate_episodes(
    model: PolicyPredictor,
    env_id: str,
    n_episodes: int,
    seed: int,
    n_envs: Optional[int] = None,
    env_kwargs: Optional[Dict[str, Any]] = None,
    deterministic: bool = True,
    on_step: Optional[StepHook] = None,
    record_observations: bool = False,
) -> Episodes:
    """
    Runs ``n_episodes`` episodes with SB3's ``evaluate_policy`` on ``make_vec_env(env_id, n_envs, seed)`` (closed
    afterwards): env ``i`` is reset with ``seed + i`` first, and each env's plan (any recurrent ``state`` of
    ``predict``) is carried and restarted with its episodes.

    :param model: anything with SB3's ``predict`` (MPAIL, an SB3 algorithm or policy, a scripted controller)
    :param env_id: registered env id
    :param n_episodes: number of episodes, split between the envs as ``evaluate_policy`` does
    :param seed: seed of the first env
    :param n_envs: environments stepped together; ``None``: one per episode, so every episode starts from its own seed
        (episodes that end early are not followed by second ones, which would weight the mean towards them)
    :param env_kwargs: keyword arguments of the env, e.g. ``dict(start_region="ood")``
    :param deterministic: execute the plans' (the policy's) most likely actions instead of sampling
    :param on_step: sees each env's ``info`` and ``done`` after every step of a counted episode
    :param record_observations: also keep every episode's observations
    :return: the episodes' measures
    """
    env = make_vec_env(env_id, n_envs=n_episodes if n_envs is None else n_envs, seed=seed, env_kwargs=env_kwargs)
    # per env, its finished episodes as (return, length, final info, observations) and its current observations
    finished: List[List[Tuple[float, int, Dict[str, Any], Optional[np.ndarray]]]] = [[] for _ in range(env.num_envs)]
    current: List[List[np.ndarray]] = [[] for _ in range(env.num_envs)]

    def record(local_variables: Dict[str, Any], _: Dict[str, Any]) -> None:
        index, info, done = local_variables["i"], local_variables["info"], bool(local_variables["done"])
        if on_step is not None:
            on_step(info, done)
        if record_observations:
            if not current[index]:
                current[index].append(np.array(local_variables["observations"][index]))
            last = info["terminal_observation"] if done else local_variables["new_observations"][index]
            current[index].append(np.array(last))
        # an episode is counted where Monitor (make_vec_env's wrapper) reports it, as evaluate_policy counts it
        if done and "episode" in info:
            observations = np.stack(current[index]) if record_observations else None
            finished[index].append((float(info["episode"]["r"]), int(info["episode"]["l"]), info, observations))
            current[index] = []

    try:
        # evaluate_policy's own lists are in the order episodes end; these records keep the envs' order
        evaluate_policy(model, env, n_eval_episodes=n_episodes, deterministic=deterministic, callback=record)
    finally:
        env.close()
    episodes = [episode for per_env in finished for episode in per_env]
    return Episodes(
        returns=np.array([episode[0] for episode in episodes], dtype=float),
        lengths=np.array([episode[1] for episode in episodes], dtype=int),
        final_infos=[episode[2] for episode in episodes],
        observations=[episode[3] for episode in episodes] if record_observations else None,
    )


def reference_returns(reference: Mapping[str, Any]) -> Tuple[float, float]:
    """
    The random policy's and the expert's mean returns of a demo information file.

    :param reference: the file's contents (:func:`~sb3_mpail.demos.shipped_demo_info`), with ``random_return_mean``
        and ``expert_return_mean``
    :return: ``(random return, expert return)``
    :raises ValueError: the file holds no such returns (e.g. the lap's demo, which is measured by its path instead)
    """
    missing = [key for key in ("random_return_mean", "expert_return_mean") if key not in reference]
    if missing:
        raise ValueError(
            f"This demo information ({reference.get('env_id', 'unknown env')}) has no {' or '.join(missing)}, so no "
            "normalised score can be measured against it."
        )
    return float(reference["random_return_mean"]), float(reference["expert_return_mean"])


def normalised_score(episode_return: float, reference: Mapping[str, Any]) -> float:
    """
    ``(R - random) / (expert - random)``: 0 is the random policy, 1 the expert.

    :param episode_return: an undiscounted (mean) episode return ``R``
    :param reference: a demo information file's contents, e.g. ``shipped_demo_info("pendulum")``
        (:func:`reference_returns`)
    """
    random_return, expert_return = reference_returns(reference)
    return float((episode_return - random_return) / (expert_return - random_return))
