"""
highway-env's highway in traffic for MPAIL, planned on the ego car and the vehicles around it. highway-env is an
optional dependency (the ``scenarios`` extra); making one of these environments without it raises an ImportError that
says what to install.

``sb3_mpail/HighwayTraffic-v0`` is highway-env's ``highway-fast-v0`` (3 lanes, 20 other vehicles driven by
highway-env's IDM/MOBIL model, 30 s episodes that end at a crash) with continuous ``[acceleration, steering]`` actions
(``5 m/s^2`` and ``pi/4`` rad at 1), as ``sb3_mpail/Highway-v0`` drives. Its observation is a flat Box of
:data:`TRAFFIC_STATE_DIM` values: the ego car's ``[x/10, y/10, vx/10, vy/10, cos h, sin h]``
(:func:`~sb3_mpail.envs.highway_roads.ego_observation`), then the :data:`TRAFFIC_VEHICLES` nearest other vehicles'
``[presence, x/10, y/10, vx/10, vy/10]``, nearest first, in absolute world coordinates, so that a planning model can
roll them forward (:class:`sb3_mpail.mppi.highway_dynamics.HighwayTrafficKinematics`); slots without a vehicle are
zero, presence included. These are the values of highway-env's own ``Kinematics`` observation with
``absolute=True``, ``normalize=False`` and ``see_behind=True`` (the vehicles behind matter to a lane change), divided
by the scales, computed from the vehicles with numpy rather than through its per-step pandas DataFrame.

highway-fast-v0 simulates at 5 Hz, but decides at highway-env's default 1 Hz: a steering angle held for 1 s is too
long to keep a lane (as ``sb3_mpail/Highway-v0`` found on highway-v0), so the policy runs at 5 Hz here, one simulation
step per action: 151 steps per 30 s episode (highway-env's clock sums 0.2 s steps, which fall just short of 30 s at
the 150th). Rewards (speed, rightmost lane, collision, zero off the road), crash terminations and the time limit are
highway-fast-v0's; the step's ``info`` holds highway-env's ``crashed`` and ``speed`` (m/s).

``sb3_mpail/HighwayTrafficDense-v0`` is the same wrapper round highway-env's ``highway-v0`` traffic: 4 lanes, 50
vehicles, 40 s episodes (200 steps), simulated at 15 Hz (three simulation steps per 5 Hz action), with collisions
between the other vehicles checked too.
"""

from typing import Any, Dict, List, Optional

import numpy as np
from gymnasium import spaces

from sb3_mpail.envs.highway import require_highway_env, vehicle_features
from sb3_mpail.envs.highway_roads import EGO_SCALES, NO_OBSERVATION, EgoRoadEnv

#: other vehicles in the observation, nearest first (highway-env's Kinematics shows 5 rows by default, the ego's among them)
TRAFFIC_VEHICLES = 5
#: each other vehicle's features, as highway-env's Kinematics observation names them, and their scales
VEHICLE_FEATURES = ["presence", "x", "y", "vx", "vy"]
VEHICLE_SCALES = np.array([1.0, 10.0, 10.0, 10.0, 10.0])
EGO_DIM = len(EGO_SCALES)
#: the observation's size: the ego's 6 features and 5 per other vehicle
TRAFFIC_STATE_DIM = EGO_DIM + TRAFFIC_VEHICLES * len(VEHICLE_FEATURES)


def vehicle_dims(feature: str) -> List[int]:
    """
    The observation's dimensions of one of :data:`VEHICLE_FEATURES` for every other vehicle, nearest first.

    :param feature: the feature's name, e.g. ``"x"``
    """
    offset = VEHICLE_FEATURES.index(feature)
    return [EGO_DIM + len(VEHICLE_FEATURES) * slot + offset for slot in range(TRAFFIC_VEHICLES)]


#: the overrides of the base environment's config (see the module docstring for the 5 Hz policy)
TRAFFIC_CONFIG = {"action": {"type": "ContinuousAction"}, "policy_frequency": 5, "observation": NO_OBSERVATION}


#: the highway-env environments whose traffic the wrapper drives in (``highway-fast-v0``, ``highway-v0``): their classes
#: in ``highway_env.envs.highway_env``
TRAFFIC_BASES: Dict[str, str] = {"highway-fast": "HighwayEnvFast", "highway": "HighwayEnv"}


def traffic_vehicles(ego: Any, vehicles: List[Any], perception_distance: float, count: int = TRAFFIC_VEHICLES) -> List[Any]:
    """
    The vehicles highway-env's ``Kinematics`` observation (``see_behind=True``, ``order="sorted"``) shows beside the
    ego: those closer than ``perception_distance``, sorted by the distance along the ego's lane (stably, as
    ``Road.close_objects_to`` sorts), the ``count`` nearest.

    :param ego: the ego vehicle
    :param vehicles: every vehicle on the road (the ego may be among them)
    :param perception_distance: highway-env's ``PERCEPTION_DISTANCE`` (m)
    :param count: how many to keep
    """
    others = [vehicle for vehicle in vehicles if vehicle is not ego]
    if not others:
        return []
    positions = np.array([vehicle.position for vehicle in others])
    near = np.linalg.norm(positions - ego.position, axis=1) < perception_distance
    along = np.abs([ego.lane_distance_to(vehicle) for vehicle in others])
    return [others[index] for index in np.argsort(along, kind="stable") if near[index]][:count]


def traffic_observation(ego: Any, vehicles: List[Any], perception_distance: float, dtype: type = np.float32) -> np.ndarray:
    """
    The flat traffic observation (see the module docstring): the ego car's features, then the nearest other vehicles'
    ``[presence, x/10, y/10, vx/10, vy/10]``, zero rows for missing ones.

    :param ego: the ego vehicle
    :param vehicles: every vehicle on the road
    :param perception_distance: highway-env's ``PERCEPTION_DISTANCE`` (m)
    :param dtype: dtype of the result
    """
    rows = np.zeros((TRAFFIC_VEHICLES, len(VEHICLE_FEATURES)))
    for row, vehicle in zip(rows, traffic_vehicles(ego, vehicles, perception_distance)):
        row[0] = 1.0
        row[1:] = np.concatenate((vehicle.position, vehicle.velocity)) / VEHICLE_SCALES[1:]
    return np.concatenate((vehicle_features(ego, EGO_SCALES), rows.ravel())).astype(dtype)


class EgoTrafficEnv(EgoRoadEnv):
    """
    highway-env's highway in traffic, observed through the ego car and the vehicles nearest to it (see the module
    docstring); rewards, crash terminations and time limits are the base environment's.

    :param base: the traffic, a key of :data:`TRAFFIC_BASES`: ``"highway-fast"`` (``highway-fast-v0``'s 3 lanes and 20
        vehicles) or ``"highway"`` (``highway-v0``'s 4 lanes and 50 vehicles)
    :param config: overrides of :data:`TRAFFIC_CONFIG` and the base's defaults; the observation and the
        ``[acceleration, steering]`` action must stay, and the simulation frequency must be a multiple of the policy's
    :param render_mode: gymnasium render mode
    :param dtype: dtype of the observation (``np.float64`` keeps the simulator's values exactly)
    :raises ValueError: an unknown base, or a config whose observation, action or frequencies the planning model
        cannot decode
    """

    def __init__(
        self,
        base: str = "highway-fast",
        config: Optional[Dict[str, Any]] = None,
        render_mode: Optional[str] = None,
        dtype: type = np.float32,
    ):
        require_highway_env()
        if base not in TRAFFIC_BASES:
            raise ValueError(f"Unknown traffic base {base!r}: choose one of {sorted(TRAFFIC_BASES)}.")
        from highway_env.envs import highway_env

        super().__init__(getattr(highway_env, TRAFFIC_BASES[base]), TRAFFIC_CONFIG, config, render_mode, dtype)
        road_config = self.road_env.config
        action = road_config["action"]
        if action.get("type") != "ContinuousAction" or not (action.get("longitudinal", True) and action.get("lateral", True)):
            raise ValueError(
                f"{type(self).__name__} drives by continuous [acceleration, steering] actions, which its planning model "
                f"decodes; the config asks for action {action}."
            )
        if road_config["simulation_frequency"] % road_config["policy_frequency"]:
            raise ValueError(
                f"{type(self).__name__} needs a simulation frequency that is a multiple of the policy frequency (its "
                f"planning model runs whole simulation steps per action); the config asks for "
                f"{road_config['simulation_frequency']} Hz and {road_config['policy_frequency']} Hz."
            )
        # generous finite bounds (observation units), as the ego's: positions 10 km, speeds 50 m/s
        vehicle_high = np.array([1.0, 1000.0, 1000.0, 5.0, 5.0])
        vehicle_low = np.array([0.0, -1000.0, -1000.0, -5.0, -5.0])
        low = np.concatenate((self.observation_space.low, np.tile(vehicle_low, TRAFFIC_VEHICLES))).astype(dtype)
        high = np.concatenate((self.observation_space.high, np.tile(vehicle_high, TRAFFIC_VEHICLES))).astype(dtype)
        self.observation_space = spaces.Box(low, high, dtype=dtype)

    @property
    def simulation_dt(self) -> float:
        """The simulation's time step (s), which the planning model integrates with (see ``substeps``)."""
        return 1.0 / self.road_env.config["simulation_frequency"]

    @property
    def substeps(self) -> int:
        """Simulation steps per action."""
        return int(self.road_env.config["simulation_frequency"] // self.road_env.config["policy_frequency"])

    def observe(self) -> np.ndarray:
        """The flat traffic observation of the current state (see :func:`traffic_observation`)."""
        road_env = self.road_env
        return traffic_observation(road_env.vehicle, road_env.road.vehicles, road_env.PERCEPTION_DISTANCE, self.dtype)
