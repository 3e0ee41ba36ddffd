"""
Planning-time fast paths for the learned networks (used under ``no_grad`` in eval mode only).

The planner evaluates the discriminator on ``H * n_envs * N`` transitions ``J`` times per planning step. The plain
module call concatenates ``(s, s')``, recomputes the spectral-norm weights on every call and allocates every
intermediate afresh. Here instead:

* the (normalised) weights are read into a :class:`FrozenMlp`, once and again only when they change (:class:`ViewCache`);
* the discriminator's first layer is split into its ``s`` and ``s'`` halves, ``W [s_t, s_{t+1}] = W_s s_t +
  W_s' s_{t+1}``: two matmuls accumulate into one output that read the rolled-out states in place (row-major or
  feature-major, see :func:`~sb3_mpail.mppi.dynamics.feature_major_states`), so no ``[s, s']`` is ever built;
* hidden layers on large blocks of contiguous CPU rows are one oneDNN call each with the bias and activation fused
  (torch's ``mkldnn._linear_pointwise``); elsewhere activations run in place in scratch tensors of a
  :class:`Workspace` reused across chunks, iterations and calls;
* the rows are processed in chunks that stay in the CPU cache;
* the markups ``eta^t`` and the output layer fold into one matrix-vector product per chunk.

On CPU float32 tensors, all of that is one compiled kernel where the machine can build it
(:mod:`sb3_mpail.mppi.native`): every layer for a block of rows in the L1 cache, summed over the horizon. Told which
state dimensions the roll-out holds at their initial values (:meth:`FusedTransitionCost.hold`), the kernel leaves
them out of the first layer's products and adds their terms as a bias per env.

Results equal the module path up to float rounding; ``tests/test_planner_equivalence.py`` checks it.
"""

from dataclasses import dataclass
from functools import partial
from itertools import chain
from typing import Callable, Dict, Generic, List, Optional, Sequence, Tuple, TypeVar

import torch as th
import torch.nn.functional as F
from torch import nn

from sb3_mpail.mppi.native import HeldInputs, NativeMlp
from sb3_mpail.mppi.reward_forms import REWARD_FORMS

#: rows per chunk of the hidden activations and thread: 8192 x 32 floats (1 MiB) stay in a core's cache between layers
CHUNK_ROWS_PER_THREAD = 8192


def chunk_rows() -> int:
    """Rows per chunk: each of torch's threads takes about ``CHUNK_ROWS_PER_THREAD`` of a chunk's matrix products."""
    return CHUNK_ROWS_PER_THREAD * th.get_num_threads()


InPlaceActivation = Callable[[th.Tensor], th.Tensor]


def _onednn_linear() -> Optional[Callable]:
    """torch's oneDNN linear with fused bias and activation, where this build of torch has it."""
    if not th.backends.mkldnn.is_available():
        return None
    try:
        return th.ops.mkldnn._linear_pointwise
    except (AttributeError, RuntimeError):
        return None


#: ``linear(input, weight, bias, activation, activation_scalars, algorithm)``, or ``None`` to use BLAS everywhere
ONEDNN_LINEAR: Optional[Callable] = _onednn_linear()
#: fewest rows per torch thread oneDNN is used for. Timed on AMD EPYC, 1 thread: a 32x32 layer and its leaky ReLU on
#: 8192 rows took 108 us through oneDNN against 220 us as addmm then the activation, but on 512 rows 21 against 16 us;
#: at 2 threads a planning step of 1 env (5120-row chunks) was 10% slower with oneDNN
ONEDNN_MIN_ROWS_PER_THREAD = 4096


class Workspace:
    """
    Named scratch tensors, reused instead of allocated afresh (large fresh tensors cost page faults).

    A tensor taken from the workspace is only valid until the next request of the same name.
    """

    def __init__(self) -> None:
        self._storage: Dict[str, th.Tensor] = {}

    def get(self, name: str, shape: tuple, like: th.Tensor) -> th.Tensor:
        """
        :param name: key of the scratch tensor
        :param shape: shape wanted
        :param like: gives the device and dtype
        :return: an uninitialised contiguous tensor of ``shape``
        """
        numel = 1
        for size in shape:
            numel *= size
        storage = self._storage.get(name)
        if storage is None or storage.numel() < numel or storage.device != like.device or storage.dtype != like.dtype:
            storage = self._storage[name] = th.empty(numel, device=like.device, dtype=like.dtype)
        return storage[:numel].view(shape)

    def clear(self) -> None:
        self._storage.clear()

    def __getstate__(self) -> dict:  # scratch memory is not worth saving or copying
        return {"_storage": {}}


View = TypeVar("View")


class ViewCache(Generic[View]):
    """
    The planning view last built from a network, kept while the network's parameters and buffers are the same tensors
    with the same contents: same objects, data pointers and version counters (which in-place updates advance:
    optimiser steps, ``load_state_dict``, spectral norm's power iteration in training mode). Freezing the weights and
    building the kernel's view cost about 0.2 ms per planning step, most of a 1-env step's overhead. Not pickled.
    """

    def __init__(self) -> None:
        self._key: Optional[tuple] = None
        self._view: Optional[View] = None
        self._tensors: List[th.Tensor] = []

    def get(self, network: nn.Module, state_dim: int, build: Callable[[], Optional[View]]) -> Optional[View]:
        """
        :param network: the network the view is built from
        :param state_dim: size of a state
        :param build: builds the view (``None``: the network has none)
        :return: the cached view, built anew if the network changed since
        """
        tensors = list(chain(network.parameters(), network.buffers()))
        # Tensor._version counts in-place changes; autograd relies on it the same way
        key = (state_dim, *((id(tensor), tensor.data_ptr(), tensor._version) for tensor in tensors))
        if key != self._key:
            # the tensors are held so that no replacement can take their ids and memory while the key names them
            self._view, self._key, self._tensors = build(), key, tensors
        return self._view

    def __getstate__(self) -> dict:  # rebuilt on demand: the kernel's view holds pointers
        return {"_key": None, "_view": None, "_tensors": []}


@dataclass(frozen=True)
class Activation:
    """
    An activation the fast paths know, in their two forms.

    :param apply_: applies it in place
    :param onednn_name: its name as a post-op of oneDNN's fused linear
    :param onednn_scalars: its arguments there
    """

    apply_: InPlaceActivation
    onednn_name: str
    onednn_scalars: Tuple[float, ...] = ()


def _activation(module: nn.Module) -> Optional[Activation]:
    if isinstance(module, nn.ReLU):
        return Activation(th.relu_, "relu")
    if isinstance(module, nn.LeakyReLU):
        return Activation(partial(F.leaky_relu_, negative_slope=module.negative_slope), "leaky_relu", (module.negative_slope,))
    if isinstance(module, nn.Tanh):
        return Activation(th.tanh_, "tanh")
    return None


@dataclass
class FrozenMlp:
    """
    A snapshot of an MLP's weights for fast inference.

    :param weights: per layer, the weight transposed to ``(in, out)``
    :param biases: per layer, the bias ``(out,)``
    :param activations: per layer, the activation applied after it, or ``None``
    """

    weights: List[th.Tensor]
    biases: List[th.Tensor]
    activations: List[Optional[Activation]]


def freeze_mlp(network: nn.Module) -> Optional[FrozenMlp]:
    """
    Reads the weights of a ``Linear``/activation ``nn.Sequential`` once (parametrisations such as spectral norm
    applied, as in eval mode), or returns ``None`` if the network has layers this fast path does not know.

    :param network: the MLP, in eval mode
    """
    if not isinstance(network, nn.Sequential) or network.training:
        return None
    weights: List[th.Tensor] = []
    biases: List[th.Tensor] = []
    activations: List[Optional[Activation]] = []
    for module in network:
        if isinstance(module, nn.Linear):
            weight = module.weight.detach()
            weights.append(weight.t())  # a transposed view: matmuls read it in place
            biases.append(module.bias.detach() if module.bias is not None else weight.new_zeros(weight.shape[0]))
            activations.append(None)
        elif _activation(module) is not None:
            if not activations or activations[-1] is not None:
                return None
            activations[-1] = _activation(module)
        elif isinstance(module, (nn.Dropout, nn.Identity, nn.Flatten)) or type(module).__name__ == "SqueezeLayer":
            continue  # identities in eval mode on 2-D batches
        else:
            return None
    if not weights:
        return None
    return FrozenMlp(weights, biases, activations)


def native_mlp(mlp: FrozenMlp) -> Optional[NativeMlp]:
    """The compiled kernel's view of a frozen MLP, or ``None`` where the kernel is unavailable or cannot take it."""
    activations = mlp.activations
    names = [None if activation is None else activation.onednn_name for activation in activations]
    slopes = [activation.onednn_scalars[0] if activation and activation.onednn_scalars else 0.0 for activation in activations]
    return NativeMlp.from_layers(mlp.weights, mlp.biases, names, slopes)


def _held_inputs(
    native: Optional[NativeMlp], held_dims: Sequence[int], initial_states: th.Tensor, pairs: bool
) -> Optional[HeldInputs]:
    """The kernel's held inputs for ``held_dims`` (``None`` without the kernel or held dimensions: read every input)."""
    return native.hold(held_dims, initial_states, pairs) if native is not None and held_dims else None


def _hidden_layers(mlp: FrozenMlp, hidden: th.Tensor, first_layer: int, last_layer: int, workspace: Workspace) -> th.Tensor:
    """
    Layers ``first_layer .. last_layer - 1`` of ``mlp`` on 2-D ``hidden``: one oneDNN call per layer with bias and
    activation fused on contiguous CPU float32 rows, ``ONEDNN_MIN_ROWS_PER_THREAD`` or more per thread (each call
    returns a fresh tensor; strided rows stay on BLAS, which reads them in place where oneDNN would copy them), else a
    BLAS ``addmm`` into two ping-ponged scratch tensors and the activation in place.
    """
    for index in range(first_layer, last_layer):
        activation = mlp.activations[index]
        if (
            ONEDNN_LINEAR is not None
            and hidden.shape[0] >= ONEDNN_MIN_ROWS_PER_THREAD * th.get_num_threads()
            and hidden.is_contiguous()
            and hidden.device.type == "cpu"
            and hidden.dtype == th.float32
        ):
            name, scalars = ("none", []) if activation is None else (activation.onednn_name, list(activation.onednn_scalars))
            hidden = ONEDNN_LINEAR(hidden, mlp.weights[index].t(), mlp.biases[index], name, scalars, "")
            continue
        output = workspace.get(f"hidden{index % 2}", (hidden.shape[0], mlp.weights[index].shape[1]), hidden)
        th.addmm(mlp.biases[index], hidden, mlp.weights[index], out=output)
        if activation is not None:
            activation.apply_(output)
        hidden = output
    return hidden


class FusedTransitionCost:
    """
    ``sum_t markups[t] * c(s_t, s_{t+1})`` with ``c = -r(d_theta) - offset`` for a whole rolled-out horizon, for a
    frozen discriminator MLP on the concatenation ``[s, s']``.

    :param mlp: the frozen discriminator; its first layer takes ``2 * state_dim`` inputs, its last gives one output
        with no activation after it
    :param state_dim: size of a state
    :param reward_form: ``r``, a key of :data:`~sb3_mpail.mppi.reward_forms.REWARD_FORMS`
    :param reward_offset: a constant added to every transition's reward
    """

    def __init__(self, mlp: FrozenMlp, state_dim: int, reward_form: str = "logit", reward_offset: float = 0.0):
        first_weight = mlp.weights[0]  # (2 * state_dim, hidden)
        self.mlp = mlp
        # W [s, s'] = W_s s + W_s' s': two matmuls accumulating into one output, no concatenated input
        self.state_weight = first_weight[:state_dim]
        self.next_state_weight = first_weight[state_dim:]
        self.output_weight = mlp.weights[-1][:, 0]
        self.reward_form, self.reward_offset = reward_form, reward_offset
        # the logit form sums the outputs before their bias and adds the bias once; the others need it per transition
        self._reward = None if reward_form == "logit" else REWARD_FORMS[reward_form]
        self.native = native_mlp(mlp)
        self._held: Optional[HeldInputs] = None
        self._markups: Optional[th.Tensor] = None
        self._negative_markups = self._constant = first_weight.new_zeros(())

    def hold(self, held_dims: Sequence[int], initial_states: th.Tensor) -> None:
        """
        Declares that the roll-outs of this planning step keep state dimensions ``held_dims`` (none: every dimension
        moves) at their values in ``initial_states``, ``(n_envs, state_dim)``: the kernel then skips those inputs
        (the torch path ignores this).
        """
        self._held = _held_inputs(self.native, held_dims, initial_states, pairs=True)

    def __call__(self, states: th.Tensor, markups: th.Tensor, workspace: Workspace) -> th.Tensor:
        """
        :param states: ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, state_dim)``, rows contiguous or
            stored feature-major
        :param markups: ``eta^t`` per step, ``(horizon,)``
        :param workspace: scratch tensors
        :return: cost per sample, ``(n_envs, n_samples)``, a workspace tensor
        """
        n_states, n_envs, n_samples, state_dim = states.shape
        horizon = n_states - 1
        columns = n_envs * n_samples
        # a view for row-major and feature-major storage alike (see feature_major_states): never a copy
        flat_states = states.reshape(n_states, columns, state_dim)
        costs = workspace.get("step_costs", (n_envs, n_samples), states).view(columns)
        if markups is not self._markups:  # the same markups come back every iteration of a planning step
            # -sum_t m_t (z_t + b + offset) = z^T (-m) - (b + offset) sum_t m_t, with z the output layer's product
            # before its bias; the other forms: -sum_t m_t r(z_t + b) - offset sum_t m_t
            self._markups = markups
            self._negative_markups = -markups
            summed = self.reward_offset + (self.mlp.biases[-1] if self._reward is None else 0.0)
            self._constant = summed * self._negative_markups.sum()
        if self.native is not None:
            self.native.marked_up_sums(flat_states, self._negative_markups, True, costs, self._held, self.reward_form)
            return costs.add_(self._constant).view(n_envs, n_samples)
        costs.copy_(self._constant.expand(columns))
        # Chunks of at most chunk_rows() transitions: several whole time steps when one step has few columns, else
        # column blocks of one time step. Either way a chunk's (time, column) rows merge into one stride, so the
        # matrix products read the states in place whatever their layout.
        rows_per_chunk = chunk_rows()
        steps_per_chunk = max(1, rows_per_chunk // columns)
        column_chunk = min(columns, rows_per_chunk)
        for start in range(0, columns, column_chunk):
            stop = min(start + column_chunk, columns)
            for first in range(0, horizon, steps_per_chunk):
                last = min(first + steps_per_chunk, horizon)
                self._add_chunk_costs(
                    flat_states[first : last + 1, start:stop], self._negative_markups[first:last], costs[start:stop], workspace
                )
        return costs.view(n_envs, n_samples)

    def _add_chunk_costs(self, states: th.Tensor, negative_markups: th.Tensor, out: th.Tensor, workspace: Workspace) -> None:
        """
        Adds ``sum_t -m_t z_t`` of the chunk's transitions ``(states[t], states[t + 1])`` to ``out`` (``r(z_t + b)``
        for a reward form other than the logit).
        """
        n_states, columns, state_dim = states.shape
        steps, mlp = n_states - 1, self.mlp
        rows = steps * columns
        hidden = workspace.get("first_layer", (rows, self.state_weight.shape[1]), states)
        first_states, next_states = states[:-1].reshape(rows, state_dim), states[1:].reshape(rows, state_dim)
        n_layers = len(mlp.weights)
        if n_layers == 1:  # a linear discriminator: its only bias is the output bias, added as any MLP's is
            th.mm(first_states, self.state_weight, out=hidden)
        else:
            th.addmm(mlp.biases[0], first_states, self.state_weight, out=hidden)
        hidden.addmm_(next_states, self.next_state_weight)
        if n_layers == 1:
            logits = hidden.view(rows)
        else:
            if mlp.activations[0] is not None:
                mlp.activations[0].apply_(hidden)
            hidden = _hidden_layers(mlp, hidden, 1, n_layers - 1, workspace)
            logits = th.mv(hidden, self.output_weight, out=workspace.get("logits", (rows,), states))
        if self._reward is not None:
            logits = self._reward(logits.add_(mlp.biases[-1]))
        out.addmv_(logits.view(steps, columns).t(), negative_markups)


class FusedValue:
    """
    A frozen value MLP ``V(s)`` on any leading shape, evaluated in cache-sized chunks with in-place activations.

    :param mlp: the frozen value network, one output with no activation after it
    """

    def __init__(self, mlp: FrozenMlp):
        self.mlp = mlp
        self.native = native_mlp(mlp)
        self._held: Optional[HeldInputs] = None
        self._unit_markup = mlp.weights[0].new_ones(1)

    def hold(self, held_dims: Sequence[int], initial_states: th.Tensor) -> None:
        """As :meth:`FusedTransitionCost.hold`: states ``(n_envs, ..., state_dim)`` hold ``held_dims`` per env."""
        self._held = _held_inputs(self.native, held_dims, initial_states, pairs=False)

    def __call__(self, states: th.Tensor, workspace: Workspace) -> th.Tensor:
        """
        :param states: ``(..., state_dim)``
        :param workspace: scratch tensors
        :return: ``V(s)`` of shape ``states.shape[:-1]``, a workspace tensor
        """
        flat_states = states.reshape(-1, states.shape[-1])
        rows = flat_states.shape[0]
        values = workspace.get("values", (rows,), states)
        mlp = self.mlp
        if self.native is not None:
            values = self.native.marked_up_sums(flat_states.unsqueeze(0), self._unit_markup, False, values, self._held)
            return values.add_(mlp.biases[-1]).view(states.shape[:-1])
        rows_per_chunk = chunk_rows()
        for start in range(0, rows, rows_per_chunk):
            stop = min(start + rows_per_chunk, rows)
            hidden = _hidden_layers(mlp, flat_states[start:stop], 0, len(mlp.weights) - 1, workspace)
            th.addmv(mlp.biases[-1], hidden, mlp.weights[-1][:, 0], out=values[start:stop])
        return values.view(states.shape[:-1])


def fused_mlp_ok(mlp: Optional[FrozenMlp], in_size: int) -> bool:
    """Whether a frozen MLP fits the fused paths: ``in_size`` inputs, one output, no activation after the output."""
    return (
        mlp is not None
        and mlp.weights[0].shape[0] == in_size
        and mlp.weights[-1].shape[1] == 1
        and mlp.activations[-1] is None
    )
