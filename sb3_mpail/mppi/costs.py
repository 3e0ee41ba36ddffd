"""
What the planner minimises: a step cost on state transitions ``c(s, s')`` and a terminal value ``V(s_H)``.

In MPAIL the step cost is the negated discriminator logit, ``c(s, s') = -d_theta(s, s')``, and the terminal value
is the learned ``V_phi``, so both are thin views of networks the algorithm trains.
"""

import math
import numbers
from collections import deque
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import torch as th
from gymnasium import spaces
from imitation.rewards.reward_nets import BasicRewardNet
from stable_baselines3.common.torch_layers import create_mlp
from torch import nn
from torch.nn.utils.parametrizations import spectral_norm

from sb3_mpail.mppi.ensemble import DiscriminatorEnsemble, FrozenEnsembleCost, ValueEnsemble, frozen_members
from sb3_mpail.mppi.fused import FrozenMlp, FusedTransitionCost, FusedValue, ViewCache, freeze_mlp, fused_mlp_ok
from sb3_mpail.mppi.reward_forms import REWARD_FORMS

#: what a network sees of a state: a module, a function, state indices, or ``{"angles": [indices]}``
FeatureSpec = Union[nn.Module, Callable[[th.Tensor], th.Tensor], Sequence[int], Mapping[str, Sequence[int]]]


def make_transition_discriminator(
    observation_space: spaces.Box,
    action_space: spaces.Box,
    hidden_sizes: Sequence[int] = (32, 32),
    use_spectral_norm: bool = True,
) -> BasicRewardNet:
    """
    The state-only discriminator logit ``d_theta(s, s')``: imitation's ``BasicRewardNet`` on ``(s, s')`` (no action),
    LeakyReLU, with spectral normalisation on every linear layer (the output layer included).

    :param observation_space: space of the states the discriminator sees
    :param action_space: the environment's action space (unused by the net, required by imitation's constructor)
    :param hidden_sizes: hidden layer widths
    :param use_spectral_norm: wrap every linear layer in spectral normalisation
    """
    discriminator = BasicRewardNet(
        observation_space,
        action_space,
        use_state=True,
        use_action=False,
        use_next_state=True,
        use_done=False,
        hid_sizes=tuple(hidden_sizes),
        activation=nn.LeakyReLU,
    )
    if use_spectral_norm:
        for name, layer in list(discriminator.mlp.named_children()):
            if isinstance(layer, nn.Linear):
                setattr(discriminator.mlp, name, spectral_norm(layer))
    return discriminator


def make_value_network(
    state_dim: int, hidden_sizes: Sequence[int] = (32, 32), layer_norm: bool = False, concave: bool = False
) -> nn.Module:
    """
    The value ``V_phi(s)``: an MLP with ReLU and a scalar output.

    :param state_dim: size of its input
    :param hidden_sizes: hidden layer widths
    :param layer_norm: layer-normalise each hidden layer before its ReLU (as MPAIL2's and TD-MPC2's networks do). It
        bounds the output: far from the data the value levels off along every direction instead of extrapolating its
        slope linearly, as a plain ReLU network does
    :param concave: a :class:`ConcaveValue` instead of the MLP (not together with ``layer_norm``)
    """
    if concave:
        if layer_norm:
            raise ValueError("A concave value has no layer normalisation: set value_layer_norm or concave_value, not both.")
        return ConcaveValue(state_dim, hidden_sizes)
    if not layer_norm:
        return nn.Sequential(*create_mlp(state_dim, 1, list(hidden_sizes), nn.ReLU))
    layers: List[nn.Module] = []
    for n_in, n_out in zip([state_dim, *hidden_sizes], hidden_sizes):
        layers += [nn.Linear(n_in, n_out), nn.LayerNorm(n_out), nn.ReLU()]
    return nn.Sequential(*layers, nn.Linear(hidden_sizes[-1] if hidden_sizes else state_dim, 1))


class ConcaveValue(nn.Module):
    """
    A value that is concave in its inputs: a negated input-convex network (Amos et al., 2017). Each hidden layer is
    ``relu(W_z z + W_x x + b)`` with ``W_z >= 0`` (the softplus of free weights), the output the negation of a
    non-negative combination of the last layer plus a linear term in ``x``. It peaks on one region it learns and
    falls away from it in every direction, so far from the data it never rises, where a ReLU MLP extrapolates
    whatever slope it has learned (on navigation: rising past the goal).

    :param in_size: size of its input
    :param hidden_sizes: hidden layer widths
    """

    def __init__(self, in_size: int, hidden_sizes: Sequence[int] = (32, 32)):
        super().__init__()
        sizes = list(hidden_sizes)
        self.input_layers = nn.ModuleList(nn.Linear(in_size, n_out) for n_out in [*sizes, 1])
        self.hidden_weights = nn.ParameterList(
            # softplus(w) starts near 1 / n_in, a fan-in scale, with a little noise to break symmetry
            nn.Parameter(math.log(math.expm1(1.0 / n_in)) + 0.1 * th.randn(n_out, n_in))
            for n_in, n_out in zip(sizes, [*sizes[1:], 1])
        )

    def forward(self, inputs: th.Tensor) -> th.Tensor:
        convex = self.input_layers[0](inputs)
        for input_layer, weight in zip(self.input_layers[1:], self.hidden_weights):
            # a non-negative combination of convex functions of the inputs, plus an affine one, stays convex
            convex = nn.functional.linear(th.relu(convex), nn.functional.softplus(weight)) + input_layer(inputs)
        return -convex


def _state_indices(indices: Any, name: str) -> List[int]:
    """
    ``indices`` as Python ints, refusing anything but a non-empty sequence of integers (numpy's included).

    :param indices: the state indices given
    :param name: the setting they were given as, which the message names
    :raises ValueError: ``indices`` is not a non-empty sequence of integers
    """
    if not (isinstance(indices, Sequence) and not isinstance(indices, str)) or len(indices) == 0:
        raise ValueError(f"{name} must be a non-empty list of state indices; got {indices!r}.")
    if not all(isinstance(index, numbers.Integral) and not isinstance(index, bool) for index in indices):
        raise ValueError(f"{name} must hold integer state indices; got {list(indices)!r}.")
    return [int(index) for index in indices]


def _check_index_range(indices: Sequence[int], low: int, state_dim: int, name: str) -> None:
    """
    Refuses indices outside ``[low, state_dim)``: torch would raise an unclear error or, for a slice, ignore them.

    :param indices: the state indices
    :param low: the smallest index allowed (``-state_dim`` where negative indices count from the end)
    :param state_dim: size of a state
    :param name: the setting they were given as, which the message names
    :raises ValueError: an index is out of range
    """
    outside = [index for index in indices if not low <= index < state_dim]
    if outside:
        raise ValueError(
            f"{name} holds state indices {outside} out of range for the {state_dim}-D state; "
            f"they must be in [{low}, {state_dim})."
        )


class FeatureSelection(nn.Module):
    """
    Discriminator features that are some of the state's dimensions, e.g. ``[0, 1, 6, 7]`` for the navigation car's
    position and body-frame velocity (a list of indices is also what a YAML hyperparameter file can hold). Negative
    indices count from the end, as in Python.

    :param indices: the state dimensions kept, in this order
    :param name: the setting the indices were given as, which error messages name
    """

    def __init__(self, indices: Sequence[int], name: str = "indices"):
        super().__init__()
        self.register_buffer("indices", th.as_tensor(_state_indices(indices, name), dtype=th.long))

    def check_state_dim(self, state_dim: int, name: str) -> None:
        """
        Refuses indices out of range for ``state_dim``-D states.

        :param state_dim: size of a state
        :param name: the setting the indices were given as, which the message names
        """
        _check_index_range(self.indices.tolist(), -state_dim, state_dim, name)

    def forward(self, states: th.Tensor) -> th.Tensor:
        return states[:, self.indices]


class AngleFeatures(nn.Module):
    """
    The state with each angle replaced by its cosine and sine (placed where the angle was), so a network sees headings
    as the continuous, bounded points they are rather than as wrapped numbers: ``-pi + 0.01`` and ``pi - 0.01`` are
    neighbours, and no heading lies beyond the data's range for a network to extrapolate to.

    :param angle_indices: the state dimensions that are angles (e.g. ``[5]``, the navigation car's yaw), distinct and
        non-negative (the angles are placed by slicing, which a negative index would misplace)
    :param name: the setting the indices were given as, which error messages name
    """

    def __init__(self, angle_indices: Sequence[int], name: str = "angle_indices"):
        super().__init__()
        indices = _state_indices(angle_indices, name)
        if len(set(indices)) != len(indices) or min(indices) < 0:
            raise ValueError(f"{name} must be distinct angle indices >= 0; got {indices}.")
        self.angle_indices = indices

    def check_state_dim(self, state_dim: int, name: str) -> None:
        """
        Refuses angle indices out of range for ``state_dim``-D states.

        :param state_dim: size of a state
        :param name: the setting the indices were given as, which the message names
        """
        _check_index_range(self.angle_indices, 0, state_dim, name)

    def forward(self, states: th.Tensor) -> th.Tensor:
        columns, previous = [], 0
        for index in sorted(self.angle_indices):
            angle = states[:, index : index + 1]
            columns += [states[:, previous:index], th.cos(angle), th.sin(angle)]
            previous = index + 1
        return th.cat([*columns, states[:, previous:]], dim=1)


class IndexPairFeatures(nn.Module):
    """
    Base of the feature maps that read named pairs of state indices (a position, a heading's cosine and sine).

    :param pairs: each pair's name and its two state indices
    :param scales: each positive factor's name and value
    :param name: the setting the map was given as, which error messages name
    """

    def __init__(self, pairs: Mapping[str, Sequence[int]], scales: Mapping[str, float], name: str):
        super().__init__()
        self.indices = {key: _state_indices(value, f"{name}['{key}']") for key, value in pairs.items()}
        wrong = {key: value for key, value in self.indices.items() if len(value) != 2}
        if wrong:
            raise ValueError(f"{name} takes two state indices for each of {sorted(wrong)}; got {wrong}.")
        for key, scale in scales.items():
            if not (isinstance(scale, numbers.Real) and scale > 0):
                raise ValueError(f"{name}['{key}'] must be a number > 0; got {scale!r}.")
        self.name = name

    def check_state_dim(self, state_dim: int, name: str) -> None:
        """
        Refuses indices out of range for ``state_dim``-D states (negative ones count from the end).

        :param state_dim: size of a state
        :param name: the setting the map was given as (the message names the map's own ``name``, which says more)
        """
        for key, indices in self.indices.items():
            _check_index_range(indices, -state_dim, state_dim, f"{self.name}['{key}']")


class GoalFrameFeatures(IndexPairFeatures):
    """
    A goal-conditioned state seen from its goal: the position and velocity in the goal's frame (along and across the
    goal's heading) and the heading relative to the goal's, as cosine and sine; for a goal without a heading (a point
    to reach), the offset from the goal and the velocity in the world's axes. Demos that end at different goals
    (parking slots, a maze's goal cell with its noise) then all look alike, and a discriminator learns one approach
    rather than one per goal.

    :param position: the state indices of the position ``(x, y)``
    :param goal_position: the indices of the goal's position
    :param heading: the indices of the heading's ``(cos, sin)``; ``None`` (with ``goal_heading``): a goal without one
    :param goal_heading: the indices of the goal heading's ``(cos, sin)``
    :param velocity: the indices of the velocity ``(vx, vy)`` (in the world frame); ``None``: no velocity features
    :param position_scale: factor on the position features (e.g. 10 where a 5 m offset is 0.05 state units: a
        spectral-normed discriminator's slope bound otherwise lets it barely tell such offsets apart)
    :param name: the setting it was given as, which error messages name
    :raises ValueError: only one of ``heading`` and ``goal_heading`` is given
    """

    def __init__(
        self,
        position: Sequence[int],
        goal_position: Sequence[int],
        heading: Sequence[int] | None = None,
        goal_heading: Sequence[int] | None = None,
        velocity: Sequence[int] | None = None,
        position_scale: float = 1.0,
        name: str = "goal_frame",
    ):
        if (heading is None) != (goal_heading is None):
            raise ValueError(
                f"{name} takes both heading and goal_heading (a goal with a heading) or neither (a point to reach); "
                f"got heading={heading!r}, goal_heading={goal_heading!r}."
            )
        pairs = dict(position=position, goal_position=goal_position)
        for key, indices in dict(heading=heading, goal_heading=goal_heading, velocity=velocity).items():
            if indices is not None:
                pairs[key] = indices
        super().__init__(pairs, dict(position_scale=position_scale), name)
        self.position_scale = float(position_scale)

    def forward(self, states: th.Tensor) -> th.Tensor:
        def pair(key: str) -> Tuple[th.Tensor, th.Tensor]:
            first, second = self.indices[key]
            return states[:, first], states[:, second]

        (x, y), (goal_x, goal_y) = pair("position"), pair("goal_position")
        if "heading" in self.indices:
            (cos, sin), (goal_cos, goal_sin) = pair("heading"), pair("goal_heading")

        def in_goal_frame(dx: th.Tensor, dy: th.Tensor) -> List[th.Tensor]:
            if "heading" not in self.indices:  # a goal without heading: the world's axes
                return [dx, dy]
            return [dx * goal_cos + dy * goal_sin, dy * goal_cos - dx * goal_sin]

        columns = [self.position_scale * column for column in in_goal_frame(x - goal_x, y - goal_y)]
        if "velocity" in self.indices:
            columns += in_goal_frame(*pair("velocity"))
        if "heading" in self.indices:
            columns += [cos * goal_cos + sin * goal_sin, sin * goal_cos - cos * goal_sin]
        return th.stack(columns, dim=1)


#: segments a :class:`LaneFrameFeatures` grid cell keeps: more than can be nearest to a point near the racetrack's lanes (13)
MAX_CANDIDATE_SEGMENTS = 16


def squared_segment_distances(positions: th.Tensor, starts: th.Tensor, directions: th.Tensor, lengths: th.Tensor) -> th.Tensor:
    """
    Each position's squared distance to each of ``n`` segments, ``(batch, n)``: the same segments for every position
    (``starts`` and ``directions`` ``(n, 2)``, ``lengths`` ``(n,)``) or each position's own (``(batch, n, 2)`` and
    ``(batch, n)``).

    :param positions: ``(batch, 2)``
    :param starts: the segments' starts
    :param directions: their unit directions
    :param lengths: their lengths
    """
    offsets = positions.unsqueeze(1) - starts
    along = th.minimum((offsets * directions).sum(dim=-1).clamp(min=0), lengths)  # the projection onto the segment
    residuals = offsets - along.unsqueeze(-1) * directions  # not |offset|^2 - along^2, which cancels in float32
    return (residuals * residuals).sum(dim=-1)


class LaneFrameFeatures(IndexPairFeatures):
    """
    A vehicle's state seen from the road: its signed lateral offset from the nearest lane's centre line and its heading
    relative to that lane's direction, as cosine and sine. Every stretch of the road then looks alike, so a
    discriminator learns "keep to the centre of a lane, along it" once, rather than where on the map the demos drove
    (from absolute positions it learns the latter, and cuts the curves it extrapolates across).

    The centre lines are polylines. The planner maps about ``10^4`` states per call, too many to measure against every
    segment, so a grid over the road holds, per cell, every segment that can be nearest to a point in it (measured
    once, at most :data:`MAX_CANDIDATE_SEGMENTS`); a state is measured against its cell's only. That is exact wherever no
    more segments can be nearest, which holds near the road (on the racetrack, within 10 m of a lane's centre); farther
    out, and beyond the grid (which reaches a tenth of the road's extent past it, its edge cells serving beyond),
    a state may be measured from a segment a little farther than the nearest: it is off the road either way.

    :param centrelines: each lane's centre line in the driving direction, ``(n_points, 2)`` positions in the state's
        units (at least two points each); or the name of a road of :data:`NAMED_LANES`
    :param position: the state indices of the position ``(x, y)``
    :param heading: the indices of the heading's ``(cos, sin)``; ``None``: no heading features (states without one,
        e.g. a demo of positions and body-frame velocities)
    :param lateral_scale: factor on the lateral offset (e.g. 10 where a state unit is 10 m, so that the feature is in
        metres: a spectral-normed discriminator's slope bound otherwise lets it barely tell a lane's centre from its edge)
    :param cell_size: the lookup grid's cell, in the state's units; ``None``: half the median segment's length
    :param keep: state indices passed on as they are after the lane-frame features (e.g. body-frame velocities, which
        no place on the road changes); ``None``: none
    :param name: the setting it was given as, which error messages name
    """

    def __init__(
        self,
        centrelines: Union[str, Sequence[Any]],
        position: Sequence[int],
        heading: Sequence[int] | None = None,
        lateral_scale: float = 1.0,
        cell_size: Optional[float] = None,
        keep: Sequence[int] | None = None,
        name: str = "lane_frame",
    ):
        pairs = dict(position=position) if heading is None else dict(position=position, heading=heading)
        super().__init__(pairs, dict(lateral_scale=lateral_scale), name)
        self.keep = [] if keep is None else _state_indices(keep, f"{name}['keep']")
        if isinstance(centrelines, str):
            if centrelines not in NAMED_LANES:
                raise ValueError(f"{name}['centrelines'] names no known road: {centrelines!r} is not one of "
                                 f"{sorted(NAMED_LANES)}.")  # fmt: skip
            centrelines = NAMED_LANES[centrelines]()
        lines = [np.asarray(line, dtype=np.float32) for line in centrelines]
        wrong = [index for index, line in enumerate(lines) if line.ndim != 2 or line.shape[1] != 2 or len(line) < 2]
        if not lines or wrong:
            raise ValueError(f"{name}['centrelines'] must be polylines of (n_points >= 2, 2) positions; got {len(lines)} "
                             f"lines, lines {wrong} of another shape.")  # fmt: skip
        starts = np.concatenate([line[:-1] for line in lines])
        steps = np.concatenate([np.diff(line, axis=0) for line in lines])
        lengths = np.linalg.norm(steps, axis=1)
        if not (np.isfinite(starts).all() and (lengths > 0).all()):
            raise ValueError(f"{name}['centrelines'] must hold finite positions with no point repeated consecutively.")
        cell_size = float(np.median(lengths) / 2) if cell_size is None else cell_size
        if not (isinstance(cell_size, numbers.Real) and cell_size > 0):
            raise ValueError(f"{name}['cell_size'] must be a number > 0 or None; got {cell_size!r}.")
        self.register_buffer("segment_starts", th.as_tensor(starts))
        self.register_buffer("segment_directions", th.as_tensor(steps / lengths[:, None]))
        self.register_buffer("segment_lengths", th.as_tensor(lengths))
        self.lateral_scale, self.cell_size = float(lateral_scale), float(cell_size)
        # the grid reaches a tenth of the road's extent beyond it; derived from the segments, so not saved
        points = np.concatenate(lines)
        margin = 0.1 * (points.max(axis=0) - points.min(axis=0)).max()
        origin = points.min(axis=0) - margin
        n_x, n_y = np.ceil((points.max(axis=0) + margin - origin) / self.cell_size).astype(int) + 1
        centres = th.as_tensor(origin + self.cell_size * (np.stack(np.meshgrid(np.arange(n_x), np.arange(n_y)), -1) + 0.5))
        segments = self.segment_starts, self.segment_directions, self.segment_lengths
        # a segment can be nearest to a point of a cell only if it lies within the nearest's distance to the cell's
        # centre plus the cell's diagonal (the triangle inequality, twice): each cell keeps those, up to a cap
        diagonal, nearest_first, most = self.cell_size * math.sqrt(2), [], 0
        for chunk in centres.reshape(-1, 2).float().split(4096):  # chunks: cells x segments can be large
            distances = squared_segment_distances(chunk, *segments)
            window = (distances.min(dim=1, keepdim=True).values.sqrt() + diagonal) ** 2
            most = max(most, int((distances <= window).sum(dim=1).max()))
            nearest_first.append(distances.topk(min(MAX_CANDIDATE_SEGMENTS, len(lengths)), largest=False).indices)
        candidates = th.cat(nearest_first)[:, : min(MAX_CANDIDATE_SEGMENTS, most)]
        self.register_buffer("grid_origin", th.as_tensor(origin, dtype=th.float32), persistent=False)
        self.register_buffer("grid_candidates", candidates.reshape(int(n_y), int(n_x), -1), persistent=False)

    def check_state_dim(self, state_dim: int, name: str) -> None:
        super().check_state_dim(state_dim, name)
        _check_index_range(self.keep, -state_dim, state_dim, f"{self.name}['keep']")

    def forward(self, states: th.Tensor) -> th.Tensor:
        positions = states[:, self.indices["position"]]
        n_y, n_x, _ = self.grid_candidates.shape
        cells = ((positions - self.grid_origin) / self.cell_size).long()
        candidates = self.grid_candidates[cells[:, 1].clamp(0, n_y - 1), cells[:, 0].clamp(0, n_x - 1)]  # (batch, k)
        segments = self.segment_starts[candidates], self.segment_directions[candidates], self.segment_lengths[candidates]
        squared_distance, nearest = squared_segment_distances(positions, *segments).min(dim=1)
        nearest = candidates.gather(1, nearest.unsqueeze(1)).squeeze(1)
        direction, offset = self.segment_directions[nearest], positions - self.segment_starts[nearest]
        # the distance to the centre line, on the left of the lane's direction > 0 (round a bend's outside, segments
        # equally near agree on it, where the distances to their lines would differ)
        side = th.sign(direction[:, 0] * offset[:, 1] - direction[:, 1] * offset[:, 0])
        columns = [self.lateral_scale * side * squared_distance.sqrt()]
        if "heading" in self.indices:
            cos, sin = states[:, self.indices["heading"]].unbind(dim=1)
            columns += [cos * direction[:, 0] + sin * direction[:, 1], sin * direction[:, 0] - cos * direction[:, 1]]
        return th.cat([th.stack(columns, dim=1), states[:, self.keep]], dim=1)


def highway_env_lane_centrelines(env: Any, position_scale: float = 1.0, spacing: float = 2.0) -> List[np.ndarray]:
    """
    Every lane's centre line of a highway-env road (its ``road.network``), sampled every ``spacing`` metres and at its
    end, divided by ``position_scale`` (the observation's units).

    :param env: a highway-env env, or one that holds it as ``road_env`` (wrappers are looked through)
    :param position_scale: metres per state unit of the position
    :param spacing: metres between samples along a lane
    """
    road_env = getattr(env.unwrapped, "road_env", env.unwrapped)
    road = getattr(road_env, "road", None)
    if road is None:
        raise ValueError(f"highway_env_lane_centrelines needs a highway-env env with a road (reset it first); got {env}.")
    lines = []
    for ends in road.network.graph.values():
        for lanes in ends.values():
            for lane in lanes:
                longitudinal = np.append(np.arange(0.0, lane.length, spacing), lane.length)
                lines.append(np.array([lane.position(s, 0.0) for s in longitudinal]) / position_scale)
    return lines


def racetrack_lanes() -> List[np.ndarray]:
    """``sb3_mpail/Racetrack-v0``'s lane centre lines in its observation's units (needs the ``scenarios`` extra)."""
    import gymnasium as gym

    import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Racetrack-v0)

    env = gym.make("sb3_mpail/Racetrack-v0")
    env.reset(seed=0)
    lines = highway_env_lane_centrelines(env, position_scale=10.0)
    env.close()
    return lines


def lap_demo_path() -> List[np.ndarray]:
    """
    The path of ``sb3_mpail/NavigationLap-v0``'s shipped demo (``lap_1``): its recorded positions, noise and all,
    closed into a loop; a car that keeps to it drives the demo's lap, wherever on the lap it is.
    """
    from sb3_mpail.demos import shipped_demos  # the demos module reads files only; imported here, where it is needed

    positions = shipped_demos("lap", 1)[0].obs[:, :2]
    return [np.concatenate([positions, positions[:1]])]


#: roads by the name a ``lane_frame`` setting's ``centrelines`` (a YAML file's, say) can give
NAMED_LANES: Dict[str, Callable[[], List[np.ndarray]]] = {"racetrack": racetrack_lanes, "lap_demo": lap_demo_path}


def maze_shortest_paths(maze_map: Sequence[Sequence[Any]]) -> Tuple[np.ndarray, np.ndarray]:
    """
    Shortest paths between a maze's cells, by breadth-first search from each free goal cell over the free cells,
    4-connected. A wall cell steps to its nearest neighbour (a state the planner imagines inside a wall still has a
    way out); cells with no way to the goal keep themselves as next, a path of ``n_cells`` steps.

    :param maze_map: rows of cells, ``1`` for a wall (anything else, gymnasium-robotics' ``0``, ``"r"`` or ``"g"``, is free)
    :return: ``next_cell[cell, goal]``, the next cell on a shortest path (flat indices ``row * n_columns + column``;
        the goal itself at the goal), and ``steps[cell, goal]``, the path's number of steps
    """
    n_rows, n_columns = len(maze_map), len(maze_map[0])
    n_cells = n_rows * n_columns
    wall = np.array([[cell == 1 for cell in row] for row in maze_map]).reshape(-1)
    next_cell = np.tile(np.arange(n_cells)[:, None], (1, n_cells))
    steps = np.full((n_cells, n_cells), n_cells)
    for goal in np.flatnonzero(~wall):
        steps[goal, goal], frontier = 0, deque([goal])
        while frontier:
            cell = frontier.popleft()
            row, column = divmod(int(cell), n_columns)
            for row_step, column_step in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                if not (0 <= row + row_step < n_rows and 0 <= column + column_step < n_columns):
                    continue
                neighbour = cell + row_step * n_columns + column_step
                # a free cell is entered only from a free cell; a wall cell leaves to anything
                if steps[neighbour, goal] == n_cells and (wall[neighbour] or not wall[cell]):
                    steps[neighbour, goal], next_cell[neighbour, goal] = steps[cell, goal] + 1, cell
                    frontier.append(neighbour)
    return next_cell, steps


class MazeFrameFeatures(IndexPairFeatures):
    """
    A goal-conditioned state in a maze seen along the maze's shortest path to the goal: the offset to the next
    waypoint (the centre of the next cell on a shortest path through free cells; the goal itself from the goal's cell
    and the cells next to it), the path length left to the goal (the offset's length plus the cells beyond the
    waypoint) and the velocity. Every start and goal then look alike to a discriminator, which learns "follow the
    path"; from the goal's offset it would learn the straight line, which the walls block. The map is what a
    designer knows, like a road's lanes.

    :param maze_map: rows of cells, ``1`` for a wall; or a map's name (:func:`sb3_mpail.envs.maze.named_maze_map`:
        ``"u_maze_fixed"``, ``"medium"``)
    :param position: the state indices of the position ``(x, y)``
    :param goal_position: the indices of the goal's position
    :param velocity: the indices of the velocity ``(vx, vy)``; ``None``: no velocity features
    :param cell_size: a cell's side (gymnasium-robotics' ``maze_size_scaling``), in the state's units; the map is
        centred on the origin, its rows running down ``y``
    :param position_scale: factor on the offset and path length
    :param name: the setting it was given as, which error messages name
    """

    def __init__(
        self,
        maze_map: Union[str, Sequence[Sequence[Any]]],
        position: Sequence[int],
        goal_position: Sequence[int],
        velocity: Sequence[int] | None = None,
        cell_size: float = 1.0,
        position_scale: float = 1.0,
        name: str = "maze_frame",
    ):
        pairs = dict(position=position, goal_position=goal_position)
        if velocity is not None:
            pairs["velocity"] = velocity
        super().__init__(pairs, dict(cell_size=cell_size, position_scale=position_scale), name)
        if isinstance(maze_map, str):
            from sb3_mpail.envs.maze import named_maze_map  # the envs need gymnasium; imported where a name is given

            maze_map = named_maze_map(maze_map)
        if not (isinstance(maze_map, Sequence) and maze_map and len({len(row) for row in maze_map}) == 1):
            raise ValueError(f"{name}['maze_map'] must be rows of cells of one length (1 for a wall); got {maze_map!r}.")
        next_cell, steps = maze_shortest_paths(maze_map)
        n_rows, n_columns = len(maze_map), len(maze_map[0])
        rows, columns = np.divmod(np.arange(n_rows * n_columns), n_columns)
        centres = np.stack([(columns + 0.5 - n_columns / 2), (n_rows / 2 - rows - 0.5)], axis=1) * cell_size
        self.register_buffer("cell_centres", th.as_tensor(centres, dtype=th.float32), persistent=False)
        self.register_buffer("next_cell", th.as_tensor(next_cell), persistent=False)
        self.register_buffer("steps", th.as_tensor(steps, dtype=th.float32), persistent=False)
        self.shape, self.cell_size, self.position_scale = (n_rows, n_columns), float(cell_size), float(position_scale)

    def cell_of(self, positions: th.Tensor) -> th.Tensor:
        """Each position's flat cell index (clamped to the map)."""
        n_rows, n_columns = self.shape
        row = th.floor(n_rows / 2 - positions[:, 1] / self.cell_size).long().clamp(0, n_rows - 1)
        column = th.floor(positions[:, 0] / self.cell_size + n_columns / 2).long().clamp(0, n_columns - 1)
        return row * n_columns + column

    def forward(self, states: th.Tensor) -> th.Tensor:
        positions, goals = states[:, self.indices["position"]], states[:, self.indices["goal_position"]]
        cell, goal_cell = self.cell_of(positions), self.cell_of(goals)
        next_cell = self.next_cell[cell, goal_cell]
        at_goal = self.steps[next_cell, goal_cell] == 0  # in the goal's cell or next to it: make for the goal itself
        waypoints = th.where(at_goal.unsqueeze(1), goals, self.cell_centres[next_cell])
        offsets = waypoints - positions
        path_left = offsets.norm(dim=1) + self.steps[next_cell, goal_cell] * self.cell_size
        columns = [self.position_scale * offsets, self.position_scale * path_left.unsqueeze(1)]
        if "velocity" in self.indices:
            columns.append(states[:, self.indices["velocity"]])
        return th.cat(columns, dim=1)


class FeatureChain(nn.Sequential):
    """
    Feature maps applied one after the other, e.g. the state dimensions a partial demo holds, then a lane frame of
    those. With ``demos_are_features``, the demos hold what the first map gives and pass through the others.

    :param maps: the maps, first applied first
    """

    def check_state_dim(self, state_dim: int, name: str) -> None:
        """Refuses indices out of range of what each map receives: ``state_dim``-D states, then its predecessor's output."""
        for index, features in enumerate(self):
            if hasattr(features, "check_state_dim"):  # the maps built from indices (a nested chain included)
                features.check_state_dim(state_dim, f"{name}['chain'][{index}]")
            with th.no_grad():
                state_dim = features(th.zeros(2, state_dim)).shape[1]


class FeatureMap(nn.Module):
    """
    A fixed map from ``(batch, state_dim)`` states to ``(batch, n_features)`` discriminator features.

    :param function: a plain function ``features(states) -> features`` on torch tensors
    """

    def __init__(self, function: Callable[[th.Tensor], th.Tensor]):
        super().__init__()
        self.function = function

    @classmethod
    def wrap(cls, features: FeatureSpec, name: str = "discriminator_features") -> nn.Module:
        """
        The module itself, a :class:`FeatureSelection` of state indices, :class:`AngleFeatures` for ``{"angles":
        [indices]}``, :class:`GoalFrameFeatures` for ``{"goal_frame": {its settings}}``, :class:`LaneFrameFeatures` for
        ``{"lane_frame": {its settings}}``, :class:`MazeFrameFeatures` for ``{"maze_frame": {its settings}}``, a
        :class:`FeatureChain` for ``{"chain": [map, map, ...]}`` (forms a YAML hyperparameter file can hold), or a
        function wrapped in a :class:`FeatureMap`.

        :param features: the feature map as given
        :param name: the setting it was given as (``discriminator_features`` or ``value_features``), which error
            messages name
        """
        if isinstance(features, nn.Module):
            return features
        if isinstance(features, Mapping):
            if set(features) == {"chain"}:
                maps = features["chain"]
                if not (isinstance(maps, Sequence) and not isinstance(maps, str)) or len(maps) < 2:
                    raise ValueError(f"{name}['chain'] must be a list of two or more feature maps; got {maps!r}.")
                return FeatureChain(*(cls.wrap(spec, f"{name}['chain'][{i}]") for i, spec in enumerate(maps)))
            if set(features) == {"angles"}:
                return AngleFeatures(features["angles"], f"{name}['angles']")
            if set(features) == {"goal_frame"} and isinstance(features["goal_frame"], Mapping):
                return GoalFrameFeatures(**features["goal_frame"], name=f"{name}['goal_frame']")
            if set(features) == {"lane_frame"} and isinstance(features["lane_frame"], Mapping):
                return LaneFrameFeatures(**features["lane_frame"], name=f"{name}['lane_frame']")
            if set(features) == {"maze_frame"} and isinstance(features["maze_frame"], Mapping):
                return MazeFrameFeatures(**features["maze_frame"], name=f"{name}['maze_frame']")
            raise ValueError(
                f"A dict of {name} takes one key, 'angles' (a list of indices), 'goal_frame' (a dict of "
                f"GoalFrameFeatures' settings), 'lane_frame' (LaneFrameFeatures'), 'maze_frame' (MazeFrameFeatures') "
                f"or 'chain' (a list of maps applied in turn); got {dict(features)}."
            )
        if isinstance(features, Sequence) and not isinstance(features, str):
            return FeatureSelection(features, name)
        if not callable(features):
            raise TypeError(
                f"{name} must be an nn.Module, a callable or a list of state indices, got {type(features).__name__}."
            )
        return cls(features)

    def forward(self, states: th.Tensor) -> th.Tensor:
        return self.function(states)

    @staticmethod
    def space(features: nn.Module, observation_space: spaces.Box, name: str = "discriminator_features") -> spaces.Box:
        """
        The unbounded ``Box`` of the features, sized by mapping two zero states; refuses state indices out of range
        and maps that do not give ``(batch, n_features)`` of the states' dtype (float64 or boolean features would
        meet the float32 networks).

        :param features: the feature map
        :param observation_space: the states it maps
        :param name: the setting it was given as (``discriminator_features`` or ``value_features``), which error
            messages name
        """
        state_dim = observation_space.shape[0]
        if hasattr(features, "check_state_dim"):  # the maps built from indices
            features.check_state_dim(state_dim, name)
        states = th.zeros((2, *observation_space.shape))
        with th.no_grad():
            probe = features(states)
        if not isinstance(probe, th.Tensor) or probe.ndim != 2 or probe.shape[0] != 2:
            shape = tuple(probe.shape) if isinstance(probe, th.Tensor) else type(probe).__name__
            raise ValueError(
                f"{name} must map (batch, {state_dim}) states to a (batch, n_features) tensor; "
                f"for a batch of 2 it gave {shape}."
            )
        if probe.dtype != states.dtype:
            raise ValueError(
                f"{name} must return features of the states' dtype ({states.dtype} here); for {str(states.dtype)[6:]} "
                f"states it gave {probe.dtype}. Return real numbers in the states' dtype (e.g. features.to(states.dtype))."
            )
        return spaces.Box(-np.inf, np.inf, (probe.shape[1],), np.float32)


class StandardisedFeatures(nn.Module):
    """
    A feature map's output standardised per feature, ``(features(x) - mean) / scale``, with statistics fitted once
    (from the demos, :meth:`fit`) and saved with the model: the networks behind it then see inputs of comparable size
    whatever the units of the state (metres beside m/s beside rad), which spectral norm's slope bound and the first
    layer's initialisation assume. The scale is floored so that features the demos hold nearly constant are not blown
    up far from them.

    :param features: the map standardised (``None``: the states themselves)
    :param n_features: its output size
    :param min_scale: the floor of each feature's scale (its standard deviation in the demos)
    """

    def __init__(self, features: Optional[nn.Module], n_features: int, min_scale: float = 1.0):
        super().__init__()
        self.features = features
        self.min_scale = float(min_scale)
        self.register_buffer("mean", th.zeros(n_features))
        self.register_buffer("scale", th.ones(n_features))
        self.register_buffer("fitted", th.tensor(False))

    def fit(self, states: th.Tensor) -> None:
        """Sets the statistics from ``(batch, state_dim)`` states (the demos'), at least two of them."""
        with th.no_grad():
            mapped = states if self.features is None else self.features(states)
            self.mean.copy_(mapped.mean(0))
            self.scale.copy_(mapped.std(0).clamp(min=self.min_scale))
            self.fitted.fill_(True)

    def forward(self, states: th.Tensor) -> th.Tensor:
        mapped = states if self.features is None else self.features(states)
        return (mapped - self.mean) / self.scale


class MappedNetwork(nn.Module):
    """
    ``network(features(x))``: a network behind a fixed feature map (the value's ``value_features``), kept apart so the
    planner's fast path can map a whole roll-out once and run the bare network on it.

    :param features: the fixed map, ``(batch, state_dim)`` to ``(batch, n_features)``
    :param network: the network on the features
    """

    def __init__(self, features: nn.Module, network: nn.Module):
        super().__init__()
        self.features = features
        self.network = network

    def forward(self, states: th.Tensor) -> th.Tensor:
        return self.network(self.features(states))


def member_values(value_network: nn.Module, states: th.Tensor) -> th.Tensor:
    """
    The values each network of ``value_network`` regresses on the returns, ``(K, batch)``, on ``(batch, state_dim)``
    states: a :class:`~sb3_mpail.mppi.ensemble.ValueEnsemble`'s members', or a single network's as ``(1, batch)``,
    behind the feature map of a :class:`MappedNetwork`.
    """
    if isinstance(value_network, MappedNetwork):
        states, value_network = value_network.features(states), value_network.network
    if isinstance(value_network, ValueEnsemble):
        return value_network.member_values(states)
    return value_network(states).view(1, -1)


class MappedView:
    """
    A planning view of a network behind a feature map: the map applied once to every state of the roll-out (a batched
    call over all rows), then the network's own fused view on the mapped states. Held state dimensions do not carry
    over to the features, so none are held.

    :param view: the fused view built for ``n_features`` inputs per state
    :param features: the feature map
    """

    def __init__(self, view, features: nn.Module):
        self.view = view
        self.features = features

    def _mapped(self, states: th.Tensor) -> th.Tensor:
        return self.features(states.reshape(-1, states.shape[-1])).view(*states.shape[:-1], -1)

    def hold(self, held_dims: Sequence[int], initial_states: th.Tensor) -> None:
        self.view.hold((), self._mapped(initial_states))

    def __call__(self, states: th.Tensor, *arguments):
        return self.view(self._mapped(states), *arguments)


def learned_reward(
    discriminator: nn.Module,
    features: Optional[nn.Module],
    states: th.Tensor,
    next_states: th.Tensor,
    reward_form: str = "logit",
    reward_offset: float = 0.0,
) -> th.Tensor:
    """
    The learned reward of ``(batch, state_dim)`` transitions, ``(batch,)``: the discriminator's logit on the features of
    ``s`` and ``s'``, in the :data:`REWARD_FORMS` form ``reward_form``, plus ``reward_offset``.

    :param discriminator: the reward net giving the logit ``d_theta``
    :param features: the discriminator's feature map ``phi``; ``None``: the states themselves
    :param states: ``s``
    :param next_states: ``s'``
    :param reward_form: a key of :data:`REWARD_FORMS`
    :param reward_offset: a constant added to every transition's reward
    """
    if features is not None:
        states, next_states = features(states), features(next_states)
    return REWARD_FORMS[reward_form](discriminator(states, None, next_states, None)) + reward_offset


class TransitionCost(nn.Module):
    """
    Step cost ``c(s, s') = -r(d_theta(phi(s), phi(s')))`` over any leading batch shape, ``r`` the reward form plus the
    reward offset.

    :param discriminator: the reward net giving the logit ``d_theta``
    :param features: the discriminator's feature map ``phi``; ``None``: the states themselves
    :param reward_form: the learned reward as a function of the logit, a key of :data:`REWARD_FORMS`
    :param reward_offset: a constant added to every transition's reward
    """

    def __init__(
        self,
        discriminator: BasicRewardNet,
        features: Optional[nn.Module] = None,
        reward_form: str = "logit",
        reward_offset: float = 0.0,
    ):
        super().__init__()
        self.discriminator = discriminator
        self.features = features
        self.reward_form = reward_form
        self.reward_offset = reward_offset
        self._planning_views: ViewCache[FusedTransitionCost] = ViewCache()

    def forward(self, states: th.Tensor, next_states: th.Tensor) -> th.Tensor:
        batch_shape = states.shape[:-1]
        states, next_states = states.reshape(-1, states.shape[-1]), next_states.reshape(-1, states.shape[-1])
        rewards = learned_reward(self.discriminator, self.features, states, next_states, self.reward_form, self.reward_offset)
        return -rewards.view(batch_shape)

    def planning_view(self, state_dim: int) -> Optional[Union[FusedTransitionCost, FrozenEnsembleCost, MappedView]]:
        """
        The fused whole-horizon cost with the discriminator's weights frozen (until they change), in this cost's reward
        form and offset, behind the feature map if there is one (:class:`~sb3_mpail.mppi.ensemble.FrozenEnsembleCost`
        for an ensemble), or ``None`` where the module path must be used: gradients enabled, training mode (spectral
        norm's power iteration then updates its vectors on every call), or a discriminator other than MLPs on
        ``(s, s')``.

        :param state_dim: size of a state
        """
        net = self.discriminator
        if th.is_grad_enabled() or net.training:
            return None
        reward = (self.reward_form, self.reward_offset)

        def inputs(mlp: Optional[FrozenMlp]) -> int:  # what each state gives the first layer: the mapped features
            return state_dim if self.features is None or mlp is None else mlp.weights[0].shape[0] // 2

        def build_ensemble() -> Optional[FrozenEnsembleCost]:
            members = frozen_members(net)
            return FrozenEnsembleCost.build(members, inputs(members[0]), net.disagreement, *reward)

        def build() -> Optional[FusedTransitionCost]:
            mlp = freeze_mlp(net.mlp)
            return FusedTransitionCost(mlp, inputs(mlp), *reward) if fused_mlp_ok(mlp, 2 * inputs(mlp)) else None

        if isinstance(net, DiscriminatorEnsemble):
            view = self._planning_views.get(net, state_dim, build_ensemble)
        elif isinstance(net, BasicRewardNet) and net.use_state and net.use_next_state and not (net.use_action or net.use_done):
            view = self._planning_views.get(net.mlp, state_dim, build)
        else:
            return None
        return view if view is None or self.features is None else MappedView(view, self.features)


class TerminalValue(nn.Module):
    """
    Terminal value ``V_phi(s)`` over any leading batch shape.

    :param value_network: network mapping ``(batch, state_dim)`` to ``(batch, 1)``, a plain MLP or a
        :class:`MappedNetwork`
    """

    def __init__(self, value_network: nn.Module):
        super().__init__()
        self.value_network = value_network
        self._planning_views: ViewCache[FusedValue] = ViewCache()

    def forward(self, states: th.Tensor) -> th.Tensor:
        return self.value_network(states.reshape(-1, states.shape[-1])).view(states.shape[:-1])

    def planning_view(self, state_dim: int) -> Optional[Union[FusedValue, MappedView]]:
        """
        The value with its weights frozen (until they change), behind its feature map if it is a
        :class:`MappedNetwork`, or ``None`` where the module path must be used (gradients enabled, training mode or a
        network other than a plain MLP).

        :param state_dim: size of a state
        """
        if th.is_grad_enabled() or self.value_network.training:
            return None
        mapped = isinstance(self.value_network, MappedNetwork)
        network = self.value_network.network if mapped else self.value_network

        def build() -> Optional[FusedValue]:
            mlp = freeze_mlp(network)
            inputs = (mlp.weights[0].shape[0] if mlp is not None else 0) if mapped else state_dim
            return FusedValue(mlp) if fused_mlp_ok(mlp, inputs) else None

        view = self._planning_views.get(network, state_dim, build)
        return view if view is None or not mapped else MappedView(view, self.value_network.features)
