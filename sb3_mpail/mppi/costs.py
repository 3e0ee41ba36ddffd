"""
What the planner minimises: a step cost on state transitions ``c(s, s')`` and a terminal value ``V(s_H)``.

In MPAIL the step cost is the negated discriminator logit, ``c(s, s') = -d_theta(s, s')``, and the terminal value
is the learned ``V_phi``, so both are thin views of networks the algorithm trains.
"""

import math
import numbers
from typing import Any, Callable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import torch as th
from gymnasium import spaces
from imitation.rewards.reward_nets import BasicRewardNet
from stable_baselines3.common.torch_layers import create_mlp
from torch import nn
from torch.nn.utils.parametrizations import spectral_norm

from sb3_mpail.mppi.fused import FusedTransitionCost, FusedValue, ViewCache, freeze_mlp, fused_mlp_ok

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


class GoalFrameFeatures(nn.Module):
    """
    A goal-conditioned vehicle's state seen from its goal: the position and velocity in the goal's frame (along and
    across the goal's heading) and the heading relative to the goal's, as cosine and sine. Demos that end at different
    goals (parking slots) then all look alike, and a discriminator learns one approach rather than one per goal.

    :param position: the state indices of the position ``(x, y)``
    :param heading: the indices of the heading's ``(cos, sin)``
    :param goal_position: the indices of the goal's position
    :param goal_heading: the indices of the goal heading's ``(cos, sin)``
    :param velocity: the indices of the velocity ``(vx, vy)`` (in the world frame); ``None``: no velocity features
    :param position_scale: factor on the position features (e.g. 10 where a 5 m offset is 0.05 state units: a
        spectral-normed discriminator's slope bound otherwise lets it barely tell such offsets apart)
    :param name: the setting it was given as, which error messages name
    """

    def __init__(
        self,
        position: Sequence[int],
        heading: Sequence[int],
        goal_position: Sequence[int],
        goal_heading: Sequence[int],
        velocity: Sequence[int] | None = None,
        position_scale: float = 1.0,
        name: str = "goal_frame",
    ):
        super().__init__()
        pairs = dict(position=position, heading=heading, goal_position=goal_position, goal_heading=goal_heading)
        if velocity is not None:
            pairs["velocity"] = velocity
        self.indices = {key: _state_indices(value, f"{name}['{key}']") for key, value in pairs.items()}
        wrong = {key: value for key, value in self.indices.items() if len(value) != 2}
        if wrong:
            raise ValueError(f"{name} takes two state indices for each of {sorted(wrong)}; got {wrong}.")
        if not (isinstance(position_scale, numbers.Real) and position_scale > 0):
            raise ValueError(f"{name}['position_scale'] must be a number > 0; got {position_scale!r}.")
        self.position_scale, self.name = float(position_scale), name

    def check_state_dim(self, state_dim: int, name: str) -> None:
        """
        Refuses indices out of range for ``state_dim``-D states (negative ones count from the end).

        :param state_dim: size of a state
        :param name: the setting the map was given as (the message names the map's own ``name``, which says more)
        """
        for key, indices in self.indices.items():
            _check_index_range(indices, -state_dim, state_dim, f"{self.name}['{key}']")

    def forward(self, states: th.Tensor) -> th.Tensor:
        def pair(key: str) -> Tuple[th.Tensor, th.Tensor]:
            first, second = self.indices[key]
            return states[:, first], states[:, second]

        (x, y), (goal_x, goal_y) = pair("position"), pair("goal_position")
        (cos, sin), (goal_cos, goal_sin) = pair("heading"), pair("goal_heading")

        def in_goal_frame(dx: th.Tensor, dy: th.Tensor) -> List[th.Tensor]:
            return [dx * goal_cos + dy * goal_sin, dy * goal_cos - dx * goal_sin]

        columns = [self.position_scale * column for column in in_goal_frame(x - goal_x, y - goal_y)]
        if "velocity" in self.indices:
            columns += in_goal_frame(*pair("velocity"))
        columns += [cos * goal_cos + sin * goal_sin, sin * goal_cos - cos * goal_sin]
        return th.stack(columns, dim=1)


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
        [indices]}``, :class:`GoalFrameFeatures` for ``{"goal_frame": {its settings}}`` (forms a YAML hyperparameter
        file can hold), or a function wrapped in a :class:`FeatureMap`.

        :param features: the feature map as given
        :param name: the setting it was given as (``discriminator_features`` or ``value_features``), which error
            messages name
        """
        if isinstance(features, nn.Module):
            return features
        if isinstance(features, Mapping):
            if set(features) == {"angles"}:
                return AngleFeatures(features["angles"], f"{name}['angles']")
            if set(features) == {"goal_frame"} and isinstance(features["goal_frame"], Mapping):
                return GoalFrameFeatures(**features["goal_frame"], name=f"{name}['goal_frame']")
            raise ValueError(
                f"A dict of {name} takes one key, 'angles' (a list of indices) or 'goal_frame' (a dict of "
                f"GoalFrameFeatures' settings); got {dict(features)}."
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
        if isinstance(features, (FeatureSelection, AngleFeatures, GoalFrameFeatures)):
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


class TransitionCost(nn.Module):
    """
    Step cost ``c(s, s') = -d_theta(phi(s), phi(s'))`` over any leading batch shape.

    :param discriminator: the reward net giving the logit ``d_theta``
    :param features: the discriminator's feature map ``phi``; ``None``: the states themselves
    """

    def __init__(self, discriminator: BasicRewardNet, features: Optional[nn.Module] = None):
        super().__init__()
        self.discriminator = discriminator
        self.features = features
        self._planning_views: ViewCache[FusedTransitionCost] = ViewCache()

    def forward(self, states: th.Tensor, next_states: th.Tensor) -> th.Tensor:
        batch_shape = states.shape[:-1]
        states, next_states = states.reshape(-1, states.shape[-1]), next_states.reshape(-1, states.shape[-1])
        if self.features is not None:
            states, next_states = self.features(states), self.features(next_states)
        return -self.discriminator(states, None, next_states, None).view(batch_shape)

    def planning_view(self, state_dim: int) -> Optional[Union[FusedTransitionCost, MappedView]]:
        """
        The fused whole-horizon cost with the discriminator's weights frozen (until they change), behind the feature
        map if there is one, or ``None`` where the module path must be used: gradients enabled, training mode
        (spectral norm's power iteration then updates its vectors on every call), or a discriminator other than an MLP
        on ``(s, s')``.

        :param state_dim: size of a state
        """
        net = self.discriminator
        if th.is_grad_enabled() or net.training or not isinstance(net, BasicRewardNet):
            return None
        if not (net.use_state and net.use_next_state) or net.use_action or net.use_done:
            return None

        def build() -> Optional[FusedTransitionCost]:
            mlp = freeze_mlp(net.mlp)
            inputs = state_dim if self.features is None else (mlp.weights[0].shape[0] // 2 if mlp is not None else 0)
            return FusedTransitionCost(mlp, inputs) if fused_mlp_ok(mlp, 2 * inputs) else None

        view = self._planning_views.get(net.mlp, state_dim, build)
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
