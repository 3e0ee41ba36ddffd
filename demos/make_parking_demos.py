"""Generate observation-only demonstrations for ``sb3_mpail/Parking-v0`` with a scripted planning expert.

The usual parking expert is HER+SAC; this script uses a scripted one instead (cheaper on a 2-core CPU): MPPI through
the exact planning model :class:`sb3_mpail.mppi.ParkingKinematics` on parking-v0's own weighted distance
``(|obs - goal| . [1, 0.3, w, w, 0.02, 0.02])^0.5`` summed over the horizon, with ``w = --stop-weight`` on the
velocity (parking-v0's reward has 0 there, so its expert arrives moving) and the lot's walls as a known cost
(:func:`sb3_mpail.mppi.constraints.parking_walls`); ``--samples`` Gaussian action sequences of ``--horizon`` steps,
``--iterations`` refinements per step and a warm start.

It evaluates the expert and a uniform-random policy on ``--eval-episodes`` seeded episodes of the stock env (success
as parking-v0 judges it, crashes), then records ``--n-demos`` episodes in which the expert parks and stops (reset
seeds 1000, 1001, ...; seeds of episodes in which it did not are listed in the metadata and skipped): those episodes
run in the same env without its early end on success, until the car is parked by parking-v0's test and slower than
``--stopped-speed``, then for ``--hold-steps`` more steps in which the expert stays parked (the demos then show where a
car stops, as often as a car stays there). It keeps only the observations and writes ``<out-dir>/parking_<n>.npz``
(``obs`` 2-D with ``episode_lengths``) and ``<out-dir>/parking.json``. Needs the ``scenarios`` extra.

Run from the repository root::

    python demos/make_parking_demos.py --n-demos 16 --eval-episodes 20 --stop-weight 0.01 --hold-steps 100  # the shipped set
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch as th
from expert_rollouts import SHIPPED_DEMO_DIR

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Parking-v0)
from sb3_mpail.mppi import ParkingKinematics
from sb3_mpail.mppi.constraints import parking_walls

ENV_ID = "sb3_mpail/Parking-v0"
DEMO_SEED_OFFSET = 1000
#: parking-v0's reward weights over [x, y, vx, vy, cos h, sin h] and its success threshold on the reward
REWARD_WEIGHTS = np.array([1.0, 0.3, 0.0, 0.0, 0.02, 0.02])
SUCCESS_GOAL_REWARD = 0.12
SPEED_SCALE = 5.0  # m/s per observation unit of vx and vy


class ParkingExpert:
    """
    MPPI on parking-v0's weighted distance to the goal, velocity included, and the walls' cost, through the exact model.

    :param stop_weight: weight of the velocity's distance to the goal's (0) in the cost
    :param samples: action sequences sampled per iteration
    :param horizon: planning horizon in steps
    :param iterations: refinements of the mean sequence per environment step
    :param noise: standard deviation of the sampled actions
    :param temperature: MPPI temperature on the summed cost
    :param seed: seed of the sampled actions
    """

    def __init__(
        self, stop_weight: float, samples: int, horizon: int, iterations: int, noise: float, temperature: float, seed: int
    ):
        self.model = ParkingKinematics()
        self.weights = th.tensor(REWARD_WEIGHTS + [0, 0, stop_weight, stop_weight, 0, 0], dtype=th.float64)
        self.walls = parking_walls().double()
        self.samples = samples
        self.horizon = horizon
        self.iterations = iterations
        self.noise = noise
        self.temperature = temperature
        self.generator = th.Generator().manual_seed(seed)
        self.mean = th.zeros(horizon, 2, dtype=th.float64)

    def reset(self) -> None:
        self.mean.zero_()

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        state = th.as_tensor(observation, dtype=th.float64)
        for _ in range(self.iterations):
            noise = th.randn(self.samples, self.horizon, 2, generator=self.generator, dtype=th.float64) * self.noise
            actions = (self.mean + noise).clamp(-1.0, 1.0)
            states = state.expand(self.samples, -1)
            cost = th.zeros(self.samples, dtype=th.float64)
            for step in range(self.horizon):
                states = self.model(states, actions[:, step])
                cost += ((states[:, :6] - states[:, 6:]).abs() @ self.weights).sqrt() + self.walls(states)
            weights = th.softmax(-(cost - cost.min()) / self.temperature, dim=0)
            self.mean = th.einsum("n,nhd->hd", weights, actions)
        action = self.mean[0].numpy().astype(np.float32)
        self.mean = th.cat((self.mean[1:], th.zeros(1, 2, dtype=th.float64)))
        return action


def parked_and_stopped(observation: np.ndarray, stopped_speed: float) -> bool:
    """Parked by parking-v0's own test (its reward above ``-0.12``) and slower than ``stopped_speed`` m/s."""
    distance = np.abs(observation[:6] - observation[6:]) @ REWARD_WEIGHTS
    speed = float(np.hypot(observation[2], observation[3])) * SPEED_SCALE
    return bool(-np.sqrt(distance) > -SUCCESS_GOAL_REWARD and speed < stopped_speed)


def run_episode(
    env: gym.Env, seed: int, policy, stopped_speed: float | None = None, hold_steps: int = 0
) -> tuple[list[np.ndarray], float, bool, bool]:
    """
    One episode from ``env.reset(seed=seed)``.

    :param env: the parking env
    :param seed: reset seed
    :param policy: observation -> action, or None for uniform-random actions
    :param stopped_speed: end the episode once the car is parked and slower than this (m/s); ``None``: the env's ends
    :param hold_steps: steps the policy goes on for once the car is parked (and stopped, with ``stopped_speed``)
    :return: the observations, the return, whether the car parked (stopped, with ``stopped_speed``) and whether it crashed
    """
    observation, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    observations, episode_return = [observation], 0.0
    if policy is not None:
        policy.reset()
    parked_at = None
    while True:
        action = env.action_space.sample() if policy is None else policy(observation)
        observation, reward, terminated, truncated, info = env.step(action)
        observations.append(observation)
        episode_return += reward
        parked = info["is_success"] if stopped_speed is None else parked_and_stopped(observation, stopped_speed)
        if parked and parked_at is None:
            parked_at = len(observations)
        if terminated or truncated or (parked_at is not None and len(observations) - parked_at >= hold_steps):
            return observations, episode_return, parked_at is not None, bool(info["crashed"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n-demos", type=int, default=4)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--stop-weight", type=float, default=0.05)
    parser.add_argument("--stopped-speed", type=float, default=0.2)
    parser.add_argument("--hold-steps", type=int, default=0)
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--horizon", type=int, default=15)
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--noise", type=float, default=0.5)
    parser.add_argument("--temperature", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out-dir", type=Path, default=SHIPPED_DEMO_DIR)
    args = parser.parse_args()
    th.set_num_threads(1)
    env = gym.make(ENV_ID)
    demo_env = gym.make(ENV_ID, config={"success_goal_reward": 0.0})  # no early end on success: the demos stop first
    expert = ParkingExpert(
        args.stop_weight, args.samples, args.horizon, args.iterations, args.noise, args.temperature, args.seed
    )
    start = time.time()
    expert_runs = [run_episode(env, seed, expert) for seed in range(args.eval_episodes)]
    random_runs = [run_episode(env, seed, None) for seed in range(args.eval_episodes)]
    demos, failed_demo_seeds, seed = [], [], DEMO_SEED_OFFSET
    while len(demos) < args.n_demos:
        run = run_episode(demo_env, seed, expert, args.stopped_speed, args.hold_steps)
        if run[2]:
            demos.append(run)
        else:
            failed_demo_seeds.append(seed)
        seed += 1
    expert_returns = [run[1] for run in expert_runs]
    random_returns = [run[1] for run in random_runs]
    np.savez(
        args.out_dir / f"parking_{args.n_demos}.npz",
        obs=np.concatenate([np.array(run[0], dtype=np.float32) for run in demos]),
        episode_lengths=np.array([len(run[0]) for run in demos]),
    )
    command = "python demos/make_parking_demos.py " + " ".join(
        f"--{name.replace('_', '-')} {getattr(args, name)}"
        for name in ("n_demos", "eval_episodes", "stop_weight", "stopped_speed", "hold_steps", "samples", "horizon",
                     "iterations", "noise", "temperature", "seed")  # fmt: skip
    )
    metadata = {
        "env_id": ENV_ID,
        "expert_algo": "scripted MPPI on the exact model, parking-v0's weighted goal distance with the velocity, and "
        "the walls' cost",
        "seed": args.seed,
        "expert_return_mean": float(np.mean(expert_returns)),
        "expert_return_std": float(np.std(expert_returns)),
        "expert_success_rate": float(np.mean([run[2] for run in expert_runs])),
        "expert_crash_rate": float(np.mean([run[3] for run in expert_runs])),
        "expert_episode_length_mean": float(np.mean([len(run[0]) - 1 for run in expert_runs])),
        "random_return_mean": float(np.mean(random_returns)),
        "random_return_std": float(np.std(random_returns)),
        "random_success_rate": float(np.mean([run[2] for run in random_runs])),
        "n_eval_episodes": args.eval_episodes,
        "demo_returns": [run[1] for run in demos],
        "failed_demo_seeds": failed_demo_seeds,
        "demo_lengths": [len(run[0]) - 1 for run in demos],
        "demo_hold_steps": args.hold_steps,
        "command": command,
        "seconds": round(time.time() - start, 1),
    }
    (args.out_dir / "parking.json").write_text(json.dumps(metadata, indent=2) + "\n")
    print(json.dumps(metadata, indent=2))


if __name__ == "__main__":
    main()
