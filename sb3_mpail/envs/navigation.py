"""Goal-reaching navigation with a MuSHR-like 1/10-scale car.

The simulator is deliberately richer than the kinematic bicycle model used by the MPPI planner
(``sb3_mpail.mppi.dynamics``): it adds first-order actuator lag on speed and steering, speed-dependent
understeer with a body-frame lateral slip velocity, and roll/pitch from a soft suspension. At low speed
and steady state the two models agree, so the planner's model is a good but imperfect approximation,
which is the setting of the MPAIL navigation experiment.
"""

import math
from typing import Any, ClassVar, Optional, Sequence

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

# The top-down picture of ``render_mode="rgb_array"``: RGB colours and sizes
RENDER_SIZE = 400  # pixels, width and height
BACKGROUND_COLOUR = (245, 245, 245)
GRID_COLOUR = (222, 222, 222)
PATH_COLOUR = (120, 165, 230)  # the reference paths (demos, track)
TRAIL_COLOUR = (240, 150, 60)  # where the car has driven this episode
GOAL_COLOUR = (40, 170, 70)
CAR_COLOUR = (200, 30, 30)
CAR_FRONT_COLOUR = (255, 210, 0)
CAR_LENGTH, CAR_WIDTH = 0.5, 0.28  # m, drawn at least 16 x 9 pixels


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
    :param render_mode: ``None`` or ``"rgb_array"``: :meth:`render` returns a top-down ``(400, 400, 3)`` uint8 picture
        of the car (red, its front yellow), the goal (green), the reference paths (blue) and the car's trail this
        episode (orange), framed on them and the car's start, widened when the car drives out of the frame.
    :param reference_paths: polylines drawn under the car, each ``(m, 2)`` positions ``(x, y)`` in metres, e.g. the
        demos' paths (``[demo[:, :2] for demo in demos]``).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": round(1 / DT)}
    #: whether the picture shows the goal (the lap env, which follows a track, does not)
    render_goal: ClassVar[bool] = True

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
        render_mode: Optional[str] = None,
        reference_paths: Optional[Sequence[Any]] = None,
    ) -> None:
        super().__init__()
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"Unsupported render_mode {render_mode!r}; choose None or {self.metadata['render_modes']}.")
        self.render_mode = render_mode
        self.reference_paths = [np.asarray(path, dtype=np.float64).reshape(-1, 2) for path in reference_paths or ()]
        self._trail: list[tuple[float, float]] = []  # recorded only when rendering
        self._view: Optional[tuple[float, float, float]] = None  # left, top (m) and pixels per metre
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
        if self.render_mode is not None:
            self._trail, self._view = [(self._x, self._y)], None
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
        if self.render_mode is not None:
            self._trail.append((x, y))

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

    def render(self) -> Optional[np.ndarray]:
        """The top-down picture (see the ``render_mode`` parameter), or ``None`` without ``render_mode="rgb_array"``.

        :return: ``(400, 400, 3)`` uint8 RGB image; +x points right and +y up.
        """
        if self.render_mode != "rgb_array":
            return None
        image = np.empty((RENDER_SIZE, RENDER_SIZE, 3), dtype=np.uint8)
        image[:] = BACKGROUND_COLOUR
        trail = np.array(self._trail or [(self._x, self._y)], dtype=np.float64)
        left, top, scale = self._frame(trail)
        size = RENDER_SIZE / scale  # m

        def to_pixels(points: np.ndarray) -> np.ndarray:
            """World ``(x, y)`` in metres to pixel ``(column, row)``."""
            return np.stack(((points[:, 0] - left) * scale, (top - points[:, 1]) * scale), axis=-1)

        spacing = 1.0 if scale >= 20.0 else 5.0 if scale >= 4.0 else 25.0  # m between grid lines
        for x in np.arange(math.ceil(left / spacing) * spacing, left + size, spacing):
            image[:, min(int(round((x - left) * scale)), RENDER_SIZE - 1)] = GRID_COLOUR
        for y in np.arange(math.ceil((top - size) / spacing) * spacing, top, spacing):
            image[min(int(round((top - y) * scale)), RENDER_SIZE - 1), :] = GRID_COLOUR
        for path in self.reference_paths:
            _draw_polyline(image, to_pixels(path), PATH_COLOUR, radius=1)
        _draw_polyline(image, to_pixels(trail), TRAIL_COLOUR, radius=0)
        if self.render_goal:
            goal = to_pixels(np.array([self._episode_goal]))[0]
            _draw_disk(image, goal, max(0.25 * scale, 6.0), GOAL_COLOUR)
        self._draw_car(image, left, top, scale)
        return image

    def _frame(self, trail: np.ndarray) -> tuple[float, float, float]:
        """The episode's view: a square on the start, the goal, the paths and the trail, widened when the car leaves it.

        :param trail: ``(n, 2)`` positions driven this episode, the car's current one last
        :return: left and top edges (m) and the scale (pixels per metre)
        """
        if self._view is not None:
            left, top, scale = self._view
            size, (x, y) = RENDER_SIZE / scale, trail[-1]
            if left + 0.5 <= x <= left + size - 0.5 and top - size + 0.5 <= y <= top - 0.5:
                return self._view
        points = [trail]
        if self.render_goal:
            points.append(np.array([self._episode_goal]))
        points.extend(self.reference_paths)
        points = np.concatenate(points)
        low, high = points.min(axis=0) - 1.5, points.max(axis=0) + 1.5
        half_size = max(float((high - low).max()) / 2, 2.0)
        centre = (low + high) / 2
        self._view = (float(centre[0] - half_size), float(centre[1] + half_size), RENDER_SIZE / (2 * half_size))
        return self._view

    def _draw_car(self, image: np.ndarray, left: float, top: float, scale: float) -> None:
        """Draws the car: a rectangle along its heading, red with a yellow front.

        :param image: the picture to draw in
        :param left: left edge of the view (m)
        :param top: top edge of the view (m)
        :param scale: pixels per metre
        """
        length, width = max(CAR_LENGTH, 16.0 / scale), max(CAR_WIDTH, 9.0 / scale)
        column, row = (self._x - left) * scale, (top - self._y) * scale
        reach = int(math.ceil(0.5 * math.hypot(length, width) * scale)) + 1
        rows = np.arange(max(int(row) - reach, 0), min(int(row) + reach + 1, RENDER_SIZE))
        columns = np.arange(max(int(column) - reach, 0), min(int(column) + reach + 1, RENDER_SIZE))
        if len(rows) == 0 or len(columns) == 0:
            return
        # pixel centres in the car's frame (m): along its heading and to its left
        dx = (columns[None, :] + 0.5 - column) / scale
        dy = (row - rows[:, None] - 0.5) / scale
        cos_yaw, sin_yaw = math.cos(self._yaw), math.sin(self._yaw)
        along, across = dx * cos_yaw + dy * sin_yaw, -dx * sin_yaw + dy * cos_yaw
        body = (np.abs(along) <= length / 2) & (np.abs(across) <= width / 2)
        window = image[rows[0] : rows[-1] + 1, columns[0] : columns[-1] + 1]
        window[body] = CAR_COLOUR
        window[body & (along >= 0.25 * length)] = CAR_FRONT_COLOUR


def _draw_polyline(image: np.ndarray, points: np.ndarray, colour: tuple[int, int, int], radius: int) -> None:
    """Draws a polyline through pixel positions, ``2 * radius + 1`` pixels wide; what falls outside is clipped.

    :param image: ``(height, width, 3)`` picture
    :param points: ``(n, 2)`` pixel positions ``(column, row)``
    :param colour: RGB
    :param radius: half-width in pixels
    """
    if len(points) > 1:
        segments = np.diff(points, axis=0)
        counts = np.maximum(np.ceil(np.abs(segments).max(axis=1) * 2).astype(int), 1)  # two samples per pixel
        counts = np.minimum(counts, 4 * RENDER_SIZE)  # a segment far longer than the view is sampled as if clipped
        segment = np.repeat(np.arange(len(segments)), counts)
        fraction = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)) / np.repeat(counts, counts)
        points = np.concatenate((points[segment] + segments[segment] * fraction[:, None], points[-1:]))
    height, width = image.shape[:2]
    columns, rows = np.floor(points[:, 0]).astype(int), np.floor(points[:, 1]).astype(int)
    for row_offset in range(-radius, radius + 1):
        for column_offset in range(-radius, radius + 1):
            r, c = rows + row_offset, columns + column_offset
            inside = (r >= 0) & (r < height) & (c >= 0) & (c < width)
            image[r[inside], c[inside]] = colour


def _draw_disk(image: np.ndarray, centre: np.ndarray, radius: float, colour: tuple[int, int, int]) -> None:
    """Draws a filled disk; what falls outside is clipped.

    :param image: ``(height, width, 3)`` picture
    :param centre: pixel position ``(column, row)``
    :param radius: radius in pixels
    :param colour: RGB
    """
    height, width = image.shape[:2]
    column, row = float(centre[0]), float(centre[1])
    rows = np.arange(max(int(row - radius), 0), min(int(row + radius) + 1, height))
    columns = np.arange(max(int(column - radius), 0), min(int(column + radius) + 1, width))
    if len(rows) == 0 or len(columns) == 0:
        return
    inside = (rows[:, None] + 0.5 - row) ** 2 + (columns[None, :] + 0.5 - column) ** 2 <= radius**2
    image[rows[0] : rows[-1] + 1, columns[0] : columns[-1] + 1][inside] = colour
