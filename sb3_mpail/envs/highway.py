"""
highway-env scenarios for MPAIL. highway-env is an optional dependency (the ``scenarios`` extra); making one of these
environments without it raises an ImportError that says what to install.

``sb3_mpail/Parking-v0`` is highway-env's ``parking-v0`` with its goal-conditioned dict observation flattened into the
Box MPAIL plans on: the ego car's ``[x/100, y/100, vx/5, vy/5, cos h, sin h]`` followed by the goal's six features in
the same units (``achieved_goal`` repeats the ego features and is dropped). Its planning model is
:class:`sb3_mpail.mppi.dynamics.ParkingKinematics`.
"""

import functools
from typing import Any, Dict, List, Optional, Tuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_mpail.envs import SCENARIOS_INSTALL_HINT

PARKING_FEATURES = ["x", "y", "vx", "vy", "cos_h", "sin_h"]
PARKING_SCALES = [100, 100, 5, 5, 1, 1]


def require_highway_env() -> None:
    """
    Imports highway-env, registering its environments with gymnasium.

    :raises ImportError: naming the extra to install when highway-env is missing
    """
    try:
        import highway_env  # noqa: F401
    except ImportError as error:
        raise ImportError(f"This scenario needs highway-env, which is not installed: {SCENARIOS_INSTALL_HINT}") from error


def vehicle_features(vehicle: Any, scales: np.ndarray) -> np.ndarray:
    """
    A highway-env vehicle's ``PARKING_FEATURES`` (``[x, y, vx, vy, cos h, sin h]``) divided by ``scales``, in float64:
    the values of its ``Kinematics`` observation row (absolute, not normalised), read with numpy instead of from a
    pandas DataFrame of its ``to_dict``.

    :param vehicle: a highway-env vehicle
    :param scales: one scale per feature
    """
    return np.concatenate((vehicle.position, vehicle.velocity, vehicle.direction)) / scales


@functools.cache
def numpy_observation_parking_env() -> type:
    """
    highway-env's ``ParkingEnv`` whose goal observations are read from the vehicles with numpy: the same float64
    values as highway-env's ``KinematicsGoalObservation``, which builds a pandas DataFrame from each vehicle's full
    ``to_dict`` (lane offsets included) and is queried four times a step (observation, reward, termination, info),
    most of a step's time. The class is made on first use because highway-env is optional.

    :return: the ``ParkingEnv`` subclass
    """
    require_highway_env()
    from highway_env.envs.common.observation import KinematicsGoalObservation
    from highway_env.envs.parking_env import ParkingEnv

    class NumpyKinematicsGoalObservation(KinematicsGoalObservation):
        """``KinematicsGoalObservation`` for ``PARKING_FEATURES`` only, without pandas."""

        def observe(self) -> Dict[str, np.ndarray]:
            vehicle = self.observer_vehicle
            if not vehicle:
                return super().observe()
            # to_dict's x, y, vx, vy, cos_h, sin_h; the goal (a Landmark) has zero speed, so zero velocity
            observation = vehicle_features(vehicle, self.scales)
            goal = vehicle.goal
            desired_goal = np.array([*goal.position, 0.0, 0.0, np.cos(goal.heading), np.sin(goal.heading)]) / self.scales
            return {"observation": observation, "achieved_goal": observation.copy(), "desired_goal": desired_goal}

    class NumpyObservationParkingEnv(ParkingEnv):
        """``ParkingEnv`` observing through :class:`NumpyKinematicsGoalObservation`."""

        def define_spaces(self) -> None:
            super().define_spaces()
            self.observation_type = NumpyKinematicsGoalObservation(self, **self.config["observation"])
            self.observation_type_parking = NumpyKinematicsGoalObservation(self, **self.PARKING_OBS["observation"])
            self.observation_space = self.observation_type.space()

    return NumpyObservationParkingEnv


class FlatParkingEnv(gym.Env):
    """
    highway-env's ``parking-v0`` with a flat Box observation: ``[observation, desired_goal]`` of its dict observation,
    12 values. It holds the highway-env environment instead of wrapping it, so it is no goal env to SB3 (whose
    ``check_env`` and HER treat any env whose unwrapped core has ``compute_reward`` as one); rewards, terminations
    (success or crash) and the 100 s time limit (500 steps) are parking-v0's.

    :param config: overrides of ``parking-v0``'s default config; the observation must stay the default one
    :param render_mode: gymnasium render mode
    :param dtype: dtype of the observation (``np.float64`` keeps the simulator's values exactly)
    :param numpy_observation: observe through :func:`numpy_observation_parking_env` (same values, several times more
        steps per second: see benchmarks/parking_model.py); ``False``: highway-env's own pandas-based observation
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 5}

    def __init__(
        self,
        config: Optional[Dict[str, Any]] = None,
        render_mode: Optional[str] = None,
        dtype: type = np.float32,
        numpy_observation: bool = True,
    ):
        require_highway_env()
        from highway_env.envs.parking_env import ParkingEnv

        # checked before the env is made, whose numpy observation reads exactly these features; highway-env
        # replaces the default config's entries whole
        observation = {**ParkingEnv.default_config(), **(config or {})}["observation"]
        if observation.get("features") != PARKING_FEATURES or list(observation.get("scales", [])) != PARKING_SCALES:
            raise ValueError(
                f"sb3_mpail/Parking-v0 keeps parking-v0's observation (features {PARKING_FEATURES}, scales "
                f"{PARKING_SCALES}), which its planning model decodes; the config asks for {observation}."
            )
        parking_env_class = numpy_observation_parking_env() if numpy_observation else ParkingEnv
        self.parking = parking_env_class(config=config, render_mode=render_mode)
        self.render_mode = render_mode
        self.dtype = dtype
        # Generous finite bounds (observation units): positions 1 km, speeds 50 m/s (highway-env caps them near 40).
        high = np.tile(np.array([10.0, 10.0, 10.0, 10.0, 1.0, 1.0], dtype=dtype), 2)
        self.observation_space = spaces.Box(-high, high, dtype=dtype)
        self.action_space = self.parking.action_space

    @property
    def road(self) -> Any:
        """The parking lot's highway-env road (its walls, goal and vehicles), e.g. for obstacle costs."""
        return self.parking.road

    @property
    def controlled_vehicles(self) -> List[Any]:
        """The ego vehicle, in highway-env's list."""
        return self.parking.controlled_vehicles

    def _flatten(self, observation: Dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate((observation["observation"], observation["desired_goal"])).astype(self.dtype)

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None
    ) -> Tuple[np.ndarray, Dict[str, Any]]:
        super().reset(seed=seed)
        observation, info = self.parking.reset(seed=seed, options=options)
        return self._flatten(observation), info

    def step(self, action: np.ndarray) -> Tuple[np.ndarray, float, bool, bool, Dict[str, Any]]:
        # float64, as numpy 1 computed it: numpy 2 keeps highway-env's action mapping in a float32 action's precision
        observation, reward, terminated, truncated, info = self.parking.step(np.asarray(action, dtype=np.float64))
        return self._flatten(observation), float(reward), terminated, truncated, info

    def render(self) -> Optional[np.ndarray]:
        return self.parking.render()

    def close(self) -> None:
        self.parking.close()
