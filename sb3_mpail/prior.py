"""
The policy prior of learned-model MPAIL (MPAIL2's and TD-MPC2's design): a SAC actor and Q ensemble trained
off-policy, on every transition the agent has made, against the *learned* reward ``d_theta(s, s')``. The planner
uses it twice: the actor proposes a share of the sampled action sequences (rolled through the planning model), and
the ensemble's mean ``Q(s_H, pi(s_H))`` replaces the on-policy ``V_phi`` as the terminal value. The networks and
their optimisers are Stable-Baselines3's :class:`~stable_baselines3.sac.policies.SACPolicy`; the update is SAC's.
"""

import copy
from typing import Any, Callable, Dict, List, NamedTuple, Optional, Sequence

import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.sac.policies import SACPolicy
from torch import nn

from sb3_mpail.checks import (
    BOOLEAN,
    FRACTION,
    HIDDEN_SIZES,
    OPTIONAL_POSITIVE_INTEGER,
    OPTIONAL_UNIT_INTERVAL,
    POSITIVE_INTEGER,
    POSITIVE_NUMBER,
    UNIT_INTERVAL,
    check_arguments,
)

#: what the prior's Q targets do where an episode terminated (see :class:`PriorReplay`)
PRIOR_TERMINATIONS = ("cut", "bootstrap", "absorbing")


class ReturnSamples(NamedTuple):
    """A minibatch of the prior's Q targets' inputs (:meth:`PriorReplay.sample`), each ``(batch, ...)``."""

    states: th.Tensor  #: the states whose Q is fitted
    unit_actions: th.Tensor  #: the actions taken there, in ``[-1, 1]``
    bootstrap_states: th.Tensor  #: where each target bootstraps: the last step's next state
    returns: th.Tensor  #: the discounted learned rewards up to there, ``(batch, 1)``
    dones: th.Tensor  #: 1 where the target does not bootstrap (a termination, unless ``"bootstrap"``), ``(batch, 1)``
    discounts: th.Tensor  #: the bootstrap's discount, ``gamma ** steps`` over the steps summed, ``(batch, 1)``
    first_rewards: th.Tensor  #: each first step's learned reward (logged)


class LayerNormCriticSACPolicy(SACPolicy):
    """
    SB3's SAC networks with a ``LayerNorm`` after each hidden product of every Q network, before its activation (as
    TD-MPC2's and MPAIL2's critics): normalised features bound how far Q can extrapolate beyond the states it was
    trained on, which is where the planner's learned model ends its roll-outs.
    """

    def make_critic(self, features_extractor: Optional[BaseFeaturesExtractor] = None) -> ContinuousCritic:
        critic = super().make_critic(features_extractor)
        for index, q_network in enumerate(critic.q_networks):
            layers: List[nn.Module] = []
            for layer in q_network[:-1]:
                layers.append(layer)
                if isinstance(layer, nn.Linear):
                    layers.append(nn.LayerNorm(layer.out_features, device=layer.weight.device))
            critic.q_networks[index] = nn.Sequential(*layers, q_network[-1])
            critic.add_module(f"qf{index}", critic.q_networks[index])  # replaces the plain network's registration
        return critic


class PolicyPrior(nn.Module):
    """
    A squashed-Gaussian actor ``pi(a | s)`` and ``n_critics`` Q networks with Polyak targets, trained by SAC with a
    learned entropy coefficient (target entropy ``-action_dim``). Actions are the env's, mapped to SAC's ``[-1, 1]``.

    :param observation_space: the env's flat ``Box`` observation space
    :param action_space: the env's bounded ``Box`` action space
    :param net_arch: hidden widths of the actor and of each Q network
    :param n_critics: Q networks in the ensemble
    :param learning_rate: Adam learning rate of actor, critics and entropy coefficient
    :param gamma: discount of the learned reward in the Q targets
    :param tau: Polyak coefficient of the target Q networks
    :param value_tau: where set, the planner's terminal value reads a slow average of the Q networks instead of the
        online ones: a running mean of every update's weights until ``1 / value_tau`` updates, then a Polyak average
        with this coefficient (0: the running mean throughout). Meant to steady a value whose landscape swings from one
        rollout to the next; on Hopper an average over some 40k env steps lowered the score instead
        (docs/learned-models.md). ``None``: the online Q networks
    :param critic_layer_norm: a ``LayerNorm`` after each hidden layer of the Q networks
        (:class:`LayerNormCriticSACPolicy`); on Hopper it lowered the score (docs/learned-models.md)
    :param target_critics: where set, each update's Q target is the minimum of this many Q networks drawn at random,
        and the actor climbs the ensemble's mean Q (REDQ's and TD-MPC2's use of a larger ensemble: its mean, the
        planner's terminal value, averages more networks without a target as pessimistic as the minimum of all).
        ``None``: the minimum of every Q network for both (SAC)
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        net_arch: Sequence[int] = (256, 256),
        n_critics: int = 2,
        learning_rate: float = 3e-4,
        gamma: float = 0.99,
        tau: float = 0.005,
        value_tau: Optional[float] = None,
        critic_layer_norm: bool = False,
        target_critics: Optional[int] = None,
    ):
        super().__init__()
        check_arguments(
            net_arch=(net_arch, HIDDEN_SIZES),
            n_critics=(n_critics, POSITIVE_INTEGER),
            learning_rate=(learning_rate, POSITIVE_NUMBER),
            gamma=(gamma, FRACTION),
            tau=(tau, UNIT_INTERVAL),
            value_tau=(value_tau, OPTIONAL_UNIT_INTERVAL),
            critic_layer_norm=(critic_layer_norm, BOOLEAN),
            target_critics=(target_critics, OPTIONAL_POSITIVE_INTEGER),
        )
        if target_critics is not None and target_critics > n_critics:
            raise ValueError(f"target_critics ({target_critics}) must not exceed n_critics ({n_critics}): the Q target is "
                             "the minimum of that many of the prior's Q networks")  # fmt: skip
        self.sac = (LayerNormCriticSACPolicy if critic_layer_norm else SACPolicy)(
            observation_space,
            action_space,
            lambda _: learning_rate,
            net_arch=list(net_arch),
            n_critics=n_critics,
            optimizer_kwargs=dict(foreach=True),  # one fused step over all parameters: small networks are overhead-bound
        )
        self.register_buffer("action_low", th.as_tensor(action_space.low, dtype=th.float32))
        self.register_buffer("action_high", th.as_tensor(action_space.high, dtype=th.float32))
        self.log_entropy_coefficient = nn.Parameter(th.zeros(1))
        self.entropy_optimizer = th.optim.Adam([self.log_entropy_coefficient], lr=learning_rate, foreach=True)
        self.target_entropy = -float(np.prod(action_space.shape))
        self.gamma = gamma
        self.tau = tau
        self.value_tau = value_tau
        self.target_critics = target_critics
        self.planning_critic = None
        if value_tau is not None:
            self.planning_critic = copy.deepcopy(self.sac.critic).requires_grad_(False)
            del self.planning_critic.optimizer  # an average is never stepped; its optimiser's state would only be saved
            self.register_buffer("planning_critic_updates", th.zeros((), dtype=th.long))

    def to_env_actions(self, unit_actions: th.Tensor) -> th.Tensor:
        """SAC's ``[-1, 1]`` actions in the env's units."""
        return self.action_low + (unit_actions + 1.0) * 0.5 * (self.action_high - self.action_low)

    def to_unit_actions(self, actions: np.ndarray) -> np.ndarray:
        """The env's actions in SAC's ``[-1, 1]`` (what the replay buffer stores)."""
        return np.clip(self.sac.scale_action(actions), -1.0, 1.0)

    def sample(self, states: th.Tensor, generator: th.Generator) -> th.Tensor:
        """
        Actions drawn from ``pi(a | s)`` with the planner's noise source (so deterministic planning stays a pure
        function of its inputs), in the env's units.

        :param states: ``(batch, state_dim)``
        :param generator: the planner's generator
        """
        mean, log_std, _ = self.sac.actor.get_action_dist_params(states)
        noise = th.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
        return self.to_env_actions(th.tanh(mean + log_std.exp() * noise))

    def propose(
        self, dynamics: Callable[[th.Tensor, th.Tensor], th.Tensor], states: th.Tensor, horizon: int, n_proposals: int,
        generator: th.Generator,
    ) -> th.Tensor:
        """
        Action sequences of the actor rolled through the planning model from each env's state.

        :param dynamics: the planner's ``f(states, actions) -> next_states``
        :param states: ``(n_envs, state_dim)``
        :param horizon: steps per sequence
        :param n_proposals: sequences per env
        :param generator: the planner's generator
        :return: time-major sequences, ``(horizon, n_envs, n_proposals, action_dim)``
        """
        n_envs = states.shape[0]
        current = states.repeat_interleave(n_proposals, dim=0)
        actions = []
        for _ in range(horizon):
            action = self.sample(current, generator)
            actions.append(action)
            current = dynamics(current, action)
        return th.stack(actions).view(horizon, n_envs, n_proposals, -1)

    def value(self, states: th.Tensor) -> th.Tensor:
        """
        The ensemble's mean ``Q(s, tanh(mean of pi(s)))`` over any leading shape, ``(*leading)``; the Q networks are the
        slow average where ``value_tau`` is set.
        """
        flat = states.reshape(-1, states.shape[-1])
        mean, _, _ = self.sac.actor.get_action_dist_params(flat)
        critic = self.sac.critic if self.planning_critic is None else self.planning_critic
        q_values = th.cat(critic(flat, th.tanh(mean)), dim=1)
        return q_values.mean(dim=1).view(states.shape[:-1])

    def target_minimum(self, q_values: th.Tensor) -> th.Tensor:
        """
        The Q target's pessimistic estimate: the minimum over every Q network, or over ``target_critics`` of them drawn
        at random (one draw for the whole minibatch).

        :param q_values: ``(batch, n_critics)``
        :return: ``(batch, 1)``
        """
        if self.target_critics is not None:
            q_values = q_values[:, th.randperm(q_values.shape[1], device=q_values.device)[: self.target_critics]]
        return q_values.min(dim=1, keepdim=True).values

    def actor_q(self, q_values: th.Tensor) -> th.Tensor:
        """
        The Q value the actor climbs: the minimum of the Q networks (SAC) or, where ``target_critics`` is set, their
        mean (REDQ: the subset targets already keep Q from overestimating).

        :param q_values: ``(batch, n_critics)``
        :return: ``(batch, 1)``
        """
        if self.target_critics is None:
            return q_values.min(dim=1, keepdim=True).values
        return q_values.mean(dim=1, keepdim=True)

    def update(
        self, states: th.Tensor, unit_actions: th.Tensor, next_states: th.Tensor, rewards: th.Tensor, dones: th.Tensor,
        discounts: Optional[th.Tensor] = None,
    ) -> Dict[str, float]:
        """
        One SAC update on a replayed minibatch labelled with the current learned reward.

        :param states: ``(batch, state_dim)``
        :param unit_actions: the actions taken, in ``[-1, 1]``, ``(batch, action_dim)``
        :param next_states: the states the targets bootstrap from, ``(batch, state_dim)``
        :param rewards: learned rewards (or their discounted sums up to ``next_states``), ``(batch, 1)``
        :param dones: 1 where the episode terminated (not a time-limit cut), ``(batch, 1)``
        :param discounts: the bootstrap's discount, ``(batch, 1)`` (``gamma ** steps`` after a sum of rewards); ``None``:
            ``gamma``
        :return: the losses and the entropy coefficient
        """
        actor, critic, critic_target = self.sac.actor, self.sac.critic, self.sac.critic_target
        new_actions, log_prob = actor.action_log_prob(states)
        log_prob = log_prob.reshape(-1, 1)
        entropy_loss = -(self.log_entropy_coefficient * (log_prob + self.target_entropy).detach()).mean()
        self.entropy_optimizer.zero_grad()
        entropy_loss.backward()
        self.entropy_optimizer.step()
        entropy_coefficient = self.log_entropy_coefficient.detach().exp()

        with th.no_grad():
            next_actions, next_log_prob = actor.action_log_prob(next_states)
            next_q = self.target_minimum(th.cat(critic_target(next_states, next_actions), dim=1))
            next_q = next_q - entropy_coefficient * next_log_prob.reshape(-1, 1)
            targets = rewards + (1 - dones) * (self.gamma if discounts is None else discounts) * next_q
        critic_loss = 0.5 * sum(F.mse_loss(q, targets) for q in critic(states, unit_actions))
        critic.optimizer.zero_grad()
        critic_loss.backward()
        critic.optimizer.step()

        critic.requires_grad_(False)  # the actor's loss needs no critic weight gradients (they were discarded)
        q_new = self.actor_q(th.cat(critic(states, new_actions), dim=1))
        actor_loss = (entropy_coefficient * log_prob - q_new).mean()
        actor.optimizer.zero_grad()
        actor_loss.backward()
        actor.optimizer.step()
        critic.requires_grad_(True)
        with th.no_grad():  # SB3's polyak_update without its per-call checks, which took 2 ms of it here (0.1-0.2 ms)
            for target, online in zip(critic_target.parameters(), critic.parameters()):
                target.lerp_(online, self.tau)
            if self.planning_critic is not None:
                self.planning_critic_updates += 1
                rate = max(self.value_tau, 1.0 / float(self.planning_critic_updates))
                for average, online in zip(self.planning_critic.parameters(), critic.parameters()):
                    average.lerp_(online, rate)
        return {
            "critic_loss": float(critic_loss.item()),
            "actor_loss": float(actor_loss.item()),
            "entropy_coefficient": float(entropy_coefficient.item()),
        }


class PriorValue(nn.Module):
    """The prior's Q ensemble as the planner's terminal value ``V(s)`` (a module, so the policy saves it).

    :param prior: the policy prior
    """

    def __init__(self, prior: PolicyPrior):
        super().__init__()
        self.prior = prior

    def forward(self, states: th.Tensor) -> th.Tensor:
        return self.prior.value(states)


class PriorReplay:
    """
    Every transition the agent has made (SB3's :class:`~stable_baselines3.common.buffers.ReplayBuffer`, time-limit
    cuts bootstrapped), replayed to train the prior ``updates_per_step`` times per new env step on minibatches
    labelled with the learned reward of the moment (so old transitions follow the discriminator as it changes).

    :param observation_space: the env's observation space
    :param action_space: the env's action space
    :param n_envs: environments stepped together
    :param buffer_size: transitions kept (the oldest are replaced)
    :param batch_size: minibatch size of an update
    :param updates_per_step: prior updates per env step (summed over envs)
    :param device: where minibatches are put
    :param terminations: one of :data:`PRIOR_TERMINATIONS`: ``"cut"`` zeroes the next state's value where an episode
        terminated (e.g. a fall), as SAC does; ``"bootstrap"`` goes on through terminations (MPAIL2's default);
        ``"absorbing"`` takes the terminal transition's reward ``r`` as repeating forever, ``r / (1 - gamma)``
    :param return_steps: each Q target sums the learned rewards of up to this many stored steps of the same episode
        before it bootstraps (n-step returns, as MPAIL2's lambda-returns reach past one step): a reward the
        discriminator has just changed reaches Q in fewer updates. A sequence stops early at its episode's end or at
        the newest stored step. 1: SAC's one-step target
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        n_envs: int,
        buffer_size: int,
        batch_size: int,
        updates_per_step: float,
        device: th.device,
        terminations: str = "cut",
        return_steps: int = 1,
    ):
        self.buffer = ReplayBuffer(
            max(buffer_size // n_envs, 1),
            observation_space,
            action_space,
            device,
            n_envs=n_envs,
            handle_timeout_termination=True,
        )
        self.batch_size = batch_size
        self.updates_per_step = updates_per_step
        self.terminations = terminations
        self.return_steps = return_steps

    def add(
        self, prior: PolicyPrior, observations: np.ndarray, next_observations: np.ndarray, actions: np.ndarray,
        dones: np.ndarray, infos: List[Dict[str, Any]],
    ) -> None:
        """Stores one step of every env (``next_observations`` the true successors, terminal ones at episode ends)."""
        unit_actions = prior.to_unit_actions(actions)
        self.buffer.add(observations, next_observations, unit_actions, np.zeros(len(dones), np.float32), dones, infos)

    def sample(self, gamma: float, reward: Callable[[th.Tensor, th.Tensor], th.Tensor]) -> ReturnSamples:
        """
        A minibatch of Q targets' inputs: steps drawn as SB3's :meth:`ReplayBuffer.sample` draws them (the same indices
        for the same numpy state), each followed along its env's stored steps for up to ``return_steps`` steps.

        :param gamma: the discount of the learned reward
        :param reward: the learned reward ``r(s, s')`` on ``(batch, state_dim)`` float32 tensors, ``(batch,)``
        """
        buffer, n_steps = self.buffer, self.return_steps
        starts = np.random.randint(0, buffer.buffer_size if buffer.full else buffer.pos, size=self.batch_size)
        envs = np.random.randint(0, buffer.n_envs, size=self.batch_size)[:, None]
        offsets = np.arange(n_steps)
        indices = (starts[:, None] + offsets) % buffer.buffer_size  # (batch, n_steps)
        stored_after = (buffer.pos - starts - 1) % buffer.buffer_size + 1  # steps stored from each start on
        ended = buffer.dones[indices, envs] > 0  # an episode's last step: a termination or a time-limit cut
        in_sequence = (offsets < stored_after[:, None]) & (np.cumsum(ended, axis=1) - ended == 0)
        lengths = in_sequence.sum(axis=1)
        rows, last_steps = np.arange(self.batch_size), lengths - 1
        terminated = ended[rows, last_steps] * (1 - buffer.timeouts[indices[rows, last_steps], envs[:, 0]])

        def tensor(array: np.ndarray) -> th.Tensor:
            return th.as_tensor(array, dtype=th.float32, device=buffer.device)

        states, next_states = tensor(buffer.observations[indices, envs]), tensor(buffer.next_observations[indices, envs])
        with th.no_grad():
            rewards = reward(states.flatten(0, 1), next_states.flatten(0, 1)).view(self.batch_size, n_steps)
        mask, lengths = tensor(in_sequence), tensor(lengths)
        returns = (rewards * mask * gamma ** tensor(offsets)).sum(dim=1)
        terminated = tensor(terminated)
        if self.terminations == "absorbing":  # the last reward repeats forever: gamma^L r / (1 - gamma) more
            last_rewards = rewards.gather(1, (lengths.long() - 1)[:, None]).squeeze(1)
            returns = returns + terminated * gamma**lengths * last_rewards / (1 - gamma)
        return ReturnSamples(
            states=states[:, 0],
            unit_actions=tensor(buffer.actions[starts, envs[:, 0]]),
            bootstrap_states=next_states[rows, last_steps],
            returns=returns[:, None],
            dones=(th.zeros_like(terminated) if self.terminations == "bootstrap" else terminated)[:, None],
            discounts=(gamma**lengths)[:, None],
            first_rewards=rewards[:, 0],
        )

    def train(
        self, prior: PolicyPrior, reward: Callable[[th.Tensor, th.Tensor], th.Tensor], n_new_steps: int
    ) -> Dict[str, float]:
        """
        ``round(updates_per_step * n_new_steps)`` SAC updates of the prior, none before a minibatch is stored.

        :param prior: the prior to train
        :param reward: the learned reward ``r(s, s')`` on ``(batch, state_dim)`` float32 tensors, ``(batch,)``
        :param n_new_steps: env steps stored since the last call
        :return: the mean of each logged figure over the updates (empty when none ran)
        """
        if self.buffer.size() * self.buffer.n_envs < self.batch_size:
            return {}
        figures: Dict[str, List[float]] = {}
        for _ in range(round(self.updates_per_step * n_new_steps)):
            batch = self.sample(prior.gamma, reward)
            update = prior.update(
                batch.states, batch.unit_actions, batch.bootstrap_states, batch.returns, batch.dones, batch.discounts
            )
            for name, value in {**update, "reward": float(batch.first_rewards.mean())}.items():
                figures.setdefault(name, []).append(value)
        return {name: float(np.mean(values)) for name, values in figures.items()}
