"""
What the planner minimises: a step cost on state transitions ``c(s, s')`` and a terminal value ``V(s_H)``.

In MPAIL the step cost is the negated discriminator logit, ``c(s, s') = -d_theta(s, s')``, and the terminal value
is the learned ``V_phi``, so both are thin views of networks the algorithm trains.
"""

from typing import Optional, Sequence

import torch as th
from gymnasium import spaces
from imitation.rewards.reward_nets import BasicRewardNet
from stable_baselines3.common.torch_layers import create_mlp
from torch import nn
from torch.nn.utils.parametrizations import spectral_norm

from sb3_mpail.mppi.fused import FusedTransitionCost, FusedValue, freeze_mlp, fused_mlp_ok


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


def make_value_network(state_dim: int, hidden_sizes: Sequence[int] = (32, 32)) -> nn.Sequential:
    """The value ``V_phi(s)``: an MLP with ReLU and a scalar output."""
    return nn.Sequential(*create_mlp(state_dim, 1, list(hidden_sizes), nn.ReLU))


class TransitionCost(nn.Module):
    """
    Step cost ``c(s, s') = -d_theta(s, s')`` over any leading batch shape.

    :param discriminator: the reward net giving the logit ``d_theta(s, s')``
    """

    def __init__(self, discriminator: BasicRewardNet):
        super().__init__()
        self.discriminator = discriminator

    def forward(self, states: th.Tensor, next_states: th.Tensor) -> th.Tensor:
        batch_shape = states.shape[:-1]
        logits = self.discriminator(
            states.reshape(-1, states.shape[-1]), None, next_states.reshape(-1, states.shape[-1]), None
        )
        return -logits.view(batch_shape)

    def planning_view(self, state_dim: int) -> Optional[FusedTransitionCost]:
        """
        The fused whole-horizon cost with the discriminator's weights frozen for one planning step, or ``None``
        where the module path must be used: gradients enabled, training mode (spectral norm's power iteration
        then updates its vectors on every call) or a discriminator other than an MLP on ``(s, s')``.

        :param state_dim: size of a state
        """
        net = self.discriminator
        if th.is_grad_enabled() or net.training or not isinstance(net, BasicRewardNet):
            return None
        if not (net.use_state and net.use_next_state) or net.use_action or net.use_done:
            return None
        mlp = freeze_mlp(net.mlp)
        if not fused_mlp_ok(mlp, 2 * state_dim):
            return None
        return FusedTransitionCost(mlp, state_dim)


class TerminalValue(nn.Module):
    """
    Terminal value ``V_phi(s)`` over any leading batch shape.

    :param value_network: network mapping ``(batch, state_dim)`` to ``(batch, 1)``
    """

    def __init__(self, value_network: nn.Module):
        super().__init__()
        self.value_network = value_network

    def forward(self, states: th.Tensor) -> th.Tensor:
        return self.value_network(states.reshape(-1, states.shape[-1])).view(states.shape[:-1])

    def planning_view(self, state_dim: int) -> Optional[FusedValue]:
        """
        The value with its weights frozen for one planning step, or ``None`` where the module path must be used
        (gradients enabled, training mode or a network other than a plain MLP).

        :param state_dim: size of a state
        """
        if th.is_grad_enabled() or self.value_network.training:
            return None
        mlp = freeze_mlp(self.value_network)
        return FusedValue(mlp) if fused_mlp_ok(mlp, state_dim) else None
