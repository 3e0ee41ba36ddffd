"""Generate observation-only expert demonstrations for gymnasium's MuJoCo locomotion tasks (``Hopper-v4``,
``Walker2d-v4``, ``HalfCheetah-v4``, ``Ant-v4``; stock rewards, terminations and 1,000-step episodes; the v4 versions
are the ones both supported gymnasium releases register).

This script:

1. trains a Stable-Baselines3 TD3 expert (``--algo sac``: SAC) on the env's own reward with rl_zoo3's MuJoCo
   settings (``learning_starts=10000``, ``learning_rate=3e-4``, ``batch_size=256``, one gradient step per env step;
   TD3 with Gaussian action noise of std 0.1 and 256 x 256 networks, not rl_zoo3's 400 x 300, to fit a 2-core CPU;
   SAC with its 256 x 256 defaults and automatic entropy). Off-policy because rl_zoo3's tuned PPO for Hopper (1M
   steps) learned here only to stand; SAC because TD3 taught the Ant-v4 only to stand still. Every ``--eval-freq`` steps the
   deterministic policy is scored on ``--n-eval-checkpoint`` seeded episodes and the best checkpoint is kept, as
   rl_zoo3's ``best_model``; training stops at ``--timesteps`` or after ``--max-minutes``, whichever comes first;
2. scores the best checkpoint and a uniform-random policy on 20 fresh seeded episodes;
3. records ``--n-demos`` episodes with the deterministic expert (episode ``i`` starts from
   ``env.reset(seed=1000 + i)``), observations only: ``<out-dir>/<name>_<n>.npz``;
4. writes ``<out-dir>/<name>.json`` (``ant.json``'s schema: returns, forward speed, steps, command).

``--resume`` goes on training a saved expert; with ``--record-only`` it skips training and does steps 2-4 only.

The expert itself is not shipped; ``--save-expert`` keeps it. Needs the ``scenarios`` extra (mujoco).

Run from the repository root::

    python demos/make_mujoco_demos.py --env Hopper-v4 --max-minutes 95 --n-demos 16
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, Optional

import gymnasium as gym
import numpy as np
import torch
from expert_rollouts import SHIPPED_DEMO_DIR, evaluate_expert, evaluate_random, record_demos, save_demos, save_metadata
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.utils import set_random_seed

from sb3_mpail.envs.locomotion import LOCOMOTION_TASKS, evaluate_locomotion

N_EVAL_EPISODES = 20
EXPERT_ALGOS = {"td3": TD3, "sac": SAC}


def parse_args() -> argparse.Namespace:
    """Parse the command-line arguments.

    :return: The parsed arguments.
    """
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", choices=sorted(LOCOMOTION_TASKS), required=True, help="gymnasium env id")
    parser.add_argument("--algo", choices=sorted(EXPERT_ALGOS), default="td3", help="the expert's learner (default: td3)")
    parser.add_argument("--timesteps", type=int, default=1_000_000, help="training timesteps (default: 1000000)")
    parser.add_argument("--max-minutes", type=float, default=None, help="stop training after this much wall-clock time")
    parser.add_argument("--eval-freq", type=int, default=20_000, help="steps between checkpoint scores (default: 20000)")
    parser.add_argument("--n-eval-checkpoint", type=int, default=5, help="episodes per checkpoint score (default: 5)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--out-dir", type=Path, default=SHIPPED_DEMO_DIR, help="folder for the .npz and .json files")
    parser.add_argument("--n-demos", type=int, default=16, help="number of demonstrations to record (default: 16)")
    parser.add_argument("--resume", type=Path, default=None, help="go on training an expert saved by --save-expert")
    parser.add_argument("--batch-warmup", type=int, default=1_000, help="with --resume: random steps stored before updates")
    parser.add_argument("--save-expert", type=Path, default=None, help="where to save the expert (not shipped)")
    parser.add_argument("--record-only", action="store_true", help="with --resume: score and record the saved expert as is")
    args = parser.parse_args()
    if args.record_only and args.resume is None:
        parser.error("--record-only needs --resume: the expert to record")
    return args


class KeepBest(BaseCallback):
    """Scores the deterministic policy every ``eval_freq`` steps, keeps the best weights and stops after a budget.

    :param env_id: The env to score on.
    :param eval_freq: Steps between scores.
    :param n_episodes: Episodes per score.
    :param seed: Seed of the scoring env's first reset.
    :param seconds: Wall-clock budget, or ``None``.
    :param save_path: Where each new best is saved as it is found (so an interrupted run can ``--resume``), or ``None``.
    """

    def __init__(self, env_id: str, eval_freq: int, n_episodes: int, seed: int, seconds: Optional[float],
                 save_path: Optional[Path] = None):
        super().__init__()
        self.env_id, self.eval_freq, self.n_episodes, self.seed, self.seconds = env_id, eval_freq, n_episodes, seed, seconds
        self.save_path = save_path
        self.best_return = -np.inf
        self.best_step = 0
        self.best_state: Optional[dict[str, Any]] = None

    def _on_training_start(self) -> None:
        self.start = time.perf_counter()

    def _on_step(self) -> bool:
        if self.num_timesteps % self.eval_freq == 0:
            mean_return, _ = evaluate_expert(self.model, self.env_id, self.seed, self.n_episodes)
            minutes = (time.perf_counter() - self.start) / 60
            print(f"{self.num_timesteps} steps ({minutes:.1f} min): return {mean_return:.0f}", flush=True)
            if mean_return > self.best_return:
                self.best_return, self.best_step = mean_return, self.num_timesteps
                self.best_state = {k: v.clone() for k, v in self.model.policy.state_dict().items()}
                if self.save_path is not None:
                    self.model.save(self.save_path)
        return self.seconds is None or time.perf_counter() - self.start < self.seconds


def main() -> None:
    """Train the expert, keep its best checkpoint, evaluate it, record the demos and write the metadata."""
    args = parse_args()
    torch.set_num_threads(1)
    set_random_seed(args.seed)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    name = LOCOMOTION_TASKS[args.env]

    env = gym.make(args.env)
    n_actions = env.action_space.shape[0]
    algo = EXPERT_ALGOS[args.algo]
    settings: dict[str, Any] = dict(
        learning_starts=10_000, learning_rate=3e-4, batch_size=256, train_freq=1, gradient_steps=1, seed=args.seed,
        device="cpu",
    )
    if algo is TD3:
        settings["action_noise"] = NormalActionNoise(np.zeros(n_actions), 0.1 * np.ones(n_actions))
    if args.resume is None:
        model = algo("MlpPolicy", env, policy_kwargs=dict(net_arch=[256, 256]), **settings)
    else:  # the saved networks go on learning; their replay buffer was not saved: it refills before updates resume
        model = algo.load(args.resume, env, **settings)
        model.learning_starts = model.num_timesteps + args.batch_warmup
    keep_best = KeepBest(args.env, args.eval_freq, args.n_eval_checkpoint, args.seed + 3,
                         None if args.max_minutes is None else 60 * args.max_minutes, args.save_expert)
    start = time.perf_counter()
    if not args.record_only:
        model.learn(total_timesteps=args.timesteps, callback=keep_best, reset_num_timesteps=args.resume is None)
    train_seconds = time.perf_counter() - start
    if keep_best.best_state is not None:
        model.policy.load_state_dict(keep_best.best_state)
    if args.save_expert is not None:
        model.save(args.save_expert)

    expert = evaluate_locomotion(model, args.env, N_EVAL_EPISODES, seed=args.seed + 1)
    expert_mean, expert_std, expert_speed = expert["return"], expert["return_std"], expert["forward_speed"]
    random_mean, random_std = evaluate_random(args.env, seed=args.seed + 2, n_episodes=N_EVAL_EPISODES)
    trained = "as saved" if args.record_only else f"best checkpoint at {keep_best.best_step}"
    print(f"expert return: {expert_mean:.1f} +/- {expert_std:.1f}, forward speed {expert_speed:.2f} m/s "
          f"({trained}, {model.num_timesteps} steps, {train_seconds:.0f} s)")
    print(f"random return: {random_mean:.1f} +/- {random_std:.1f}")

    episodes, demo_returns = record_demos(model, args.env, args.n_demos)
    npz_path = args.out_dir / f"{name}_{args.n_demos}.npz"
    shape = save_demos(episodes, npz_path)
    print(f"saved demos {shape} (episode lengths {[len(e) for e in episodes]}) to {npz_path}; returns {demo_returns}")

    meta: dict[str, Any] = {
        "env_id": args.env,
        "expert_algo": algo.__name__,
        "expert_timesteps": model.num_timesteps,
        "resumed_from": None if args.resume is None else str(args.resume),
        "expert_checkpoint_timesteps": None if args.record_only else keep_best.best_step,
        "seed": args.seed,
        "expert_return_mean": expert_mean,
        "expert_return_std": expert_std,
        "expert_forward_speed": expert_speed,
        "random_return_mean": random_mean,
        "random_return_std": random_std,
        "n_eval_episodes": N_EVAL_EPISODES,
        "demo_returns": demo_returns,
        "command": "python demos/make_mujoco_demos.py " + " ".join(sys.argv[1:]),
        "train_seconds": round(train_seconds, 1),
    }
    save_metadata(meta, args.out_dir / f"{name}.json")


if __name__ == "__main__":
    main()
