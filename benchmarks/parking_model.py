"""
How far :class:`sb3_mpail.mppi.ParkingKinematics`'s one-step prediction is from highway-env's simulator on
``sb3_mpail/Parking-v0``: uniformly random actions, episodes restarted when they end, and for every step the largest
absolute error over the 12 observation values (ego ``[x/100, y/100, vx/5, vy/5, cos h, sin h]`` and the goal),
separately for steps on which the car crashed (highway-env then pushes it out of the obstacle, which the model does
not know about). The model runs in float64 on the simulator's float64 observation, and in float32 on the float32
observation MPAIL plans on.

It also times, in the same run, what a training step costs: env steps per second with highway-env's pandas
observation and with the env's numpy one (same values), and the planner's roll-out of sampled sequences step by step
and batched (:meth:`~sb3_mpail.mppi.ParkingKinematics.rollout`), alternating the two in each of ``--rounds`` rounds.

Run: ``python -m benchmarks.parking_model`` (``--steps 1000 --seed 0``; needs the ``scenarios`` extra); writes the
``parking_model`` section of BENCHMARKS.md.
"""

import argparse
import time
from typing import Callable, Dict, Tuple

import gymnasium as gym
import numpy as np
import torch as th

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Parking-v0)
from benchmarks.report import machine_description, write_section
from sb3_mpail.mppi import ParkingKinematics
from sb3_mpail.mppi.reference import rollout as rollout_step_by_step


def measure(n_steps: int, seed: int) -> Dict[str, np.ndarray]:
    """
    One-step prediction errors of the parking model over ``n_steps`` random-action steps.

    :param n_steps: number of environment steps
    :param seed: seed of the environment and of the actions
    :return: per step, ``error64`` and ``error32`` (largest absolute error over the observation in float64 and
        float32), ``position_error`` (metres, float64) and ``crashed``
    """
    env = gym.make("sb3_mpail/Parking-v0", dtype=np.float64)
    model = ParkingKinematics()
    rng = np.random.default_rng(seed)
    observation, _ = env.reset(seed=seed)
    results: Dict[str, list] = {"error64": [], "error32": [], "position_error": [], "crashed": []}
    for _ in range(n_steps):
        action = rng.uniform(-1, 1, size=2).astype(np.float32)
        with th.no_grad():
            predicted64 = model(th.as_tensor(observation[None]), th.as_tensor(action[None], dtype=th.float64))[0].numpy()
            predicted32 = model(th.as_tensor(observation[None], dtype=th.float32), th.as_tensor(action[None]))[0].numpy()
        next_observation, _, terminated, truncated, info = env.step(action)
        results["error64"].append(np.abs(predicted64 - next_observation).max())
        results["error32"].append(np.abs(predicted32.astype(np.float64) - next_observation).max())
        results["position_error"].append(100.0 * np.hypot(*(predicted64[:2] - next_observation[:2])))
        results["crashed"].append(bool(info["crashed"]))
        observation = next_observation
        if terminated or truncated:
            observation, _ = env.reset()
    env.close()
    return {key: np.array(values) for key, values in results.items()}


def seconds_each(first: Callable[[], None], second: Callable[[], None], rounds: int) -> Tuple[float, float]:
    """Total seconds of ``first`` and ``second`` over ``rounds`` alternating calls (both see the same machine load)."""
    totals = [0.0, 0.0]
    for _ in range(rounds):
        for index, function in enumerate((first, second)):
            start = time.perf_counter()
            function()
            totals[index] += time.perf_counter() - start
    return totals[0], totals[1]


def env_steps_per_second(n_steps: int, seed: int, rounds: int) -> Tuple[float, float]:
    """Random-action steps per second of ``sb3_mpail/Parking-v0`` with highway-env's observation and the numpy one."""

    def stepper(numpy_observation: bool) -> Callable[[], None]:
        env = gym.make("sb3_mpail/Parking-v0", numpy_observation=numpy_observation)
        env.reset(seed=seed)
        env.action_space.seed(seed)

        def run() -> None:
            for _ in range(n_steps):
                _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                if terminated or truncated:
                    env.reset()

        return run

    pandas_seconds, numpy_seconds = seconds_each(stepper(False), stepper(True), rounds)
    return rounds * n_steps / pandas_seconds, rounds * n_steps / numpy_seconds


def rollout_milliseconds(n_envs: int, n_samples: int, horizon: int, rounds: int) -> Tuple[float, float]:
    """Milliseconds per float32 roll-out of ``n_envs x n_samples`` random sequences, step by step and batched."""
    model = ParkingKinematics()
    generator = th.Generator().manual_seed(0)
    states = th.zeros(n_envs, 12)
    states[:, 4] = 1.0  # heading 0, at rest
    actions = th.rand(horizon, n_envs, n_samples, 2, generator=generator) * 2 - 1
    calls = 20

    def repeat(function: Callable[[], th.Tensor]) -> Callable[[], None]:
        def run() -> None:
            with th.no_grad():
                for _ in range(calls):
                    function()

        return run

    step_by_step, batched = seconds_each(
        repeat(lambda: rollout_step_by_step(model, states, actions)), repeat(lambda: model.rollout(states, actions)), rounds
    )
    return 1e3 * step_by_step / (rounds * calls), 1e3 * batched / (rounds * calls)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds of each speed measurement")
    parser.add_argument("--speed-steps", type=int, default=300, help="env steps per round of the env speed measurement")
    parser.add_argument("--no-write", action="store_true", help="print only; leave BENCHMARKS.md alone")
    args = parser.parse_args()
    th.set_num_threads(1)
    results = measure(args.steps, args.seed)
    crashed = results["crashed"]
    free = ~crashed

    def row(label: str, mask: np.ndarray) -> str:
        if not mask.any():
            return f"| {label} | 0 | - | - | - | - | - |"
        e64, e32, position = results["error64"][mask], results["error32"][mask], results["position_error"][mask]
        return (
            f"| {label} | {mask.sum()} | {e64.mean():.2e} | {e64.max():.2e} | {e32.mean():.2e} | {e32.max():.2e} "
            f"| {position.mean():.3g} / {position.max():.3g} |"
        )

    pandas_speed, numpy_speed = env_steps_per_second(args.speed_steps, args.seed, args.rounds)
    rollout_shape = dict(n_envs=4, n_samples=256, horizon=15)  # the zoo entry's planner
    step_by_step_ms, batched_ms = rollout_milliseconds(**rollout_shape, rounds=args.rounds)
    env_row = (
        f"| env steps/s, random actions ({args.speed_steps} per round): highway-env's pandas observation / numpy observation "
        f"| {pandas_speed:.0f} | {numpy_speed:.0f} | {numpy_speed / pandas_speed:.2f} |"
    )
    rollout_row = (
        f"| roll-out ms, float32, {rollout_shape['n_envs']} envs x {rollout_shape['n_samples']} samples x "
        f"{rollout_shape['horizon']} steps: step by step / batched "
        f"| {step_by_step_ms:.2f} | {batched_ms:.2f} | {step_by_step_ms / batched_ms:.2f} |"
    )
    command = (
        f"python -m benchmarks.parking_model --steps {args.steps} --seed {args.seed} --rounds {args.rounds} "
        f"--speed-steps {args.speed_steps}"
    )
    markdown = f"""## Parking-v0 planning model (highway-env)

One-step prediction error of `ParkingKinematics` (highway-env 1.9.1's kinematic bicycle decoded from the
observation) against the simulator on `sb3_mpail/Parking-v0`, over {args.steps} steps of uniformly random actions
(episodes restarted when they end). Error: the largest absolute error over the 12 observation values (positions
/100, velocities /5, cos h, sin h, goal), in observation units; position error in metres. float64: model and
observation in float64; float32: the model in float32 on the float32 observation MPAIL plans on, against the
float64 truth.

| steps | count | float64 mean | float64 max | float32 mean | float32 max | position error mean / max (m) |
|---|---|---|---|---|---|---|
{row("no crash", free)}
{row("crash", crashed)}

On a crash step highway-env pushes the car out of the obstacle and the episode ends; the model knows nothing of
obstacles, so the planner needs a cost or a terminal state for them.

Speed, in the same run ({args.rounds} alternating rounds each, on a shared machine):

| | before | after | ratio |
|---|---|---|---|
{env_row}
{rollout_row}

Command: `{command}` on {machine_description()}.
"""
    print(markdown)
    if not args.no_write:
        write_section("parking_model", markdown)


if __name__ == "__main__":
    main()
