"""Model Predictive Adversarial Imitation Learning (Han et al., ICLR 2026) as a Stable-Baselines3 algorithm."""

import inspect
import io
import math
import pathlib
import sys
import time
from collections.abc import Mapping
from typing import Any, ClassVar, Dict, Iterable, List, Tuple, Type, TypeVar, Union

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from imitation.data.buffer import Buffer
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.utils import explained_variance, safe_mean
from stable_baselines3.common.vec_env import VecEnv
from torch.nn import functional as F

from sb3_mpail.averaging import PolicyAverage
from sb3_mpail.buffers import TransitionRolloutBuffer
from sb3_mpail.checks import (
    BETAS,
    BOOLEAN,
    FRACTION,
    NON_NEGATIVE_INTEGER,
    NON_NEGATIVE_NUMBER,
    OPTIONAL_DECAY_FACTOR,
    OPTIONAL_DICT,
    OPTIONAL_FINITE_NUMBER,
    OPTIONAL_POSITIVE_INTEGER,
    POSITIVE_INTEGER,
    POSITIVE_NUMBER,
    SEED,
    TIMESTEPS,
    UNIT_INTERVAL,
    Rule,
    check_arguments,
    check_finite,
    one_of,
    refuse_normalised_observations,
)
from sb3_mpail.demos import DemoSource, ExpertTransitions, load_demos
from sb3_mpail.model_files import check_model_file, raise_for_unpicklable_settings, save_atomically
from sb3_mpail.mppi.costs import member_values
from sb3_mpail.mppi.dynamics import DEFAULT_DYNAMICS, ENV_DYNAMICS_KWARGS, LearnedDynamics, how_to_give_dynamics
from sb3_mpail.mppi.ensemble import member_logits
from sb3_mpail.policies import NON_FINITE_OBSERVATION, MlpMPPI, MPPIPolicy
from sb3_mpail.prior import PRIOR_TERMINATIONS, PriorReplay

SelfMPAIL = TypeVar("SelfMPAIL", bound="MPAIL")
#: constructor settings that Stable-Baselines3's ``load`` must set under another attribute name
_SETTING_ATTRIBUTES = {"temperature": "temperature_mode", "stats_window_size": "_stats_window_size"}

#: how the MPPI temperature can move (:class:`MPAIL`'s ``temperature``)
TEMPERATURES = ("decay", "learned")

#: what ``learn``'s ``callback`` may be, as Stable-Baselines3 takes it
CALLBACK = Rule(
    "None, a BaseCallback, a list of BaseCallbacks or a function f(locals, globals) -> bool",
    lambda value: (
        value is None
        or isinstance(value, BaseCallback)
        or (isinstance(value, list) and all(isinstance(item, BaseCallback) for item in value))
        or callable(value)
    ),
)


class MPAIL(BaseAlgorithm):
    """
    Model Predictive Adversarial Imitation Learning: an MPPI planner learns its cost from observation-only demos.

    Each iteration (paper Alg. 1): run the planner in the envs for ``n_steps`` per env; label every transition with
    the learned reward ``r = d_theta(s, s')``; update the discriminator (BCE, expert vs agent) every
    ``discriminator_update_interval`` iterations; update the value ``V_phi`` on GAE returns of the learned reward;
    fit the dynamics model if it is learned online. There is no policy update: the policy is the planner.

    Defaults follow the paper's hyperparameter table; the planner's own settings (``N``, ``H``, ``J``, ``Sigma``,
    markup, dynamics) are ``policy_kwargs`` of :class:`~sb3_mpail.policies.MPPIPolicy`.

    :param policy: ``"MlpMPPI"`` or an :class:`~sb3_mpail.policies.MPPIPolicy` subclass
    :param env: env id, ``gym.Env`` or ``VecEnv`` (``None`` only when loading)
    :param demos: observation-only expert demos (see :func:`~sb3_mpail.demos.load_demos`); needed to train, not to plan
    :param demos_are_features: the demos hold what the discriminator sees (the policy's ``discriminator_features``,
        e.g. a partially observed demo; for a chain of maps, what its first map gives, the later maps applied to
        them), not full observations. ``False``: demos are observations and pass through the same feature map as the
        agent's states
    :param n_steps: env steps per env per iteration
    :param gamma: discount of the learned reward in the value targets
    :param gae_lambda: GAE lambda of the value targets
    :param n_epochs: epochs per discriminator and value update
    :param n_minibatches: minibatches per epoch
    :param discriminator_learning_rate: Adam learning rate of the discriminator
    :param discriminator_betas: Adam betas of the discriminator
    :param discriminator_l2: weight decay of the discriminator (paper: 0 in simulation, 1e-3 on real data)
    :param discriminator_update_interval: iterations between discriminator updates (paper's 3:1 value:disc ratio)
    :param discriminator_replay_size: agent transitions of earlier rollouts kept for the discriminator (imitation's FIFO
        ``Buffer``); each discriminator minibatch adds as many of them as it has of the current rollout, so behaviour
        the agent has left behind stays agent-like. ``0``: the current rollout only (the paper's)
    :param discriminator_gradient_penalty: weight of a gradient penalty on the discriminator, ``(||grad d|| - 1)^2`` at
        random points between expert and agent transitions (WGAN-GP's, as MPAIL2's critic), beside or instead of
        spectral norm (``use_spectral_norm``); ``0``: none, the paper's
    :param value_learning_rate: Adam learning rate of the value
    :param value_betas: Adam betas of the value
    :param value_clip: clip range of the value loss around the values at collection time
    :param max_grad_norm: gradient-norm clip of the value update
    :param temperature: how the MPPI temperature moves: ``"decay"`` (the paper's schedule, ``temperature_decay``) or
        ``"learned"`` (the authors' code: ``log lambda`` stepped by RMSprop, ``temperature_learning_rate``, after every
        env step of a rollout, to lower the entropy of the planner's last MPPI weights; floored at
        ``min_temperature``)
    :param initial_temperature: MPPI temperature ``lambda_0``
    :param temperature_decay: per-episode multiplicative decay: ``lambda = lambda_0 (1 - decay)^episodes``, counting
        episodes per env so the schedule does not depend on ``n_envs``
    :param min_temperature: temperature floor, at most ``initial_temperature``
    :param temperature_learning_rate: RMSprop learning rate of the learned temperature's logarithm
    :param prior_buffer_size: transitions the policy prior's replay keeps (with ``policy_kwargs=dict(policy_prior=True)``)
    :param prior_batch_size: minibatch size of the prior's SAC updates
    :param prior_updates_per_step: SAC updates of the prior per env step (summed over envs), run after each rollout
    :param prior_terminations: what the prior's Q targets do at a termination (e.g. a fall): ``"cut"`` stops them, as
        SAC's do; ``"bootstrap"`` goes on through it (MPAIL2's default), which let the Ant fall in most episodes here;
        ``"absorbing"`` lets the terminal transition's learned reward repeat forever (an absorbing state, as DAC's),
        so ending an episode is worth what the discriminator thinks of how it ends, whatever the reward's offset
    :param prior_return_steps: each of the prior's Q targets sums the learned rewards of up to this many stored steps
        of an episode before it bootstraps (n-step returns; see :class:`~sb3_mpail.prior.PriorReplay`); 1: SAC's
        one-step targets. On Hopper 3 steps scored 1.09, -0.01 and 0.26 on three seeds, below the entry
    :param agent_reward_mean: where set, the learned reward that trains the value (or the policy prior's Q) is shifted
        after every rollout so that its mean over that rollout's transitions is this (the shift is logged as
        ``train/reward_shift`` and saved with the model). A constant added to every transition leaves the planner's
        choices within its horizon as they were, but where falls end episodes it decides whether staying up pays: as
        the discriminator learns to tell the agent's steps apart, their logit turns negative and falling looks best; a
        small positive mean keeps staying up worth a little, whatever the discriminator makes of the agent. The shift
        takes the place of the policy's constant ``reward_offset``, which must then be 0. ``None``: no shift (the
        paper's)
    :param policy_average_rate: where set, a running average of the policy's weights is kept beside it (an exponential
        moving average over training's updates, each weighing this much, from the first update's weights; see
        :class:`~sb3_mpail.averaging.PolicyAverage`) and :meth:`predict` plans with it, while the planner in training
        goes on with the live weights (``model.policy``). It is saved with the model. ``None``: ``predict`` plans with
        the live weights. On Hopper 0.2 and 0.5 scored level with the live weights over 10 and 7 seeds, and slower averages
        (0.02, 0.05) lower (docs/learned-models.md)
    :param stats_window_size: episodes averaged in the logged episode return
    :param tensorboard_log: tensorboard log folder
    :param policy_kwargs: keyword arguments of the policy (planner settings, ``dynamics``)
    :param verbose: 0 silent, 1 training info
    :param seed: seed of networks, environments and planner noise
    :param device: ``"cpu"``, ``"cuda"`` or ``"auto"``
    :param _init_setup_model: build the networks at construction (``False`` when loading)
    :raises ValueError: a setting is out of its range (each is named), or the env's observations are normalised
    """

    policy_aliases: ClassVar[Dict[str, Type[BasePolicy]]] = {"MlpMPPI": MlpMPPI}
    policy: MPPIPolicy
    rollout_buffer: TransitionRolloutBuffer

    def __init__(
        self,
        policy: Union[str, Type[MPPIPolicy]],
        env: Union[GymEnv, str] | None,
        demos: DemoSource | None = None,
        demos_are_features: bool = False,
        n_steps: int = 200,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        n_epochs: int = 3,
        n_minibatches: int = 3,
        discriminator_learning_rate: float = 1e-4,
        discriminator_betas: Tuple[float, float] = (0.5, 0.999),
        discriminator_l2: float = 0.0,
        discriminator_update_interval: int = 3,
        discriminator_replay_size: int = 0,
        discriminator_gradient_penalty: float = 0.0,
        value_learning_rate: float = 1e-3,
        value_betas: Tuple[float, float] = (0.9, 0.999),
        value_clip: float = 0.2,
        max_grad_norm: float = 1.0,
        temperature: str = "decay",
        initial_temperature: float = 1.0,
        temperature_decay: float = 0.01,
        min_temperature: float = 1e-5,
        temperature_learning_rate: float = 1e-4,
        prior_buffer_size: int = 1_000_000,
        prior_batch_size: int = 256,
        prior_updates_per_step: float = 1.0,
        prior_terminations: str = "cut",
        prior_return_steps: int = 1,
        agent_reward_mean: float | None = None,
        policy_average_rate: float | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: Dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: Union[th.device, str] = "auto",
        _init_setup_model: bool = True,
    ):
        super().__init__(
            policy=policy,
            env=env,
            learning_rate=value_learning_rate,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            support_multi_env=True,
            seed=seed,
        )
        self.demos_are_features = demos_are_features
        self.n_steps = n_steps
        self.gamma = gamma
        self.gae_lambda = gae_lambda
        self.n_epochs = n_epochs
        self.n_minibatches = n_minibatches
        self.discriminator_learning_rate = discriminator_learning_rate
        self.discriminator_betas = discriminator_betas
        self.discriminator_l2 = discriminator_l2
        self.discriminator_update_interval = discriminator_update_interval
        self.discriminator_replay_size = discriminator_replay_size
        self.discriminator_replay: Buffer | None = None
        self.discriminator_gradient_penalty = discriminator_gradient_penalty
        self.value_learning_rate = value_learning_rate
        self.value_betas = value_betas
        self.value_clip = value_clip
        self.max_grad_norm = max_grad_norm
        self.temperature_mode = temperature
        self.initial_temperature = initial_temperature
        self.temperature_decay = temperature_decay
        self.min_temperature = min_temperature
        self.temperature_learning_rate = temperature_learning_rate
        self.prior_buffer_size = prior_buffer_size
        self.prior_batch_size = prior_batch_size
        self.prior_updates_per_step = prior_updates_per_step
        self.prior_terminations = prior_terminations
        self.prior_return_steps = prior_return_steps
        self.prior_replay: PriorReplay | None = None
        self.agent_reward_mean = agent_reward_mean
        self.reward_shift = 0.0
        self.policy_average_rate = policy_average_rate
        self.policy_average: PolicyAverage | None = None
        self.episodes_completed = 0
        self.n_iterations = 0
        self.expert: ExpertTransitions | None = None
        self._plan: th.Tensor | None = None
        self._check_settings()
        if env is not None:
            self._check_spaces()
            refuse_normalised_observations(self.env)
            if _init_setup_model:  # not when loading: the file holds the model's own dynamics
                self._default_dynamics()
        if _init_setup_model:
            self._setup_model()
        if demos is not None:
            self.set_demos(demos)

    def _check_settings(self) -> None:
        """Refuses settings that would train or plan nonsense, naming each (at construction, and after ``load``'s)."""
        check_arguments(
            demos_are_features=(self.demos_are_features, BOOLEAN),
            n_steps=(self.n_steps, POSITIVE_INTEGER),
            gamma=(self.gamma, UNIT_INTERVAL),
            gae_lambda=(self.gae_lambda, UNIT_INTERVAL),
            n_epochs=(self.n_epochs, POSITIVE_INTEGER),
            n_minibatches=(self.n_minibatches, POSITIVE_INTEGER),
            discriminator_learning_rate=(self.discriminator_learning_rate, POSITIVE_NUMBER),
            discriminator_betas=(self.discriminator_betas, BETAS),
            discriminator_l2=(self.discriminator_l2, NON_NEGATIVE_NUMBER),
            discriminator_update_interval=(self.discriminator_update_interval, POSITIVE_INTEGER),
            discriminator_replay_size=(self.discriminator_replay_size, NON_NEGATIVE_INTEGER),
            discriminator_gradient_penalty=(self.discriminator_gradient_penalty, NON_NEGATIVE_NUMBER),
            value_learning_rate=(self.value_learning_rate, POSITIVE_NUMBER),
            value_betas=(self.value_betas, BETAS),
            value_clip=(self.value_clip, POSITIVE_NUMBER),
            max_grad_norm=(self.max_grad_norm, POSITIVE_NUMBER),
            initial_temperature=(self.initial_temperature, POSITIVE_NUMBER),
            temperature_decay=(self.temperature_decay, FRACTION),
            min_temperature=(self.min_temperature, POSITIVE_NUMBER),
            temperature=(self.temperature_mode, one_of(TEMPERATURES)),
            temperature_learning_rate=(self.temperature_learning_rate, POSITIVE_NUMBER),
            prior_buffer_size=(self.prior_buffer_size, POSITIVE_INTEGER),
            prior_batch_size=(self.prior_batch_size, POSITIVE_INTEGER),
            prior_updates_per_step=(self.prior_updates_per_step, NON_NEGATIVE_NUMBER),
            prior_terminations=(self.prior_terminations, one_of(PRIOR_TERMINATIONS)),
            prior_return_steps=(self.prior_return_steps, POSITIVE_INTEGER),
            agent_reward_mean=(self.agent_reward_mean, OPTIONAL_FINITE_NUMBER),
            policy_average_rate=(self.policy_average_rate, OPTIONAL_DECAY_FACTOR),
            stats_window_size=(self._stats_window_size, POSITIVE_INTEGER),
            policy_kwargs=(self.policy_kwargs, OPTIONAL_DICT),
            verbose=(self.verbose, NON_NEGATIVE_INTEGER),
            seed=(self.seed, SEED),
        )
        if self.min_temperature > self.initial_temperature:
            raise ValueError(
                f"min_temperature ({self.min_temperature}) must not exceed initial_temperature ({self.initial_temperature}): "
                "the temperature starts at initial_temperature and never goes below min_temperature, which would leave "
                "initial_temperature unused."
            )
        reward_offset = (self.policy_kwargs or {}).get("reward_offset", 0.0)
        if self.agent_reward_mean is not None and reward_offset != 0.0:
            raise ValueError(
                f"agent_reward_mean ({self.agent_reward_mean}) sets the learned reward's mean over each rollout, whatever "
                f"constant is added to it, so policy_kwargs' reward_offset ({reward_offset}) would change nothing: set "
                "one of them."
            )

    def _check_spaces(self) -> None:
        if not isinstance(self.action_space, spaces.Box):
            raise ValueError(
                "MPAIL plans continuous actions (a gymnasium.spaces.Box); "
                f"this environment's action space is {self.action_space}."
            )
        if not isinstance(self.observation_space, spaces.Box) or len(self.observation_space.shape) != 1:
            raise ValueError(
                f"MPAIL plans on flat Box observations; this environment's observation space is {self.observation_space}."
            )

    def _default_dynamics(self) -> None:
        """
        Fills in the planning model of environments whose dynamics the package knows (e.g. ``Pendulum-v1``), with the
        settings it reads from the env (:data:`~sb3_mpail.mppi.dynamics.ENV_DYNAMICS_KWARGS`: Pendulum's ``g``) unless
        ``dynamics_kwargs`` give them. An env wrapped in a gymnasium ``ObservationWrapper`` gets none: its observations
        may no longer be the states the model reads (reordered, scaled).

        :raises ValueError: the env's model is known, but the env's observations are wrapped
        """
        if self.policy_kwargs.get("dynamics") is not None:
            return
        assert self.env is not None
        spec = self.env.get_attr("spec", indices=[0])[0]
        if spec is None or spec.id not in DEFAULT_DYNAMICS:
            return
        name = DEFAULT_DYNAMICS[spec.id]
        wrapped = [index for index, is_wrapped in enumerate(self.env.env_is_wrapped(gym.ObservationWrapper)) if is_wrapped]
        if wrapped:
            wrappers = self.env.env_method("__str__", indices=wrapped[:1])[0]
            raise ValueError(
                f"The environment {spec.id} (env {wrapped[0]}) is wrapped in a gymnasium ObservationWrapper ({wrappers}), "
                f"which may change the observations that its dynamics model {name!r} reads as states, so the model is not "
                f"chosen automatically: if the wrapper leaves them as they are, pass dynamics={name!r}; else "
                f"{how_to_give_dynamics()}"
            )
        policy_kwargs = {**self.policy_kwargs, "dynamics": name}
        from_env = {
            keyword: self.env.env_method("get_wrapper_attr", attribute, indices=[0])[0]
            for keyword, attribute in ENV_DYNAMICS_KWARGS.get(name, {}).items()
        }
        given = policy_kwargs.get("dynamics_kwargs")
        if from_env and (given is None or isinstance(given, Mapping)):  # other kinds are refused by the policy, named
            policy_kwargs["dynamics_kwargs"] = {**from_env, **(given or {})}
        self.policy_kwargs = policy_kwargs

    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        self.policy = self.policy_class(self.observation_space, self.action_space, **self.policy_kwargs)
        self.policy = self.policy.to(self.device)
        self.policy.seed(self.seed)
        rate = self.policy_average_rate
        self.policy_average = None if rate is None else PolicyAverage(self.policy, rate)
        self.log_temperature = th.nn.Parameter(th.tensor(math.log(self.initial_temperature), device=self.device))
        self.temperature_optimizer = th.optim.RMSprop([self.log_temperature], lr=self.temperature_learning_rate)
        self.policy.temperature.fill_(self.temperature())
        self.discriminator_optimizer = th.optim.Adam(
            self.policy.discriminator.parameters(),
            lr=self.discriminator_learning_rate,
            betas=self.discriminator_betas,
            weight_decay=self.discriminator_l2,
        )
        self.value_optimizer = th.optim.Adam(
            self.policy.value_net.parameters(), lr=self.value_learning_rate, betas=self.value_betas
        )

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """
        Sets a new environment (same spaces and number of envs), refusing one whose observations are normalised.

        :param env: a ``gym.Env`` or ``VecEnv``
        :param force_reset: reset it before training goes on
        """
        env = self._wrap_env(env, self.verbose)
        refuse_normalised_observations(env)
        super().set_env(env, force_reset)

    def set_random_seed(self, seed: int | None = None) -> None:
        """Seeds python, numpy, torch, the action space, the env and the planner's noise."""
        super().set_random_seed(seed)
        if getattr(self, "policy", None) is not None:
            self.policy.seed(seed)
        if getattr(self, "policy_average", None) is not None:
            self.policy_average.policy.seed(seed)

    def set_demos(self, demos: DemoSource) -> None:
        """
        Sets the expert demos (e.g. on a loaded model, to go on training); they are checked against the observation
        space (the feature space with ``demos_are_features``), stored as discriminator features and never saved with
        the model.
        """
        if self.demos_are_features:
            if self.policy_kwargs.get("standardise_inputs"):
                raise ValueError(
                    "standardise_inputs fits its statistics to demo observations, but demos_are_features=True gives "
                    "features: pass observation demos, or standardise inside your discriminator_features map."
                )
            expert = load_demos(demos, self.policy.demo_feature_space, "the discriminator's feature space")
            with th.no_grad():
                self.expert = ExpertTransitions(
                    *(self.policy.features_of_demo_features(self._tensor(array)).cpu().numpy() for array in expert)
                )
            return
        expert = load_demos(demos, self.observation_space)
        self.policy.fit_input_statistics(self._tensor(np.concatenate([expert.observations, expert.next_observations])))
        with th.no_grad():
            self.expert = ExpertTransitions(
                *(self.policy.features(self._tensor(array)).cpu().numpy() for array in expert)
            )

    def _tensor(self, array: np.ndarray) -> th.Tensor:
        """A float array as a float32 tensor on the model's device: the networks are float32 whatever the env's dtype."""
        return th.as_tensor(array, dtype=th.float32, device=self.device)

    def temperature(self) -> float:
        """The MPPI temperature now: the learned one, or the schedule's after the episodes completed so far."""
        if self.temperature_mode == "learned":
            return max(math.exp(self.log_temperature.item()), self.min_temperature)
        episodes_per_env = self.episodes_completed / max(self.n_envs, 1)
        return max(self.initial_temperature * (1 - self.temperature_decay) ** episodes_per_env, self.min_temperature)

    def _excluded_save_params(self) -> List[str]:
        return [*super()._excluded_save_params(), "expert", "_plan", "discriminator_replay", "prior_replay"]

    def _get_torch_save_params(self) -> Tuple[List[str], List[str]]:
        state_dicts = ["policy", "discriminator_optimizer", "value_optimizer"]
        if self.policy_average is not None:
            state_dicts.append("policy_average")
        if isinstance(self.policy.dynamics, LearnedDynamics):
            state_dicts.append("policy.dynamics.optimizer")
        if self.temperature_mode == "learned":
            return [*state_dicts, "temperature_optimizer"], ["log_temperature"]
        return state_dicts, []

    @classmethod
    def load(
        cls: Type[SelfMPAIL],
        path: Union[str, pathlib.Path, io.BufferedIOBase],
        env: GymEnv | None = None,
        device: Union[th.device, str] = "auto",
        custom_objects: Dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfMPAIL:
        """
        Loads a model saved by :meth:`save` (Stable-Baselines3's ``load``), after checking that the file is a whole
        MPAIL model; settings given as ``kwargs`` are checked as the constructor checks them.

        :param path: the model file (``.zip`` may be left out) or a file object
        :param env: the environment to go on with (``None`` to plan only)
        :param device: ``"cpu"``, ``"cuda"`` or ``"auto"``
        :param custom_objects: saved objects to replace rather than unpickle
        :param print_system_info: print the saving and the current system's information
        :param force_reset: reset ``env`` before training goes on
        :param kwargs: settings to change, e.g. ``n_steps``
        :raises FileNotFoundError: there is no such file
        :raises ValueError: the file is empty, truncated, damaged or not a zip archive, or it is not an MPAIL model;
            ``kwargs`` hold a setting MPAIL does not have, ``demos`` or another ``temperature`` mode than the model's
        """
        source, data = check_model_file(path)
        if "temperature" in kwargs and kwargs["temperature"] != data.get("temperature_mode"):
            raise ValueError(
                f"temperature is fixed when a model is made: this one's is {data.get('temperature_mode')!r}; got "
                f"{kwargs['temperature']!r}. A learned temperature is saved with its optimiser, a decaying one is not: "
                "train a new model to change it."
            )
        settings = cls._load_settings(kwargs)
        saved_rate = data.get("policy_average_rate")
        asked_rate = settings.get("policy_average_rate", saved_rate)
        check_arguments(policy_average_rate=(asked_rate, OPTIONAL_DECAY_FACTOR))
        # a weight average asked of a file without one starts at the next update; one the file holds is loaded, then
        # dropped where None is asked (predict plans with the live weights)
        average_changes = (saved_rate is None) != (asked_rate is None)
        if average_changes:
            settings.pop("policy_average_rate")
        model = super().load(source, env, device, custom_objects, print_system_info, force_reset, **settings)
        if average_changes:
            model.policy_average_rate = asked_rate
            model.policy_average = None if asked_rate is None else PolicyAverage(model.policy, asked_rate)
        if "prior_use_terminations" in data and "prior_terminations" not in data:  # a file saved before its rename
            model.prior_terminations = "cut" if data["prior_use_terminations"] else "bootstrap"
            del model.prior_use_terminations
        if "prior_return_steps" not in data:  # a file saved before n-step targets, which trained one-step ones
            model.prior_return_steps = 1
        model._check_settings()
        return model

    @classmethod
    def _load_settings(cls, settings: Dict[str, Any]) -> Dict[str, Any]:
        """
        ``load``'s settings as the attributes Stable-Baselines3 sets, refusing names that are no setting (which SB3
        would store as attributes nothing reads, e.g. a typo).
        """
        if "demos" in settings:
            raise ValueError(
                "MPAIL.load takes no demos (they are never saved with the model): load it, then call "
                "model.set_demos(demos) to go on training."
            )
        not_settings = {"self", "policy", "env", "demos", "device", "_init_setup_model"}
        known = set(inspect.signature(cls.__init__).parameters) - not_settings
        unknown = sorted(set(settings) - known)
        if unknown:
            raise ValueError(f"MPAIL.load got settings that MPAIL does not have: {unknown}; its settings are {sorted(known)}.")
        return {_SETTING_ATTRIBUTES.get(name, name): value for name, value in settings.items()}

    def save(
        self,
        path: Union[str, pathlib.Path, io.BufferedIOBase],
        exclude: Iterable[str] | None = None,
        include: Iterable[str] | None = None,
    ) -> None:
        """
        Saves the model (demos excluded). The file is written beside its destination as ``<name>.partial`` and then
        renamed over it, so a crash while saving never leaves a truncated checkpoint behind; a ``.partial`` left by a
        killed process is overwritten and removed by the next save. As Stable-Baselines3's ``save`` does, a symbolic
        link is followed (its target is written) and a read-only file is refused.

        :raises PermissionError: the destination is a read-only file
        :raises TypeError: a ``policy_kwargs`` setting cannot be pickled (the message names it)
        """
        if isinstance(path, io.BufferedIOBase):
            super().save(path, exclude, include)
            return
        try:
            save_atomically(path, lambda file: super(MPAIL, self).save(file, exclude, include))
        except Exception as error:
            raise_for_unpicklable_settings(self.policy_kwargs, error)
            raise

    def learn(
        self: SelfMPAIL,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "MPAIL",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfMPAIL:
        """
        Trains for ``total_timesteps`` env steps (summed over envs): the last iteration collects only what is left of
        the budget, so ``num_timesteps`` ends at ``total_timesteps`` when it is a multiple of ``n_envs``. Such a
        shorter rollout trains the value (and a learned model) but not the discriminator.
        """
        check_arguments(
            total_timesteps=(total_timesteps, TIMESTEPS),
            callback=(callback, CALLBACK),
            log_interval=(log_interval, OPTIONAL_POSITIVE_INTEGER),
        )
        total_timesteps = int(total_timesteps)
        if self.env is None:
            raise ValueError(
                "MPAIL has no environment to learn in (a model loaded without one plans only): pass env= to "
                "MPAIL.load(path, env=...) or call model.set_env(env)."
            )
        if self.expert is None:
            raise ValueError("MPAIL needs expert demos to learn: pass demos=... to MPAIL(...) or call model.set_demos(demos).")
        total_timesteps, callback = self._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        callback.on_training_start(locals(), globals())
        while self.num_timesteps < total_timesteps:
            n_rollout_steps = min(self.n_steps, math.ceil((total_timesteps - self.num_timesteps) / self.env.num_envs))
            if not self.collect_rollouts(self.env, callback, n_rollout_steps):
                break
            self.n_iterations += 1
            self._update_current_progress_remaining(self.num_timesteps, total_timesteps)
            self.train()
            if log_interval is not None and self.n_iterations % log_interval == 0:
                self._dump_logs()
        callback.on_training_end()
        return self

    def predict(
        self,
        observation: Union[np.ndarray, Dict[str, np.ndarray]],
        state: Tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> Tuple[np.ndarray, Tuple[np.ndarray, ...] | None]:
        """
        Plans an action per observation (:meth:`~sb3_mpail.policies.MPPIPolicy.predict`) with the deployed policy: the
        running average of the weights where ``policy_average_rate`` is set and training has updated it, else the live
        policy.
        """
        return self.deployed_policy().predict(observation, state, episode_start, deterministic)

    def deployed_policy(self) -> MPPIPolicy:
        """The policy :meth:`predict` plans with: the average of the weights once it has started, else ``self.policy``."""
        if self.policy_average is not None and self.policy_average.is_started:
            return self.policy_average.policy
        return self.policy

    def collect_rollouts(self, env: VecEnv, callback: BaseCallback, n_rollout_steps: int) -> bool:
        """
        Runs the planner in every env for ``n_rollout_steps`` steps, then labels the rollout with learned rewards,
        values and GAE returns.

        :return: ``False`` if a callback asked to stop training
        """
        assert self._last_obs is not None
        self.policy.set_training_mode(False)
        if getattr(self, "rollout_buffer", None) is None or self.rollout_buffer.buffer_size != n_rollout_steps:
            self.rollout_buffer = TransitionRolloutBuffer(
                n_rollout_steps,
                self.observation_space,
                self.action_space,
                self.device,
                self.gae_lambda,
                self.gamma,
                env.num_envs,
            )
        self.rollout_buffer.reset()
        if self._plan is None or self._plan.shape[0] != env.num_envs:
            self._plan = self.policy.initial_plan(env.num_envs)
        callback.on_rollout_start()
        check_finite(self._last_obs, "The observation the environment returned", NON_FINITE_OBSERVATION)
        for _ in range(n_rollout_steps):
            fresh = th.as_tensor(self._last_episode_starts, device=self.device).view(-1, 1, 1)
            previous_plan = th.where(fresh, self.policy.initial_plan(env.num_envs), self._plan)
            observations = self._tensor(self._last_obs)
            with th.no_grad():
                actions, self._plan, costs = self.policy.plan_actions(observations, previous_plan)
            if self.temperature_mode == "learned":
                self._learn_temperature(costs)
            actions = actions.cpu().numpy()
            self.policy.check_plan(actions, "The action planned from a finite observation", observations, previous_plan)
            new_obs, _, dones, infos = env.step(actions)
            check_finite(new_obs, "The observation the environment returned", NON_FINITE_OBSERVATION)
            self.num_timesteps += env.num_envs
            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
            next_obs = new_obs.copy()
            timeouts = np.zeros(env.num_envs, dtype=np.float32)
            for index in np.flatnonzero(dones):
                next_obs[index] = infos[index]["terminal_observation"]
                timeouts[index] = infos[index].get("TimeLimit.truncated", False)
            check_finite(next_obs, "The terminal observation the environment returned", NON_FINITE_OBSERVATION)
            if self.policy.prior is not None:
                self._prior_replay().add(self.policy.prior, self._last_obs, next_obs, actions, dones, infos)
            self.rollout_buffer.add_transition(self._last_obs, actions, next_obs, self._last_episode_starts, timeouts)
            self.episodes_completed += int(dones.sum())
            if self.temperature_mode == "decay":
                self.policy.temperature.fill_(self.temperature())
            self._last_obs = new_obs
            self._last_episode_starts = dones
        self._label_rollout(new_obs, dones)
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    def _learn_temperature(self, costs: th.Tensor) -> None:
        """One RMSprop step on ``log lambda`` lowering the mean entropy of ``softmax(-costs / lambda)`` over the envs."""
        floor = math.log(self.min_temperature)
        log_weights = th.log_softmax(-costs / self.log_temperature.clamp(min=floor).exp(), dim=-1)
        entropy = -(log_weights.exp() * log_weights).sum(-1).mean()
        self.temperature_optimizer.zero_grad()
        entropy.backward()
        self.temperature_optimizer.step()
        with th.no_grad():
            self.log_temperature.clamp_(min=floor)
            self.policy.temperature.copy_(self.log_temperature.exp())

    def _label_rollout(self, last_obs: np.ndarray, dones: np.ndarray) -> None:
        """Learned rewards ``d_theta(s, s')``, values and GAE returns for the whole rollout in a few batched calls."""
        buffer = self.rollout_buffer
        shape = (buffer.buffer_size, buffer.n_envs)
        with th.no_grad():
            observations = self._tensor(buffer.flat("observations"))
            next_observations = self._tensor(buffer.flat("next_observations"))
            rewards = self.policy.learned_reward(observations, next_observations)
            next_values = self.policy.value_net(next_observations).squeeze(-1)
            values = self.policy.value_net(observations).squeeze(-1)
            last_values = self.policy.value_net(self._tensor(last_obs)).squeeze(-1)
        timeouts = self._tensor(buffer.flat("timeouts"))
        # a time-limit cut is not a real end: bootstrap it with the value of the state reached, as SB3's PPO does
        buffer.rewards = (rewards + self.reward_shift + self.gamma * next_values * timeouts).cpu().numpy().reshape(shape)
        buffer.values = values.cpu().numpy().reshape(shape)
        buffer.compute_returns_and_advantage(last_values, dones)
        self.logger.record("rollout/learned_reward_mean", rewards.mean().item())

    def _learned_reward(self, observations: th.Tensor, next_observations: th.Tensor) -> th.Tensor:
        """
        The reward the value or the prior's Q learns on ``(batch, obs_dim)`` observations, ``(batch,)``: the policy's
        learned reward plus the ``agent_reward_mean`` shift.
        """
        return self.policy.learned_reward(observations, next_observations) + self.reward_shift

    def _shift_learned_reward(self, observations: th.Tensor, next_observations: th.Tensor) -> None:
        """Sets the shift that brings the learned reward's mean over the rollout's transitions to ``agent_reward_mean``."""
        with th.no_grad():
            rollout_mean = self.policy.learned_reward(observations, next_observations).mean().item()
        self.reward_shift = self.agent_reward_mean - rollout_mean
        self.logger.record("train/reward_shift", self.reward_shift)

    def _prior_replay(self) -> PriorReplay:
        """The policy prior's replay of every transition (created on first use; never saved, as SB3's replay buffers)."""
        if self.prior_replay is None:
            self.prior_replay = PriorReplay(
                self.observation_space,
                self.action_space,
                self.n_envs,
                self.prior_buffer_size,
                self.prior_batch_size,
                self.prior_updates_per_step,
                self.device,
                self.prior_terminations,
                self.prior_return_steps,
            )
        return self.prior_replay

    def _minibatches(self, n_items: int) -> List[th.Tensor]:
        batch_size = math.ceil(n_items / self.n_minibatches)
        return list(th.randperm(n_items, device=self.device).split(batch_size))

    def train(self) -> None:
        """Discriminator update (every ``discriminator_update_interval`` iterations), value update, dynamics fit."""
        self.policy.set_training_mode(True)
        buffer = self.rollout_buffer
        observations = self._tensor(buffer.flat("observations"))
        next_observations = self._tensor(buffer.flat("next_observations"))
        # a rollout cut short by the budget holds only the start of each episode: too biased an agent sample to
        # train the discriminator on (it lowered the final navigation score by 0.1-0.2 in every seed tried)
        whole_rollout = buffer.buffer_size == self.n_steps
        if whole_rollout and (self.n_iterations - 1) % self.discriminator_update_interval == 0:
            self._train_discriminator(observations, next_observations)
        if self.agent_reward_mean is not None:
            self._shift_learned_reward(observations, next_observations)
        if self.policy.prior is None:
            self._train_value(observations)
        else:  # the prior's Q ensemble, trained off-policy, is the planner's value
            figures = self._prior_replay().train(self.policy.prior, self._learned_reward, buffer.buffer_size * buffer.n_envs)
            for name, value in figures.items():
                self.logger.record(f"train/prior_{name}", value)
        if isinstance(self.policy.dynamics, LearnedDynamics):
            loss = self.policy.dynamics.fit(
                buffer.flat("observations"), buffer.flat("actions"), buffer.flat("next_observations")
            )
            self.logger.record("train/dynamics_loss", loss)
            self.logger.record("train/dynamics_learning_rate", self.policy.dynamics.current_learning_rate())
        self.policy.set_training_mode(False)
        if self.policy_average is not None:
            self.policy_average.update(self.policy)
        self.logger.record("train/temperature", self.temperature())
        self.logger.record("train/episodes", self.episodes_completed)

    def _train_discriminator(self, observations: th.Tensor, next_observations: th.Tensor) -> None:
        """BCE on logits, expert transitions labelled 1 and the agent's 0, each agent batch with as many expert pairs."""
        assert self.expert is not None
        expert_observations = self._tensor(self.expert.observations)
        expert_next_observations = self._tensor(self.expert.next_observations)
        discriminator = self.policy.discriminator
        with th.no_grad():
            agent_features, agent_next_features = self.policy.features(observations), self.policy.features(next_observations)
        replay = self._replay_buffer(tuple(agent_features.shape[1:]))
        replay_ready = replay is not None and replay.size() > 0
        losses, expert_accuracies, agent_accuracies = [], [], []
        for _ in range(self.n_epochs):
            for batch in self._minibatches(len(observations)):
                batch_features, batch_next_features = agent_features[batch], agent_next_features[batch]
                if replay_ready:
                    replayed = replay.sample(len(batch))
                    batch_features = th.cat((batch_features, self._tensor(replayed["features"])))
                    batch_next_features = th.cat((batch_next_features, self._tensor(replayed["next_features"])))
                expert_batch = th.randint(len(expert_observations), (len(batch_features),), device=self.device)
                # (members, batch): an ensemble's members each learn from the whole batch
                expert_pair = (expert_observations[expert_batch], expert_next_observations[expert_batch])
                agent_logits = member_logits(discriminator, batch_features, batch_next_features)
                expert_logits = member_logits(discriminator, *expert_pair)
                logits = th.cat((expert_logits, agent_logits), dim=1)
                labels = th.cat((th.ones_like(expert_logits), th.zeros_like(agent_logits)), dim=1)
                loss = F.binary_cross_entropy_with_logits(logits, labels)
                if self.discriminator_gradient_penalty > 0:
                    penalty = self._gradient_penalty(expert_pair, (batch_features, batch_next_features))
                    loss = loss + self.discriminator_gradient_penalty * penalty
                self.discriminator_optimizer.zero_grad()
                loss.backward()
                self.discriminator_optimizer.step()
                losses.append(loss.item())
                expert_accuracies.append((expert_logits > 0).float().mean().item())
                agent_accuracies.append((agent_logits < 0).float().mean().item())
        if replay is not None:  # stored after the update: every minibatch already holds the current rollout
            replay.store({"features": agent_features.cpu().numpy(), "next_features": agent_next_features.cpu().numpy()}, True)
        self.logger.record("train/discriminator_loss", np.mean(losses))
        self.logger.record("train/discriminator_accuracy", (np.mean(expert_accuracies) + np.mean(agent_accuracies)) / 2)
        self.logger.record("train/expert_accuracy", np.mean(expert_accuracies))
        self.logger.record("train/agent_accuracy", np.mean(agent_accuracies))

    def _gradient_penalty(self, expert: Tuple[th.Tensor, th.Tensor], agent: Tuple[th.Tensor, th.Tensor]) -> th.Tensor:
        """
        ``(||grad d(x)|| - 1)^2`` (of each member of an ensemble) averaged over points ``x`` drawn uniformly between
        paired expert and agent transitions ``(features, next_features)``, the gradient taken over both states.
        """
        mix = th.rand(len(agent[0]), 1, device=self.device)
        points = [th.lerp(agent_part, expert_part, mix).requires_grad_(True) for expert_part, agent_part in zip(expert, agent)]
        penalties = []
        for logits in member_logits(self.policy.discriminator, *points):  # each member's own slope
            gradients = th.autograd.grad(logits.sum(), points, create_graph=True, retain_graph=True)
            penalties.append((th.cat(gradients, dim=1).norm(dim=1) - 1).square().mean())
        return th.stack(penalties).mean()

    def _replay_buffer(self, feature_shape: Tuple[int, ...]) -> Buffer | None:
        """The discriminator's replay of earlier agent rollouts (created on first use), or ``None`` when it is off."""
        if self.discriminator_replay_size <= 0:
            return None
        if self.discriminator_replay is None:
            self.discriminator_replay = Buffer(
                self.discriminator_replay_size,
                sample_shapes={"features": feature_shape, "next_features": feature_shape},
                dtypes={"features": np.float32, "next_features": np.float32},
            )
        return self.discriminator_replay

    def _train_value(self, observations: th.Tensor) -> None:
        """
        Clipped regression of ``V_phi`` onto the GAE returns, as PPO's value loss; each member of a value ensemble on
        its own, clipped about its own values before the update.
        """
        buffer = self.rollout_buffer
        returns = self._tensor(buffer.flat("returns"))
        old_values = self._tensor(buffer.flat("values")).unsqueeze(0)  # (networks, rows)
        if self.policy.value_ensemble_size > 1:
            with th.no_grad():
                old_values = member_values(self.policy.value_net, observations)
        losses = []
        for _ in range(self.n_epochs):
            for batch in self._minibatches(len(observations)):
                values = member_values(self.policy.value_net, observations[batch])
                old = old_values[:, batch]
                clipped = old + th.clamp(values - old, -self.value_clip, self.value_clip)
                loss = th.max((values - returns[batch]).square(), (clipped - returns[batch]).square()).mean()
                self.value_optimizer.zero_grad()
                loss.backward()
                th.nn.utils.clip_grad_norm_(self.policy.value_net.parameters(), self.max_grad_norm)
                self.value_optimizer.step()
                losses.append(loss.item())
        self.logger.record("train/value_loss", np.mean(losses))
        self.logger.record("train/explained_variance", explained_variance(buffer.flat("values"), buffer.flat("returns")))

    def _dump_logs(self) -> None:
        assert self.ep_info_buffer is not None
        time_elapsed = max((time.time_ns() - self.start_time) / 1e9, sys.float_info.epsilon)
        self.logger.record("time/iterations", self.n_iterations, exclude="tensorboard")
        if len(self.ep_info_buffer) > 0:
            self.logger.record("rollout/ep_rew_mean", safe_mean([info["r"] for info in self.ep_info_buffer]))
            self.logger.record("rollout/ep_len_mean", safe_mean([info["l"] for info in self.ep_info_buffer]))
        self.logger.record("time/fps", int((self.num_timesteps - self._num_timesteps_at_start) / time_elapsed))
        self.logger.record("time/time_elapsed", int(time_elapsed), exclude="tensorboard")
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(step=self.num_timesteps)
