"""
Record the single noisy, partially observed demo of the lap scenario: ``lap_1.npz`` and ``lap.json`` in the
package's data folder (``sb3_mpail/data/``).

One lap (240 steps) of ``sb3_mpail/NavigationLap-v0`` driven by the scripted pure-pursuit driver
:func:`sb3_mpail.envs.lap.lap_driver` (the stand-in for the paper's human-driven lap), from ``reset(seed=1000)``.
Only position and body-frame velocity are kept (:data:`sb3_mpail.envs.lap.DEMO_FEATURES`), each with Gaussian
sensor noise (``--position-noise`` m, ``--velocity-noise`` m/s). ``obs`` has shape ``(1, 241, 4)``; train with
``demos_are_features=True`` and ``policy_kwargs=dict(discriminator_features=[0, 1, 6, 7])``.

The JSON file holds the noise levels and the driver's own figures on the benchmark's evaluation laps (cross-track
error to the recorded path, mean planar speed), the reference for MPAIL's. Run from the repository root::

    python demos/make_lap_demo.py
"""

import argparse
import json

import gymnasium as gym
import numpy as np
from expert_rollouts import SHIPPED_DEMO_DIR

from sb3_mpail.envs.lap import DEMO_FEATURES, LAP_STEPS, TRACK_RADIUS, lap_driver, lap_metrics

DEMO_SEED = 1000
EVAL_SEED = 10_000  # the reset seed of benchmarks/scenarios.py's first evaluation lap
N_EVAL_LAPS = 5
OUT_DIR = SHIPPED_DEMO_DIR


def record(position_noise: float, velocity_noise: float, seed: int) -> np.ndarray:
    """
    One noisy, partially observed lap.

    :param position_noise: std of the noise on x and y (m)
    :param velocity_noise: std of the noise on vx and vy (m/s)
    :param seed: seed of the noise
    :return: ``(LAP_STEPS + 1, 4)`` float32 features
    """
    env = gym.make("sb3_mpail/NavigationLap-v0")
    observation, _ = env.reset(seed=DEMO_SEED)
    observations = [observation]
    for _ in range(LAP_STEPS):
        observation, *_ = env.step(lap_driver(observation))
        observations.append(observation)
    features = np.array(observations)[:, list(DEMO_FEATURES)]
    noise_std = np.array([position_noise, position_noise, velocity_noise, velocity_noise])
    return (features + np.random.default_rng(seed).normal(size=features.shape) * noise_std).astype(np.float32)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--position-noise", type=float, default=0.05)
    parser.add_argument("--velocity-noise", type=float, default=0.05)
    parser.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    args = parser.parse_args()
    demo = record(args.position_noise, args.velocity_noise, args.seed)
    np.savez_compressed(OUT_DIR / "lap_1.npz", obs=demo[None])
    driver = lap_metrics(lambda observation, start: lap_driver(observation), demo[:, :2], N_EVAL_LAPS, EVAL_SEED)
    meta = {
        "env_id": "sb3_mpail/NavigationLap-v0",
        "expert": "sb3_mpail.envs.lap.lap_driver (pure pursuit, 1 m/s)",
        "track_radius": TRACK_RADIUS,
        "features": ["x", "y", "vx (body)", "vy (body)"],
        "position_noise": args.position_noise,
        "velocity_noise": args.velocity_noise,
        "noise_seed": args.seed,
        "demo_reset_seed": DEMO_SEED,
        "driver_on_eval_laps": {**driver, "n_laps": N_EVAL_LAPS, "first_reset_seed": EVAL_SEED},
        "command": "python demos/make_lap_demo.py",
    }
    (OUT_DIR / "lap.json").write_text(json.dumps(meta, indent=2) + "\n")
    print(json.dumps(meta, indent=2))


if __name__ == "__main__":
    main()
