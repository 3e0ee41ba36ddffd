"""
A closed track for the navigation car, its lap driver and the cross-track error, for the single noisy, partially
observed demo scenario (the paper's real-sim-real experiment in simulation).

The track is a circle of :data:`TRACK_RADIUS` through the origin, centred at ``(0, TRACK_RADIUS)``, driven
counter-clockwise from the navigation env's default start (near the origin, heading about +x): one lap at 1 m/s
takes :data:`LAP_STEPS` (240) steps of 0.1 s. ``sb3_mpail/NavigationLap-v0`` is the navigation env cut at 240 steps
(:class:`NavigationLapEnv`, whose picture draws the track).
The demo records only :data:`DEMO_FEATURES` of the observation (position and body-frame velocity) with sensor noise.
"""

import math
from typing import Any, Callable, Dict, Optional

import gymnasium as gym
import numpy as np

from sb3_mpail.envs.navigation import MAX_SPEED, MAX_STEER, WHEELBASE, NavigationEnv

LAP_STEPS = 240
LAP_SPEED = 1.0  # m/s
TRACK_RADIUS = LAP_SPEED * LAP_STEPS * 0.1 / (2 * math.pi)  # m, one lap in LAP_STEPS steps at LAP_SPEED
DEMO_FEATURES = (0, 1, 6, 7)  # x, y, body-frame vx, vy
LOOKAHEAD = 0.5  # m, pure-pursuit lookahead of the lap driver


def track_points(n_points: int = LAP_STEPS) -> np.ndarray:
    """
    The track, counter-clockwise from the origin and closed (its last point is its first).

    :param n_points: points around the circle
    :return: ``(n_points + 1, 2)`` positions ``(x, y)`` in metres
    """
    angles = np.linspace(-math.pi / 2, 3 * math.pi / 2, n_points + 1)
    return np.stack((TRACK_RADIUS * np.cos(angles), TRACK_RADIUS * (1.0 + np.sin(angles))), axis=-1)


class NavigationLapEnv(NavigationEnv):
    """
    The navigation env for the lap (``sb3_mpail/NavigationLap-v0``): the same car, start, observation and reward;
    its ``rgb_array`` picture draws the track (the default reference path) and no goal.

    :param render_mode: ``None`` or ``"rgb_array"``
    :param reference_paths: polylines to draw (default: the track, :func:`track_points`)
    :param kwargs: :class:`~sb3_mpail.envs.navigation.NavigationEnv`'s other parameters
    """

    render_goal = False

    def __init__(self, render_mode: Optional[str] = None, reference_paths: Optional[Any] = None, **kwargs: Any):
        paths = [track_points()] if reference_paths is None else reference_paths
        super().__init__(render_mode=render_mode, reference_paths=paths, **kwargs)


def lap_driver(observation: np.ndarray) -> np.ndarray:
    """
    The scripted expert: pure pursuit of a point :data:`LOOKAHEAD` ahead on the circle, at :data:`LAP_SPEED`.

    :param observation: the navigation env's 12-D observation
    :return: the normalised ``[speed, steering]`` action
    """
    x, y, yaw = float(observation[0]), float(observation[1]) - TRACK_RADIUS, float(observation[5])
    angle = math.atan2(y, x) + LOOKAHEAD / TRACK_RADIUS  # counter-clockwise, ahead of the car's projection
    target_x, target_y = TRACK_RADIUS * math.cos(angle), TRACK_RADIUS * math.sin(angle)
    bearing = math.atan2(target_y - y, target_x - x) - yaw
    distance = math.hypot(target_x - x, target_y - y)
    steer = math.atan2(2 * WHEELBASE * math.sin(bearing), distance)
    return np.array([LAP_SPEED / MAX_SPEED, np.clip(steer / MAX_STEER, -1.0, 1.0)], dtype=np.float32)


def cross_track_errors(positions: np.ndarray, path: np.ndarray) -> np.ndarray:
    """
    Distance from each position to the nearest point of a path (a polyline through its points, closed).

    :param positions: ``(n, 2)`` positions
    :param path: ``(m, 2)`` points of the path, in driving order
    :return: ``(n,)`` distances
    """
    starts, ends = path, np.roll(path, -1, axis=0)
    segments = ends - starts
    lengths = np.maximum((segments**2).sum(1), 1e-12)
    offsets = positions[:, None, :] - starts[None]
    along = np.clip((offsets * segments[None]).sum(-1) / lengths[None], 0.0, 1.0)
    nearest = starts[None] + along[..., None] * segments[None]
    return np.sqrt(((positions[:, None, :] - nearest) ** 2).sum(-1)).min(1)


def lap_metrics(
    policy: Callable[[np.ndarray, bool], np.ndarray], path: np.ndarray, n_laps: int, seed: int
) -> Dict[str, float]:
    """
    Drives ``n_laps`` episodes of ``sb3_mpail/NavigationLap-v0`` (reset seeds ``seed``, ``seed + 1``, ...) and
    measures them against a path.

    :param policy: ``policy(observation, episode_start) -> action`` for one env
    :param path: ``(m, 2)`` points of the reference path (e.g. the demo's recorded positions)
    :param n_laps: episodes driven
    :param seed: reset seed of the first episode
    :return: ``cte_mean`` and ``cte_max`` (m, over every step of every lap) and ``speed`` (m/s, mean planar speed)
    """
    env = gym.make("sb3_mpail/NavigationLap-v0")
    errors, speeds = [], []
    for lap in range(n_laps):
        observation, _ = env.reset(seed=seed + lap)
        start, done = True, False
        while not done:
            observation, _, terminated, truncated, _ = env.step(policy(observation, start))
            start, done = False, terminated or truncated
            errors.append(cross_track_errors(observation[None, :2], path)[0])
            speeds.append(math.hypot(observation[6], observation[7]))
    env.close()
    return {"cte_mean": float(np.mean(errors)), "cte_max": float(np.max(errors)), "speed": float(np.mean(speeds))}
