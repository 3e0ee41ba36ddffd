"""
highway-env road scenarios with continuous steering for MPAIL, planned on the ego car's state. highway-env is an
optional dependency (the ``scenarios`` extra); making one of these environments without it raises an ImportError that
says what to install.

``sb3_mpail/Racetrack-v0`` is highway-env's ``racetrack-v0`` with the ego car's own state as a flat Box observation:
``[x/10, y/10, vx/10, vy/10, cos h, sin h]`` in the world frame (racetrack's default occupancy grid is relative to
the car and hides where it is on the track). Positions are in tens of metres, not parking's hundreds, so that the
discriminator, Lipschitz-bounded by its spectral normalisation, can tell a car in its lane (5 m wide) from one
beside it; the track spans about 12 x 10 observation units. The other vehicles are removed (``other_vehicles=0``):
the observation does not show them and the planning model,
:class:`sb3_mpail.mppi.highway_dynamics.RacetrackKinematics`, cannot predict them, so the task is lane keeping round
the track. The action is racetrack's steering in ``[-1, 1]`` (``pi/4`` rad at 1); highway-env then applies no
acceleration, so the car keeps its initial 10 m/s.

``sb3_mpail/Highway-v0`` is highway-env's ``highway-v0`` (a straight 4-lane road) without other vehicles, with the
same observation and continuous ``[acceleration, steering]`` actions (``5 m/s^2`` and ``pi/4`` rad at 1) at 5 Hz
like racetrack's (highway-v0's 1 Hz holds a steering angle too long to keep a lane): the task is highway-v0's reward,
driving fast (20-30 m/s) in the rightmost lane. Its planning model is
:class:`sb3_mpail.mppi.highway_dynamics.HighwayKinematics`.
"""

from typing import Any, Dict, Optional, Tuple, Type

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_mpail.envs.highway import PARKING_FEATURES, require_highway_env, vehicle_features

EGO_FEATURES = PARKING_FEATURES
EGO_SCALES = np.array([10.0, 10.0, 10.0, 10.0, 1.0, 1.0])
# highway-env computes its own observation every step; the cheapest (an empty dict) is asked for, since the flat one
# is computed here with numpy, with the values of an absolute Kinematics observation
NO_OBSERVATION = {"type": "AttributesObservation", "attributes": []}
# One lap of the racetrack is 348 m (inner lane) to 382 m (outer) at 10 m/s: 40 s (200 steps at 5 Hz) drive it once.
# highway-env 1.10+ ends racetrack episodes off the road unless told not to (1.9.1 never does, and ignores the key):
# the same episodes on both stacks, whose share of steps on the road is then a figure of every episode's 200 steps
RACETRACK_CONFIG = {"other_vehicles": 0, "duration": 40, "observation": NO_OBSERVATION, "terminate_off_road": False}
HIGHWAY_CONFIG = {
    "vehicles_count": 0,
    "action": {"type": "ContinuousAction"},
    "policy_frequency": 5,
    "observation": NO_OBSERVATION,
}


def ego_observation(vehicle: Any, dtype: type = np.float32) -> np.ndarray:
    """
    The vehicle's ``[x/10, y/10, vx/10, vy/10, cos h, sin h]``: the values of highway-env's ``Kinematics`` observation
    (``absolute=True``, ``normalize=False``, features :data:`EGO_FEATURES`) of the ego car divided by
    :data:`EGO_SCALES`, without its per-step pandas DataFrame.

    :param vehicle: a highway-env vehicle
    :param dtype: dtype of the result
    """
    return vehicle_features(vehicle, EGO_SCALES).astype(dtype)


class EgoRoadEnv(gym.Env):
    """
    A highway-env environment observed through the ego car's flat state ``[x/10, y/10, vx/10, vy/10, cos h, sin h]``
    (see :func:`ego_observation`); rewards, terminations and time limits are the highway-env environment's. It holds
    that environment instead of wrapping it, so its observation space is the flat Box.

    :param road_env_class: the highway-env environment class
    :param default_config: this scenario's overrides of the class's default config
    :param config: the user's overrides; the observation must stay, since the planning model decodes it
    :param render_mode: gymnasium render mode
    :param dtype: dtype of the observation (``np.float64`` keeps the simulator's values exactly)
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 5}

    def __init__(
        self,
        road_env_class: Type,
        default_config: Dict[str, Any],
        config: Optional[Dict[str, Any]] = None,
        render_mode: Optional[str] = None,
        dtype: type = np.float32,
    ):
        config = {**default_config, **(config or {})}
        if config["observation"] != NO_OBSERVATION:
            raise ValueError(
                f"{type(self).__name__} computes its own ego observation, which its planning model decodes; the config asks "
                f"for observation {config['observation']}."
            )
        self.road_env = road_env_class(config=config, render_mode=render_mode)
        self.render_mode = render_mode
        self.dtype = dtype
        # Generous finite bounds (observation units): positions 10 km, speeds 50 m/s (highway-env caps them at 40).
        high = np.array([1000.0, 1000.0, 5.0, 5.0, 1.0, 1.0], dtype=dtype)
        self.observation_space = spaces.Box(-high, high, dtype=dtype)
        self.action_space = self.road_env.action_space

    def observe(self) -> np.ndarray:
        """The flat observation of the current state: the ego car's (see :func:`ego_observation`)."""
        return ego_observation(self.road_env.vehicle, self.dtype)

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None
    ) -> Tuple[np.ndarray, Dict[str, Any]]:
        super().reset(seed=seed)
        _, info = self.road_env.reset(seed=seed, options=options)
        return self.observe(), info

    def step(self, action: np.ndarray) -> Tuple[np.ndarray, float, bool, bool, Dict[str, Any]]:
        # float64, as numpy 1 computed it: numpy 2 keeps highway-env's action mapping in a float32 action's precision
        _, reward, terminated, truncated, info = self.road_env.step(np.asarray(action, dtype=np.float64))
        return self.observe(), float(reward), terminated, truncated, info

    def render(self) -> Optional[np.ndarray]:
        return self.road_env.render()

    def close(self) -> None:
        self.road_env.close()


class EgoRacetrackEnv(EgoRoadEnv):
    """
    highway-env's ``racetrack-v0`` without other vehicles (see the module docstring): rewards (lane centring, steering
    penalty, zero off the road) and the 40 s time limit (200 steps) are racetrack's; the episode never terminates
    early, since crashes need another vehicle.

    :param config: overrides of :data:`RACETRACK_CONFIG` and ``racetrack-v0``'s defaults; the observation and the
        steering-only action must stay
    :param render_mode: gymnasium render mode
    :param dtype: dtype of the observation
    """

    def __init__(self, config: Optional[Dict[str, Any]] = None, render_mode: Optional[str] = None, dtype: type = np.float32):
        require_highway_env()
        from highway_env.envs.racetrack_env import RacetrackEnv

        super().__init__(RacetrackEnv, RACETRACK_CONFIG, config, render_mode, dtype)
        action = self.road_env.config["action"]
        if action.get("longitudinal", True):
            raise ValueError(
                f"sb3_mpail/Racetrack-v0 steers only (its planning model holds the speed); the config asks for action "
                f"{action}."
            )


class EgoHighwayEnv(EgoRoadEnv):
    """
    highway-env's ``highway-v0`` without other vehicles, with continuous ``[acceleration, steering]`` actions (see the
    module docstring): rewards (speed, rightmost lane, zero off the road) and the 40 s time limit (200 steps at 5 Hz)
    are highway-v0's.

    :param config: overrides of :data:`HIGHWAY_CONFIG` and ``highway-v0``'s defaults; the observation must stay
    :param render_mode: gymnasium render mode
    :param dtype: dtype of the observation
    """

    def __init__(self, config: Optional[Dict[str, Any]] = None, render_mode: Optional[str] = None, dtype: type = np.float32):
        require_highway_env()
        from highway_env.envs.highway_env import HighwayEnv

        super().__init__(HighwayEnv, HIGHWAY_CONFIG, config, render_mode, dtype)
