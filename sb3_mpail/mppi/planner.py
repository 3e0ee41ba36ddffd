"""
Infinite-horizon MPPI (paper Alg. 2), batched over environments and samples.

One planning step, for every env at once:

1. **warm start**: shift the previous plan one step forward, the new last step at the neutral action;
2. repeat ``J`` times:

   a. **sample** ``N`` action sequences around the plan (and add the policy prior's ``K`` proposals, when there is one),
   b. **roll out** each through the dynamics model for ``H`` steps,
   c. **cost** each trajectory: ``C = sum_t eta^t c(s_t, s_{t+1}) - eta^H V(s_H)``,
   d. **weight** the samples by ``softmax(-C / temperature)`` and set the plan to the weighted mean;
3. the **policy std** of the first action is the weighted spread of the last iteration's samples around it.

Tensors inside a planning step are time-major, ``(horizon, n_envs, n_samples, dim)``. The same step written plainly
is :func:`sb3_mpail.mppi.reference.reference_plan`; this planner gives the same plan faster:

* dynamics models with a batched ``rollout(initial_states, actions)`` roll out all ``H`` steps in one call;
* the discriminator and value run through their fused planning views (:mod:`sb3_mpail.mppi.fused`), their weights
  frozen until they change, when gradients are off and the networks are in eval mode;
* optionally the roll-out/cost/weight update is compiled with ``torch.compile`` (``compile_planner``).
"""

import threading
from typing import Callable, NamedTuple, Optional, Sequence, Tuple, Union

import torch as th
from torch import nn

from sb3_mpail.checks import NON_NEGATIVE_INTEGER, POSITIVE_INTEGER, POSITIVE_NUMBER, Rule, check_arguments
from sb3_mpail.mppi.dynamics import DynamicsFunction
from sb3_mpail.mppi.fused import Workspace
from sb3_mpail.mppi.reference import (
    mppi_weights,
    reference_plan,
    shift_plan,
    trajectory_costs,
    weighted_action_std,
    weighted_plan,
)
from sb3_mpail.mppi.reference import rollout as rollout_step_by_step

__all__ = [
    "LastIteration",
    "MPPIPlanner",
    "PlanResult",
    "TrajectoryCost",
    "mppi_weights",
    "rollout",
    "shift_plan",
    "trajectory_costs",
    "weighted_action_std",
    "weighted_mean",
    "weighted_plan",
]

#: what ``compile_planner`` may be (the modes are looked up only for a string: listing them imports torch's compiler)
COMPILE_PLANNER = Rule(
    "False, True or a torch.compile mode (one of torch._inductor.list_mode_options())",
    lambda value: isinstance(value, bool) or (isinstance(value, str) and value in th._inductor.list_mode_options()),
)


class PlanResult(NamedTuple):
    """Output of one planning step."""

    plan: th.Tensor  #: optimised action sequence per env, ``(n_envs, horizon, action_dim)``
    action_std: th.Tensor  #: weighted std of the first action per env, ``(n_envs, action_dim)``


class LastIteration(NamedTuple):
    """The last MPPI iteration of a planning step, as :meth:`MPPIPlanner.optimise` leaves it."""

    plan: th.Tensor  #: the plan it gave, ``(n_envs, horizon, action_dim)``
    samples: th.Tensor  #: its sampled sequences, ``(horizon, n_envs, n_samples, action_dim)``
    weights: th.Tensor  #: their MPPI weights, ``(n_envs, n_samples)``
    costs: th.Tensor  #: their trajectory costs, ``(n_envs, n_samples)``


def rollout(dynamics: DynamicsFunction, initial_states: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """
    Predicts the states visited by every sampled sequence: through the model's own batched
    ``rollout(initial_states, actions)`` when it has one and gradients are off (batched roll-outs write into
    preallocated storage), else one dynamics call per step.

    :param dynamics: ``f(states, actions) -> next_states`` on 2-D batches
    :param initial_states: current state per env, ``(n_envs, state_dim)``
    :param actions: sampled sequences, ``(horizon, n_envs, n_samples, action_dim)``
    :return: states ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, state_dim)``
    """
    batched_rollout = getattr(dynamics, "rollout", None)
    if batched_rollout is not None and not th.is_grad_enabled():
        return batched_rollout(initial_states, actions)
    return rollout_step_by_step(dynamics, initial_states, actions)


def weighted_mean(weights: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """
    :func:`~sb3_mpail.mppi.reference.weighted_plan` as one batched product ``w_e (N x A block of step t, env e)``,
    which reads the samples in place (twice as fast at 64 envs as ``(A x N) w_e`` over the transposed blocks).
    """
    return th.matmul(weights.unsqueeze(1), actions).squeeze(2).transpose(0, 1)


class TrajectoryCost:
    """
    ``C_k = sum_t eta^t c(s_t, s_{t+1}) - eta^H V(s_H) + sum_t g(s_{t+1})`` for one planning step. Step cost and value
    run through their fused planning views (weights frozen, see :class:`~sb3_mpail.mppi.fused.ViewCache`) where they
    offer one, else as plain calls.

    :param step_cost: ``c(s, s')`` over any leading shape, or ``None`` (value-only)
    :param terminal_value: ``V(s)`` over any leading shape, or ``None`` (cost-only)
    :param markup: ``eta``
    :param horizon: ``H``
    :param states: the current states, ``(n_envs, state_dim)`` (their size, device and dtype are used)
    :param workspace: scratch tensors of the fused views
    :param fused: use the fused views where available
    :param held_dims: state dimensions the roll-outs keep at their values in ``states`` (the dynamics model's
        ``held_state_dims``), which the fused views then need not read
    :param constraint_cost: a known cost ``g(s)`` of every state reached (obstacles, walls) over any leading shape,
        added unmarked-up to the learned costs, or ``None``
    """

    def __init__(
        self,
        step_cost: Optional[Callable[[th.Tensor, th.Tensor], th.Tensor]],
        terminal_value: Optional[Callable[[th.Tensor], th.Tensor]],
        markup: float,
        horizon: int,
        states: th.Tensor,
        workspace: Workspace,
        fused: bool = True,
        held_dims: Sequence[int] = (),
        constraint_cost: Optional[Callable[[th.Tensor], th.Tensor]] = None,
    ):
        self.step_cost = step_cost
        self.constraint_cost = constraint_cost
        self.terminal_value = terminal_value
        self.markups = markup ** th.arange(horizon, device=states.device, dtype=states.dtype)
        self.terminal_markup = markup**horizon
        self.workspace = workspace
        state_dim = states.shape[-1]
        self.fused_step_cost = _planning_view(step_cost, state_dim) if fused else None
        self.fused_value = _planning_view(terminal_value, state_dim) if fused else None
        for view in (self.fused_step_cost, self.fused_value):
            if hasattr(view, "hold"):  # views outlive a planning step (see fused.ViewCache): always set, even to none
                view.hold(held_dims, states)

    def __call__(self, states: th.Tensor) -> th.Tensor:
        """
        :param states: rolled-out states, ``(horizon + 1, n_envs, n_samples, state_dim)``
        :return: total cost per sample, ``(n_envs, n_samples)``
        """
        costs = None
        if self.step_cost is not None:
            if self.fused_step_cost is not None:
                costs = self.fused_step_cost(states, self.markups, self.workspace)
            else:
                step_costs = _checked_output(self.step_cost(states[:-1], states[1:]), states, "step_cost", 1)
                costs = th.einsum("t,ten->en", self.markups, step_costs)
        if self.terminal_value is not None:
            final_states = states[-1]
            if self.fused_value is not None:
                values = self.fused_value(final_states, self.workspace)
            else:
                values = _checked_output(self.terminal_value(final_states), final_states, "terminal_value")
            costs = values * -self.terminal_markup if costs is None else costs.sub_(values, alpha=self.terminal_markup)
        assert costs is not None
        if self.constraint_cost is not None:
            penalties = _checked_output(self.constraint_cost(states[1:]), states, "constraint_cost", 1, flags=True)
            costs.add_(penalties.sum(0))
        return costs


def _checked_output(output: th.Tensor, states: th.Tensor, name: str, skipped_steps: int = 0, flags: bool = False) -> th.Tensor:
    """
    A user's cost or value output, refused unless it is one real number per state, and cast to the states' dtype
    (float64 costs of float32 states, as a float64 dynamics model's next states are); a shape and dtype check: no host
    sync.

    :param output: what ``name`` returned
    :param states: the states it scored (their shape less the last, state, dimension, and their dtype are used)
    :param name: the setting it came from, as the error names it
    :param skipped_steps: time steps fewer than ``states`` has (transitions are one fewer than states)
    :param flags: booleans are taken, as 0 and 1 (a constraint's "inside a wall"); a cost or value must be numbers
    """
    expected = (states.shape[0] - skipped_steps, *states.shape[1:-1])
    if not isinstance(output, th.Tensor) or tuple(output.shape) != expected:
        got = f"shape {tuple(output.shape)}" if isinstance(output, th.Tensor) else type(output).__name__
        raise ValueError(
            f"{name} must return a torch tensor of one number per state, shape {expected} here (the leading shape of "
            f"the states it was given); got {got}."
        )
    if output.is_complex() or (output.dtype == th.bool and not flags):
        raise ValueError(
            f"{name} must return real numbers (a floating-point tensor, cast to the states' {states.dtype}); got dtype "
            f"{output.dtype}. Turn a flag into a number first, e.g. flag.to(states.dtype) * weight."
        )
    return output.to(states.dtype)  # itself when it has that dtype


def _checked_samples(samples: th.Tensor, plan: th.Tensor, n_samples: int) -> th.Tensor:
    """
    The sampler's action sequences, refused unless they are a tensor of the time-major shape the planner reads (a shape
    check: no host sync).

    :param samples: what the sampler returned
    :param plan: the plan it sampled around, ``(n_envs, horizon, action_dim)``
    :param n_samples: ``N``, the sequences asked for per env
    """
    n_envs, horizon, action_dim = plan.shape
    expected = (horizon, n_envs, n_samples, action_dim)
    if not isinstance(samples, th.Tensor) or tuple(samples.shape) != expected:
        got = f"shape {tuple(samples.shape)}" if isinstance(samples, th.Tensor) else type(samples).__name__
        raise ValueError(f"sampler must return (H, n_envs, N, A) = {expected} action sequences; got {got}.")
    return samples


def _envs(indices: Sequence[int]) -> str:
    """Env indices as a message names them: ``env 1`` or ``envs [0, 1]``."""
    return f"env {indices[0]}" if len(indices) == 1 else f"envs {list(indices)}"


def _planning_view(network: Optional[Callable], state_dim: int) -> Optional[Callable]:
    view = getattr(network, "planning_view", None)
    return view(state_dim) if view is not None else None


class MPPIPlanner(nn.Module):
    """
    Infinite-horizon MPPI with swappable sampler, dynamics, step cost and terminal value.

    :param dynamics: ``f(states, actions) -> next_states`` on 2-D batches, optionally with a batched
        ``rollout(initial_states, actions)`` over time-major sequences
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
    :param compile_planner: compile the roll-out/cost/weight update with ``torch.compile``: ``False`` (default),
        ``True`` (default mode) or a ``torch.compile`` mode such as ``"reduce-overhead"`` (CUDA graphs on a GPU)
    :param prior: a policy prior (:class:`~sb3_mpail.prior.PolicyPrior`) whose ``propose(dynamics, states, horizon,
        n_proposals, generator)`` adds ``n_proposals`` sequences to every iteration's samples, or ``None``
    :param n_proposals: ``K``, the prior's sequences per env, drawn once per planning step
    :param constraint_cost: a known cost ``g(s)`` of every state reached (walls, obstacles: what the dynamics model
        does not know), over any leading shape, added to the learned costs; ``None``: none
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
        compile_planner: Union[bool, str] = False,
        prior: Optional[nn.Module] = None,
        n_proposals: int = 0,
        constraint_cost: Optional[Callable[[th.Tensor], th.Tensor]] = None,
    ):
        super().__init__()
        check_arguments(
            n_proposals=(n_proposals, NON_NEGATIVE_INTEGER),
            n_samples=(n_samples, POSITIVE_INTEGER),
            horizon=(horizon, POSITIVE_INTEGER),
            n_iterations=(n_iterations, POSITIVE_INTEGER),
            markup=(markup, POSITIVE_NUMBER),
            compile_planner=(compile_planner, COMPILE_PLANNER),
        )
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
        self.compile_planner = compile_planner
        self.prior = prior
        self.n_proposals = n_proposals if prior is not None else 0
        self.constraint_cost = constraint_cost
        self._workspace = Workspace()
        self._compiled_update: Optional[Callable] = None
        # one planning step at a time: the scratch tensors and the fused views' held inputs are shared between calls
        self._lock = threading.Lock()

    def initial_plan(self, n_envs: int) -> th.Tensor:
        """A fresh plan: the neutral action at every step, ``(n_envs, horizon, action_dim)``."""
        return self.neutral_action.expand(n_envs, self.horizon, -1).clone()

    def trajectory_cost(self, states: th.Tensor, horizon: int) -> TrajectoryCost:
        """The trajectory cost of this planning step, networks frozen (fused views only when not compiling)."""
        return TrajectoryCost(
            self.step_cost if self.use_step_cost else None,
            self.terminal_value if self.use_terminal_value else None,
            self.markup,
            horizon,
            states,
            self._workspace,
            fused=not self.compile_planner,
            held_dims=getattr(self.dynamics, "held_state_dims", ()),
            constraint_cost=self.constraint_cost,
        )

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
        last = self.optimise(states, previous_plan, temperature, generator)
        return PlanResult(last.plan, weighted_action_std(last.weights, last.samples, last.plan))

    def optimise(
        self, states: th.Tensor, previous_plan: th.Tensor, temperature: th.Tensor, generator: th.Generator
    ) -> LastIteration:
        """
        The ``J`` iterations of one planning step (what :meth:`forward` runs), keeping the last one's samples. Safe to
        call from several threads: the steps run one at a time, and what they return is their own (never scratch).
        """
        with self._lock:
            plan = shift_plan(previous_plan, self.neutral_action)
            trajectory_cost = self.trajectory_cost(states, plan.shape[1])
            update = self._update
            if self.compile_planner:
                update = self._compiled()
            proposals = self._proposals(states, plan.shape[1], generator)
            for _ in range(self.n_iterations):
                actions = _checked_samples(self.sampler(plan, self.n_samples, generator), plan, self.n_samples)
                if proposals is not None:
                    actions = th.cat((actions, proposals), dim=2)
                plan, weights, costs = update(states, actions, temperature, trajectory_cost)
            return LastIteration(plan, actions, weights, costs.clone())  # the costs are scratch of the fused views

    def non_finite_cause(self, states: th.Tensor, previous_plan: th.Tensor) -> Optional[str]:
        """
        Why a planning step from finite ``states`` and ``previous_plan`` made a non-finite plan, where the cause is the
        constraint cost or a sampled set with no finite cost: the step's first iteration is re-run step by step (fresh
        noise, no prior proposals) and its constraint values and trajectory costs read. Only for a plan already found
        non-finite: it reads values back to the host.

        A constraint that is infinite for every sampled sequence of an env leaves it no feasible sample: the MPPI
        weights ``softmax(-C / lambda)`` of costs that are all infinite are undefined (NaN), so the plan is refused
        rather than made up. Where some sequences are feasible, the infinite ones simply get weight 0.

        :param states: the states planned from, ``(n_envs, state_dim)``
        :param previous_plan: the plans planned from (before the warm start's shift), ``(n_envs, horizon, action_dim)``
        :return: the cause, or ``None`` when neither is it (or the re-run does not reproduce it)
        """
        with th.no_grad():
            generator = th.Generator(device=states.device).manual_seed(0)
            plan = shift_plan(previous_plan, self.neutral_action)
            actions = _checked_samples(self.sampler(plan, self.n_samples, generator), plan, self.n_samples)
            visited = rollout_step_by_step(self.dynamics, states, actions)
            trajectory_cost = TrajectoryCost(
                self.step_cost if self.use_step_cost else None,
                self.terminal_value if self.use_terminal_value else None,
                self.markup,
                plan.shape[1],
                states,
                self._workspace,
                fused=False,
                constraint_cost=self.constraint_cost,
            )
            costs = trajectory_cost(visited)  # (n_envs, N)
            penalties = None
            if self.constraint_cost is not None:  # per sequence, (n_envs, N): NaN or +inf if any state's is
                penalties = _checked_output(self.constraint_cost(visited[1:]), visited, "constraint_cost", 1, True).sum(0)
        causes = []
        if penalties is not None:
            nan_envs = th.isnan(penalties).any(1).nonzero().flatten().tolist()
            if nan_envs:
                causes.append(f"constraint_cost returned NaN for {_envs(nan_envs)}")
        infeasible = th.isposinf(costs).all(1).nonzero().flatten().tolist()
        if infeasible:
            constrained = penalties is not None and bool(th.isposinf(penalties[infeasible]).all())
            causes.append(
                f"every sampled sequence of {_envs(infeasible)} has an infinite cost (no feasible sample)"
                + (": constraint_cost is infinite on each" if constrained else "")
                + ", and MPPI's weights of costs that are all infinite are undefined. Give a large finite cost instead "
                "of an infinite one (as RectangleObstacles' weight), or start where some sequence within the horizon "
                "keeps to the constraint"
            )
        return "; ".join(causes) + "." if causes else None

    def _proposals(self, states: th.Tensor, horizon: int, generator: th.Generator) -> Optional[th.Tensor]:
        """The prior's sequences of this planning step, ``(horizon, n_envs, K, action_dim)``, or ``None`` without one."""
        if self.prior is None or self.n_proposals == 0:
            return None
        return self.prior.propose(self.dynamics, states, horizon, self.n_proposals, generator)

    def _update(
        self, states: th.Tensor, actions: th.Tensor, temperature: th.Tensor, trajectory_cost: TrajectoryCost
    ) -> Tuple[th.Tensor, th.Tensor, th.Tensor]:
        """One MPPI iteration after sampling: roll out, cost, weight, new plan (and the weights and costs)."""
        states_visited = rollout(self.dynamics, states, actions)
        costs = trajectory_cost(states_visited)
        weights = mppi_weights(costs, temperature)
        return weighted_mean(weights, actions), weights, costs

    def _compiled(self) -> Callable:
        if self._compiled_update is None:
            mode = None if self.compile_planner is True else self.compile_planner
            self._compiled_update = th.compile(self._update, mode=mode, dynamic=False)
        return self._compiled_update

    def reference_forward(
        self, states: th.Tensor, previous_plan: th.Tensor, temperature: th.Tensor, generator: th.Generator
    ) -> PlanResult:
        """The same planning step through the plain implementation, :func:`~sb3_mpail.mppi.reference.reference_plan`."""
        plan, action_std = reference_plan(
            self.dynamics,
            self.sampler,
            self.step_cost if self.use_step_cost else None,
            self.terminal_value if self.use_terminal_value else None,
            self.neutral_action,
            states,
            previous_plan,
            temperature,
            generator,
            self.n_samples,
            self.n_iterations,
            self.markup,
            self.constraint_cost,
        )
        return PlanResult(plan, action_std)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_compiled_update"] = None  # compiled code is rebuilt on demand, never pickled
        del state["_lock"]  # locks cannot be pickled; a copy gets its own
        return state

    def __setstate__(self, state: dict) -> None:
        super().__setstate__(state)
        self._lock = threading.Lock()
