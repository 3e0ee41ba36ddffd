"""Generate observation-only demonstrations for the highway-env road scenarios with a scripted driver.

- ``racetrack`` (``sb3_mpail/Racetrack-v0``): keep to the closest lane round the track, steering only;
- ``highway`` (``sb3_mpail/Highway-v0``): move to the rightmost lane and drive at 30 m/s (highway-v0's reward is
  highest there), acceleration and steering.

No SB3 expert is trained (the 2-core CPU is shared; a scripted driver is cheaper and exact): the driver is
highway-env's own lane and speed control, ``ControlledVehicle.steering_control`` (proportional lateral and heading
control with a short pursuit) and ``speed_control`` (proportional), applied to the car decoded from the observation
and the road, its commands normalised by the action's ``pi/4`` rad and ``5 m/s^2`` and clipped to ``[-1, 1]``.

It evaluates the driver and a uniform-random policy on ``--eval-episodes`` seeded episodes each, records ``--n-demos``
episodes with the driver (episode ``i`` starts from ``reset(seed=1000 + i)``), keeps only the observations and writes
``<out-dir>/<scenario>_<n>.npz`` (``obs`` of shape ``(n, T + 1, 6)``) and ``<out-dir>/<scenario>.json``. Needs the
``scenarios`` extra.

Run from the repository root::

    python demos/make_racetrack_demos.py --n-demos 4 --eval-episodes 20
    python demos/make_racetrack_demos.py --scenario highway --n-demos 4 --eval-episodes 20
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any, NamedTuple, Optional

import gymnasium as gym
import numpy as np
from expert_rollouts import SHIPPED_DEMO_DIR, evaluate_expert, evaluate_random, record_demos, save_demos, save_metadata

import sb3_mpail.envs  # noqa: F401  (registers the road scenarios)
from sb3_mpail.envs.highway_roads import EGO_SCALES

DEFAULT_OUT_DIR = SHIPPED_DEMO_DIR
MAX_STEERING = np.pi / 4  # highway-env's steering for an action of 1
MAX_ACCELERATION = 5.0  # and its acceleration


class RoadScenario(NamedTuple):
    """
    What the driver does on one scenario.

    :param env_id: registered env id
    :param rightmost_lane: head for the rightmost lane (else keep to the closest one)
    :param target_speed: speed to hold in m/s; ``None``: the action is steering only
    """

    env_id: str
    rightmost_lane: bool
    target_speed: Optional[float]


SCENARIOS = {
    "racetrack": RoadScenario("sb3_mpail/Racetrack-v0", rightmost_lane=False, target_speed=None),
    "highway": RoadScenario("sb3_mpail/Highway-v0", rightmost_lane=True, target_speed=30.0),
}


class LaneKeepingDriver:
    """
    highway-env's lane and speed control, from the observation alone (with ``predict`` like an SB3 model, so the
    shared rollout helpers run it).

    :param scenario: what to drive
    """

    def __init__(self, scenario: RoadScenario):
        from highway_env.vehicle.controller import ControlledVehicle

        env = gym.make(scenario.env_id)
        env.reset(seed=0)
        self.road = env.unwrapped.road_env.road  # the same road in every episode
        self.vehicle_class = ControlledVehicle
        self.scenario = scenario

    def act(self, observation: np.ndarray) -> np.ndarray:
        """Normalised action for one observation ``[x/10, y/10, vx/10, vy/10, cos h, sin h]``."""
        x, y, vx, vy, cos_heading, sin_heading = observation.astype(np.float64) * EGO_SCALES
        car = self.vehicle_class(
            self.road, np.array([x, y]), np.arctan2(sin_heading, cos_heading), vx * cos_heading + vy * sin_heading
        )
        lane = self.road.network.all_side_lanes(car.lane_index)[-1] if self.scenario.rightmost_lane else car.lane_index
        action = [car.steering_control(lane) / MAX_STEERING]
        if self.scenario.target_speed is not None:
            action.insert(0, car.speed_control(self.scenario.target_speed) / MAX_ACCELERATION)
        return np.clip(action, -1.0, 1.0).astype(np.float32)

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        """:return: the action(s) for one observation or a batch, and no recurrent state"""
        actions = np.array([self.act(row) for row in np.atleast_2d(observation)])
        return (actions if observation.ndim == 2 else actions[0]), None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", choices=sorted(SCENARIOS), default="racetrack")
    parser.add_argument("--seed", type=int, default=0, help="seed of the evaluation episodes (driver: seed + 1, random: + 2)")
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT_DIR, help="output folder for the .npz and .json files")
    parser.add_argument("--n-demos", type=int, default=4, help="number of observation-only demonstrations to record")
    parser.add_argument("--eval-episodes", type=int, default=20, help="episodes scoring the driver and the random policy")
    args = parser.parse_args()
    scenario = SCENARIOS[args.scenario]
    start = time.perf_counter()
    driver = LaneKeepingDriver(scenario)
    expert_mean, expert_std = evaluate_expert(driver, scenario.env_id, seed=args.seed + 1, n_episodes=args.eval_episodes)
    random_mean, random_std = evaluate_random(scenario.env_id, seed=args.seed + 2, n_episodes=args.eval_episodes)
    print(f"driver return: {expert_mean:.1f} +/- {expert_std:.1f}; random return: {random_mean:.1f} +/- {random_std:.1f}")

    episodes, demo_returns = record_demos(driver, scenario.env_id, args.n_demos)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    npz_path = args.out_dir / f"{args.scenario}_{args.n_demos}.npz"
    shape = save_demos(episodes, npz_path)  # no crashes without other vehicles: every episode lasts the time limit
    print(f"saved demos {shape} to {npz_path}; demo returns: {demo_returns}")

    meta: dict[str, Any] = {
        "env_id": scenario.env_id,
        "expert_algo": "scripted highway-env lane "
        + ("and speed control" if scenario.target_speed is not None else "keeping")
        + " (ControlledVehicle)",
        "seed": args.seed,
        "expert_return_mean": expert_mean,
        "expert_return_std": expert_std,
        "random_return_mean": random_mean,
        "random_return_std": random_std,
        "n_eval_episodes": args.eval_episodes,
        "demo_returns": demo_returns,
        "command": f"python demos/make_racetrack_demos.py --scenario {args.scenario} --n-demos {args.n_demos} "
        f"--eval-episodes {args.eval_episodes} --seed {args.seed}",
        "seconds": round(time.perf_counter() - start, 1),
    }
    save_metadata(meta, args.out_dir / f"{args.scenario}.json")


if __name__ == "__main__":
    main()
