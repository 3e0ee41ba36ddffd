"""Generate observation-only expert demonstrations for ``sb3_mpail/ContinuousCartPole-v0``.

This script:

1. trains a Stable-Baselines3 PPO expert on the env's own reward (+1 per step alive, 200-step episodes) with
   rl-zoo's ``CartPole-v1`` PPO hyperparameters (8 envs, ``n_steps=32``, ``batch_size=256``, ``gae_lambda=0.8``,
   ``gamma=0.98``, ``n_epochs=20``, ``ent_coef=0``, linearly decaying ``learning_rate=1e-3``, ``clip_range``
   0.2 decaying linearly), Gaussian policy on the continuous force;
2. evaluates the deterministic expert and a uniform-random policy on 100 seeded episodes each;
3. records ``--n-demos`` episodes with the deterministic expert (episode ``i`` starts from
   ``env.reset(seed=1000 + i)``) and keeps only the observations (no actions). Full 200-step episodes give
   ``<out-dir>/cartpole_<n>.npz`` with key ``obs`` of shape ``(n, 201, 4)`` (float32); if some episode ended
   early, ``obs`` is 2-D (all episodes concatenated) with ``episode_lengths``;
4. writes the metadata file ``<out-dir>/cartpole.json`` (same schema as ``pendulum.json``).

The trained expert model is not saved. The script is deterministic for a fixed ``--seed`` (single-threaded torch,
seeded PPO, environments and action spaces).

Run from the repository root::

    python demos/make_cartpole_demos.py
    python demos/make_cartpole_demos.py --timesteps 100000 --seed 0 --n-demos 4
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import torch
from expert_rollouts import SHIPPED_DEMO_DIR, evaluate_expert, evaluate_random, record_demos, save_demos, save_metadata
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.utils import get_linear_fn, set_random_seed

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/ContinuousCartPole-v0)

ENV_ID = "sb3_mpail/ContinuousCartPole-v0"
N_EVAL_EPISODES = 100
DEFAULT_OUT_DIR = SHIPPED_DEMO_DIR


def parse_args() -> argparse.Namespace:
    """Parse the command-line arguments.

    :return: The parsed arguments (``timesteps``, ``seed``, ``out_dir``, ``n_demos``).
    """
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--timesteps", type=int, default=100_000, help="PPO training timesteps for the expert")
    parser.add_argument("--seed", type=int, default=0, help="Random seed (PPO, environments, numpy)")
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT_DIR, help="Output folder for the .npz and .json files")
    parser.add_argument("--n-demos", type=int, default=4, help="Number of observation-only demonstrations to record")
    return parser.parse_args()


def train_expert(timesteps: int, seed: int) -> tuple[PPO, float]:
    """Train a PPO expert on ``sb3_mpail/ContinuousCartPole-v0``.

    :param timesteps: Number of environment steps to train for.
    :param seed: Seed for PPO (torch, numpy, python ``random``) and the training environments.
    :return: The trained model and the wall-clock training time in seconds.
    """
    env = make_vec_env(ENV_ID, n_envs=8, seed=seed)
    # rl-zoo hyperparameters for CartPole-v1 (PPO), on the continuous force
    model = PPO(
        "MlpPolicy",
        env,
        n_steps=32,
        batch_size=256,
        gae_lambda=0.8,
        gamma=0.98,
        n_epochs=20,
        ent_coef=0.0,
        learning_rate=get_linear_fn(1e-3, 0.0, 1.0),
        clip_range=get_linear_fn(0.2, 0.0, 1.0),
        seed=seed,
        verbose=0,
        device="cpu",
    )
    start = time.perf_counter()
    model.learn(total_timesteps=timesteps)
    train_seconds = time.perf_counter() - start
    env.close()
    return model, train_seconds


def main() -> None:
    """Train the expert, evaluate it, record the demos and write the metadata."""
    args = parse_args()
    torch.set_num_threads(1)
    set_random_seed(args.seed)
    out_dir: Path = args.out_dir
    out_dir.mkdir(parents=True, exist_ok=True)

    model, train_seconds = train_expert(args.timesteps, args.seed)
    # Distinct seeds for training and evaluation environments
    expert_mean, expert_std = evaluate_expert(model, ENV_ID, seed=args.seed + 1, n_episodes=N_EVAL_EPISODES)
    random_mean, random_std = evaluate_random(ENV_ID, seed=args.seed + 2, n_episodes=N_EVAL_EPISODES)
    print(f"expert return: {expert_mean:.1f} +/- {expert_std:.1f} ({train_seconds:.0f}s training)")
    print(f"random return: {random_mean:.1f} +/- {random_std:.1f}")

    episodes, demo_returns = record_demos(model, ENV_ID, args.n_demos)
    npz_path = out_dir / f"cartpole_{args.n_demos}.npz"
    shape = save_demos(episodes, npz_path)
    lengths = [len(episode) for episode in episodes]
    print(f"saved demos {shape} (episode lengths {lengths}) to {npz_path}; demo returns: {demo_returns}")

    meta: dict[str, Any] = {
        "env_id": ENV_ID,
        "expert_algo": "PPO",
        "expert_timesteps": args.timesteps,
        "seed": args.seed,
        "expert_return_mean": expert_mean,
        "expert_return_std": expert_std,
        "random_return_mean": random_mean,
        "random_return_std": random_std,
        "n_eval_episodes": N_EVAL_EPISODES,
        "demo_returns": demo_returns,
        "command": "python demos/make_cartpole_demos.py",
        "train_seconds": round(train_seconds, 1),
    }
    save_metadata(meta, out_dir / "cartpole.json")


if __name__ == "__main__":
    main()
