"""Generate observation-only demonstrations for ``sb3_mpail/HighwayTraffic-v0`` with highway-env's IDM/MOBIL driver.

No SB3 expert is trained (the 2-core CPU is shared): the expert is highway-env's own driver model, the one its other
vehicles follow, ``IDMVehicle`` (IDM for the speed, here towards 30 m/s, the top of highway-fast's rewarded range;
MOBIL for lane changes). At every step an ``IDMVehicle`` at the ego's state, put on the road in the ego's place, decides
as it would in the simulation (its lane-change timer and target lane carried from step to step); its acceleration and
steering, normalised by the action's ``5 m/s^2`` and ``pi/4`` rad and clipped to ``[-1, 1]``, drive the ego through
the env's own continuous action. highway-fast simulates one step per 5 Hz action, so that is exactly what the
``IDMVehicle`` would do but for the clipping (it may ask for up to ``6 m/s^2`` and ``pi/3`` rad).

It scores the driver and a uniform-random policy on ``--eval-episodes`` seeded episodes each (return, share of
episodes that end in a crash, mean speed), in highway-fast's traffic and in ``highway-v0``'s
(``sb3_mpail/HighwayTrafficDense-v0``: 4 lanes, 50 vehicles; the ``dense_`` figures), then records ``--n-demos``
collision-free episodes (reset seeds 1000, 1001, ...; the seeds of episodes that crashed are listed in the metadata
and skipped), keeps only the observations and writes ``<out-dir>/highway_traffic_<n>.npz`` and
``<out-dir>/highway_traffic.json``. Needs the ``scenarios`` extra.

Run from the repository root::

    python demos/make_highway_traffic_demos.py --n-demos 16 --eval-episodes 10
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple, Optional

import gymnasium as gym
import numpy as np
from expert_rollouts import DEMO_SEED_OFFSET, SHIPPED_DEMO_DIR, save_demos, save_metadata

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/HighwayTraffic-v0)

ENV_ID = "sb3_mpail/HighwayTraffic-v0"
DENSE_ENV_ID = "sb3_mpail/HighwayTrafficDense-v0"
MAX_ACCELERATION = 5.0  # highway-env's acceleration for an action of 1
MAX_STEERING = np.pi / 4  # and its steering
TARGET_SPEED = 30.0  # m/s: highway-fast's speed reward is highest from 30 m/s, its lanes' speed limit


class IdmMobilDriver:
    """
    highway-env's ``IDMVehicle`` deciding for the ego of a traffic env (see the module docstring).

    :param env: the traffic env (wrappers are looked through)
    :param target_speed: the IDM's desired speed (m/s)
    """

    def __init__(self, env: gym.Env, target_speed: float = TARGET_SPEED):
        from highway_env.vehicle.behavior import IDMVehicle

        self.env = env.unwrapped
        self.vehicle_class = IDMVehicle
        self.target_speed = target_speed
        self.driver: Optional[Any] = None

    def reset(self) -> None:
        """Forgets the last episode's driver (its target lane and lane-change timer)."""
        self.driver = None

    def __call__(self) -> np.ndarray:
        """:return: the normalised ``[acceleration, steering]`` the driver chooses in the env's current state"""
        road_env = self.env.road_env
        ego, road = road_env.vehicle, road_env.road
        if self.driver is None:
            self.driver = self.vehicle_class(road, ego.position.copy(), ego.heading, ego.speed, target_speed=self.target_speed)
        else:
            self.driver.position, self.driver.heading, self.driver.speed = ego.position.copy(), ego.heading, ego.speed
            self.driver.on_state_update()  # its lane, from the new position
        # in the ego's place, so that its neighbours are the ego's and it does not see the ego as one of them
        index = road.vehicles.index(ego)
        road.vehicles[index] = self.driver
        try:
            self.driver.act()
        finally:
            road.vehicles[index] = ego
        self.driver.timer += self.env.simulation_dt * self.env.substeps  # as IDMVehicle.step counts it over the action
        action = [self.driver.action["acceleration"] / MAX_ACCELERATION, self.driver.action["steering"] / MAX_STEERING]
        return np.clip(action, -1.0, 1.0).astype(np.float32)


class Episode(NamedTuple):
    """One episode: its observations (the final one included), return, whether it ended in a crash, its speeds (m/s)."""

    observations: np.ndarray
    episode_return: float
    crashed: bool
    speeds: list[float]


def run_episode(env: gym.Env, seed: int, policy: Optional[Callable[[], np.ndarray]]) -> Episode:
    """
    One episode from ``env.reset(seed=seed)``.

    :param env: the traffic env
    :param seed: reset seed (and the random policy's)
    :param policy: the driver, or ``None`` for uniform-random actions
    """
    observation, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    if policy is not None:
        policy.reset()
    observations, episode_return, speeds = [observation], 0.0, []
    while True:
        action = env.action_space.sample() if policy is None else policy()
        observation, reward, terminated, truncated, info = env.step(action)
        observations.append(observation)
        episode_return += float(reward)
        speeds.append(float(info["speed"]))
        if terminated or truncated:
            return Episode(np.asarray(observations, dtype=np.float32), episode_return, bool(info["crashed"]), speeds)


def figures(episodes: list[Episode], prefix: str) -> dict[str, float]:
    """Mean and standard deviation of the returns, share of episodes ending in a crash and mean speed over every step."""
    returns = [episode.episode_return for episode in episodes]
    return {
        f"{prefix}_return_mean": float(np.mean(returns)),
        f"{prefix}_return_std": float(np.std(returns)),
        f"{prefix}_crash_rate": float(np.mean([episode.crashed for episode in episodes])),
        f"{prefix}_speed_mean": float(np.mean([speed for episode in episodes for speed in episode.speeds])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0, help="reset seed of the first evaluation episode")
    parser.add_argument("--out-dir", type=Path, default=SHIPPED_DEMO_DIR, help="output folder for the .npz and .json files")
    parser.add_argument("--n-demos", type=int, default=16, help="number of collision-free demonstrations to record")
    parser.add_argument("--eval-episodes", type=int, default=10, help="episodes scoring the driver and the random policy")
    args = parser.parse_args()
    start = time.perf_counter()
    env = gym.make(ENV_ID)
    driver = IdmMobilDriver(env)
    eval_seeds = range(args.seed, args.seed + args.eval_episodes)
    expert_runs = [run_episode(env, seed, driver) for seed in eval_seeds]
    random_runs = [run_episode(env, seed, None) for seed in eval_seeds]
    dense_env = gym.make(DENSE_ENV_ID)
    dense_driver = IdmMobilDriver(dense_env)
    dense_expert_runs = [run_episode(dense_env, seed, dense_driver) for seed in eval_seeds]
    dense_random_runs = [run_episode(dense_env, seed, None) for seed in eval_seeds]
    dense_env.close()
    demos: list[Episode] = []
    failed_demo_seeds: list[int] = []
    seed = DEMO_SEED_OFFSET
    while len(demos) < args.n_demos:
        run = run_episode(env, seed, driver)
        if run.crashed:
            failed_demo_seeds.append(seed)
        else:
            demos.append(run)
        seed += 1
    env.close()
    args.out_dir.mkdir(parents=True, exist_ok=True)
    npz_path = args.out_dir / f"highway_traffic_{args.n_demos}.npz"
    shape = save_demos([run.observations for run in demos], npz_path)
    print(f"saved demos {shape} to {npz_path}")
    meta: dict[str, Any] = {
        "env_id": ENV_ID,
        "expert_algo": f"highway-env's IDM/MOBIL driver (IDMVehicle, target speed {TARGET_SPEED:g} m/s) through the "
        "continuous action",
        "seed": args.seed,
        **figures(expert_runs, "expert"),
        **figures(random_runs, "random"),
        **figures(dense_expert_runs, "dense_expert"),
        **figures(dense_random_runs, "dense_random"),
        "n_eval_episodes": args.eval_episodes,
        "demo_returns": [run.episode_return for run in demos],
        "demo_speed_mean": figures(demos, "demo")["demo_speed_mean"],
        # the recorded episodes' crash rate: the dropped ones among all that were driven
        "demo_crash_rate": len(failed_demo_seeds) / (len(failed_demo_seeds) + len(demos)),
        "failed_demo_seeds": failed_demo_seeds,
        "demo_lengths": [len(run.observations) - 1 for run in demos],
        "command": f"python demos/make_highway_traffic_demos.py --n-demos {args.n_demos} --eval-episodes "
        f"{args.eval_episodes} --seed {args.seed}",
        "seconds": round(time.perf_counter() - start, 1),
    }
    save_metadata(meta, args.out_dir / "highway_traffic.json")
    print({key: value for key, value in meta.items() if key not in ("demo_returns", "demo_lengths")})


if __name__ == "__main__":
    main()
