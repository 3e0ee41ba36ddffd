"""
Known costs a designer adds to the learned ones (the policy's ``constraint_cost``): what the planning model does not
know, such as walls and obstacles, scored on every state a roll-out reaches. The standard MPPI answer to constraints:
a large cost on the states that violate them, so that the exponential weights drop the samples that do.
"""

import functools
from typing import Any, Callable, Dict, Optional, Tuple, Union

import numpy as np
import torch as th
from torch import nn

from sb3_mpail.checks import check_signature
from sb3_mpail.envs.highway_traffic import EGO_DIM, TRAFFIC_STATE_DIM, TRAFFIC_VEHICLES, VEHICLE_FEATURES


class RectangleObstacles(nn.Module):
    """
    ``weight * (1 + depth / margin)`` for every state whose position lies within ``margin`` of one of a set of rectangles
    (walls, parked cars), ``depth`` how far inside the inflated rectangle it is; 0 elsewhere. The depth term ranks
    samples that all collide by how deep they go. The position is read from two state dimensions, in the observation's
    units.

    :param centres: rectangle centres, ``(n, 2)``
    :param half_sizes: half length (along the rectangle's heading) and half width, ``(n, 2)``
    :param headings: each rectangle's heading (rad), ``(n,)``; ``None``: all 0 (axis-aligned)
    :param margin: how far around each rectangle the cost reaches (e.g. the vehicle's half width), ``> 0``
    :param weight: the cost of a state at the inflated rectangle's edge, ``> 0``
    :param x_index: the state dimension of the position's x (checked against the state's size when the planner is built,
        and at every call)
    :param y_index: the state dimension of the position's y
    """

    def __init__(
        self,
        centres: Any,
        half_sizes: Any,
        headings: Any = None,
        margin: float = 1.0,
        weight: float = 100.0,
        x_index: int = 0,
        y_index: int = 1,
    ):
        super().__init__()
        centres = th.as_tensor(np.asarray(centres, dtype=np.float32)).reshape(-1, 2)
        half_sizes = th.as_tensor(np.asarray(half_sizes, dtype=np.float32)).reshape(-1, 2)
        headings = th.zeros(len(centres)) if headings is None else th.as_tensor(np.asarray(headings, np.float32)).reshape(-1)
        if not (len(centres) == len(half_sizes) == len(headings)):
            raise ValueError(
                f"RectangleObstacles needs one centre, half size and heading per rectangle; got {len(centres)} centres, "
                f"{len(half_sizes)} half sizes and {len(headings)} headings."
            )
        if not (margin > 0 and weight > 0) or bool((half_sizes < 0).any()):
            raise ValueError(f"RectangleObstacles needs margin > 0, weight > 0 and half sizes >= 0; got margin={margin}, "
                             f"weight={weight}, half sizes {half_sizes.tolist()}.")  # fmt: skip
        self.register_buffer("centres", centres)
        self.register_buffer("inflated_half_sizes", half_sizes + margin)
        self.register_buffer("cos_sin", th.stack((th.cos(headings), th.sin(headings)), dim=1))
        self.margin, self.weight, self.x_index, self.y_index = float(margin), float(weight), x_index, y_index

    def check_state_dim(self, state_dim: int) -> None:
        """
        Refuses position indices out of range for ``state_dim``-D states (negative ones count from the end).

        :param state_dim: size of a state
        :raises ValueError: ``x_index`` or ``y_index`` is out of range
        """
        indices = {"x_index": self.x_index, "y_index": self.y_index}
        outside = [f"{name}={index}" for name, index in indices.items() if not -state_dim <= index < state_dim]
        if outside:
            raise ValueError(
                f"RectangleObstacles' {' and '.join(outside)} {'is' if len(outside) == 1 else 'are'} out of range for the "
                f"{state_dim}-D state (indices in [-{state_dim}, {state_dim})): give the state dimensions of the position."
            )

    def forward(self, states: th.Tensor) -> th.Tensor:
        self.check_state_dim(states.shape[-1])  # Python integers: no host sync
        offsets = states[..., [self.x_index, self.y_index]].unsqueeze(-2) - self.centres  # (..., n, 2)
        cos, sin = self.cos_sin[:, 0], self.cos_sin[:, 1]
        along = offsets[..., 0] * cos + offsets[..., 1] * sin
        across = offsets[..., 1] * cos - offsets[..., 0] * sin
        # how far inside each inflated rectangle: positive inside, on both of its axes
        depth = th.minimum(self.inflated_half_sizes[:, 0] - along.abs(), self.inflated_half_sizes[:, 1] - across.abs())
        inside = depth > 0
        costs = th.where(inside, self.weight * (1 + depth / self.margin), th.zeros_like(depth))
        return costs.sum(-1)


def highway_env_obstacles(env: Any, position_scale: float = 1.0, margin: float = 1.0, weight: float = 100.0,
                          x_index: int = 0, y_index: int = 1) -> RectangleObstacles:  # fmt: skip
    """
    The solid objects of a highway-env env's road after its reset (e.g. ``parking-v0``'s walls) and its vehicles other
    than the controlled ones (parked cars), as :class:`RectangleObstacles` in the observation's units. They stay where
    they were at that reset: objects that move, or change between episodes, need a cost of their own.

    :param env: a highway-env env, reset (wrappers are looked through)
    :param position_scale: metres per observation unit of the position (``sb3_mpail/Parking-v0``: 100)
    :param margin: how far around each object the cost reaches, in metres (the ego's half width: 1 m)
    :param weight: the cost at the edge
    :param x_index: the state dimension of the position's x
    :param y_index: the state dimension of the position's y
    """
    road = getattr(env.unwrapped, "road", None)
    if road is None:
        raise ValueError(f"highway_env_obstacles needs a highway-env env that has been reset; {env} has no road.")
    controlled = set(map(id, getattr(env.unwrapped, "controlled_vehicles", ())))
    objects = [o for o in road.objects if getattr(o, "solid", True)]
    objects += [v for v in road.vehicles if id(v) not in controlled]
    scale = float(position_scale)
    return RectangleObstacles(
        centres=[np.asarray(o.position, np.float64) / scale for o in objects] or np.zeros((0, 2)),
        half_sizes=[(o.LENGTH / 2 / scale, o.WIDTH / 2 / scale) for o in objects] or np.zeros((0, 2)),
        headings=[o.heading for o in objects],
        margin=margin / scale,
        weight=weight,
        x_index=x_index,
        y_index=y_index,
    )


def parking_walls(margin: float = 2.7, weight: float = 100.0) -> RectangleObstacles:
    """
    parking-v0's four walls (its default config, walls on) in ``sb3_mpail/Parking-v0``'s observation units, read from a
    freshly reset env (needs the ``scenarios`` extra).

    :param margin: how far around each wall the cost reaches, in metres: the ego's half diagonal (5 m x 2 m: 2.7 m), so
        that no corner reaches a wall at any heading (with its half width, 1 m, 75% of a trained planner's episodes
        still ended in a crash); every slot lies farther from the walls than that
    :param weight: the cost at the edge
    """
    import gymnasium as gym

    import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Parking-v0)

    env = gym.make("sb3_mpail/Parking-v0")
    env.reset(seed=0)
    walls = highway_env_obstacles(env, position_scale=100.0, margin=margin, weight=weight)
    env.close()
    return walls


def maze_walls(env: Any, margin: float = 0.1, weight: float = 100.0, x_index: int = 0,
               y_index: int = 1) -> RectangleObstacles:  # fmt: skip
    """
    The wall cells of a gymnasium-robotics maze env (PointMaze, AntMaze: anything whose unwrapped env has a ``maze``)
    as :class:`RectangleObstacles`, in metres.

    :param env: a gymnasium-robotics maze env (wrappers are looked through)
    :param margin: how far around each wall the cost reaches, in metres (PointMaze's ball radius: 0.1 m)
    :param weight: the cost at the edge
    :param x_index: the state dimension of the position's x
    :param y_index: the state dimension of the position's y
    """
    maze = getattr(env.unwrapped, "maze", None)
    if maze is None or not hasattr(maze, "cell_rowcol_to_xy"):
        raise ValueError(f"maze_walls needs a gymnasium-robotics maze env (one whose unwrapped env has a maze); got {env}.")
    cells = [(row, column) for row, cells in enumerate(maze.maze_map) for column, cell in enumerate(cells) if cell == 1]
    half_size = maze.maze_size_scaling / 2
    return RectangleObstacles(
        centres=[maze.cell_rowcol_to_xy(np.array(cell)) for cell in cells] or np.zeros((0, 2)),
        half_sizes=[(half_size, half_size)] * len(cells) or np.zeros((0, 2)),
        margin=margin,
        weight=weight,
        x_index=x_index,
        y_index=y_index,
    )


def point_maze_walls(margin: float = 0.1, weight: float = 100.0, env_id: str = "sb3_mpail/PointMaze-v0") -> RectangleObstacles:
    """
    A flat PointMaze's walls (:func:`maze_walls` of ``sb3_mpail/PointMaze-v0``'s U-maze, or of ``env_id``'s maze;
    needs the ``scenarios`` extra).

    :param margin: how far around each wall the cost reaches, in metres (the ball's radius: 0.1 m)
    :param weight: the cost at the edge
    :param env_id: the maze env's id
    """
    import gymnasium as gym

    import sb3_mpail.envs  # noqa: F401  (registers the flat PointMazes)

    env = gym.make(env_id)
    walls = maze_walls(env, margin=margin, weight=weight)
    env.close()
    return walls


#: highway-env's lane width (m): its straight roads' lanes are centred on ``y = 0, 4, 8, ...``
LANE_WIDTH = 4.0
#: highway-env's vehicles' length and width (m)
VEHICLE_SIZE = (5.0, 2.0)


class TrafficCollisions(nn.Module):
    """
    Collisions with the other vehicles of ``sb3_mpail/HighwayTraffic-v0``'s states (:mod:`sb3_mpail.envs.highway_traffic`:
    the ego's ``[x, y, ...]``, then per vehicle ``[presence, x, y, vx, vy]``, positions in ``position_scale`` metres),
    and leaving the road. The obstacles move: each state is scored against the vehicles where that state puts them,
    so the planning model's predicted traffic is what the ego must keep clear of.

    For each present vehicle: ``weight * (1 + depth)`` when the ego's centre lies inside the rectangle (along the
    road, ``x``, and across it, ``y``) where the two cars touch, each vehicle's length and width (5 m x 2 m: its
    half sizes plus the ego's), inflated by ``margin``; ``depth`` is how far inside, in margins, on the nearer axis, so
    that samples that all collide are ranked by how deep they go. 0 elsewhere. The rectangles lie along the road: the
    observation has no heading of the other vehicles, and its vehicles drive along their lanes but for lane changes,
    which the lateral margin covers. With ``road_edges``, the same cost when the ego's centre is closer to an edge
    than its half width (its body leaves the road, where highway-env's reward is 0), ``depth`` in lateral margins.

    :param margin: how far beyond the touching rectangle the cost reaches, along and across the road (m), ``> 0``:
        along, constant-velocity traffic moves a few metres from its prediction within a second; across, less than
        the 2 m between cars centred in neighbouring lanes, which may then pass each other
    :param weight: the cost at the inflated rectangle's edge, ``> 0``: large against the learned costs, finite so that
        the samples that collide are still ranked
    :param road_edges: the road's edges ``(y_min, y_max)`` (m); ``None``: no cost for leaving the road
    :param position_scale: metres per observation unit of the positions
    """

    def __init__(
        self,
        margin: Tuple[float, float] = (2.0, 1.0),
        weight: float = 1000.0,
        road_edges: Optional[Tuple[float, float]] = None,
        position_scale: float = 10.0,
    ):
        super().__init__()
        margin = tuple(float(value) for value in margin)
        if len(margin) != 2 or min(margin) <= 0 or not weight > 0 or not position_scale > 0:
            raise ValueError(
                f"TrafficCollisions needs two margins > 0 (along and across the road), weight > 0 and position_scale "
                f"> 0; got margin={margin}, weight={weight}, position_scale={position_scale}."
            )
        if road_edges is not None and not road_edges[0] + VEHICLE_SIZE[1] < road_edges[1]:
            raise ValueError(f"TrafficCollisions' road_edges must be (y_min, y_max), wider than a car; got {road_edges}.")
        self.register_buffer("margin", th.tensor(margin))
        self.register_buffer("inflated_half_size", th.tensor(VEHICLE_SIZE) + self.margin)
        self.weight, self.position_scale = float(weight), float(position_scale)
        # where the ego's centre keeps its body on the road
        half_width = VEHICLE_SIZE[1] / 2
        self.road_edges = None if road_edges is None else (road_edges[0] + half_width, road_edges[1] - half_width)

    def check_state_dim(self, state_dim: int) -> None:
        """
        Refuses states of another size than the traffic observation's.

        :param state_dim: size of a state
        :raises ValueError: ``state_dim`` is not :data:`~sb3_mpail.envs.highway_traffic.TRAFFIC_STATE_DIM`
        """
        if state_dim != TRAFFIC_STATE_DIM:
            raise ValueError(
                f"TrafficCollisions scores sb3_mpail/HighwayTraffic-v0's {TRAFFIC_STATE_DIM}-D states (the ego, then "
                f"{TRAFFIC_VEHICLES} vehicles' {VEHICLE_FEATURES}); got {state_dim}-D states."
            )

    def forward(self, states: th.Tensor) -> th.Tensor:
        self.check_state_dim(states.shape[-1])  # Python integers: no host sync
        ego = states[..., :2] * self.position_scale
        vehicles = states[..., EGO_DIM:].unflatten(-1, (TRAFFIC_VEHICLES, len(VEHICLE_FEATURES)))  # (..., K, 5)
        present = vehicles[..., 0] > 0.5
        offsets = (ego.unsqueeze(-2) - vehicles[..., 1:3] * self.position_scale).abs()  # (..., K, 2), metres
        # how far inside each inflated rectangle, in margins, on the nearer axis: positive inside
        depth = ((self.inflated_half_size - offsets) / self.margin).amin(dim=-1)
        costs = th.where(present & (depth > 0), self.weight * (1 + depth), th.zeros_like(depth)).sum(-1)
        if self.road_edges is not None:
            y, (low, high) = ego[..., 1], self.road_edges
            beyond = th.maximum(low - y, y - high) / self.margin[1]
            costs = costs + th.where(beyond > 0, self.weight * (1 + beyond), th.zeros_like(beyond))
        return costs


def highway_traffic_vehicles(lanes_count: int = 3, margin: Tuple[float, float] = (2.0, 1.0),
                             weight: float = 1000.0) -> TrafficCollisions:  # fmt: skip
    """
    :class:`TrafficCollisions` of ``sb3_mpail/HighwayTraffic-v0``: its vehicles and the edges of its road (highway-fast's
    3 lanes, 4 m wide, centred on ``y = 0, 4, 8`` m; ``lanes_count=4`` for ``sb3_mpail/HighwayTrafficDense-v0``).

    :param lanes_count: the road's lanes
    :param margin: how far beyond where two cars touch the cost reaches, along and across the road (m)
    :param weight: the cost at the edge
    """
    return TrafficCollisions(margin, weight, road_edges=(-LANE_WIDTH / 2, LANE_WIDTH * (lanes_count - 0.5)))


#: constraint costs by the name a ``constraint_cost`` setting (a YAML file's, say) can give
CONSTRAINT_COSTS: Dict[str, Callable[[], nn.Module]] = {
    "parking_walls": parking_walls,
    "point_maze_walls": point_maze_walls,
    "point_maze_medium_walls": functools.partial(point_maze_walls, env_id="sb3_mpail/PointMazeMedium-v0"),
    "highway_traffic_vehicles": highway_traffic_vehicles,
    "highway_traffic_dense_vehicles": functools.partial(highway_traffic_vehicles, lanes_count=4),
}


def make_constraint_cost(
    spec: Union[str, Callable[[th.Tensor], th.Tensor], None], state_dim: Optional[int] = None
) -> Optional[Callable]:
    """
    The ``constraint_cost`` a setting names: a name of :data:`CONSTRAINT_COSTS`, a callable ``g(states)`` or ``None``.

    :param spec: the setting
    :param state_dim: size of the states it will score, to check a cost that reads given state dimensions (its
        ``check_state_dim``, e.g. :class:`RectangleObstacles`'); ``None``: unknown
    :raises ValueError: an unknown name, something else than a callable, or state dimensions out of range
    :raises TypeError: a callable that cannot be called with the states alone
    """
    if isinstance(spec, str):
        if spec not in CONSTRAINT_COSTS:
            raise ValueError(f"Unknown constraint_cost {spec!r}: a name of {sorted(CONSTRAINT_COSTS)}, a callable or None.")
        spec = CONSTRAINT_COSTS[spec]()
    if spec is not None and not callable(spec):
        raise ValueError(f"constraint_cost must be a name of {sorted(CONSTRAINT_COSTS)}, a callable or None; got {spec!r}.")
    if spec is not None:
        check_signature(spec, "constraint_cost", "g(states) -> costs", 1)
    if hasattr(spec, "check_state_dim") and state_dim is not None:
        spec.check_state_dim(state_dim)
    return spec

