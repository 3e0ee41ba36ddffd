"""
The plain MPPI planning step (paper Alg. 2), written for clarity, not speed: one dynamics call per horizon step
and the networks called as ordinary modules. :class:`~sb3_mpail.mppi.planner.MPPIPlanner` computes the same plan
faster; ``tests/test_planner_equivalence.py`` and ``benchmarks/planner_speed.py`` compare the two.

Tensors are time-major, ``(horizon, n_envs, n_samples, dim)``.
"""

from typing import Callable, Optional, Tuple

import torch as th
from torch import nn

from sb3_mpail.mppi.dynamics import DynamicsFunction

SamplerFunction = Callable[[th.Tensor, int, th.Generator], th.Tensor]


def shift_plan(plan: th.Tensor, neutral_action: th.Tensor) -> th.Tensor:
    """Warm start: drop the executed first step and append the neutral action (paper: mean 0)."""
    return th.cat((plan[:, 1:], neutral_action.expand(plan.shape[0], 1, -1)), dim=1)


def rollout(dynamics: DynamicsFunction, initial_states: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """
    Predicts the states visited by every sampled sequence, one dynamics call per step.

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
    step_cost: Optional[Callable[[th.Tensor, th.Tensor], th.Tensor]],
    terminal_value: Optional[Callable[[th.Tensor], th.Tensor]],
    markup: float,
    constraint_cost: Optional[Callable[[th.Tensor], th.Tensor]] = None,
) -> th.Tensor:
    """
    ``C_k = sum_t eta^t c(s_t, s_{t+1}) - eta^H V(s_H) + sum_t g(s_{t+1})``; any term may be switched off (``None``).

    :param states: rolled-out states, ``(horizon + 1, n_envs, n_samples, state_dim)``
    :param step_cost: ``c(s, s')`` over any leading shape, or ``None`` for the value-only planner
    :param terminal_value: ``V(s)`` over any leading shape, or ``None`` for the cost-only planner
    :param markup: ``eta``, the per-step factor on step costs (``1 / gamma`` in MPAIL)
    :param constraint_cost: a known cost ``g(s)`` of every state reached (obstacles, walls), over any leading shape
    :return: total cost per sample, ``(n_envs, n_samples)``
    """
    horizon = states.shape[0] - 1
    costs = states.new_zeros(states.shape[1:3])
    if step_cost is not None:
        markups = markup ** th.arange(horizon, device=states.device, dtype=states.dtype)
        costs = costs + th.einsum("t,ten->en", markups, step_cost(states[:-1], states[1:]))
    if terminal_value is not None:
        costs = costs - markup**horizon * terminal_value(states[-1])
    if constraint_cost is not None:
        costs = costs + constraint_cost(states[1:]).sum(0)
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


def reference_plan(
    dynamics: DynamicsFunction,
    sampler: SamplerFunction,
    step_cost: Optional[nn.Module],
    terminal_value: Optional[nn.Module],
    neutral_action: th.Tensor,
    states: th.Tensor,
    previous_plan: th.Tensor,
    temperature: th.Tensor,
    generator: th.Generator,
    n_samples: int = 512,
    n_iterations: int = 5,
    markup: float = 1.01,
    constraint_cost: Optional[Callable[[th.Tensor], th.Tensor]] = None,
) -> Tuple[th.Tensor, th.Tensor]:
    """
    One planning step for every env, exactly as the paper's Algorithm 2 reads.

    :param dynamics: ``f(states, actions) -> next_states`` on 2-D batches
    :param sampler: ``sampler(plan, n_samples, generator)`` returning time-major clamped action sequences
    :param step_cost: ``c(s, s')`` over any leading shape, or ``None`` (value-only)
    :param terminal_value: ``V(s)`` over any leading shape, or ``None`` (cost-only)
    :param neutral_action: action appended by the warm start, ``(action_dim,)``
    :param states: current state per env, ``(n_envs, state_dim)``
    :param previous_plan: last step's plan per env (not yet shifted), ``(n_envs, horizon, action_dim)``
    :param temperature: ``lambda`` of the exponential weights (scalar tensor)
    :param generator: source of the sampling noise
    :param n_samples: ``N``
    :param n_iterations: ``J``
    :param markup: ``eta``
    :param constraint_cost: a known cost ``g(s)`` of every state reached, or ``None``
    :return: the plan ``(n_envs, horizon, action_dim)`` and the first action's std ``(n_envs, action_dim)``
    """
    plan = shift_plan(previous_plan, neutral_action)
    for _ in range(n_iterations):
        actions = sampler(plan, n_samples, generator)
        states_visited = rollout(dynamics, states, actions)
        costs = trajectory_costs(states_visited, step_cost, terminal_value, markup, constraint_cost)
        weights = mppi_weights(costs, temperature)
        plan = weighted_plan(weights, actions)
    return plan, weighted_action_std(weights, actions, plan)
