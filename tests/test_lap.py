"""The lap scenario: the closed track, its scripted driver, the cross-track error and the shipped noisy demo."""


import gymnasium as gym
import numpy as np
import pytest

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/NavigationLap-v0)
from sb3_mpail.demos import SHIPPED_DEMO_DIR, shipped_demo_info
from sb3_mpail.envs.lap import LAP_STEPS, TRACK_RADIUS, cross_track_errors, lap_driver, lap_metrics


def circle(n_points=720):
    angles = np.linspace(0, 2 * np.pi, n_points, endpoint=False)
    return np.stack([TRACK_RADIUS * np.sin(angles), TRACK_RADIUS * (1 - np.cos(angles))], axis=1)


def test_cross_track_error_is_the_distance_to_the_nearest_segment():
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    positions = np.array([[1.0, 0.5], [1.0, -0.3], [3.0, 3.0], [0.0, 1.0], [1.0, 1.0]])
    np.testing.assert_allclose(cross_track_errors(positions, square), [0.5, 0.3, np.sqrt(2), 0.0, 1.0])


def test_the_driver_completes_one_lap_of_the_track_in_240_steps():
    env = gym.make("sb3_mpail/NavigationLap-v0")
    observation, _ = env.reset(seed=0)
    positions, truncated, steps = [], False, 0
    while not truncated:
        observation, _, _, truncated, _ = env.step(lap_driver(observation))
        positions.append(observation[:2])
        steps += 1
    positions = np.array(positions)
    assert steps == LAP_STEPS
    assert cross_track_errors(positions, circle()).mean() < 0.05
    # it went all the way round: every quarter of the circle was visited, and it ends within 1 m of the start
    quarters = np.floor(np.arctan2(positions[:, 1] - TRACK_RADIUS, positions[:, 0]) / (np.pi / 2)) % 4
    assert set(quarters) == {0, 1, 2, 3}
    assert np.hypot(*positions[-1]) < 1.0


def test_lap_metrics_of_a_car_standing_still():
    figures = lap_metrics(lambda observation, start: np.zeros(2, np.float32), circle(), n_laps=2, seed=0)
    assert figures["speed"] == 0.0
    assert figures["cte_max"] < 0.5 * np.sqrt(2) + 1e-6  # it starts within the 1 x 1 m square around the origin


def test_shipped_demo_is_one_noisy_lap_of_position_and_body_velocity():
    meta = shipped_demo_info("lap")
    with np.load(SHIPPED_DEMO_DIR / "lap_1.npz") as data:
        demo = data["obs"]
    assert demo.shape == (1, LAP_STEPS + 1, 4)
    speed = np.hypot(demo[0, 1:, 2], demo[0, 1:, 3])
    assert speed[50:].mean() == pytest.approx(1.0, abs=0.05)
    errors = cross_track_errors(demo[0, :, :2], circle())
    assert 0 < np.median(errors) < 4 * meta["position_noise"]  # noisy, but on the track
    assert meta["driver_on_eval_laps"]["cte_mean"] < 0.1
