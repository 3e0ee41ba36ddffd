"""
Infinite-horizon MPPI (paper Alg. 2), batched over environments and samples.

One planning step, for every env at once:

1. **warm start**: shift the previous plan one step forward, the new last step at the neutral action;
2. repeat ``J`` times:
   a. **sample** ``N`` action sequences around the plan,
   b. **roll out** each through the dynamics model for ``H`` steps,
   c. **cost** each trajectory: ``C = sum_t eta^t c(s_t, s_{t+1}) - eta^H V(s_H)``,
   d. **weight** the samples by ``softmax(-C / temperature)`` and set the plan to the weighted mean;
3. the **policy std** of the first action is the weighted spread of the last iteration's samples around it.

Tensors inside a planning step are time-major, ``(horizon, n_envs, n_samples, dim)``, so each horizon step is
one contiguous block: the dynamics model sees ``n_envs * n_samples`` states per call and the step cost sees
the whole horizon in a single call.
"""

from typing import NamedTuple

import torch as th
from torch import nn

from sb3_mpail.mppi.dynamics import DynamicsFunction


class PlanResult(NamedTuple):
    """Output of one planning step."""

    plan: th.Tensor  #: optimised action sequence per env, ``(n_envs, horizon, action_dim)``
    action_std: th.Tensor  #: weighted std of the first action per env, ``(n_envs, action_dim)``


def shift_plan(plan: th.Tensor, neutral_action: th.Tensor) -> th.Tensor:
    """Warm start: drop the executed first step and append the neutral action (paper: mean 0)."""
    return th.cat((plan[:, 1:], neutral_action.expand(plan.shape[0], 1, -1)), dim=1)


def rollout(dynamics: DynamicsFunction, initial_states: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """
    Predicts the states visited by every sampled sequence.

    :param dynamics: ``f(states, actions) -> next_states`` on 2-D batches
    :param initial_states: current state per env, ``(n_envs, state_dim)``
    :param actions: sampled sequences, ``(horizon, n_envs, n_samples, action_dim)``
    :return: states ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, state_dim)``
    """
    horizon, n_envs, n_samples, _ = actions.shape
    states = actions.new_empty(horizon + 1, n_envs, n_samples, initial_states.shape[-1])
    states[0] = initial_states.unsqueeze(1)
    for step in range(horizon):
        states[step + 1] = dynamics(
            states[step].view(n_envs * n_samples, -1), actions[step].view(n_envs * n_samples, -1)
        ).view(n_envs, n_samples, -1)
    return states


def trajectory_costs(
    states: th.Tensor,
    step_cost: nn.Module | None,
    terminal_value: nn.Module | None,
    markup: float,
) -> th.Tensor:
    """
    ``C_k = sum_t eta^t c(s_t, s_{t+1}) - eta^H V(s_H)``; either term may be switched off (``None``).

    :param states: rolled-out states, ``(horizon + 1, n_envs, n_samples, state_dim)``
    :param step_cost: ``c(s, s')`` over any leading shape, or ``None`` for the value-only planner
    :param terminal_value: ``V(s)`` over any leading shape, or ``None`` for the cost-only planner
    :param markup: ``eta``, the per-step factor on step costs (``1 / gamma`` in MPAIL)
    :return: total cost per sample, ``(n_envs, n_samples)``
    """
    horizon = states.shape[0] - 1
    costs = states.new_zeros(states.shape[1:3])
    if step_cost is not None:
        markups = markup ** th.arange(horizon, device=states.device, dtype=states.dtype)
        costs = costs + th.einsum("t,ten->en", markups, step_cost(states[:-1], states[1:]))
    if terminal_value is not None:
        costs = costs - markup**horizon * terminal_value(states[-1])
    return costs


def mppi_weights(costs: th.Tensor, temperature: th.Tensor) -> th.Tensor:
    """Exponential weights ``softmax(-C / lambda)`` over samples (subtracting ``min C`` for stability is built in)."""
    return th.softmax(-costs / temperature, dim=-1)


def weighted_plan(weights: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """Weighted mean of the sampled sequences, ``(n_envs, horizon, action_dim)``."""
    return th.einsum("en,tena->eta", weights, actions)


def weighted_action_std(weights: th.Tensor, actions: th.Tensor, plan: th.Tensor) -> th.Tensor:
    """``sqrt(sum_k w_k (plan_0 - a_k,0)^2)`` per env and action dimension, ``(n_envs, action_dim)``."""
    deviations = actions[0] - plan[:, :1]
    return th.sqrt(th.einsum("en,ena->ea", weights, deviations.square()))


class MPPIPlanner(nn.Module):
    """
    Infinite-horizon MPPI with swappable sampler, dynamics, step cost and terminal value.

    :param dynamics: ``f(states, actions) -> next_states`` on 2-D batches
    :param sampler: ``sampler(plan, n_samples, generator)`` returning time-major clamped action sequences
    :param step_cost: ``c(s, s')`` over any leading shape
    :param terminal_value: ``V(s)`` over any leading shape
    :param neutral_action: action appended by the warm start and used for a fresh plan, ``(action_dim,)``
    :param n_samples: ``N``, sequences sampled per env and iteration
    :param horizon: ``H``, steps per sequence
    :param n_iterations: ``J``, refinement iterations per planning step
    :param markup: ``eta`` on step costs
    :param use_step_cost: include the step costs (switch off for the value-only ablation)
    :param use_terminal_value: include the terminal value (switch off for the cost-only ablation)
    """

    def __init__(
        self,
        dynamics: nn.Module,
        sampler: nn.Module,
        step_cost: nn.Module,
        terminal_value: nn.Module,
        neutral_action: th.Tensor,
        n_samples: int = 512,
        horizon: int = 10,
        n_iterations: int = 5,
        markup: float = 1.01,
        use_step_cost: bool = True,
        use_terminal_value: bool = True,
    ):
        super().__init__()
        if not (use_step_cost or use_terminal_value):
            raise ValueError("The planner needs step costs, a terminal value or both; both were switched off.")
        self.dynamics = dynamics
        self.sampler = sampler
        self.step_cost = step_cost
        self.terminal_value = terminal_value
        self.register_buffer("neutral_action", neutral_action)
        self.n_samples = n_samples
        self.horizon = horizon
        self.n_iterations = n_iterations
        self.markup = markup
        self.use_step_cost = use_step_cost
        self.use_terminal_value = use_terminal_value

    def initial_plan(self, n_envs: int) -> th.Tensor:
        """A fresh plan: the neutral action at every step, ``(n_envs, horizon, action_dim)``."""
        return self.neutral_action.expand(n_envs, self.horizon, -1).clone()

    def forward(
        self, states: th.Tensor, previous_plan: th.Tensor, temperature: th.Tensor, generator: th.Generator
    ) -> PlanResult:
        """
        One planning step for every env.

        :param states: current state per env, ``(n_envs, state_dim)``
        :param previous_plan: last step's plan per env (not yet shifted), ``(n_envs, horizon, action_dim)``
        :param temperature: ``lambda`` of the exponential weights (scalar tensor)
        :param generator: source of the sampling noise
        """
        plan = shift_plan(previous_plan, self.neutral_action)
        step_cost = self.step_cost if self.use_step_cost else None
        terminal_value = self.terminal_value if self.use_terminal_value else None
        for _ in range(self.n_iterations):
            actions = self.sampler(plan, self.n_samples, generator)
            states_visited = rollout(self.dynamics, states, actions)
            costs = trajectory_costs(states_visited, step_cost, terminal_value, self.markup)
            weights = mppi_weights(costs, temperature)
            plan = weighted_plan(weights, actions)
        return PlanResult(plan, weighted_action_std(weights, actions, plan))
