"""Generate observation-only expert demonstrations for ``sb3_mpail/Ant-v0`` (MuJoCo Ant-v4, 200-step episodes).

This script:

1. trains a Stable-Baselines3 PPO expert on the env's own reward (forward velocity + 1 while healthy - control cost)
   with 8 envs and ``VecNormalize`` (observations and rewards), CleanRL's MuJoCo PPO settings otherwise
   (``learning_rate=3e-4``, ``gamma=0.99``, ``gae_lambda=0.95``, ``n_epochs=10``, ``clip_range=0.2``, 64 x 64
   networks) with ``n_steps=256``, ``batch_size=256`` and an initial action std of ``exp(-1)``. PPO rather than SAC
   because on a shared CPU its cheap updates buy far more env steps per minute (SAC: 61 steps/s on an idle core,
   about 10 under the shared load); the low initial std because with std 1 the control cost outweighs the healthy
   reward and PPO learnt to end episodes early (jumping or flipping) instead of walking. Training stops at
   ``--timesteps`` or after ``--max-minutes`` of wall-clock time, whichever comes first (the steps reached are
   recorded);
2. evaluates the deterministic expert (return and forward speed) and a uniform-random policy on seeded episodes;
3. records ``--n-demos`` episodes with the deterministic expert (episode ``i`` starts from
   ``env.reset(seed=1000 + i)``) and keeps only the observations (no actions): ``<out-dir>/ant_<n>.npz`` with key
   ``obs`` of shape ``(n, 201, 27)`` (float32) when every episode runs its 200 steps, otherwise 2-D (all episodes
   concatenated) with ``episode_lengths``;
4. writes the metadata file ``<out-dir>/ant.json`` (``cartpole.json``'s schema plus the forward speeds).

The expert is not shipped; ``--save-expert`` keeps it (and its ``VecNormalize`` statistics) elsewhere. Needs the
``scenarios`` extra (mujoco).

Run from the repository root::

    python demos/make_ant_demos.py
    python demos/make_ant_demos.py --timesteps 2000000 --max-minutes 15 --seed 0 --n-demos 4
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch
from expert_rollouts import SHIPPED_DEMO_DIR, evaluate_random, record_demos, save_demos, save_metadata
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecNormalize

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Ant-v0)
from sb3_mpail.envs.ant import ANT_FORWARD_VELOCITY_INDEX, evaluate_ant

ENV_ID = "sb3_mpail/Ant-v0"
N_EVAL_EPISODES = 20
DEFAULT_OUT_DIR = SHIPPED_DEMO_DIR


def parse_args() -> argparse.Namespace:
    """Parse the command-line arguments.

    :return: The parsed arguments (``timesteps``, ``max_minutes``, ``seed``, ``out_dir``, ``n_demos``, ``save_expert``).
    """
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--timesteps", type=int, default=2_000_000, help="PPO training timesteps for the expert")
    parser.add_argument("--max-minutes", type=float, default=None, help="Stop training after this much wall-clock time")
    parser.add_argument("--seed", type=int, default=0, help="Random seed (PPO, environments, numpy)")
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT_DIR, help="Output folder for the .npz and .json files")
    parser.add_argument("--n-demos", type=int, default=4, help="Number of observation-only demonstrations to record")
    parser.add_argument("--save-expert", type=Path, default=None, help="Where to save the trained expert (not shipped)")
    return parser.parse_args()


class StopAfter(BaseCallback):
    """Stops training after a wall-clock budget.

    :param seconds: The budget in seconds.
    """

    def __init__(self, seconds: float):
        super().__init__()
        self.seconds = seconds

    def _on_training_start(self) -> None:
        self.start = time.perf_counter()

    def _on_step(self) -> bool:
        return time.perf_counter() - self.start < self.seconds


class NormalizedExpert:
    """The PPO expert acting on raw observations: normalises them with the training ``VecNormalize`` statistics.

    :param model: The trained PPO.
    :param normalization: The ``VecNormalize`` it was trained with (its statistics are no longer updated).
    """

    def __init__(self, model: PPO, normalization: VecNormalize):
        self.model = model
        self.normalization = normalization
        self.normalization.training = False

    def predict(
        self,
        observation: np.ndarray,
        state: Optional[tuple[np.ndarray, ...]] = None,
        episode_start: Optional[np.ndarray] = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, Optional[tuple[np.ndarray, ...]]]:
        return self.model.predict(self.normalization.normalize_obs(observation), state, episode_start, deterministic)


def train_expert(
    timesteps: int, max_minutes: Optional[float], seed: int, save_path: Optional[Path]
) -> tuple[NormalizedExpert, int, float]:
    """Train a PPO expert on ``sb3_mpail/Ant-v0``.

    :param timesteps: Number of environment steps to train for.
    :param max_minutes: Wall-clock budget after which training stops early, or ``None``.
    :param seed: Seed for PPO (torch, numpy, python ``random``) and the training environment.
    :param save_path: Where to save the trained expert (``<save_path>.zip`` and ``<save_path>_vecnormalize.pkl``), or
        ``None``.
    :return: The trained expert, its number of training steps and the wall-clock training time in seconds.
    """
    env = VecNormalize(make_vec_env(ENV_ID, n_envs=8, seed=seed))
    model = PPO(
        "MlpPolicy",
        env,
        n_steps=256,
        batch_size=256,
        n_epochs=10,
        learning_rate=3e-4,
        gamma=0.99,
        gae_lambda=0.95,
        clip_range=0.2,
        policy_kwargs=dict(log_std_init=-1.0),
        seed=seed,
        verbose=1,
        device="cpu",
    )
    start = time.perf_counter()
    model.learn(total_timesteps=timesteps, callback=StopAfter(60 * max_minutes) if max_minutes is not None else None)
    train_seconds = time.perf_counter() - start
    if save_path is not None:
        model.save(save_path)
        env.save(f"{save_path}_vecnormalize.pkl")
    return NormalizedExpert(model, env), model.num_timesteps, train_seconds


def main() -> None:
    """Train the expert, evaluate it, record the demos and write the metadata."""
    args = parse_args()
    torch.set_num_threads(1)
    set_random_seed(args.seed)
    out_dir: Path = args.out_dir
    out_dir.mkdir(parents=True, exist_ok=True)

    model, expert_timesteps, train_seconds = train_expert(args.timesteps, args.max_minutes, args.seed, args.save_expert)
    # Distinct seeds for training and evaluation environments
    expert = evaluate_ant(model, N_EVAL_EPISODES, seed=args.seed + 1)
    random_mean, random_std = evaluate_random(ENV_ID, seed=args.seed + 2, n_episodes=N_EVAL_EPISODES)
    print(f"expert return: {expert['return']:.1f} +/- {expert['return_std']:.1f}, forward speed "
          f"{expert['forward_speed']:.2f} m/s ({expert_timesteps} steps, {train_seconds:.0f}s training)")
    print(f"random return: {random_mean:.1f} +/- {random_std:.1f}")

    episodes, demo_returns = record_demos(model, ENV_ID, args.n_demos)
    npz_path = out_dir / f"ant_{args.n_demos}.npz"
    shape = save_demos(episodes, npz_path)
    lengths = [len(episode) for episode in episodes]
    print(f"saved demos {shape} (episode lengths {lengths}) to {npz_path}; demo returns: {demo_returns}")

    meta: dict[str, Any] = {
        "env_id": ENV_ID,
        "expert_algo": "PPO",
        "expert_timesteps": expert_timesteps,
        "seed": args.seed,
        "expert_return_mean": expert["return"],
        "expert_return_std": expert["return_std"],
        "expert_forward_speed": expert["forward_speed"],
        "random_return_mean": random_mean,
        "random_return_std": random_std,
        "n_eval_episodes": N_EVAL_EPISODES,
        "demo_returns": demo_returns,
        # the torso's x velocity in the observation over the recorded demo steps
        "demo_forward_speed": float(np.mean([episode[1:, ANT_FORWARD_VELOCITY_INDEX].mean() for episode in episodes])),
        "command": "python demos/make_ant_demos.py " + " ".join(sys.argv[1:]),
        "train_seconds": round(train_seconds, 1),
    }
    save_metadata(meta, out_dir / "ant.json")


if __name__ == "__main__":
    main()
