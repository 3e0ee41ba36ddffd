"""Goal-reaching navigation with a MuSHR-like 1/10-scale car.

The simulator is deliberately richer than the kinematic bicycle model used by the MPPI planner
(``sb3_mpail.mppi.dynamics``): it adds first-order actuator lag on speed and steering, speed-dependent
understeer with a body-frame lateral slip velocity, and roll/pitch from a soft suspension. At low speed
and steady state the two models agree, so the planner's model is a good but imperfect approximation,
which is the setting of the MPAIL navigation experiment.
"""

import math
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

# Actuator limits shared with the planner's bicycle model.
MAX_SPEED = 3.0  # m/s, target speed for a normalised action of 1
MAX_STEER = 0.488  # rad, steering angle for a normalised action of 1
WHEELBASE = 0.325  # m
DT = 0.1  # s per env step

# Reward offset from the paper: the straight-line distance from the origin to the default goal (10, 10),
# so the per-step reward is about 0 at the start and at most ~14.1 on the goal.
REWARD_OFFSET = math.sqrt(10.0**2 + 10.0**2)

OOD_HALF_WIDTH = 20.0  # m, half-width of the out-of-distribution start box


class NavigationEnv(gym.Env):
    """Drive a 1/10-scale car from near the origin to a goal on flat ground.

    Observation (12-D): ``[x, y, z, roll, pitch, yaw, vx, vy, vz, wx, wy, wz]`` with the pose in the world frame
    (yaw wrapped to ``[-pi, pi)``) and the linear and angular velocities in the body frame.
    Action (2-D, in ``[-1, 1]``): normalised target speed (``3.0 * a[0]`` m/s, reverse allowed) and normalised
    steering angle (``0.488 * a[1]`` rad). Reward: ``sqrt(200) - ||(x, y) - goal||``. The environment never
    terminates; register it with a time limit (``sb3_mpail/Navigation-v0`` truncates after 100 steps).

    :param start_region: ``"default"`` (uniform in the 1 x 1 m square centred at the origin, heading uniform in
        ``[-pi/8, pi/8]``), ``"ood"`` (uniform in the 40 x 40 m box centred at the origin, heading uniform in
        ``[-pi, pi)``) or a float half-width of a custom square centred at the origin with uniform heading.
        ``reset(options={"start_region": ...})`` overrides it for one episode.
    :param goal: Goal position ``(x, y)`` in metres; ``reset(options={"goal": ...})`` overrides it for one episode.
    :param n_substeps: Number of integration substeps per ``DT`` step.
    :param speed_time_constant: Time constant (s) of the first-order lag from target to actual speed.
    :param steer_time_constant: Time constant (s) of the first-order lag from target to actual steering angle.
    :param understeer_gradient: ``K`` in the effective curvature ``tan(delta) / (L * (1 + K v^2))`` (s^2/m^2).
    :param slip_gain: Body lateral velocity per unit lateral acceleration, ``vy = -slip_gain * v * yaw_rate`` (s);
        the rear of the car drifts outwards in a turn.
    :param roll_gain: Steady-state roll per unit lateral acceleration (rad s^2/m).
    :param pitch_gain: Steady-state pitch per unit longitudinal acceleration (rad s^2/m).
    :param suspension_time_constant: Time constant (s) of the roll and pitch response.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(
        self,
        start_region: str | float = "default",
        goal: tuple[float, float] = (10.0, 10.0),
        n_substeps: int = 4,
        speed_time_constant: float = 0.25,
        steer_time_constant: float = 0.1,
        understeer_gradient: float = 0.04,
        slip_gain: float = 0.02,
        roll_gain: float = 0.008,
        pitch_gain: float = 0.005,
        suspension_time_constant: float = 0.1,
    ) -> None:
        super().__init__()
        self._check_start_region(start_region)
        self.start_region = start_region
        self.goal = (float(goal[0]), float(goal[1]))
        self.n_substeps = int(n_substeps)
        self.understeer_gradient = understeer_gradient
        self.slip_gain = slip_gain
        self.roll_gain = roll_gain
        self.pitch_gain = pitch_gain
        self._h = DT / self.n_substeps
        # Exact discretisation of the first-order lags, so the response does not depend on the substep count.
        self._speed_alpha = 1.0 - math.exp(-self._h / speed_time_constant)
        self._steer_alpha = 1.0 - math.exp(-self._h / steer_time_constant)
        self._suspension_alpha = 1.0 - math.exp(-self._h / suspension_time_constant)

        # Generous finite bounds: positions far beyond the +-20 m OOD starts plus 100 steps at full speed.
        high = np.array(
            [1e4, 1e4, 10.0, math.pi, math.pi / 2, math.pi, 50.0, 50.0, 50.0, 100.0, 100.0, 100.0], dtype=np.float32
        )
        self.observation_space = spaces.Box(-high, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

        self._episode_goal = self.goal
        # Simulator state; speed and steer are the hidden actual actuator states.
        self._x = self._y = self._yaw = 0.0
        self._roll = self._pitch = 0.0
        self._speed = self._steer = 0.0
        self._vy = 0.0
        self._roll_rate = self._pitch_rate = self._yaw_rate = 0.0

    @property
    def episode_goal(self) -> tuple[float, float]:
        """Goal of the current episode: the constructor's ``goal`` unless ``reset`` options overrode it."""
        return self._episode_goal

    @staticmethod
    def _check_start_region(start_region: str | float) -> None:
        """Raise ``ValueError`` for an unknown start region.

        :param start_region: ``"default"``, ``"ood"`` or a positive float half-width.
        """
        if isinstance(start_region, str):
            if start_region not in ("default", "ood"):
                raise ValueError(f"Unknown start_region {start_region!r}, expected 'default', 'ood' or a float")
        elif not float(start_region) > 0.0:
            raise ValueError(f"start_region half-width must be positive, got {start_region}")

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Place the car at rest in the start region.

        :param seed: Seed for the environment's random generator.
        :param options: Optional ``start_region`` and ``goal`` overriding the constructor values for this episode.
        :return: The first observation and an info dict with ``distance_to_goal``.
        """
        super().reset(seed=seed)
        options = options or {}
        start_region = options.get("start_region", self.start_region)
        self._check_start_region(start_region)
        goal = options.get("goal", self.goal)
        self._episode_goal = (float(goal[0]), float(goal[1]))

        if start_region == "default":
            half_width, max_heading = 0.5, math.pi / 8
        else:
            half_width = OOD_HALF_WIDTH if start_region == "ood" else float(start_region)
            max_heading = math.pi
        x, y = self.np_random.uniform(-half_width, half_width, size=2)
        self._x, self._y = float(x), float(y)
        # Uniform in [-max_heading, max_heading), wrapped like the stepped yaw.
        yaw = float(self.np_random.uniform(-max_heading, max_heading))
        self._yaw = (yaw + math.pi) % (2.0 * math.pi) - math.pi
        self._roll = self._pitch = 0.0
        self._speed = self._steer = self._vy = 0.0
        self._roll_rate = self._pitch_rate = self._yaw_rate = 0.0
        return self._get_obs(), {"distance_to_goal": self._distance_to_goal()}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Advance the simulation by ``DT`` seconds.

        :param action: Normalised ``[target speed, steering]``, clipped into ``[-1, 1]``.
        :return: Observation, reward, terminated (always False), truncated (always False) and info.
        """
        target_speed = MAX_SPEED * min(max(float(action[0]), -1.0), 1.0)
        target_steer = MAX_STEER * min(max(float(action[1]), -1.0), 1.0)
        h = self._h
        x, y, yaw = self._x, self._y, self._yaw
        roll, pitch = self._roll, self._pitch
        speed, steer = self._speed, self._steer
        vy = yaw_rate = roll_rate = pitch_rate = 0.0
        for _ in range(self.n_substeps):
            new_speed = speed + (target_speed - speed) * self._speed_alpha
            accel = (new_speed - speed) / h
            speed = new_speed
            steer += (target_steer - steer) * self._steer_alpha
            # Understeer: tyre slip reduces the achieved curvature as lateral acceleration grows with speed.
            yaw_rate = speed * math.tan(steer) / (WHEELBASE * (1.0 + self.understeer_gradient * speed * speed))
            lateral_accel = speed * yaw_rate
            vy = -self.slip_gain * lateral_accel
            cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
            x += (speed * cos_yaw - vy * sin_yaw) * h
            y += (speed * sin_yaw + vy * cos_yaw) * h
            yaw += yaw_rate * h
            # Suspension: the body rolls outwards in turns and pitches nose-up when accelerating (FLU axes).
            new_roll = roll + (self.roll_gain * lateral_accel - roll) * self._suspension_alpha
            new_pitch = pitch + (-self.pitch_gain * accel - pitch) * self._suspension_alpha
            roll_rate, pitch_rate = (new_roll - roll) / h, (new_pitch - pitch) / h
            roll, pitch = new_roll, new_pitch

        self._x, self._y = x, y
        self._yaw = (yaw + math.pi) % (2.0 * math.pi) - math.pi
        self._roll, self._pitch = roll, pitch
        self._speed, self._steer, self._vy = speed, steer, vy
        self._roll_rate, self._pitch_rate, self._yaw_rate = roll_rate, pitch_rate, yaw_rate

        distance = self._distance_to_goal()
        return self._get_obs(), REWARD_OFFSET - distance, False, False, {"distance_to_goal": distance}

    def _distance_to_goal(self) -> float:
        """:return: Euclidean distance from the car to this episode's goal."""
        return math.hypot(self._x - self._episode_goal[0], self._y - self._episode_goal[1])

    def _get_obs(self) -> np.ndarray:
        """Build the observation, rotating the planar velocities into the rolled and pitched body frame.

        :return: The 12-D float32 observation.
        """
        roll, pitch = self._roll, self._pitch
        cos_r, sin_r = math.cos(roll), math.sin(roll)
        cos_p, sin_p = math.cos(pitch), math.sin(pitch)
        speed, vy = self._speed, self._vy
        roll_rate, pitch_rate, yaw_rate = self._roll_rate, self._pitch_rate, self._yaw_rate
        return np.array(
            [
                self._x,
                self._y,
                0.0,  # flat ground
                roll,
                pitch,
                self._yaw,
                cos_p * speed,
                cos_r * vy + sin_r * sin_p * speed,
                cos_r * sin_p * speed - sin_r * vy,
                # Euler angle rates to body angular velocity (ZYX convention).
                roll_rate - sin_p * yaw_rate,
                cos_r * pitch_rate + sin_r * cos_p * yaw_rate,
                cos_r * cos_p * yaw_rate - sin_r * pitch_rate,
            ],
            dtype=np.float32,
        )
