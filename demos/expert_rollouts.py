"""
Rollouts shared by the demo scripts: scoring an expert and a random policy, recording an expert's observations and
saving them with their metadata. Imported by the ``make_*_demos.py`` scripts, which run from this folder.

The demos they write are package data: ``<name>_<n>.npz`` and ``<name>.json`` go to ``sb3_mpail/data/``
(:data:`SHIPPED_DEMO_DIR`), so a new demo set is shipped by adding its files there; expert-action twins, which only the
BC baseline reads, go to ``benchmarks/action_demos/`` (:data:`ACTION_DEMO_DIR`).
"""

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_mpail.evaluation import evaluate_episodes

DEMO_SEED_OFFSET = 1000
#: where the demo scripts write the shipped demos and their information files (the package's data folder)
SHIPPED_DEMO_DIR = Path(__file__).resolve().parent.parent / "sb3_mpail" / "data"
#: where the expert-action twins of the demos go (experiment data for the BC baseline, not shipped)
ACTION_DEMO_DIR = Path(__file__).resolve().parent.parent / "benchmarks" / "action_demos"


def evaluate_expert(model: BaseAlgorithm, env_id: str, seed: int, n_episodes: int) -> tuple[float, float]:
    """Evaluate the deterministic expert on a seeded evaluation environment.

    :param model: The trained expert.
    :param env_id: Gymnasium id of the environment.
    :param seed: Seed of the evaluation environment.
    :param n_episodes: Number of evaluation episodes.
    :return: Mean and standard deviation of the episode returns.
    """
    episodes = evaluate_episodes(model, env_id, n_episodes, seed, n_envs=1)
    return episodes.mean_return, episodes.std_return


def evaluate_random(env_id: str, seed: int, n_episodes: int) -> tuple[float, float]:
    """Evaluate a uniform-random policy (``action_space.sample`` with a seeded space).

    :param env_id: Gymnasium id of the environment.
    :param seed: Seed for the environment's first reset and for the action space.
    :param n_episodes: Number of evaluation episodes.
    :return: Mean and standard deviation of the episode returns.
    """
    env = gym.make(env_id)
    env.action_space.seed(seed)
    returns: list[float] = []
    for episode in range(n_episodes):
        # Seed only the first reset; later resets continue the seeded RNG stream
        env.reset(seed=seed if episode == 0 else None)
        done, ep_return = False, 0.0
        while not done:
            _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            ep_return += float(reward)
            done = terminated or truncated
        returns.append(ep_return)
    env.close()
    return float(np.mean(returns)), float(np.std(returns))


def record_demos(model: BaseAlgorithm, env_id: str, n_demos: int) -> tuple[list[np.ndarray], list[float]]:
    """Record observation-only demonstrations with the deterministic expert.

    :param model: The trained expert.
    :param env_id: Gymnasium id of the environment.
    :param n_demos: Number of episodes to record; episode ``i`` uses ``reset(seed=1000 + i)``.
    :return: Float32 observations per episode, each ``(T_i + 1, obs_dim)`` (the final observation kept), and the
        per-demo returns.
    """
    env = gym.make(env_id)
    all_obs: list[np.ndarray] = []
    demo_returns: list[float] = []
    for i in range(n_demos):
        obs, _ = env.reset(seed=DEMO_SEED_OFFSET + i)
        episode_obs = [obs]
        done, ep_return = False, 0.0
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, _ = env.step(action)
            episode_obs.append(obs)
            ep_return += float(reward)
            done = terminated or truncated
        all_obs.append(np.asarray(episode_obs, dtype=np.float32))
        demo_returns.append(ep_return)
    env.close()
    return all_obs, demo_returns


def save_demos(episodes: list[np.ndarray], npz_path: Path) -> tuple[int, ...]:
    """Write observation-only demos in sb3_mpail's ``.npz`` layout.

    :param episodes: Observations per episode, each ``(T_i + 1, obs_dim)``.
    :param npz_path: The file to write.
    :return: Shape of the stored ``obs``: ``(n_demos, T + 1, obs_dim)`` when every episode has the same length, else
        the episodes concatenated, ``(sum_i (T_i + 1), obs_dim)``, stored with their ``episode_lengths``.
    """
    lengths = [len(episode) for episode in episodes]
    if len(set(lengths)) == 1:
        obs = np.stack(episodes)
        np.savez_compressed(npz_path, obs=obs)
    else:
        obs = np.concatenate(episodes)
        np.savez_compressed(npz_path, obs=obs, episode_lengths=np.asarray(lengths, dtype=np.int64))
    return obs.shape


def save_metadata(meta: dict[str, Any], json_path: Path) -> None:
    """Write the demos' metadata (expert and random returns, settings, command) as indented JSON.

    :param meta: The metadata.
    :param json_path: The file to write.
    """
    json_path.write_text(json.dumps(meta, indent=2) + "\n")
    print(f"saved metadata to {json_path}")
