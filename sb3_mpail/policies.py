"""The MPPI "policy": no actor network, an online planner over a learned cost, value and a dynamics model."""

import hashlib
from typing import Any, Callable, Dict, Sequence, Tuple, Union

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from torch import nn

from sb3_mpail.checks import (
    BOOLEAN,
    FINITE_NUMBER,
    HIDDEN_SIZES,
    NON_NEGATIVE_INTEGER,
    NON_NEGATIVE_NUMBER,
    OPTIONAL_DICT,
    POSITIVE_INTEGER,
    POSITIVE_NUMBER,
    check_arguments,
    check_finite,
    check_signature,
    one_of,
    per_action_dimension,
)
from sb3_mpail.mppi.constraints import make_constraint_cost
from sb3_mpail.mppi.costs import (
    FeatureChain,
    FeatureMap,
    FeatureSpec,
    MappedNetwork,
    StandardisedFeatures,
    TerminalValue,
    TransitionCost,
    learned_reward,
    make_transition_discriminator,
    make_value_network,
)
from sb3_mpail.mppi.dynamics import DynamicsSpec, LearnedDynamics, make_dynamics
from sb3_mpail.mppi.ensemble import DiscriminatorEnsemble, ValueEnsemble
from sb3_mpail.mppi.planner import MPPIPlanner, weighted_action_std
from sb3_mpail.mppi.reward_forms import REWARD_FORMS
from sb3_mpail.mppi.sampling import make_sampler
from sb3_mpail.prior import PolicyPrior, PriorValue

#: deterministic planning draws its sampling noise afresh at every call from this seed (mixed, by ``predict``, with its
#: inputs), so its actions are a pure function of the inputs (and the model), whatever was planned before and whatever
#: the model's seed
DETERMINISTIC_PLANNING_SEED = 1_000_003


def deterministic_planning_seed(*inputs: np.ndarray) -> int:
    """
    The seed of deterministic planning's noise for these inputs (``predict``'s observations and the plans it starts from):
    the same inputs give the same seed, so the same action, and the next step's inputs another one. One seed for every
    step would draw the same samples at every step: a warm-started plan then moves by the same perturbations step after
    step, and their sample mean's bias builds up (a lap driven that way went 4.5 m off its path on average, against
    0.45 m with fresh samples).

    :param inputs: host arrays, hashed as float32 values
    """
    digest = hashlib.blake2b(DETERMINISTIC_PLANNING_SEED.to_bytes(8, "little"), digest_size=8)
    for array in inputs:
        digest.update(np.ascontiguousarray(array, dtype=np.float32).tobytes())
    return int.from_bytes(digest.digest(), "little") >> 1  # torch seeds are below 2**63


#: what the errors on a non-finite observation and on a non-finite plan advise
NON_FINITE_OBSERVATION = "the planner cannot plan from it. Check the environment (SB3's VecCheckNan wrapper finds the step)."
#: observations beyond this magnitude are refused: float32 products of two such values overflow
LARGE_OBSERVATION = 1e18
NON_FINITE_PLAN = (
    "the step cost, value or dynamics model returned NaN or infinite values (e.g. training diverged, or a learned "
    "model met states far outside its data)."
)


class MPPIPolicy(BasePolicy):
    """
    Holds the discriminator ``d_theta(s, s')``, the value ``V_phi(s)``, a dynamics model and the MPPI planner that
    combines them. Acting means planning: the warm-start plan of each env is the recurrent ``state`` of
    :meth:`predict`, reset on ``episode_start``, so SB3's ``evaluate_policy`` and callbacks work unchanged.

    :param observation_space: a flat ``Box`` (the planner's state is the observation)
    :param action_space: a ``Box``; planned actions are clamped to its bounds
    :param dynamics: the planning model: a name (``"bicycle"``, ``"pendulum"``, ``"learned"``), an ``nn.Module`` or a
        callable ``f(states, actions) -> next_states``
    :param dynamics_kwargs: keyword arguments for a named dynamics model
    :param n_samples: ``N``, sampled sequences per env and iteration
    :param horizon: ``H``, planning horizon in env steps
    :param n_iterations: ``J``, MPPI iterations per planning step
    :param noise_std: sampling std relative to the action half-range (paper's ``Sigma = diag(0.3)``), ``>= 0``: one
        number for all action dimensions or one per dimension
    :param markup: ``eta`` on step costs (paper: 1.01, about ``1 / gamma``)
    :param use_step_cost: plan with the discriminator's step costs (``False``: value-only ablation)
    :param use_terminal_value: bootstrap with the value (``False``: cost-only ablation)
    :param discriminator_hidden_sizes: hidden widths of the discriminator
    :param value_hidden_sizes: hidden widths of the value network
    :param value_layer_norm: layer-normalise the value's hidden layers, which bounds it: far from the data it levels off
        instead of extrapolating linearly (:func:`~sb3_mpail.mppi.costs.make_value_network`)
    :param concave_value: a value concave in its inputs (:class:`~sb3_mpail.mppi.costs.ConcaveValue`): it peaks on one
        region it learns and falls away from it in every direction, never rising far from the data
    :param value_ensemble_size: ``K`` value networks instead of one, each regressed on the returns, the value their
        mean less ``value_disagreement`` times their standard deviation (:class:`~sb3_mpail.mppi.ensemble.ValueEnsemble`):
        states far from the visited ones, where the members extrapolate differently, are worth less. ``1``: one
        network (the paper's)
    :param value_disagreement: weight of the value ensemble's standard deviation, ``>= 0``
    :param use_spectral_norm: spectral normalisation on the discriminator's layers
    :param discriminator_ensemble_size: ``K`` discriminators instead of one, the reward and step cost their mean logit
        less ``discriminator_disagreement`` times their standard deviation
        (:class:`~sb3_mpail.mppi.ensemble.DiscriminatorEnsemble`): transitions far from the data, where the members
        extrapolate differently, look less expert-like. ``1``: one discriminator (the paper's)
    :param discriminator_disagreement: weight of the ensemble's standard deviation, ``>= 0``
    :param discriminator_features: what the discriminator sees of a state: a fixed map ``features(states) ->
        (batch, n_features)`` on ``(batch, state_dim)`` tensors (an ``nn.Module``, a picklable function, a list of
        the state indices kept, ``{"angles": [indices]}`` for :class:`~sb3_mpail.mppi.costs.AngleFeatures`,
        ``{"goal_frame": {...}}`` for :class:`~sb3_mpail.mppi.costs.GoalFrameFeatures`, ``{"lane_frame": {...}}``
        for :class:`~sb3_mpail.mppi.costs.LaneFrameFeatures`, or ``{"chain": [map, map, ...]}`` for maps applied in
        turn, :class:`~sb3_mpail.mppi.costs.FeatureChain`),
        applied to ``s`` and ``s'`` before the discriminator, which is built on ``n_features`` inputs. The planner and
        the dynamics still use the full state. ``None``: the full observation. Its parameters, if any, are saved
        but not trained. Functions are saved with cloudpickle (module-level functions by reference, so their
        module must be importable when loading; lambdas and closures by value)
    :param value_features: what the value sees of a state, the same kinds of map as ``discriminator_features``
        (e.g. :class:`~sb3_mpail.mppi.costs.AngleFeatures` for headings as cosine and sine); ``None``: the full state
    :param sampler: how action sequences are sampled around the plan: ``"gaussian"`` (the paper's, std
        ``noise_std``), ``"delta"`` (the authors' code: smooth random walks,
        :class:`~sb3_mpail.mppi.sampling.DeltaSampler`, ``noise_std`` its increments' std) or a module
        ``sampler(plan, n_samples, generator)`` returning time-major action sequences clamped to the bounds
    :param sampler_kwargs: keyword arguments of a named sampler (e.g. ``max_delta`` of ``"delta"``)
    :param step_cost: replaces the discriminator cost in the planner: ``c(states, next_states)`` over any leading shape,
        real numbers (cast to the states' dtype; booleans are refused)
    :param terminal_value: replaces the learned value in the planner: ``V(states)`` over any leading shape, real numbers
        (cast like ``step_cost``'s)
    :param constraint_cost: a known cost ``g(states)`` over any leading shape (one number per state), added to the
        learned costs of every state a roll-out reaches: what a designer knows that the dynamics model does not, such
        as walls and obstacles (e.g. :class:`~sb3_mpail.mppi.constraints.RectangleObstacles`), or the name of a ready
        one (``"parking_walls"``, :data:`~sb3_mpail.mppi.constraints.CONSTRAINT_COSTS`); never learned, saved with the
        model like ``step_cost``. Flags (booleans) count as 0 and 1. An infinite cost drops the samples that pay it,
        but where every sample of an env pays one there is no plan: :meth:`predict` refuses it, naming the env
    :param compile_planner: compile the planner's roll-out/cost/weight update with ``torch.compile``: ``False``
        (default), ``True`` or a ``torch.compile`` mode (``"reduce-overhead"`` uses CUDA graphs on a GPU); same plans
    :param policy_prior: learned-model MPAIL's policy prior (:class:`~sb3_mpail.prior.PolicyPrior`, trained off-policy
        by :class:`~sb3_mpail.MPAIL` on the learned reward): its actor proposes ``n_proposals`` of the sequences and
        its Q ensemble is the terminal value (unless ``terminal_value`` is given), so the value network's settings
        (``value_ensemble_size``, ``value_layer_norm``, ``concave_value``) are refused with it; ``False``: the paper's planner
    :param prior_kwargs: keyword arguments of the :class:`~sb3_mpail.prior.PolicyPrior` (``net_arch``, ``n_critics``,
        ``learning_rate``, ``gamma``, ``tau``, ``value_tau``, ``critic_layer_norm``, ``target_critics``)
    :param n_proposals: sequences per env the prior adds to each iteration's ``n_samples``
    :param standardise_inputs: the discriminator's and the value's inputs (after ``discriminator_features`` and
        ``value_features``) standardised with the demos' statistics (:class:`~sb3_mpail.mppi.costs.StandardisedFeatures`,
        fitted by :class:`~sb3_mpail.MPAIL` from the first demos it is given and saved with the model); the policy
        prior's networks see the raw observations
    :param min_input_scale: the floor of each standardised input's scale (``1``: inputs that vary less than one unit
        in the demos are only centred)
    :param reward_form: the learned reward as a function of the discriminator's logit ``d``
        (:data:`~sb3_mpail.mppi.reward_forms.REWARD_FORMS`), for the planner's step costs, the value's returns and the
        prior's Q targets alike: ``"logit"``, ``d`` itself (AIRL's form, the paper's); ``"softplus"``, ``-log(1 - D)``
        (GAIL's form), positive everywhere, so that on tasks whose episodes end at a fall staying up always pays; or
        ``"capped"``, ``log 2D``, the logit's slope where transitions look like the agent's and flat at ``log 2``
        where they look like the expert's, so nothing pays for out-doing the demos
    :param reward_offset: a constant added to the learned reward wherever it is used: a bonus per step alive where
        falls end episodes, keeping the logit's ranking of transitions (the planner's choices within its horizon do
        not change; the value's and the prior's, which see episodes end, do)
    :raises ValueError: a setting is out of its range (each is named)
    :raises TypeError: ``step_cost``, ``terminal_value``, ``constraint_cost`` or ``dynamics`` cannot be called with the
        arguments the planner gives it
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        dynamics: DynamicsSpec | None = None,
        dynamics_kwargs: Dict[str, Any] | None = None,
        n_samples: int = 512,
        horizon: int = 10,
        n_iterations: int = 5,
        noise_std: Union[float, Sequence[float]] = 0.3,
        markup: float = 1.01,
        use_step_cost: bool = True,
        use_terminal_value: bool = True,
        discriminator_hidden_sizes: Sequence[int] = (32, 32),
        value_hidden_sizes: Sequence[int] = (32, 32),
        value_layer_norm: bool = False,
        concave_value: bool = False,
        value_ensemble_size: int = 1,
        value_disagreement: float = 1.0,
        use_spectral_norm: bool = True,
        discriminator_ensemble_size: int = 1,
        discriminator_disagreement: float = 1.0,
        discriminator_features: FeatureSpec | None = None,
        value_features: FeatureSpec | None = None,
        sampler: Union[str, nn.Module] = "gaussian",
        sampler_kwargs: Dict[str, Any] | None = None,
        step_cost: nn.Module | None = None,
        terminal_value: nn.Module | None = None,
        constraint_cost: str | Callable[[th.Tensor], th.Tensor] | None = None,
        compile_planner: Union[bool, str] = False,
        policy_prior: bool = False,
        prior_kwargs: Dict[str, Any] | None = None,
        n_proposals: int = 24,
        standardise_inputs: bool = False,
        min_input_scale: float = 1.0,
        reward_form: str = "logit",
        reward_offset: float = 0.0,
    ):
        super().__init__(observation_space, action_space)
        if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 1:
            raise ValueError(f"MPPI policies plan on flat Box observations; got {observation_space}.")
        if not isinstance(action_space, spaces.Box) or len(action_space.shape) != 1:
            raise ValueError(f"MPPI policies plan continuous actions (a flat gymnasium.spaces.Box); got {action_space}.")
        if not (np.isfinite(action_space.low).all() and np.isfinite(action_space.high).all()):
            raise ValueError(
                "MPPI samples actions relative to the action space's range, so its bounds must be finite; got "
                f"low={action_space.low}, high={action_space.high}. Give the env's action space the limits its actuators "
                "have (e.g. through a gymnasium.ActionWrapper)."
            )
        check_arguments(
            use_step_cost=(use_step_cost, BOOLEAN),
            use_terminal_value=(use_terminal_value, BOOLEAN),
            use_spectral_norm=(use_spectral_norm, BOOLEAN),
            discriminator_ensemble_size=(discriminator_ensemble_size, POSITIVE_INTEGER),
            discriminator_disagreement=(discriminator_disagreement, NON_NEGATIVE_NUMBER),
            dynamics_kwargs=(dynamics_kwargs, OPTIONAL_DICT),
            noise_std=(noise_std, per_action_dimension(NON_NEGATIVE_NUMBER, action_space.shape[0])),
            discriminator_hidden_sizes=(discriminator_hidden_sizes, HIDDEN_SIZES),
            value_hidden_sizes=(value_hidden_sizes, HIDDEN_SIZES),
            value_layer_norm=(value_layer_norm, BOOLEAN),
            concave_value=(concave_value, BOOLEAN),
            value_ensemble_size=(value_ensemble_size, POSITIVE_INTEGER),
            value_disagreement=(value_disagreement, NON_NEGATIVE_NUMBER),
            sampler_kwargs=(sampler_kwargs, OPTIONAL_DICT),
            policy_prior=(policy_prior, BOOLEAN),
            prior_kwargs=(prior_kwargs, OPTIONAL_DICT),
            n_proposals=(n_proposals, NON_NEGATIVE_INTEGER),
            standardise_inputs=(standardise_inputs, BOOLEAN),
            min_input_scale=(min_input_scale, POSITIVE_NUMBER),
            reward_form=(reward_form, one_of(tuple(REWARD_FORMS))),
            reward_offset=(reward_offset, FINITE_NUMBER),
        )
        value_settings = dict(value_ensemble_size=value_ensemble_size != 1, value_layer_norm=value_layer_norm,
                              concave_value=concave_value)  # fmt: skip
        if policy_prior and any(value_settings.values()):
            raise ValueError(
                "With policy_prior=True the prior's Q ensemble is the terminal value and the value network is neither "
                f"trained nor planned with, so {', '.join(name for name, set_ in value_settings.items() if set_)} would "
                "change nothing: leave each at its default, or set policy_prior=False."
            )
        if step_cost is not None:
            check_signature(step_cost, "step_cost", "c(states, next_states) -> costs", 2)
        if terminal_value is not None:
            check_signature(terminal_value, "terminal_value", "V(states) -> values", 1)
        self._constructor_kwargs = dict(
            dynamics=dynamics,
            dynamics_kwargs=dynamics_kwargs,
            n_samples=n_samples,
            horizon=horizon,
            n_iterations=n_iterations,
            noise_std=noise_std,
            markup=markup,
            use_step_cost=use_step_cost,
            use_terminal_value=use_terminal_value,
            discriminator_hidden_sizes=discriminator_hidden_sizes,
            value_hidden_sizes=value_hidden_sizes,
            value_layer_norm=value_layer_norm,
            concave_value=concave_value,
            value_ensemble_size=value_ensemble_size,
            value_disagreement=value_disagreement,
            use_spectral_norm=use_spectral_norm,
            discriminator_ensemble_size=discriminator_ensemble_size,
            discriminator_disagreement=discriminator_disagreement,
            discriminator_features=discriminator_features,
            value_features=value_features,
            sampler=sampler,
            sampler_kwargs=sampler_kwargs,
            step_cost=step_cost,
            terminal_value=terminal_value,
            constraint_cost=constraint_cost,
            compile_planner=compile_planner,
            policy_prior=policy_prior,
            prior_kwargs=prior_kwargs,
            n_proposals=n_proposals,
            standardise_inputs=standardise_inputs,
            min_input_scale=min_input_scale,
            reward_form=reward_form,
            reward_offset=reward_offset,
        )
        self.reward_form, self.reward_offset = reward_form, float(reward_offset)
        self.discriminator_features: nn.Module | None = None
        self.feature_space = self.demo_feature_space = observation_space
        if discriminator_features is not None:
            self.discriminator_features = FeatureMap.wrap(discriminator_features, "discriminator_features")
            self.feature_space = FeatureMap.space(self.discriminator_features, observation_space, "discriminator_features")
            # demos that hold features hold a chain's first map's: the later maps are applied to them
            self.demo_feature_space = self.feature_space
            if isinstance(self.discriminator_features, FeatureChain):
                self.demo_feature_space = FeatureMap.space(self.discriminator_features[0], observation_space)
        if standardise_inputs:
            n_features = self.feature_space.shape[0]
            self.discriminator_features = StandardisedFeatures(self.discriminator_features, n_features, min_input_scale)
        discriminators = [
            make_transition_discriminator(self.feature_space, action_space, discriminator_hidden_sizes, use_spectral_norm)
            for _ in range(discriminator_ensemble_size)
        ]
        self.discriminator = discriminators[0]
        if discriminator_ensemble_size > 1:
            self.discriminator = DiscriminatorEnsemble(discriminators, discriminator_disagreement)

        def make_value(n_inputs: int) -> nn.Module:
            networks = [
                make_value_network(n_inputs, value_hidden_sizes, value_layer_norm, concave_value)
                for _ in range(value_ensemble_size)
            ]
            return networks[0] if value_ensemble_size == 1 else ValueEnsemble(networks, value_disagreement)

        self.value_ensemble_size = value_ensemble_size
        self.value_net = make_value(observation_space.shape[0])
        value_map, value_inputs = None, observation_space.shape[0]
        if value_features is not None:
            value_map = FeatureMap.wrap(value_features, "value_features").requires_grad_(False)  # fixed: not optimised
            value_inputs = FeatureMap.space(value_map, observation_space, "value_features").shape[0]
        if standardise_inputs:
            value_map = StandardisedFeatures(value_map, value_inputs, min_input_scale)
        if value_map is not None:
            self.value_net = MappedNetwork(value_map, make_value(value_inputs))
        self.dynamics = make_dynamics(dynamics, observation_space, action_space, dynamics_kwargs)
        self.prior = PolicyPrior(observation_space, action_space, **(prior_kwargs or {})) if policy_prior else None
        if terminal_value is None:
            terminal_value = TerminalValue(self.value_net) if self.prior is None else PriorValue(self.prior)
        low, high = action_space.low.astype(np.float32), action_space.high.astype(np.float32)
        self.planner = MPPIPlanner(
            dynamics=self.dynamics,
            sampler=make_sampler(sampler, low, high, noise_std, sampler_kwargs),
            step_cost=step_cost
            if step_cost is not None
            else TransitionCost(self.discriminator, self.discriminator_features, reward_form, self.reward_offset),
            terminal_value=terminal_value,
            # the paper's zero mean, kept inside the bounds for spaces that exclude 0
            neutral_action=th.as_tensor(np.clip(np.zeros_like(low), low, high)),
            n_samples=n_samples,
            horizon=horizon,
            n_iterations=n_iterations,
            markup=markup,
            use_step_cost=use_step_cost,
            use_terminal_value=use_terminal_value,
            compile_planner=compile_planner,
            prior=self.prior,
            n_proposals=n_proposals,
            constraint_cost=make_constraint_cost(constraint_cost, observation_space.shape[0]),
        )
        self.register_buffer("temperature", th.tensor(1.0))
        self.register_buffer("action_low", th.as_tensor(low))
        self.register_buffer("action_high", th.as_tensor(high))
        self._seed: int | None = None
        self._generator: th.Generator | None = None

    def _get_constructor_parameters(self) -> Dict[str, Any]:
        return {**super()._get_constructor_parameters(), **self._constructor_kwargs}

    def fit_input_statistics(self, states: th.Tensor) -> None:
        """
        Fits the standardised inputs (``standardise_inputs``) not fitted yet to ``(batch, state_dim)`` states, the
        demos': once fitted (or loaded), a network's input scaling stays what it was trained with.
        """
        for module in self.modules():
            if isinstance(module, StandardisedFeatures) and not module.fitted:
                module.fit(states)

    def learned_reward(self, observations: th.Tensor, next_observations: th.Tensor) -> th.Tensor:
        """The learned reward of ``(batch, obs_dim)`` transitions, ``(batch,)``: the policy's ``reward_form`` plus its
        ``reward_offset``."""
        features = self.discriminator_features
        return learned_reward(
            self.discriminator, features, observations, next_observations, self.reward_form, self.reward_offset
        )

    def features(self, states: th.Tensor) -> th.Tensor:
        """What the discriminator sees of ``(batch, state_dim)`` states: ``discriminator_features`` or the states."""
        return states if self.discriminator_features is None else self.discriminator_features(states)

    def features_of_demo_features(self, demo_features: th.Tensor) -> th.Tensor:
        """
        What the discriminator sees of demos that hold features (``demos_are_features``, in ``demo_feature_space``):
        themselves, or, for a :class:`~sb3_mpail.mppi.costs.FeatureChain`, the chain's later maps of them.
        """
        if isinstance(self.discriminator_features, FeatureChain):
            return self.discriminator_features[1:](demo_features)
        return demo_features

    def seed(self, seed: int | None) -> None:
        """
        Re-seeds the planner's noise (the same seed gives the same plans and actions) and, for a learned dynamics
        model, its replay buffer and minibatch order (the same seed gives the same fitted model).
        """
        self._seed = seed
        self._generator = None
        if isinstance(self.dynamics, LearnedDynamics):
            self.dynamics.seed(seed)

    def generator(self, deterministic: bool = False, seed: int | None = None) -> th.Generator:
        """
        The planner's noise source, on the policy's device (re-created, re-seeded, if the policy moved). Deterministic
        planning (evaluation, deployment) gets a new generator at every call, seeded with ``seed``
        (:func:`deterministic_planning_seed` of ``predict``'s inputs): the same observation, plan and model give the
        same action, from any thread and after any history, and evaluating during training leaves the training
        samples, and with them the learning curve, unchanged.

        :param deterministic: the noise of deterministic planning rather than the training stream
        :param seed: deterministic planning's seed; ``None``: :data:`DETERMINISTIC_PLANNING_SEED`
        """
        if deterministic:
            return th.Generator(device=self.device).manual_seed(DETERMINISTIC_PLANNING_SEED if seed is None else seed)
        generator = self._generator
        if generator is None or generator.device != self.device:
            generator = self._generator = th.Generator(device=self.device)
            if self._seed is None:
                generator.seed()
            else:
                generator.manual_seed(self._seed)
        return generator

    def initial_plan(self, n_envs: int) -> th.Tensor:
        """The plan of an env at the start of an episode, ``(n_envs, horizon, action_dim)``."""
        return self.planner.initial_plan(n_envs)

    def act(
        self, observations: th.Tensor, previous_plan: th.Tensor, deterministic: bool = False, seed: int | None = None
    ) -> Tuple[th.Tensor, th.Tensor]:
        """
        Plans from each env's state and picks the action to execute (paper Alg. 3): the plan's first action when
        deterministic, else a sample from ``N(first action, weighted std)``; the plan and the action are clamped to the
        bounds, whatever the sampler.

        :param observations: ``(n_envs, state_dim)``
        :param previous_plan: ``(n_envs, horizon, action_dim)``
        :param deterministic: execute the plan's first action, planning with deterministic planning's noise
        :param seed: that noise's seed (:meth:`generator`); give one that changes from step to step
        :return: actions ``(n_envs, action_dim)`` and the new plan
        """
        actions, plan, _ = self.plan_actions(observations, previous_plan, deterministic, seed)
        return actions, plan

    def plan_actions(
        self, observations: th.Tensor, previous_plan: th.Tensor, deterministic: bool = False, seed: int | None = None
    ) -> Tuple[th.Tensor, th.Tensor, th.Tensor]:
        """
        :meth:`act`, also returning the trajectory costs of the planner's last iteration ``(n_envs, n_samples)`` (what
        a learned temperature is fitted to).

        :return: actions ``(n_envs, action_dim)``, the new plan and those costs
        """
        generator = self.generator(deterministic, seed)
        last = self.planner.optimise(observations.float(), previous_plan, self.temperature, generator)
        # a user's sampler may not clamp its samples (and a weighted mean may pass a bound by a rounding error)
        plan = th.clamp(last.plan, self.action_low, self.action_high)
        actions = plan[:, 0]
        if not deterministic:
            action_std = weighted_action_std(last.weights, last.samples, last.plan)
            noise = th.randn(actions.shape, generator=generator, device=actions.device, dtype=actions.dtype)
            actions = th.clamp(actions + action_std * noise, self.action_low, self.action_high)
        return actions, plan, last.costs

    def set_training_mode(self, mode: bool) -> None:
        """
        Puts every submodule in training (``True``) or evaluation mode, as SB3's does; a no-op where each already is.
        ``predict`` calls it on every step, and setting the mode of every module costs about a sixth of a one-env
        planning step, reading it far less.

        :param mode: training mode (spectral norm's power iteration moves on every call then) or evaluation mode
        """
        if any(module.training != mode for module in self.modules()):
            super().set_training_mode(mode)

    def forward(self, obs: th.Tensor, deterministic: bool = False) -> th.Tensor:
        return self._predict(obs, deterministic)

    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        """Stateless planning from a fresh plan; :meth:`predict` carries the warm start."""
        return self.act(observation, self.initial_plan(observation.shape[0]), deterministic)[0]

    def predict(
        self,
        observation: np.ndarray,
        state: np.ndarray | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> Tuple[np.ndarray, np.ndarray]:
        """
        Plans an action per observation.

        :param observation: one observation or a batch of them
        :param state: the plans returned by the previous call, ``(n_envs, horizon, action_dim)``, or ``None`` at start
        :param episode_start: per env, whether its episode just started (its plan is reset)
        :param deterministic: execute the plan's first action instead of sampling around it
        :return: the actions and the plans to pass back as ``state`` on the next call
        :raises ValueError: an observation, ``state`` or ``episode_start`` holds NaN or infinite values, an observation
            holds complex numbers or values beyond ``LARGE_OBSERVATION``, or the planner made a non-finite plan (the error
            names the env, and the cause where it finds one); ``state`` is not plans of this model's shape;
            ``episode_start`` is not one flag per env
        """
        self.set_training_mode(False)
        is_complex = observation.is_complex() if isinstance(observation, th.Tensor) else np.iscomplexobj(observation)
        if is_complex:
            dtype = str(getattr(observation, "dtype", np.asarray(observation).dtype)).replace("torch.", "")
            raise ValueError(
                f"The observation passed to predict holds complex numbers ({dtype}): "
                "planning on their real parts would drop the imaginary parts. Pass real observations (e.g. the real and "
                "imaginary parts as separate dimensions, as the environment gives them)."
            )
        observations, vectorized = self.obs_to_tensor(observation)
        n_envs = observations.shape[0]
        fresh = self.initial_plan(n_envs)
        if n_envs == 0:  # an empty batch: no actions, no plans (a state and episode_start given are checked all the same)
            if state is not None:
                self._previous_plan(state, fresh)
            if episode_start is not None:
                self._episode_starts(episode_start, n_envs, vectorized)
            return np.zeros((0, *self.action_space.shape), np.float32), fresh.cpu().numpy()
        raw = np.asarray(observation).reshape(n_envs, -1)
        check_finite(raw, "The observation passed to predict", NON_FINITE_OBSERVATION)
        huge = np.flatnonzero((np.abs(raw) > LARGE_OBSERVATION).any(axis=1))
        if len(huge) > 0:
            raise ValueError(
                f"The observation passed to predict holds values beyond +-{LARGE_OBSERVATION:g} for envs {huge.tolist()} "
                f"(env {huge[0]}: {raw[huge[0]]}): the planner computes in float32, where products of such values "
                "overflow. Check the environment's units, or scale its observations."
            )
        with th.no_grad():
            previous_plan = fresh if state is None else self._previous_plan(state, fresh)
            if episode_start is not None:
                previous_plan = th.where(self._episode_starts(episode_start, n_envs, vectorized), fresh, previous_plan)
            seed = None
            if deterministic:
                seed = deterministic_planning_seed(raw, self._plan_key(state, episode_start, tuple(fresh.shape)))
            actions, plan = self.act(observations, previous_plan, deterministic, seed)
        actions, plan = actions.cpu().numpy(), plan.cpu().numpy()
        self.check_plan(plan, "The plan made from a finite observation and state", observations, previous_plan)
        if not vectorized:
            actions = actions.squeeze(axis=0)
        return actions, plan

    def check_plan(self, plan: np.ndarray, what: str, observations: th.Tensor, previous_plan: th.Tensor) -> None:
        """
        Refuses a non-finite plan (or action) the planner made from finite ``observations`` and ``previous_plan``,
        naming the envs and the cause where it finds one (:meth:`~sb3_mpail.mppi.planner.MPPIPlanner.non_finite_cause`,
        run only for a non-finite plan).

        :param plan: the plans or actions made, one row per env (on the host)
        :param what: what they are, as the message names them
        :param observations: the states planned from, ``(n_envs, state_dim)``
        :param previous_plan: the plans planned from, ``(n_envs, horizon, action_dim)``
        :raises ValueError: ``plan`` holds NaN or infinite values
        """
        if not np.isfinite(plan).all():
            cause = self.planner.non_finite_cause(observations.float(), previous_plan)
            check_finite(plan, what, cause or NON_FINITE_PLAN)

    @staticmethod
    def _plan_key(state: np.ndarray | None, episode_start: np.ndarray | None, shape: Tuple[int, ...]) -> np.ndarray:
        """
        The plans ``predict`` starts from, on the host, for deterministic planning's seed: ``state`` with NaN (never a
        plan's value: plans are checked finite) for every env that starts afresh, so a restarted plan keys the same as
        none given. ``state`` and ``episode_start`` were checked already.
        """
        key = np.full(shape, np.nan, np.float32) if state is None else np.array(state, np.float32)
        if episode_start is not None:
            key[np.asarray(episode_start).astype(bool).reshape(shape[0])] = np.nan
        return key

    def _previous_plan(self, state: np.ndarray, fresh: th.Tensor) -> th.Tensor:
        """``predict``'s ``state``, checked to be plans of the right shape and finite, as a tensor."""
        state = np.asarray(state)
        if state.shape != tuple(fresh.shape) or not np.issubdtype(state.dtype, np.number):
            raise ValueError(
                f"state must be the plans returned by predict, numbers of shape {tuple(fresh.shape)}; got "
                f"{state.dtype} of shape {state.shape}."
            )
        check_finite(state, "The state passed to predict", "pass back the plans predict returned, or None to start afresh.")
        return th.as_tensor(state, dtype=th.float32, device=self.device)

    def _episode_starts(self, episode_start: np.ndarray, n_envs: int, vectorized: bool) -> th.Tensor:
        """``predict``'s ``episode_start``: one flag per env (a single flag for a single observation)."""
        starts = np.asarray(episode_start)
        numeric = starts.dtype == bool or np.issubdtype(starts.dtype, np.number)
        if not numeric or starts.size != n_envs or (vectorized and starts.ndim != 1):
            raise ValueError(
                f"episode_start must hold one flag per env ({n_envs}, shape ({n_envs},)); got {starts.dtype} of shape "
                f"{starts.shape}: {starts!r}."
            )
        check_finite(starts.reshape(n_envs, 1), "The episode_start passed to predict", "pass True or False per env.")
        return th.as_tensor(starts.astype(bool).reshape(n_envs, 1, 1), device=self.device)

MlpMPPI = MPPIPolicy
