"""
Ensembles of discriminators and of values: several logits ``d_k(s, s')`` or values ``V_k(s)`` whose disagreement marks
the transitions or states none of them was trained near, so that a planner can treat them as worse than any single
network's extrapolation says.
"""

from typing import List, Optional, Sequence

import torch as th
from torch import nn

from sb3_mpail.mppi.fused import FrozenMlp, Workspace, chunk_rows, freeze_mlp, native_mlp
from sb3_mpail.mppi.native import NativeEnsemble
from sb3_mpail.mppi.reward_forms import REWARD_FORMS


class _Ensemble(nn.Module):
    """
    ``K >= 2`` networks and the weight of their standard deviation in what the ensemble gives.

    :param members: the networks
    :param disagreement: weight of the members' standard deviation, ``>= 0`` (``0``: their mean)
    :param kind: what the members are, for the error message
    """

    def __init__(self, members: Sequence[nn.Module], disagreement: float, kind: str):
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"An ensemble needs at least 2 {kind}; got {len(members)}.")
        self.members = nn.ModuleList(members)
        self.disagreement = float(disagreement)


class DiscriminatorEnsemble(_Ensemble):
    """
    ``K`` discriminators on ``(s, s')``, trained on the same batches from different initialisations. The logit it
    gives (the reward, and the planner's negated step cost) is their mean less ``disagreement`` times their standard
    deviation: near the data they agree, far from it each extrapolates its own way, and the spread lowers the reward
    there (a pessimistic cost for out-of-distribution transitions).

    :param members: the discriminators, each called as imitation's reward nets are, ``(state, action, next_state,
        done)`` to ``(batch,)`` logits
    :param disagreement: weight of the members' standard deviation, ``>= 0`` (``0``: their mean)
    """

    def __init__(self, members: Sequence[nn.Module], disagreement: float = 1.0):
        super().__init__(members, disagreement, "discriminators")

    def member_logits(self, state: th.Tensor, next_state: th.Tensor) -> th.Tensor:
        """Each member's logits ``(K, batch)`` on ``(batch, n_features)`` states and next states."""
        return th.stack([member(state, None, next_state, None) for member in self.members])

    def forward(self, state: th.Tensor, action: None, next_state: th.Tensor, done: None) -> th.Tensor:
        return pessimistic_mean(self.member_logits(state, next_state), self.disagreement)


def pessimistic_mean(outputs: th.Tensor, disagreement: float) -> th.Tensor:
    """The mean of ``(K, batch)`` members' outputs less ``disagreement`` times their standard deviation, ``(batch,)``."""
    return outputs.mean(dim=0) - disagreement * outputs.std(dim=0, unbiased=False)


class ValueEnsemble(_Ensemble):
    """
    ``K`` value networks, each regressed on the same returns from its own initialisation. The value it gives (the
    planner's terminal value and the returns' bootstrap) is their mean less ``disagreement`` times their standard
    deviation: on the states the agent visits they agree; far from them each extrapolates its own learned slope (a
    ReLU network's far field is linear), and the spread lowers the value there, so that no single network's
    extrapolation draws the planner away from the data.

    :param members: the value networks, ``(batch, state_dim)`` to ``(batch, 1)``
    :param disagreement: weight of the members' standard deviation, ``>= 0`` (``0``: their mean)
    """

    def __init__(self, members: Sequence[nn.Module], disagreement: float = 1.0):
        super().__init__(members, disagreement, "value networks")

    def member_values(self, states: th.Tensor) -> th.Tensor:
        """Each member's values ``(K, batch)`` on ``(batch, state_dim)`` states."""
        return th.stack([member(states)[:, 0] for member in self.members])

    def forward(self, states: th.Tensor) -> th.Tensor:
        return pessimistic_mean(self.member_values(states), self.disagreement).unsqueeze(-1)


def member_logits(discriminator: nn.Module, state: th.Tensor, next_state: th.Tensor) -> th.Tensor:
    """
    The logits each discriminator of ``discriminator`` is trained on, ``(K, batch)``: an ensemble's members', or a
    single network's as ``(1, batch)``.
    """
    if isinstance(discriminator, DiscriminatorEnsemble):
        return discriminator.member_logits(state, next_state)
    return discriminator(state, None, next_state, None).unsqueeze(0)


class FrozenEnsembleCost:
    """
    ``sum_t markups[t] * c(s_t, s_{t+1})`` for a whole rolled-out horizon, with ``c`` the negated reward (a form of the
    logit plus an offset) of a :class:`DiscriminatorEnsemble` of frozen MLPs of one architecture on ``[s, s']``,
    instead of ``K`` module calls that each concatenate ``[s, s']`` and re-normalise their weights: by the compiled
    kernel where it takes the members (:class:`~sb3_mpail.mppi.native.NativeEnsemble`, every member on a block of rows
    while it is in the cache), else in torch, every layer one batched product over the members, the first split into
    its ``s`` and ``s'`` halves.

    :param mlps: the members, frozen
    :param state_dim: size of a state (the first layers take ``2 * state_dim`` inputs)
    :param disagreement: the ensemble's weight on the members' standard deviation
    :param reward_form: the reward as a function of the logit, a key of
        :data:`~sb3_mpail.mppi.reward_forms.REWARD_FORMS`
    :param reward_offset: a constant added to every transition's reward
    """

    def __init__(
        self,
        mlps: Sequence[FrozenMlp],
        state_dim: int,
        disagreement: float,
        reward_form: str = "logit",
        reward_offset: float = 0.0,
    ):
        first = th.stack([mlp.weights[0] for mlp in mlps])  # (K, 2 * state_dim, hidden)
        self.state_weight, self.next_state_weight = first[:, :state_dim].contiguous(), first[:, state_dim:].contiguous()
        self.first_bias = th.stack([mlp.biases[0] for mlp in mlps])[:, None]  # (K, 1, hidden)
        self.first_activation = mlps[0].activations[0]
        # (K, in, out) weights and (K, 1, out) biases of each hidden layer
        self.hidden = [(th.stack([mlp.weights[layer] for mlp in mlps]), th.stack([mlp.biases[layer] for mlp in mlps])[:, None],
                        mlps[0].activations[layer]) for layer in range(1, len(mlps[0].weights) - 1)]  # fmt: skip
        self.output_weight = th.stack([mlp.weights[-1][:, 0] for mlp in mlps])[:, None]  # (K, 1, hidden)
        self.output_bias = th.stack([mlp.biases[-1][0] for mlp in mlps])[:, None]  # (K, 1)
        self.disagreement = disagreement
        self.reward_form, self.reward_offset = reward_form, reward_offset
        self.native = NativeEnsemble.from_members([native_mlp(mlp) for mlp in mlps], self.output_bias[:, 0], disagreement)

    @staticmethod
    def build(
        mlps: Sequence[Optional[FrozenMlp]],
        state_dim: int,
        disagreement: float,
        reward_form: str = "logit",
        reward_offset: float = 0.0,
    ) -> Optional["FrozenEnsembleCost"]:
        """
        The view (arguments as the constructor's), or ``None`` where the members are not MLPs of one architecture (at
        least one hidden layer) on ``2 * state_dim`` inputs with one output and the same activations.
        """
        frozen = [mlp for mlp in mlps if mlp is not None]
        if len(frozen) < len(mlps):
            return None
        shapes = {tuple(tuple(weight.shape) for weight in mlp.weights) for mlp in frozen}
        activations = {tuple(activation and activation.onednn_name for activation in mlp.activations) for mlp in frozen}
        if len(shapes) != 1 or len(activations) != 1:
            return None
        layers = next(iter(shapes))
        if len(layers) < 2 or layers[0][0] != 2 * state_dim or layers[-1][1] != 1 or frozen[0].activations[-1] is not None:
            return None
        return FrozenEnsembleCost(frozen, state_dim, disagreement, reward_form, reward_offset)

    def hold(self, held_dims: Sequence[int], initial_states: th.Tensor) -> None:
        """Held state dimensions are not exploited here (every input is multiplied)."""

    def __call__(self, states: th.Tensor, markups: th.Tensor, workspace: Workspace) -> th.Tensor:
        """
        :param states: ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, state_dim)``
        :param markups: ``eta^t`` per step, ``(horizon,)``
        :param workspace: scratch tensors
        :return: cost per sample, ``(n_envs, n_samples)``
        """
        n_states, n_envs, n_samples, state_dim = states.shape
        offset_costs = markups.sum() * -self.reward_offset
        if self.native is not None:
            costs = workspace.get("step_costs", (n_envs, n_samples), states).view(-1)
            # a view for row-major and feature-major storage alike (see feature_major_states): never a copy
            flat_states = states.reshape(n_states, n_envs * n_samples, state_dim)
            costs = self.native.marked_up_sums(flat_states, -markups, True, costs, self.reward_form)
            return costs.add_(offset_costs).view(n_envs, n_samples)
        rows = states[:-1].reshape(-1, state_dim), states[1:].reshape(-1, state_dim)
        logits = workspace.get("ensemble_logits", (len(rows[0]),), states)
        # chunks whose K activations stay in the CPU cache between layers (half of fused.chunk_rows(): faster than the
        # whole batch in a timing on a busy 2-core AMD EPYC, about as fast as smaller chunks)
        chunk = max(1, chunk_rows() // 2)
        for start in range(0, len(logits), chunk):
            logits[start : start + chunk] = self.logits(rows[0][start : start + chunk], rows[1][start : start + chunk])
        rewards = REWARD_FORMS[self.reward_form](logits.view(n_states - 1, n_envs, n_samples))
        return th.einsum("t,ten->en", -markups, rewards).add_(offset_costs)

    def logits(self, states: th.Tensor, next_states: th.Tensor) -> th.Tensor:
        """The ensemble's logits on ``(rows, state_dim)`` transitions: the members' mean less their weighted spread."""
        # (K, rows, hidden), contiguous for the batched products: W_s s + W_s' s' per member, no [s, s'] built
        members = th.matmul(states, self.state_weight).add_(th.matmul(next_states, self.next_state_weight))
        members.add_(self.first_bias)
        if self.first_activation is not None:
            self.first_activation.apply_(members)
        for weight, bias, activation in self.hidden:
            members = th.baddbmm(bias, members, weight)
            if activation is not None:
                activation.apply_(members)
        member_logits = (members * self.output_weight).sum(dim=2) + self.output_bias  # (K, rows)
        mean = member_logits.mean(dim=0)
        # the spread as the module computes it (std, unbiased=False), in elementwise steps: std's reduction over the
        # K rows of a (K, rows) tensor is far slower
        spread = (member_logits - mean).square_().mean(dim=0).sqrt_()
        return mean.sub_(spread, alpha=self.disagreement)


def frozen_members(ensemble: DiscriminatorEnsemble) -> List[Optional[FrozenMlp]]:
    """Each member's MLP, frozen; ``None`` for a member that is not an MLP on ``(s, s')`` alone."""
    frozen: List[Optional[FrozenMlp]] = []
    for member in ensemble.members:
        on_transitions = getattr(member, "use_state", False) and getattr(member, "use_next_state", False)
        on_transitions = on_transitions and not getattr(member, "use_action", True) and not getattr(member, "use_done", True)
        frozen.append(freeze_mlp(member.mlp) if on_transitions and hasattr(member, "mlp") else None)
    return frozen
