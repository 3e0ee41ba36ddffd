"""Train a PPO expert on ``sb3_mpail/Navigation-v0`` and record observation-only demonstrations.

Writes ``navigation_{1,4,16}.npz`` (``obs`` of shape ``(n_demos, 101, 12)``, float32) and ``navigation.json``
(expert and random-policy returns, training settings) to ``--out-dir`` (the package's ``sb3_mpail/data/``, so they
ship), and their expert-action twins ``navigation_{1,4,16}_actions.npz`` (for the BC baseline only) to
``--actions-dir`` (``benchmarks/action_demos/``). The expert model is saved outside the repository (``--model-path``).
Usage::

    python demos/make_navigation_demos.py
    python demos/make_navigation_demos.py --min-speed 1.0 --name navigation_circling   # an expert that cannot stop

With ``--min-speed`` the expert's target speed never drops below that many m/s, so on the goal it circles instead of
stopping, as the paper's PPO expert does; its files are named after ``--name``.
"""

import argparse
import json
import math
import os
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np
import torch
from expert_rollouts import ACTION_DEMO_DIR, SHIPPED_DEMO_DIR
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Navigation-v0)
from sb3_mpail.envs.navigation import MAX_SPEED

ENV_ID = "sb3_mpail/Navigation-v0"
DEMO_COUNTS = (1, 4, 16)
N_EVAL_EPISODES = 100
# Disjoint seed ranges so evaluation episodes and demonstrations never share a start state.
EVAL_SEED_BASE = 10_000
DEMO_SEED_BASE = 20_000


def goal_relative_features(obs: np.ndarray, goal: tuple[float, float]) -> np.ndarray:
    """Expert-only features: the goal offset in the car's heading frame plus scaled body velocities.

    Goal-relative, heading-frame inputs make the task translation/rotation invariant, which PPO learns much
    faster than from raw world-frame poses. The demonstrations themselves keep the raw 12-D observation.

    :param obs: Raw 12-D navigation observation.
    :param goal: Goal position ``(x, y)``.
    :return: 6-D float32 feature vector.
    """
    dx, dy = goal[0] - float(obs[0]), goal[1] - float(obs[1])
    cos_yaw, sin_yaw = math.cos(float(obs[5])), math.sin(float(obs[5]))
    return np.array(
        [
            (cos_yaw * dx + sin_yaw * dy) / 10.0,
            (-sin_yaw * dx + cos_yaw * dy) / 10.0,
            math.hypot(dx, dy) / 10.0,
            float(obs[6]) / 3.0,
            float(obs[7]),
            float(obs[11]) / 5.0,
        ],
        dtype=np.float32,
    )


class MinimumSpeed(gym.ActionWrapper):
    """The expert's speed action mapped onto ``[min_speed, MAX_SPEED]``: it cannot stop, so it circles on the goal.

    :param env: A navigation environment (possibly wrapped).
    :param min_speed: The lowest target speed (m/s).
    """

    def __init__(self, env: gym.Env, min_speed: float) -> None:
        super().__init__(env)
        self.low = min_speed / MAX_SPEED

    def action(self, action: np.ndarray) -> np.ndarray:
        """:param action: The expert's action in ``[-1, 1]^2``.
        :return: The env's action, its speed in ``[min_speed / MAX_SPEED, 1]``.
        """
        speed = self.low + (1.0 - self.low) * (np.clip(action[0], -1.0, 1.0) + 1.0) / 2.0
        return np.array([speed, action[1]], dtype=np.float32)


class GoalRelativeObservation(gym.ObservationWrapper):
    """Replace the raw observation by :func:`goal_relative_features`; used only to train the expert.

    :param env: A navigation environment (possibly wrapped).
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(6,), dtype=np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        """:param observation: Raw observation.
        :return: Goal-relative features for the current episode's goal.
        """
        return goal_relative_features(observation, self.unwrapped.episode_goal)


def rollout(env: gym.Env, act: Callable[[np.ndarray], np.ndarray], seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Run one full episode from the default start region.

    :param env: The registered (time-limited) navigation environment with raw observations.
    :param act: Maps a raw observation to an action.
    :param seed: Reset seed.
    :return: The episode's observations, shape ``(T + 1, 12)``, its actions ``(T, 2)`` and its undiscounted return.
    """
    obs, _ = env.reset(seed=seed)
    observations: list[np.ndarray] = [obs]
    actions: list[np.ndarray] = []
    episode_return = 0.0
    done = False
    while not done:
        actions.append(np.asarray(act(obs), dtype=np.float32))
        obs, reward, terminated, truncated, _ = env.step(actions[-1])
        observations.append(obs)
        episode_return += float(reward)
        done = terminated or truncated
    return np.stack(observations), np.stack(actions), episode_return


def make_expert_policy(model: PPO, env: gym.Env, min_speed: float | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """Wrap the trained model as a deterministic policy on raw observations.

    :param model: PPO model trained on :class:`GoalRelativeObservation` features.
    :param env: The environment whose current goal the features are relative to.
    :param min_speed: The :class:`MinimumSpeed` the expert was trained with, if any.
    :return: A function mapping a raw observation to the env's action.
    """
    to_env = MinimumSpeed(env, min_speed).action if min_speed is not None else (lambda action: action)

    def act(obs: np.ndarray) -> np.ndarray:
        action, _ = model.predict(goal_relative_features(obs, env.unwrapped.episode_goal), deterministic=True)
        return to_env(action)

    return act


def train_expert(timesteps: int, seed: int, n_envs: int, min_speed: float | None = None) -> tuple[PPO, float]:
    """Train the PPO expert on the known reward.

    :param timesteps: Environment steps to train for.
    :param seed: Training seed.
    :param n_envs: Number of vectorised environments.
    :param min_speed: The lowest target speed the expert may choose (m/s), or ``None``.
    :return: The trained model and the wall-clock training time in seconds.
    """

    def make_env() -> gym.Env:
        env = gym.make(ENV_ID)
        return env if min_speed is None else MinimumSpeed(env, min_speed)

    # A factory rather than the id: make_vec_env would otherwise request an unsupported rgb_array render mode.
    venv = make_vec_env(make_env, n_envs=n_envs, seed=seed, wrapper_class=GoalRelativeObservation)
    # Per-step rewards reach ~14, so normalise returns for stable value learning; features are already scaled.
    venv = VecNormalize(venv, norm_obs=False, norm_reward=True, gamma=0.99)
    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=512,
        batch_size=128,
        gamma=0.99,
        gae_lambda=0.95,
        learning_rate=3e-4,
        seed=seed,
        verbose=0,
    )
    start = time.perf_counter()
    model.learn(total_timesteps=timesteps)
    return model, time.perf_counter() - start


def evaluate(env: gym.Env, act: Callable[[np.ndarray], np.ndarray]) -> dict[str, float]:
    """Mean and standard deviation of the return over ``N_EVAL_EPISODES`` seeded episodes.

    :param env: The registered navigation environment.
    :param act: Policy on raw observations.
    :return: ``{"mean": ..., "std": ...}``.
    """
    returns = [rollout(env, act, EVAL_SEED_BASE + i)[2] for i in range(N_EVAL_EPISODES)]
    return {"mean": float(np.mean(returns)), "std": float(np.std(returns))}


def main() -> None:
    """Train, evaluate, and write the demonstration files and summary."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--timesteps", type=int, default=300_000, help="PPO training steps")
    parser.add_argument("--seed", type=int, default=0, help="training seed")
    parser.add_argument("--n-envs", type=int, default=4, help="vectorised training environments")
    parser.add_argument("--out-dir", default=str(SHIPPED_DEMO_DIR), help="where the .npz demos and <name>.json go")
    parser.add_argument("--actions-dir", default=str(ACTION_DEMO_DIR), help="where the expert-action twins go")
    parser.add_argument("--model-path", default=None, help="expert model (default /tmp/<name>_expert_ppo.zip)")
    parser.add_argument("--min-speed", type=float, default=None, help="lowest target speed of the expert (m/s)")
    parser.add_argument("--name", default="navigation", help="file names: <name>_<n>.npz and <name>.json")
    args = parser.parse_args()

    # The machine's few CPU cores are shared; extra torch threads only add contention for this small MLP.
    torch.set_num_threads(1)
    model, train_seconds = train_expert(args.timesteps, args.seed, args.n_envs, args.min_speed)
    model.save(args.model_path or f"/tmp/{args.name}_expert_ppo.zip")

    env = gym.make(ENV_ID)
    expert = make_expert_policy(model, env, args.min_speed)
    expert_stats = evaluate(env, expert)
    # Seeded so the random baseline is reproducible too.
    env.action_space.seed(args.seed)
    random_stats = evaluate(env, lambda _obs: env.action_space.sample())

    demos = [rollout(env, expert, DEMO_SEED_BASE + i) for i in range(max(DEMO_COUNTS))]
    demo_obs = np.stack([obs for obs, _, _ in demos]).astype(np.float32)
    demo_actions = np.stack([actions for _, actions, _ in demos])
    os.makedirs(args.out_dir, exist_ok=True)
    os.makedirs(args.actions_dir, exist_ok=True)
    for n_demos in DEMO_COUNTS:
        # Nested subsets: the first n of the 16 demonstrations; the action-labelled twins are for BC only.
        np.savez_compressed(os.path.join(args.out_dir, f"{args.name}_{n_demos}.npz"), obs=demo_obs[:n_demos])
        labelled = os.path.join(args.actions_dir, f"{args.name}_{n_demos}_actions.npz")
        np.savez_compressed(labelled, obs=demo_obs[:n_demos], acts=demo_actions[:n_demos])

    summary = {
        "env_id": ENV_ID,
        "expert_algo": "PPO",
        "expert_timesteps": args.timesteps,
        "expert_min_speed": args.min_speed,
        "expert_return_mean": expert_stats["mean"],
        "expert_return_std": expert_stats["std"],
        "random_return_mean": random_stats["mean"],
        "random_return_std": random_stats["std"],
        "n_eval_episodes": N_EVAL_EPISODES,
        "demo_return_mean": float(np.mean([ret for _, _, ret in demos])),
        "command": "python demos/make_navigation_demos.py"
        + ("" if args.min_speed is None else f" --min-speed {args.min_speed} --name {args.name}"),
        "train_seconds": round(train_seconds, 1),
    }
    with open(os.path.join(args.out_dir, f"{args.name}.json"), "w") as file:
        json.dump(summary, file, indent=2)
        file.write("\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
