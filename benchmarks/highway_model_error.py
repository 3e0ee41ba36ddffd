"""
How far the planning models of the highway-env road scenarios are from highway-env's simulator:
:class:`sb3_mpail.mppi.RacetrackKinematics` on ``sb3_mpail/Racetrack-v0`` (steering) and
:class:`sb3_mpail.mppi.HighwayKinematics` on ``sb3_mpail/Highway-v0`` (acceleration and steering), under uniformly
random actions (episodes restarted when they end):

- one step: for every step, the largest absolute error over the 6 observation values (``[x/10, y/10, vx/10, vy/10,
  cos h, sin h]``) and the position error in metres; the model in float64 on the simulator's float64 observation,
  and in float32 on the float32 observation MPAIL plans on (against the float64 truth);
- over a plan: the position error after ``--horizon`` steps of the batched roll-out the planner uses (float32),
  from each step's state along the recorded actions.

Run: ``python -m benchmarks.highway_model_error racetrack`` (or ``highway``; ``--steps 1000 --horizon 10 --seed 0``;
needs the ``scenarios`` extra); writes the ``<scenario>_model`` section of BENCHMARKS.md.
"""

import argparse
from typing import Dict, NamedTuple, Type

import gymnasium as gym
import numpy as np
import torch as th

import sb3_mpail.envs  # noqa: F401  (registers the road scenarios)
from benchmarks.report import machine_description, write_section
from sb3_mpail.envs.highway_roads import EGO_SCALES
from sb3_mpail.mppi import HighwayKinematics, ParkingKinematics, RacetrackKinematics


class RoadModel(NamedTuple):
    """
    A road scenario and its planning model.

    :param env_id: registered env id
    :param model_class: its planning model
    :param description: what the model is, for BENCHMARKS.md
    """

    env_id: str
    model_class: Type[ParkingKinematics]
    description: str


ROAD_MODELS = {
    "racetrack": RoadModel(
        "sb3_mpail/Racetrack-v0", RacetrackKinematics, "steering only, so no acceleration; random steering"
    ),
    "highway": RoadModel(
        "sb3_mpail/Highway-v0", HighwayKinematics, "acceleration and steering, speed limited to 40 m/s; random actions"
    ),
}


def measure(road: RoadModel, n_steps: int, horizon: int, seed: int) -> Dict[str, np.ndarray]:
    """
    Prediction errors of a road model over ``n_steps`` random-action steps.

    :param road: the scenario and its model
    :param n_steps: number of environment steps
    :param horizon: steps of the open-loop roll-outs
    :param seed: seed of the environment and of the actions
    :return: per step, ``error64`` and ``error32`` (largest absolute one-step error over the observation, in
        observation units), ``position_error`` (one step, metres, float64) and, per roll-out that stays within one
        episode, ``horizon_position_error`` (metres, float32)
    """
    env = gym.make(road.env_id, dtype=np.float64)
    model = road.model_class()
    rng = np.random.default_rng(seed)
    observation, _ = env.reset(seed=seed)
    results: Dict[str, list] = {"error64": [], "error32": [], "position_error": [], "horizon_position_error": []}
    episode_observations, episode_actions = [observation], []
    for _ in range(n_steps):
        action = rng.uniform(-1, 1, size=env.action_space.shape).astype(np.float32)
        with th.no_grad():
            predicted64 = model(th.as_tensor(observation[None]), th.as_tensor(action[None], dtype=th.float64))[0].numpy()
            predicted32 = model(th.as_tensor(observation[None], dtype=th.float32), th.as_tensor(action[None]))[0].numpy()
        observation, _, terminated, truncated, _ = env.step(action)
        results["error64"].append(np.abs(predicted64 - observation).max())
        results["error32"].append(np.abs(predicted32.astype(np.float64) - observation).max())
        results["position_error"].append(EGO_SCALES[0] * np.hypot(*(predicted64[:2] - observation[:2])))
        episode_observations.append(observation)
        episode_actions.append(action)
        if terminated or truncated:
            results["horizon_position_error"].extend(horizon_errors(model, episode_observations, episode_actions, horizon))
            observation, _ = env.reset()
            episode_observations, episode_actions = [observation], []
    results["horizon_position_error"].extend(horizon_errors(model, episode_observations, episode_actions, horizon))
    env.close()
    return {key: np.array(values) for key, values in results.items()}


def horizon_errors(model: ParkingKinematics, observations: list, actions: list, horizon: int) -> np.ndarray:
    """
    Position errors (metres) after ``horizon`` steps of the model's float32 roll-out from every state of one episode
    that has ``horizon`` recorded actions after it.

    :param model: the planning model
    :param observations: the episode's float64 observations, one more than ``actions``
    :param actions: the executed actions
    :param horizon: roll-out length
    """
    n_starts = len(actions) - horizon + 1
    if n_starts <= 0:
        return np.empty(0)
    states = th.as_tensor(np.array(observations[:n_starts]), dtype=th.float32)
    sequences = th.as_tensor(np.array([actions[start : start + horizon] for start in range(n_starts)]))
    with th.no_grad():
        # one "env" per start state, one sample each: (horizon, n_starts, 1, action_dim)
        predicted = model.rollout(states, sequences.transpose(0, 1).unsqueeze(2))[-1, :, 0].double().numpy()
    truth = np.array(observations[horizon : horizon + n_starts])
    return EGO_SCALES[0] * np.hypot(*(predicted[:, :2] - truth[:, :2]).T)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario", choices=sorted(ROAD_MODELS))
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--horizon", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-write", action="store_true", help="print only; leave BENCHMARKS.md alone")
    args = parser.parse_args()
    th.set_num_threads(1)
    road = ROAD_MODELS[args.scenario]
    results = measure(road, args.steps, args.horizon, args.seed)
    columns = {
        "one step, float64": results["error64"],
        "one step, float32": results["error32"],
        "one-step position error (m)": results["position_error"],
        f"position error after {args.horizon} steps (m)": results["horizon_position_error"],
    }
    header = " | ".join(f"{title}, mean / max" for title in columns)
    row = " | ".join(f"{errors.mean():.2e} / {errors.max():.2e}" for errors in columns.values())
    command = (
        f"python -m benchmarks.highway_model_error {args.scenario} --steps {args.steps} --horizon {args.horizon} "
        f"--seed {args.seed}"
    )
    markdown = f"""## {road.env_id} planning model (highway-env)

Prediction error of `{road.model_class.__name__}` (highway-env 1.9.1's kinematic bicycle: slip angle
`arctan(tan(delta) / 2)`, length 5 m, 3 Euler steps of 1/15 s per action; {road.description}) against the simulator
on `{road.env_id}` (no other vehicles, ego observation `[x/10, y/10, vx/10, vy/10, cos h, sin h]`), over
{args.steps} steps (episodes restarted when they end). One step: the largest absolute error over the 6 observation
values, in observation units, and the position error in metres (float64); float64: model and observation in float64;
float32: the model in float32 on the float32 observation MPAIL plans on, against the float64 truth. Over a plan: the
position error after {args.horizon} steps of the float32 batched roll-out the planner uses, from
{len(results["horizon_position_error"])} start states.

| {header} |
|---|---|---|---|
| {row} |

The model is highway-env's own integration, so the float64 error is rounding; the float32 error comes from the
observation's float32 storage and the model's float32 arithmetic. Nothing on the road is unmodelled once the other
vehicles are removed (off the road the car drives on; only the reward drops to 0).

Command: `{command}` on {machine_description()}.
"""
    print(markdown)
    if not args.no_write:
        write_section(f"{args.scenario}_model", markdown)


if __name__ == "__main__":
    main()
