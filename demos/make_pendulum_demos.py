"""Generate observation-only expert demonstrations for ``Pendulum-v1``.

This script:

1. trains a Stable-Baselines3 SAC expert on gymnasium ``Pendulum-v1`` (rl-zoo
   hyperparameters: ``learning_rate=1e-3``, defaults otherwise);
2. evaluates the deterministic expert and a uniform-random policy on 100 seeded
   episodes each;
3. records ``--n-demos`` full 200-step episodes with the deterministic expert
   (episode ``i`` starts from ``env.reset(seed=1000 + i)``) and keeps only the
   201 observations of each episode (no actions), saved as
   ``<out-dir>/pendulum_<n>.npz`` with key ``obs`` of shape ``(n, 201, 3)``
   (float32);
4. writes the metadata file ``<out-dir>/pendulum.json``.

The trained expert model is not saved. The script is deterministic for a fixed
``--seed`` (single-threaded torch, seeded SAC, environments and action spaces).

Run from the repository root::

    python demos/make_pendulum_demos.py
    python demos/make_pendulum_demos.py --timesteps 20000 --seed 0 --n-demos 4
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import torch
from expert_rollouts import SHIPPED_DEMO_DIR, evaluate_expert, evaluate_random, record_demos, save_demos, save_metadata
from stable_baselines3 import SAC
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.utils import set_random_seed

ENV_ID = "Pendulum-v1"
N_EVAL_EPISODES = 100
DEFAULT_OUT_DIR = SHIPPED_DEMO_DIR


def parse_args() -> argparse.Namespace:
    """Parse the command-line arguments.

    :return: The parsed arguments (``timesteps``, ``seed``, ``out_dir``, ``n_demos``).
    """
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--timesteps", type=int, default=20_000, help="SAC training timesteps for the expert")
    parser.add_argument("--seed", type=int, default=0, help="Random seed (SAC, environments, numpy)")
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT_DIR, help="Output folder for the .npz and .json files")
    parser.add_argument("--n-demos", type=int, default=4, help="Number of observation-only demonstrations to record")
    return parser.parse_args()


def train_expert(timesteps: int, seed: int) -> tuple[SAC, float]:
    """Train a SAC expert on ``Pendulum-v1``.

    :param timesteps: Number of environment steps to train for.
    :param seed: Seed for SAC (torch, numpy, python ``random``) and the training environment.
    :return: The trained model and the wall-clock training time in seconds.
    """
    env = make_vec_env(ENV_ID, n_envs=1, seed=seed)
    # rl-zoo hyperparameters for Pendulum-v1: learning_rate=1e-3, SAC defaults otherwise
    model = SAC("MlpPolicy", env, learning_rate=1e-3, seed=seed, verbose=0, device="cpu")
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
    npz_path = out_dir / f"pendulum_{args.n_demos}.npz"
    shape = save_demos(episodes, npz_path)
    print(f"saved demos {shape} to {npz_path}; demo returns: {[round(r, 1) for r in demo_returns]}")

    meta: dict[str, Any] = {
        "env_id": ENV_ID,
        "expert_algo": "SAC",
        "expert_timesteps": args.timesteps,
        "seed": args.seed,
        "expert_return_mean": expert_mean,
        "expert_return_std": expert_std,
        "random_return_mean": random_mean,
        "random_return_std": random_std,
        "n_eval_episodes": N_EVAL_EPISODES,
        "demo_returns": demo_returns,
        "command": "python demos/make_pendulum_demos.py",
        "train_seconds": round(train_seconds, 1),
    }
    save_metadata(meta, out_dir / "pendulum.json")


if __name__ == "__main__":
    main()
