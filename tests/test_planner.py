"""The MPPI planner does what the paper's Algorithm 2 says, on problems whose answer is known."""

import numpy as np
import pytest
import torch as th
from torch import nn

from sb3_mpail.mppi import DeltaSampler, GaussianSampler, MPPIPlanner
from sb3_mpail.mppi.planner import mppi_weights, rollout, shift_plan, trajectory_costs, weighted_action_std


def integrator(states: th.Tensor, actions: th.Tensor) -> th.Tensor:
    return states + actions


class DistanceToTarget(nn.Module):
    """Quadratic step cost ``||s' - target||^2``."""

    def __init__(self, target: float):
        super().__init__()
        self.target = target

    def forward(self, states: th.Tensor, next_states: th.Tensor) -> th.Tensor:
        return (next_states - self.target).square().sum(-1)


class RecordingSampler(nn.Module):
    """Gaussian sampler that keeps its last samples so a test can inspect them."""

    def __init__(self, sampler: nn.Module):
        super().__init__()
        self.sampler = sampler
        self.last_actions = None

    def forward(self, plan, n_samples, generator):
        self.last_actions = self.sampler(plan, n_samples, generator)
        return self.last_actions


def make_planner(step_cost=None, terminal_value=None, noise_std=0.3, low=-2.0, high=2.0, **kwargs) -> MPPIPlanner:
    low_bounds, high_bounds = np.full(1, low, np.float32), np.full(1, high, np.float32)
    settings = dict(n_samples=256, horizon=4, n_iterations=8, markup=1.0)
    settings.update(kwargs)
    return MPPIPlanner(
        dynamics=integrator,
        sampler=GaussianSampler(low_bounds, high_bounds, noise_std),
        step_cost=step_cost if step_cost is not None else DistanceToTarget(1.0),
        terminal_value=terminal_value if terminal_value is not None else (lambda states: states.sum(-1) * 0),
        neutral_action=th.zeros(1),
        **settings,
    )


def test_quadratic_cost_converges_to_analytic_optimum():
    # s' = s + a with cost sum_t (s_{t+1} - 1)^2: optimal plan jumps to the target at once, then stays (a = 0).
    # For a quadratic cost each MPPI iteration moves the Gaussian's mean a fixed fraction of the way to the optimum.
    planner = make_planner(use_terminal_value=False, n_samples=4096, horizon=2, n_iterations=10)
    start = th.tensor([[-0.5], [0.25], [1.5]])
    generator = th.Generator().manual_seed(0)
    plan = planner.initial_plan(3)
    for _ in range(4):  # replanning from the same state refines the warm-started plan further
        plan, _ = planner(start, th.cat((plan[:, :1], plan[:, :-1]), dim=1), th.tensor(1.0), generator)
    assert th.allclose(plan[:, 0, 0], 1.0 - start[:, 0], atol=0.1)  # Monte Carlo error of N = 4096 samples
    assert th.allclose(plan[:, 1:], th.zeros_like(plan[:, 1:]), atol=0.1)


def test_vanishing_temperature_picks_the_best_sample():
    sampler = RecordingSampler(GaussianSampler(np.full(1, -2.0, np.float32), np.full(1, 2.0, np.float32), 0.5))
    planner = MPPIPlanner(
        integrator,
        sampler,
        DistanceToTarget(1.0),
        lambda s: s.sum(-1) * 0,
        th.zeros(1),
        n_samples=64,
        horizon=3,
        n_iterations=1,
        markup=1.0,
        use_terminal_value=False,
    )
    start = th.tensor([[0.0], [3.0]])
    plan, _ = planner(start, planner.initial_plan(2), th.tensor(1e-9), th.Generator().manual_seed(1))
    actions = sampler.last_actions
    costs = trajectory_costs(rollout(integrator, start, actions), DistanceToTarget(1.0), None, 1.0)
    best = costs.argmin(dim=1)
    for env in range(2):
        assert th.allclose(plan[env], actions[:, env, best[env]], atol=1e-6)


def test_warm_start_shifts_the_plan_and_appends_the_neutral_action():
    previous = th.arange(8, dtype=th.float32).view(2, 4, 1)
    shifted = shift_plan(previous, th.tensor([-7.0]))
    assert th.equal(shifted[:, :3], previous[:, 1:])
    assert th.equal(shifted[:, 3], th.full((2, 1), -7.0))
    # with no sampling noise every sample equals the shifted plan, so the planner returns it unchanged
    planner = make_planner(noise_std=0.0, low=-10.0, high=10.0)
    plan, action_std = planner(th.zeros(2, 1), previous, th.tensor(1.0), th.Generator().manual_seed(0))
    assert th.allclose(plan, shift_plan(previous, th.zeros(1)))
    assert th.all(action_std == 0)


def test_samples_and_plans_stay_inside_the_action_bounds():
    sampler = RecordingSampler(GaussianSampler(np.full(1, -0.1, np.float32), np.full(1, 0.2, np.float32), 3.0))
    planner = MPPIPlanner(
        integrator, sampler, DistanceToTarget(5.0), lambda s: s.sum(-1), th.zeros(1), n_samples=32, horizon=3, n_iterations=2
    )
    plan, _ = planner(th.zeros(4, 1), planner.initial_plan(4), th.tensor(1.0), th.Generator().manual_seed(0))
    for tensor in (sampler.last_actions, plan):
        assert tensor.min() >= -0.1 - 1e-6 and tensor.max() <= 0.2 + 1e-6


def test_same_seed_gives_same_plan_and_other_seed_differs():
    planner = make_planner()
    start = th.tensor([[0.3]])

    def plan_with(seed):
        return planner(start, planner.initial_plan(1), th.tensor(1.0), th.Generator().manual_seed(seed)).plan

    assert th.equal(plan_with(3), plan_with(3))
    assert not th.equal(plan_with(3), plan_with(4))


def test_trajectory_cost_applies_markup_and_subtracts_terminal_value():
    states = th.zeros(3, 1, 1, 1)  # horizon 2
    states[1], states[2] = 1.0, 2.0
    step_cost = DistanceToTarget(0.0)  # costs 1 then 4

    def value(s):
        return 10 * s.sum(-1)  # V(s_H) = 20

    markup = 1.5
    assert trajectory_costs(states, step_cost, value, markup).item() == pytest.approx(1 + 1.5 * 4 - 1.5**2 * 20)
    assert trajectory_costs(states, step_cost, None, markup).item() == pytest.approx(1 + 1.5 * 4)  # cost-only
    assert trajectory_costs(states, None, value, markup).item() == pytest.approx(-(1.5**2) * 20)  # value-only


def test_planner_refuses_to_switch_off_both_cost_terms():
    with pytest.raises(ValueError, match="both were switched off"):
        make_planner(use_step_cost=False, use_terminal_value=False)


def test_weights_are_softmax_of_negative_cost_and_std_is_their_spread():
    costs = th.tensor([[0.0, 1.0, 2.0]])
    weights = mppi_weights(costs, th.tensor(0.5))
    expected = th.exp(-costs / 0.5) / th.exp(-costs / 0.5).sum()
    assert th.allclose(weights, expected)
    actions = th.tensor([[-1.0], [0.0], [1.0]]).view(1, 1, 3, 1)  # horizon 1, env 1, samples 3
    plan = th.einsum("en,tena->eta", weights, actions)
    std = weighted_action_std(weights, actions, plan)
    assert std.item() == pytest.approx(float(th.sqrt((weights * (actions.view(3) - plan.view(1)).square()).sum())))


def sampler_and_plan(uniform: bool) -> tuple:
    low = np.array([-1.0, -1.0] if uniform else [-1.0, -4.0], np.float32)
    high = np.array([1.0, 1.0] if uniform else [1.0, 0.5], np.float32)
    sampler = GaussianSampler(low, high, 0.1 if uniform else np.array([0.1, 0.05], np.float32))
    plan = th.tensor([[[0.0, -2.0]], [[0.9, 0.4]]]).expand(2, 3, 2).contiguous()
    return sampler, plan


@pytest.mark.parametrize("uniform", [True, False])
@pytest.mark.parametrize("n_samples", [4000, 30, 7])
def test_samples_are_the_plan_plus_scaled_noise_clamped_to_the_bounds(uniform, n_samples):
    # the sampler adds the plan over rows of several samples (as many as divide n_samples): the same numbers as a
    # plain broadcast over single samples
    sampler, plan = sampler_and_plan(uniform)
    actions = sampler(plan, n_samples, th.Generator().manual_seed(0))
    expected = th.randn(actions.shape, generator=th.Generator().manual_seed(0))
    expected = expected * sampler.noise_std + plan.transpose(0, 1).unsqueeze(2)
    expected = th.clamp(expected, sampler.action_low, sampler.action_high)
    assert th.equal(actions, expected)


@pytest.mark.parametrize("uniform", [True, False])
def test_samples_follow_each_action_dimensions_own_std_and_bounds(uniform):
    sampler, plan = sampler_and_plan(uniform)
    actions = sampler(plan, 4000, th.Generator().manual_seed(0))
    assert (actions >= sampler.action_low).all() and (actions <= sampler.action_high).all()
    unclamped_std = actions[:, 0].reshape(-1, 2).std(dim=0)  # env 0, dimension 0 is far from its bounds
    assert unclamped_std[0] == pytest.approx(float(sampler.noise_std[0]), rel=0.05)


def delta_samples_step_by_step(sampler: DeltaSampler, plan: th.Tensor, noise: th.Tensor) -> th.Tensor:
    """The delta sampler written as its docstring reads, one step at a time: a clamped random walk from the plan's start."""
    horizon, n_envs, n_samples, _ = noise.shape
    samples = th.empty_like(noise)
    current = plan[:, 0].unsqueeze(1).expand(n_envs, n_samples, -1)
    for step in range(horizon):
        increment = plan[:, step] - plan[:, step - 1] if step > 0 else th.zeros_like(plan[:, 0])
        change = th.clamp(increment.unsqueeze(1) + noise[step] * sampler.noise_std, -sampler.max_delta, sampler.max_delta)
        current = current + change
        samples[step] = current
    return th.clamp(samples, sampler.action_low, sampler.action_high)


@pytest.mark.parametrize("n_samples", [64, 7])
def test_delta_samples_are_clamped_random_walks_around_the_plan_as_written_step_by_step(n_samples):
    sampler = DeltaSampler(np.array([-1.0, -2.0], np.float32), np.array([1.0, 2.0], np.float32), [1.0, 0.5], [0.2, 0.1])
    plan = th.stack([th.linspace(-0.5, 0.9, 6), th.linspace(1.5, -1.5, 6)], dim=-1).expand(3, 6, 2).contiguous()
    actions = sampler(plan, n_samples, th.Generator().manual_seed(0))
    noise = th.randn(actions.shape, generator=th.Generator().manual_seed(0))
    assert th.allclose(actions, delta_samples_step_by_step(sampler, plan, noise), atol=1e-6)
    # consecutive actions never jump by more than max_delta (in action units: relative to the half-range)
    assert (th.diff(actions, dim=0).abs() <= sampler.max_delta + 1e-6).all()
    assert th.allclose(sampler.max_delta, th.tensor([0.2, 0.2]))


def test_delta_samples_without_noise_are_the_plan_where_its_increments_are_within_the_limit():
    sampler = DeltaSampler(np.full(1, -1.0, np.float32), np.full(1, 1.0, np.float32), 0.0, 0.5)
    plan = th.tensor([0.0, 0.3, 0.5, 0.4]).view(1, 4, 1)
    actions = sampler(plan, 3, th.Generator().manual_seed(0))
    assert th.allclose(actions[:, 0, :, 0], plan[0, :, 0].unsqueeze(1).expand(4, 3))


def test_delta_sampler_refuses_a_negative_std_or_a_zero_step_limit():
    with pytest.raises(ValueError, match="DeltaSampler needs noise_std >= 0; got -0.1"):
        DeltaSampler(np.full(1, -1.0), np.full(1, 1.0), -0.1, 0.2)
    with pytest.raises(ValueError, match="max_delta must be a finite number > 0, .* one per action dimension"):
        DeltaSampler(np.full(1, -1.0), np.full(1, 1.0), 0.5, 0.0)
