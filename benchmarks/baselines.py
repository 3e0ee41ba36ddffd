"""
The algorithms of the benchmark grid, trained on the same observation-only demos and the same env-step budget,
built on the ``imitation`` library and Stable-Baselines3:

* ``mpail``: :class:`~sb3_mpail.MPAIL`.
* ``mpail_om``: MPAIL-OM, :class:`~sb3_mpail.MPAIL` planning through a dynamics model learned online from its own
  transitions (``dynamics="learned"``), no prior model: as much information as GAIL has.
* ``mpail_one_discriminator``: :class:`~sb3_mpail.MPAIL` with the paper's single discriminator where ``mpail.yml``
  trains an ensemble (navigation), its other settings ``mpail.yml``'s.
* ``gail``: imitation's GAIL, PPO generator, state-only discriminator ``d(s, s')`` (MPAIL's discriminator,
  :func:`~sb3_mpail.mppi.costs.make_transition_discriminator`; dummy zero actions in the demos, never read). With
  ``reward_net_kwargs`` ``features`` it sees only those features of the state, in any form MPAIL's
  ``discriminator_features`` takes (:class:`FeatureMappedRewardNet`), and ``demos_are_features: True`` reads demos
  that hold only the state dimensions ``features`` lists (the lap's).
* ``airl``: **AIRL (obs-only)**. imitation's AIRL subtracts ``log pi(a_expert | s)`` from its logit, meaningless
  without expert actions, so this is imitation's adversarial trainer with AIRL's shaped state-only reward
  ``f(s, s') = g(s) + gamma h(s') - h(s)`` (``BasicShapedRewardNet``) as the logit, no policy term, PPO generator.
* ``bc``: imitation's BC. It **uses expert actions**: ``benchmarks/action_demos/<env>_<n>_actions.npz``
  (:func:`make_action_demos`; pendulum's and cartpole's recovered exactly from the demos by inverting the env's
  dynamics).
* ``irl_mpc``: the GAIL-learned reward and critic deployed through MPAIL's MPPI planner with no further training:
  the GAIL run of ``zoo_configs/gail.yml``, its discriminator as step cost ``log(1 - D(s, s'))`` (the negated GAIL
  reward) and its PPO critic as terminal value. Its env steps are GAIL's.

Hyperparameters come from ``zoo_configs/<algo>.yml`` and, for MPAIL, from the package's own
``sb3_mpail/hyperparams/mpail.yml`` (rl_zoo3's layout, :func:`load_config`).

Action-labelled demos for BC: ``python -m benchmarks.baselines make-action-demos --env navigation``.
"""

import argparse
import importlib.util
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import gymnasium as gym
import numpy as np
import torch as th
import yaml
from gymnasium import spaces
from imitation.algorithms import bc as imitation_bc
from imitation.algorithms.adversarial.common import AdversarialTrainer
from imitation.algorithms.adversarial.gail import GAIL
from imitation.data import rollout, types
from imitation.rewards.reward_nets import BasicShapedRewardNet, RewardNet
from imitation.util import logger as imitation_logger
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv
from torch import nn
from torch.nn import functional as F
from torch.nn.utils.parametrizations import spectral_norm

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Navigation-v0)
from sb3_mpail.demos import DemoSource, list_shipped_demos, load_demos, shipped_demo_info, shipped_demos
from sb3_mpail.envs import cartpole
from sb3_mpail.envs.locomotion import LOCOMOTION_TASKS
from sb3_mpail.mppi.costs import FeatureMap, FeatureSpec, make_transition_discriminator
from sb3_mpail.mppi.dynamics import DEFAULT_DYNAMICS, PendulumDynamics

#: every algorithm's rl_zoo3-style hyperparameter file; MPAIL's is the package's own (``sb3_mpail.zoo.HYPERPARAMS``,
#: linked there as ``mpail.yml``)
CONFIG_DIR = Path(__file__).resolve().parent.parent / "zoo_configs"
#: the expert-action twins of the shipped demos, for BC only (experiment data, not shipped with the package)
ACTION_DEMO_DIR = Path(__file__).resolve().parent / "action_demos"
#: the scripts that made the shipped demos
DEMO_SCRIPT_DIR = Path(__file__).resolve().parent.parent / "demos"

#: MPAIL's variants: algorithms trained by :func:`train_mpail`, each with its own hyperparameter file
MPAIL_VARIANTS: Tuple[str, ...] = ("mpail", "mpail_om", "mpail_one_discriminator")
ALGOS: Tuple[str, ...] = (*MPAIL_VARIANTS, "gail", "airl", "bc", "irl_mpc")
#: names used in every table and figure
ALGO_LABELS: Dict[str, str] = {
    "mpail": "MPAIL",
    "mpail_om": "MPAIL-OM (dynamics learned online)",
    "mpail_one_discriminator": "MPAIL, one discriminator",
    "gail": "GAIL (state-only)",
    "airl": "AIRL (obs-only)",
    "bc": "BC (uses expert actions)",
    "irl_mpc": "IRL-MPC (GAIL reward + critic via MPPI)",
}
#: short names of the benchmark's environments (the demo files' prefix)
ENV_NAMES: Dict[str, str] = {
    "sb3_mpail/Navigation-v0": "navigation",
    "Pendulum-v1": "pendulum",
    "sb3_mpail/ContinuousCartPole-v0": "cartpole",
    "sb3_mpail/NavigationLap-v0": "lap",
    "sb3_mpail/HighwayTraffic-v0": "highway_traffic",
    "sb3_mpail/PointMaze-v0": "pointmaze",
    "sb3_mpail/PointMazeMedium-v0": "pointmaze_medium",
    "sb3_mpail/Racetrack-v0": "racetrack",
    "sb3_mpail/Highway-v0": "highway",
    "sb3_mpail/Parking-v0": "parking",
    **LOCOMOTION_TASKS,
}
#: keys of a config entry that are strings of Python expressions (rl_zoo3 evaluates ``policy_kwargs`` this way)
EXPRESSION_KEYS = ("policy_kwargs", "reward_net_kwargs")
#: keys of a config entry that describe the run rather than the algorithm
META_KEYS = ("n_timesteps", "n_envs", "demos")
#: keys of ``gail.yml``/``airl.yml`` for the adversarial trainer; the others go to PPO. ``allow_variable_horizon``:
#: generator episodes may end early (cartpole's falls), which imitation refuses by default
ADVERSARIAL_KEYS = (
    "demo_batch_size", "n_disc_updates_per_round", "disc_learning_rate", "disc_betas", "reward_net_kwargs",
    "allow_variable_horizon", "demos_are_features",
)  # fmt: skip

#: ``on_eval(env_steps, {algo: predictor})``: called during training with anything SB3's ``predict`` works on
EvalHook = Callable[[int, Dict[str, Any]], None]


# --------------------------------------------------------------------------------------------------------------------
# configs and demos


def env_id_of(env: str) -> str:
    """
    The gymnasium id of ``env``.

    :param env: an id or a short name (``navigation``, ``pendulum``)
    """
    return {name: env_id for env_id, name in ENV_NAMES.items()}.get(env, env)


def env_name_of(env_id: str) -> str:
    """
    The short name of ``env_id`` (the prefix of its demo files).

    :param env_id: a gymnasium id
    """
    return ENV_NAMES.get(env_id, env_id.split("/")[-1].split("-")[0].lower())


def config_path(algo: str, config_dir: Optional[Path] = None) -> Path:
    """
    The hyperparameter file of ``algo``: ``<config_dir>/<algo>.yml``.

    :param algo: one of :data:`ALGOS`
    :param config_dir: a folder holding every algorithm's file (``None``: :data:`CONFIG_DIR`)
    """
    return Path(CONFIG_DIR if config_dir is None else config_dir) / f"{algo}.yml"


def load_config(algo: str, env_id: str, config_dir: Optional[Path] = None) -> Dict[str, Any]:
    """
    The entry of ``env_id`` in ``algo``'s hyperparameter file (:func:`config_path`, rl_zoo3's layout) with its
    ``policy_kwargs`` and ``reward_net_kwargs`` strings evaluated as rl_zoo3 does. ``irl_mpc``'s entry also gets
    ``gail``: the GAIL entry whose reward and critic it deploys (same ``n_timesteps``, ``n_envs`` and ``demos``,
    checked).

    :param algo: one of :data:`ALGOS`
    :param env_id: the gymnasium id (the YAML key)
    :param config_dir: a folder holding every algorithm's file (``None``: the defaults)
    :raises ValueError: the file has no entry for ``env_id``, or IRL-MPC's entry disagrees with GAIL's
    """
    path = config_path(algo, config_dir)
    entry = (yaml.safe_load(path.read_text()) or {}).get(env_id)
    if entry is None:
        raise ValueError(f"{path} has no entry for {env_id}.")
    entry = dict(entry)
    for key in EXPRESSION_KEYS:
        if isinstance(entry.get(key), str):
            # rl_zoo3 evaluates these strings with eval() too; literals, dict() and torch.nn suffice here
            entry[key] = eval(entry[key], {"__builtins__": {}, "dict": dict, "nn": nn})  # noqa: S307
    entry["n_timesteps"] = int(float(entry["n_timesteps"]))
    if algo == "irl_mpc":
        entry["gail"] = load_config("gail", env_id, config_dir)
        for key in META_KEYS:
            if entry[key] != entry["gail"][key]:
                raise ValueError(f"irl_mpc.yml's {key} for {env_id} must equal gail.yml's (IRL-MPC deploys that run).")
    return entry


def action_demos_path(demos: Path | str, directory: Path = ACTION_DEMO_DIR) -> Path:
    """
    The action-labelled twin of an observation-only demo set: ``navigation_4`` (or ``.../navigation_4.npz``) ->
    ``<directory>/navigation_4_actions.npz``.

    :param demos: a shipped demo set's name or an observation-only demo file
    :param directory: folder of the twins
    """
    return Path(directory) / f"{Path(demos).stem}_actions.npz"


def observation_only_transitions(
    path: DemoSource, env: VecEnv, feature_indices: Optional[Sequence[int]] = None
) -> types.Transitions:
    """
    The demos as imitation ``Transitions`` for a state-only discriminator: real ``(s, s')``, dummy zero actions
    (imitation requires ``acts``; the reward nets here never read them).

    :param path: observation-only demos (a shipped demo set's name, an ``.npz``, ...)
    :param env: the training env (its spaces check the demos)
    :param feature_indices: the demos hold only these state dimensions: they are written there into otherwise zero
        states, since imitation batches demo and agent states together; the discriminator must then read only those
        dimensions (:class:`FeatureMappedRewardNet` with these indices)
    """
    if feature_indices is None:
        pairs = load_demos(path, env.observation_space)
        observations, next_observations = pairs.observations, pairs.next_observations
    else:
        indices = list(feature_indices)
        pairs = load_demos(path, spaces.Box(-np.inf, np.inf, (len(indices),), np.float32), "the discriminator's features")
        observations, next_observations = (np.zeros((len(pairs.observations), *env.observation_space.shape), np.float32)
                                           for _ in range(2))  # fmt: skip
        observations[:, indices], next_observations[:, indices] = pairs.observations, pairs.next_observations
    n = len(observations)
    return types.Transitions(
        obs=observations, acts=np.zeros((n, *env.action_space.shape), np.float32), infos=np.array([{}] * n),
        next_obs=next_observations, dones=np.zeros(n, dtype=bool),
    )  # fmt: skip


def action_transitions(path: Path | str) -> types.Transitions:
    """
    Expert transitions with actions for BC, from the action-labelled twin of ``path``.

    :param path: the observation-only demo set; its ``_actions`` twin is read
    :raises FileNotFoundError: the action-labelled file is missing (make it with :func:`make_action_demos`)
    """
    labelled = action_demos_path(path)
    if not labelled.exists():
        raise FileNotFoundError(
            f"BC needs expert actions: {labelled} is missing; make it with "
            "`python -m benchmarks.baselines make-action-demos --env <name>`."
        )
    with np.load(labelled) as data:
        observations, actions = data["obs"], data["acts"]
        if "episode_lengths" in data:  # episodes of several lengths, concatenated: T_i + 1 observations, T_i actions
            ends = np.cumsum(data["episode_lengths"])
            observations = np.split(observations, ends[:-1])
            actions = np.split(actions, (ends - np.arange(1, len(ends) + 1))[:-1])
    trajectories = [types.Trajectory(obs=o, acts=a, infos=None, terminal=True) for o, a in zip(observations, actions)]
    return rollout.flatten_trajectories(trajectories)


class _EvalSchedule:
    """
    Calls ``on_eval`` when the env-step count passes each multiple of ``eval_every`` (and when forced), on a forked
    torch RNG so that evaluating does not change the training run.

    :param eval_every: env steps between evaluations; 0: only forced ones
    :param on_eval: the hook, or ``None``
    """

    def __init__(self, eval_every: int, on_eval: Optional[EvalHook]):
        self.eval_every = eval_every
        self.on_eval = on_eval
        self.last_step: Optional[int] = None

    def __call__(self, steps: int, predictors: Callable[[], Dict[str, Any]], force: bool = False) -> None:
        if self.on_eval is None or steps == self.last_step:
            return
        passed = self.eval_every > 0 and steps // self.eval_every > (self.last_step or 0) // self.eval_every
        if force or passed:
            self.last_step = steps
            with th.random.fork_rng():
                self.on_eval(steps, predictors())


# --------------------------------------------------------------------------------------------------------------------
# GAIL, AIRL (obs-only), IRL-MPC


def _quiet_logger() -> imitation_logger.HierarchicalLogger:
    return imitation_logger.configure(tempfile.mkdtemp(prefix="sb3_mpail_baseline_"), format_strs=[])


def state_only_airl_reward(
    env: VecEnv, hid_sizes: Sequence[int] = (32, 32), discount: float = 0.99, use_spectral_norm: bool = True
) -> BasicShapedRewardNet:
    """
    AIRL's shaped reward ``f(s, s') = g(s) + discount h(s') - h(s)`` with state-only ``g`` and ``h`` (LeakyReLU,
    spectral norm on every linear layer, as MPAIL's discriminator).

    :param env: the training env (its spaces)
    :param hid_sizes: hidden widths of ``g`` and ``h``
    :param discount: the shaping discount (the generator's gamma)
    :param use_spectral_norm: spectral normalisation on every linear layer
    """
    net = BasicShapedRewardNet(
        env.observation_space, env.action_space, use_state=True, use_action=False, use_next_state=False, use_done=False,
        reward_hid_sizes=tuple(hid_sizes), potential_hid_sizes=tuple(hid_sizes), discount_factor=discount,
        activation=nn.LeakyReLU,
    )  # fmt: skip
    if use_spectral_norm:
        for mlp in (net.base.mlp, net.potential._potential_net):
            for name, layer in list(mlp.named_children()):
                if isinstance(layer, nn.Linear):
                    setattr(mlp, name, spectral_norm(layer))
    return net


class ObsOnlyAIRL(AdversarialTrainer):
    """
    **AIRL (obs-only)**: imitation's adversarial trainer with AIRL's shaped state-only reward as the discriminator
    logit and *no* ``- log pi(a | s)`` term; the generator's reward is that logit, ``log D - log(1 - D)``.
    """

    def logits_expert_is_high(
        self,
        state: th.Tensor,
        action: th.Tensor,
        next_state: th.Tensor,
        done: th.Tensor,
        log_policy_act_prob: Optional[th.Tensor] = None,
    ) -> th.Tensor:
        return self._reward_net(state, action, next_state, done)

    @property
    def reward_train(self) -> RewardNet:
        return self._reward_net

    @property
    def reward_test(self) -> RewardNet:
        return self._reward_net.base


class FeatureMappedRewardNet(RewardNet):
    """
    A reward net that reads chosen features of ``s`` and ``s'``: MPAIL's ``discriminator_features`` for GAIL (state
    indices, ``{"lane_frame": ...}`` and the other forms :meth:`~sb3_mpail.mppi.costs.FeatureMap.wrap` takes). Its
    discriminator is :func:`~sb3_mpail.mppi.costs.make_transition_discriminator` built on those features.

    :param observation_space: the env's observation space
    :param action_space: the env's action space (never read)
    :param features: what the discriminator sees of a state
    :param hid_sizes: hidden widths
    :param use_spectral_norm: spectral normalisation on every linear layer
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        features: FeatureSpec,
        hid_sizes: Sequence[int] = (32, 32),
        use_spectral_norm: bool = True,
    ):
        super().__init__(observation_space, action_space)
        self.features = FeatureMap.wrap(features, "reward_net_kwargs features")
        feature_space = FeatureMap.space(self.features, observation_space, "reward_net_kwargs features")
        self.discriminator = make_transition_discriminator(feature_space, action_space, hid_sizes, use_spectral_norm)

    def forward(self, state: th.Tensor, action: th.Tensor, next_state: th.Tensor, done: th.Tensor) -> th.Tensor:
        return self.discriminator(self.features(state), action, self.features(next_state), done)


def make_gail_discriminator(
    observation_space: spaces.Box, action_space: spaces.Box, net_kwargs: Optional[Dict[str, Any]] = None
) -> RewardNet:
    """
    GAIL's state-only discriminator ``d(s, s')``, on the whole state or, with ``features``, on those features.

    :param observation_space: the env's observation space
    :param action_space: the env's action space (never read)
    :param net_kwargs: ``reward_net_kwargs``: ``hid_sizes`` (default ``(32, 32)``), ``spectral_norm`` (default on),
        ``features`` (MPAIL's ``discriminator_features`` forms; default the whole state)
    """
    net_kwargs = net_kwargs or {}
    hid_sizes, use_spectral_norm = net_kwargs.get("hid_sizes", (32, 32)), net_kwargs.get("spectral_norm", True)
    if net_kwargs.get("features") is None:
        return make_transition_discriminator(observation_space, action_space, hid_sizes, use_spectral_norm)
    return FeatureMappedRewardNet(observation_space, action_space, net_kwargs["features"], hid_sizes, use_spectral_norm)


def make_adversarial(algo: str, env: VecEnv, demos: DemoSource, seed: int, hyperparams: Dict[str, Any]) -> AdversarialTrainer:
    """
    A GAIL or AIRL (obs-only) trainer with a PPO generator.

    :param algo: ``gail`` or ``airl``
    :param env: the training env
    :param demos: observation-only demos
    :param seed: PPO's seed
    :param hyperparams: the config entry without :data:`META_KEYS`; keys other than :data:`ADVERSARIAL_KEYS` go to PPO
    """
    net_kwargs = dict(hyperparams.get("reward_net_kwargs") or {})
    features = net_kwargs.get("features")
    if features is not None and algo != "gail":
        raise ValueError("Only GAIL's discriminator can read features of the state (reward_net_kwargs features).")
    # demos that hold features hold state dimensions: the features' list, or the first map of a chain
    held = features["chain"][0] if isinstance(features, Mapping) and set(features) == {"chain"} else features
    if hyperparams.get("demos_are_features") and not (isinstance(held, Sequence) and not isinstance(held, str)):
        raise ValueError("demos_are_features needs reward_net_kwargs features to list the state dimensions the demos hold "
                         f"(or a chain that starts with that list); got {features!r}.")  # fmt: skip
    demo_features = held if hyperparams.get("demos_are_features") else None
    transitions = observation_only_transitions(demos, env, demo_features)
    ppo_kwargs = {key: value for key, value in hyperparams.items() if key not in ADVERSARIAL_KEYS}
    generator = PPO(ppo_kwargs.pop("policy", "MlpPolicy"), env, seed=seed, device="cpu", verbose=0, **ppo_kwargs)
    if algo == "gail":
        trainer_class: type = GAIL
        reward_net = make_gail_discriminator(env.observation_space, env.action_space, net_kwargs)
    else:
        trainer_class = ObsOnlyAIRL
        reward_net = state_only_airl_reward(env, net_kwargs.get("hid_sizes", (32, 32)), generator.gamma,
                                            net_kwargs.get("spectral_norm", True))  # fmt: skip
    return trainer_class(
        demonstrations=transitions,
        demo_batch_size=min(int(hyperparams.get("demo_batch_size", 256)), len(transitions)),
        venv=env,
        gen_algo=generator,
        reward_net=reward_net,
        n_disc_updates_per_round=int(hyperparams.get("n_disc_updates_per_round", 4)),
        disc_opt_kwargs=dict(lr=float(hyperparams.get("disc_learning_rate", 3e-4)),
                             betas=tuple(hyperparams.get("disc_betas", (0.5, 0.999)))),
        custom_logger=_quiet_logger(),
        allow_variable_horizon=bool(hyperparams.get("allow_variable_horizon", False)),
    )  # fmt: skip


class GAILRewardCost(nn.Module):
    """
    Planner step cost ``c(s, s') = -r_GAIL(s, s') = log sigmoid(-d(s, s'))`` over any leading batch shape.

    :param discriminator: the state-only discriminator logit ``d``
    """

    def __init__(self, discriminator: RewardNet):
        super().__init__()
        self.discriminator = discriminator

    def forward(self, states: th.Tensor, next_states: th.Tensor) -> th.Tensor:
        flat = states.reshape(-1, states.shape[-1]), next_states.reshape(-1, states.shape[-1])
        return F.logsigmoid(-self.discriminator(flat[0], None, flat[1], None)).view(states.shape[:-1])


class CriticValue(nn.Module):
    """
    Planner terminal value ``V(s)`` from a PPO actor-critic's value head, over any leading batch shape.

    :param policy: the actor-critic
    """

    def __init__(self, policy: ActorCriticPolicy):
        super().__init__()
        self.policy = policy

    def forward(self, states: th.Tensor) -> th.Tensor:
        return self.policy.predict_values(states.reshape(-1, states.shape[-1])).view(states.shape[:-1])


def irl_mpc_policy(trainer: GAIL, env_id: str, hyperparams: Dict[str, Any]) -> nn.Module:
    """
    IRL-MPC: an :class:`~sb3_mpail.policies.MPPIPolicy` planning with copies of GAIL's discriminator (step cost
    :class:`GAILRewardCost`) and of its PPO critic (terminal value; ``value: none`` drops it). Nothing is trained.

    :param trainer: a GAIL trainer (state-only discriminator)
    :param env_id: the env (its planning model is ``DEFAULT_DYNAMICS[env_id]`` unless ``policy_kwargs`` names one)
    :param hyperparams: :func:`load_config`'s ``irl_mpc`` entry: ``policy_kwargs`` (the planner), ``temperature``,
        ``value`` and ``gail`` (the discriminator's ``reward_net_kwargs``)
    """
    from sb3_mpail.policies import MPPIPolicy

    planner_kwargs = dict(hyperparams.get("policy_kwargs") or {})
    value = hyperparams.get("value", "gail_critic")
    if value not in ("gail_critic", "none"):
        raise ValueError(f"irl_mpc value must be 'gail_critic' or 'none', got {value!r}.")
    discriminator = make_gail_discriminator(trainer.venv.observation_space, trainer.venv.action_space,
                                            hyperparams["gail"].get("reward_net_kwargs"))  # fmt: skip
    discriminator.load_state_dict(trainer._reward_net.state_dict())  # copies: evaluating must not touch GAIL's nets
    generator = trainer.gen_algo.policy
    critic = type(generator)(**generator._get_constructor_parameters())  # as SB3's BasePolicy.load rebuilds a policy
    critic.load_state_dict(generator.state_dict())
    policy = MPPIPolicy(
        trainer.venv.observation_space,
        trainer.venv.action_space,
        dynamics=planner_kwargs.pop("dynamics", DEFAULT_DYNAMICS.get(env_id)),
        step_cost=GAILRewardCost(discriminator),
        terminal_value=CriticValue(critic),
        use_terminal_value=value == "gail_critic",
        **planner_kwargs,
    )
    policy.temperature.fill_(float(hyperparams.get("temperature", 1.0)))
    policy.seed(0)
    return policy.eval()


def train_adversarial(
    algo: str,
    env_id: str,
    demos: DemoSource,
    timesteps: int,
    seed: int,
    n_envs: int,
    hyperparams: Dict[str, Any],
    eval_every: int = 0,
    on_eval: Optional[EvalHook] = None,
    irl_mpc_hyperparams: Optional[Dict[str, Any]] = None,
) -> Tuple[AdversarialTrainer, Callable[[], Dict[str, Any]]]:
    """
    Trains GAIL or AIRL (obs-only) for ``timesteps`` env steps in whole rounds of PPO's ``n_steps * n_envs``.

    :param algo: ``gail`` or ``airl``
    :param env_id: gymnasium id
    :param demos: observation-only demos
    :param timesteps: env-step budget
    :param seed: envs' and PPO's seed
    :param n_envs: parallel training envs
    :param hyperparams: the config entry without :data:`META_KEYS`
    :param eval_every: env steps between ``on_eval`` calls (also called at the end)
    :param on_eval: the evaluation hook
    :param irl_mpc_hyperparams: (GAIL only) also hand ``on_eval`` the IRL-MPC policy built from the GAIL of that moment
    :return: the trainer and a function giving the predictors ``{algo: ...}`` (and ``irl_mpc``) of its current state
    """
    if irl_mpc_hyperparams is not None and algo != "gail":
        raise ValueError("IRL-MPC deploys GAIL's reward.")
    trainer = make_adversarial(algo, make_vec_env(env_id, n_envs=n_envs, seed=seed), demos, seed, hyperparams)

    def predictors() -> Dict[str, Any]:
        found = {algo: trainer.gen_algo}
        if irl_mpc_hyperparams is not None:
            found["irl_mpc"] = irl_mpc_policy(trainer, env_id, irl_mpc_hyperparams)
        return found

    schedule = _EvalSchedule(eval_every, on_eval)
    trainer.train(timesteps, callback=lambda _: schedule(trainer.gen_algo.num_timesteps, predictors))
    schedule(trainer.gen_algo.num_timesteps, predictors, force=True)
    return trainer, predictors


# --------------------------------------------------------------------------------------------------------------------
# BC and MPAIL


def train_bc(env_id: str, demos: Path | str, seed: int, hyperparams: Dict[str, Any]) -> imitation_bc.BC:
    """
    imitation's BC on the action-labelled twin of ``demos`` (it **uses expert actions**, and no env steps).

    :param env_id: gymnasium id
    :param demos: the observation-only demo file (its ``_actions`` twin is read)
    :param seed: network and minibatch seed
    :param hyperparams: ``policy_kwargs``, ``learning_rate``, ``batch_size``, ``n_epochs``, ``ent_weight``,
        ``l2_weight``
    """
    env = gym.make(env_id)
    th.manual_seed(seed)
    transitions = action_transitions(demos)
    learning_rate = float(hyperparams.get("learning_rate", 1e-3))
    policy = ActorCriticPolicy(env.observation_space, env.action_space, lr_schedule=lambda _: learning_rate,
                               **(hyperparams.get("policy_kwargs") or {}))  # fmt: skip
    trainer = imitation_bc.BC(
        observation_space=env.observation_space,
        action_space=env.action_space,
        rng=np.random.default_rng(seed),
        policy=policy,
        demonstrations=transitions,
        batch_size=min(int(hyperparams.get("batch_size", 64)), len(transitions)),
        optimizer_kwargs=dict(lr=learning_rate),
        ent_weight=float(hyperparams.get("ent_weight", 1e-3)),
        l2_weight=float(hyperparams.get("l2_weight", 0.0)),
        device="cpu",
        custom_logger=_quiet_logger(),
    )
    trainer.train(n_epochs=int(hyperparams.get("n_epochs", 100)), progress_bar=False, log_interval=10**9)
    return trainer


class _RolloutEvalCallback(BaseCallback):
    """
    Evaluates at the end of rollouts, except the last one: that rollout's update comes after it, so the final
    evaluation is left to the caller, after ``learn`` returns.
    """

    def __init__(self, schedule: _EvalSchedule, budget: int, name: str = "mpail"):
        super().__init__()
        self.schedule = schedule
        self.budget = budget
        self.name = name

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.num_timesteps < self.budget:
            self.schedule(self.num_timesteps, lambda: {self.name: self.model})


def train_mpail(
    env_id: str,
    demos: DemoSource,
    timesteps: int,
    seed: int,
    n_envs: int,
    hyperparams: Dict[str, Any],
    eval_every: int = 0,
    on_eval: Optional[EvalHook] = None,
    name: str = "mpail",
) -> Any:
    """
    :class:`~sb3_mpail.MPAIL` with ``mpail.yml``'s (or another of :data:`MPAIL_VARIANTS`' files') settings, evaluated at
    the end of rollouts.

    :param env_id: gymnasium id
    :param demos: observation-only demos
    :param timesteps: env-step budget
    :param seed: training seed
    :param n_envs: parallel training envs
    :param hyperparams: the config entry without :data:`META_KEYS`
    :param eval_every: env steps between ``on_eval`` calls (also called at the end)
    :param on_eval: the evaluation hook
    :param name: the algorithm's name in ``on_eval``'s dict (one of :data:`MPAIL_VARIANTS`)
    """
    from sb3_mpail.mpail import MPAIL

    settings = dict(hyperparams)
    model = MPAIL(settings.pop("policy", "MlpMPPI"), make_vec_env(env_id, n_envs=n_envs, seed=seed), demos, seed=seed,
                  device="cpu", **settings)  # fmt: skip
    schedule = _EvalSchedule(eval_every, on_eval)
    model.learn(timesteps, callback=_RolloutEvalCallback(schedule, timesteps, name))
    schedule(model.num_timesteps, lambda: {name: model}, force=True)
    return model


def train_baseline(
    algo: str,
    env_id: str,
    demos: Path | str,
    seed: int,
    hyperparams: Dict[str, Any],
    eval_every: int = 0,
    on_eval: Optional[EvalHook] = None,
    timesteps: Optional[int] = None,
) -> Any:
    """
    Trains one algorithm of the grid and returns what plans or acts (an SB3 algorithm or policy).

    :param algo: one of :data:`ALGOS`
    :param env_id: gymnasium id or short name
    :param demos: a shipped demo set, ``<prefix>_<n>`` (BC reads its ``_actions`` twin)
    :param seed: training seed (envs, networks, planner noise)
    :param hyperparams: :func:`load_config`'s entry (``n_timesteps`` and ``n_envs`` are the budget)
    :param eval_every: env steps between ``on_eval`` calls; BC, which has no env steps, is evaluated once at step 0
    :param on_eval: ``on_eval(env_steps, {algo: predictor})``; IRL-MPC's run also hands over its GAIL generator
    :param timesteps: overrides ``n_timesteps`` (tests)
    """
    env_id = env_id_of(env_id)
    timesteps = int(hyperparams["n_timesteps"] if timesteps is None else timesteps)
    n_envs = int(hyperparams.get("n_envs", 1))
    hp = {key: value for key, value in hyperparams.items() if key not in META_KEYS}
    if algo in ("gail", "airl"):
        return train_adversarial(algo, env_id, demos, timesteps, seed, n_envs, hp, eval_every, on_eval)[0].gen_algo
    if algo == "irl_mpc":
        gail_hp = {key: value for key, value in hp["gail"].items() if key not in META_KEYS}
        predictors = train_adversarial("gail", env_id, demos, timesteps, seed, n_envs, gail_hp, eval_every, on_eval, hp)[1]
        return predictors()["irl_mpc"]
    if algo == "bc":
        policy = train_bc(env_id, demos, seed, hp).policy
        if on_eval is not None:
            on_eval(0, {"bc": policy})
        return policy
    if algo in MPAIL_VARIANTS:
        return train_mpail(env_id, demos, timesteps, seed, n_envs, hp, eval_every, on_eval, algo)
    raise ValueError(f"Unknown algorithm {algo!r}; expected one of {ALGOS}.")


# --------------------------------------------------------------------------------------------------------------------
# action-labelled demos for BC


def _demo_script(name: str) -> Any:
    """The module ``demos/<name>.py`` (the scripts that made the shipped demos)."""
    if str(DEMO_SCRIPT_DIR) not in sys.path:  # the scripts import their shared helpers as top-level modules
        sys.path.append(str(DEMO_SCRIPT_DIR))
    spec = importlib.util.spec_from_file_location(name, DEMO_SCRIPT_DIR / f"{name}.py")
    assert spec is not None and spec.loader is not None
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return script


#: the shipped sets whose expert is replayed from the demos' reset seeds, besides the MuJoCo tasks' (:func:`_demo_experts`)
REPLAYED_EXPERTS = ("navigation", "highway_traffic", "racetrack", "highway", "parking")


class _RecordedExpert:
    """A parking expert whose actions of the episode under way are kept (``reset`` starts an episode)."""

    def __init__(self, expert: Any):
        self.expert, self.actions = expert, []

    def reset(self) -> None:
        self.expert.reset()
        self.actions = []

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        self.actions.append(self.expert(observation))
        return self.actions[-1]


def _in_turn(actions: List[np.ndarray]) -> Callable[[np.ndarray], np.ndarray]:
    """A policy that plays recorded actions in turn, whatever it observes."""
    remaining = iter(actions)
    return lambda _: next(remaining)


def _parking_demo_actions(n_episodes: int) -> List[Tuple[int, List[np.ndarray]]]:
    """
    The reset seed and the actions of each of the first ``n_episodes`` parking demos: ``demos/make_parking_demos.py``'s
    MPPI expert draws from one sampling stream, so its episodes are rerun in the script's order (its evaluation
    episodes, then every demo seed, the ones it skipped included) with the settings its command line recorded.
    """
    script = _demo_script("make_parking_demos")
    words = shipped_demo_info("parking")["command"].split()[2:]
    option = {key.lstrip("-").replace("-", "_"): value for key, value in zip(words[::2], words[1::2])}
    expert = script.ParkingExpert(
        float(option["stop_weight"]), int(option["samples"]), int(option["horizon"]), int(option["iterations"]),
        float(option["noise"]), float(option["temperature"]), int(option["seed"]),
    )  # fmt: skip
    stock_env = gym.make(script.ENV_ID)
    for seed in range(int(option["eval_episodes"])):
        script.run_episode(stock_env, seed, expert)
    demo_env = gym.make(script.ENV_ID, config={"success_goal_reward": 0.0})  # as the script records: no early end
    recorder, demos, seed = _RecordedExpert(expert), [], script.DEMO_SEED_OFFSET
    while len(demos) < n_episodes:
        if script.run_episode(demo_env, seed, recorder, float(option["stopped_speed"]), int(option["hold_steps"]))[2]:
            demos.append((seed, recorder.actions))
        seed += 1
    return demos


#: the MuJoCo point mazes, whose demos the graph expert of demos/make_maze_demos.py made
POINT_MAZE_DEMO_SETS = ("pointmaze", "pointmaze_medium")


def _stateless_expert(
    name: str, env_id: str, env: gym.Env, expert_path: Optional[Path]
) -> Optional[Callable[[np.ndarray], np.ndarray]]:
    """
    The expert of a shipped set recorded by ``demos/expert_rollouts.py``'s ``record_demos`` (episode ``i`` from its
    ``DEMO_SEED_OFFSET + i``) that acts on the observation alone, or ``None`` for the sets made otherwise.
    """
    if env_id in LOCOMOTION_TASKS:  # the TD3 or SAC expert of demos/make_mujoco_demos.py --save-expert
        algo = _demo_script("make_mujoco_demos").EXPERT_ALGOS[shipped_demo_info(name)["expert_algo"].lower()]
        expert = algo.load(expert_path, device="cpu")
        return lambda obs: expert.predict(obs, deterministic=True)[0]
    if name in POINT_MAZE_DEMO_SETS:  # the next cell follows from the ball's and the goal's positions
        return _demo_script("make_maze_demos").MazeGraphExpert(env).action
    if name in ("racetrack", "highway"):  # highway-env's lane (and speed) control of the observed car
        script = _demo_script("make_racetrack_demos")
        return script.LaneKeepingDriver(script.SCENARIOS[name]).act
    return None


def _demo_experts(
    name: str, env_id: str, env: gym.Env, expert_path: Optional[Path], n_episodes: int
) -> List[Tuple[int, Callable[[np.ndarray], np.ndarray]]]:
    """The reset seed and the expert of each of a shipped set's first ``n_episodes`` demos, as its script made them."""
    expert = _stateless_expert(name, env_id, env, expert_path)
    if expert is not None:
        first_seed = _demo_script("expert_rollouts").DEMO_SEED_OFFSET
        return [(first_seed + i, expert) for i in range(n_episodes)]
    if name == "navigation":
        script = _demo_script("make_navigation_demos")
        ppo = PPO.load(expert_path or "/tmp/navigation_expert_ppo.zip", device="cpu")
        navigator = script.make_expert_policy(ppo, env)
        return [(script.DEMO_SEED_BASE + i, navigator) for i in range(n_episodes)]
    if name == "parking":
        return [(seed, _in_turn(actions)) for seed, actions in _parking_demo_actions(n_episodes)]
    # highway_traffic: a fresh driver per episode (its lane-change timer is state); the crashed episodes' seeds skipped
    script = _demo_script("make_highway_traffic_demos")
    failed = set(shipped_demo_info(name)["failed_demo_seeds"])
    seeds = [seed for seed in range(script.DEMO_SEED_OFFSET, script.DEMO_SEED_OFFSET + n_episodes + len(failed))
             if seed not in failed]  # fmt: skip
    drivers = [script.IdmMobilDriver(env) for _ in seeds]  # it decides from the env's state, not the observation
    return [(seed, lambda _, driver=driver: driver()) for seed, driver in zip(seeds, drivers)]


def _replay(env: gym.Env, act: Callable[[np.ndarray], np.ndarray], seed: int, steps: int) -> Tuple[np.ndarray, np.ndarray]:
    """One episode of ``steps`` from ``reset(seed=seed)``: observations ``(steps + 1, d)`` and the actions taken."""
    obs, _ = env.reset(seed=seed)
    observations, actions = [obs], []
    for _ in range(steps):
        actions.append(np.asarray(act(obs), np.float32))
        obs = env.step(actions[-1])[0]
        observations.append(obs)
    return np.asarray(observations, np.float32), np.asarray(actions, np.float32)


def pendulum_actions(observations: np.ndarray, gravity: float = 10.0) -> np.ndarray:
    """
    The torques that produced a pendulum episode, recovered exactly from consecutive observations by inverting
    ``Pendulum-v1``'s dynamics: ``thdot' = thdot + (3 g / (2 l) sin(th) + 3 u / (m l^2)) dt``.

    :param observations: ``(T + 1, 3)`` observations ``(cos th, sin th, thdot)``
    :param gravity: the environment's ``g``
    :return: ``(T, 1)`` torques
    """
    p = PendulumDynamics
    obs = np.asarray(observations, np.float64)
    acceleration = (obs[1:, 2] - obs[:-1, 2]) / p.dt - 3 * gravity / (2 * p.length) * obs[:-1, 1]
    return (acceleration * p.mass * p.length**2 / 3).astype(np.float32)[:, None]


def cartpole_actions(observations: np.ndarray) -> np.ndarray:
    """
    The normalised forces that produced a ``sb3_mpail/ContinuousCartPole-v0`` episode, recovered exactly from
    consecutive observations by solving the env's pole equation for the force ``F``:
    ``theta_acc = (g sin th - cos th temp) / (l (4/3 - m_pole cos^2 th / M))``, ``temp = (F + m_pole l thdot^2 sin th) / M``,
    ``theta_acc = (thdot' - thdot) / tau``.

    :param observations: ``(T + 1, 4)`` observations ``(x, x_dot, theta, theta_dot)``
    :return: ``(T, 1)`` actions ``F / 10 N``
    """
    obs = np.asarray(observations, np.float64)
    theta, theta_dot = obs[:-1, 2], obs[:-1, 3]
    theta_acc = (obs[1:, 3] - theta_dot) / cartpole.TAU
    cos_theta, sin_theta = np.cos(theta), np.sin(theta)
    temp = (cartpole.GRAVITY * sin_theta - theta_acc * cartpole.HALF_LENGTH
            * (4.0 / 3.0 - cartpole.MASS_POLE * cos_theta**2 / cartpole.TOTAL_MASS)) / cos_theta  # fmt: skip
    force = temp * cartpole.TOTAL_MASS - cartpole.POLE_MASS_LENGTH * theta_dot**2 * sin_theta
    return (force / cartpole.FORCE_MAG).astype(np.float32)[:, None]


#: per env, the actions recovered from an episode's observations and the exact model that checks them step by step
INVERSE_DYNAMICS: Dict[str, Tuple[Callable[[np.ndarray], np.ndarray], Callable[[th.Tensor, th.Tensor], th.Tensor]]] = {
    "pendulum": (pendulum_actions, PendulumDynamics()),
    "cartpole": (cartpole_actions, cartpole.cartpole_dynamics),
}


def make_action_demos(env: str, expert_path: Optional[Path] = None, out_dir: Path = ACTION_DEMO_DIR) -> List[Path]:
    """
    Writes ``<out_dir>/<env>_<n>_actions.npz`` (``obs`` and the expert's ``acts``) for each shipped demo set
    ``<env>_<n>``, after checking that the actions reproduce the shipped observations.

    MuJoCo locomotion (``hopper``, ``walker2d``, ``halfcheetah``, ``ant_v4``): the TD3 or SAC expert that
    ``demos/make_mujoco_demos.py --save-expert`` saved (``expert_path``) is checked on the first step of each demo from
    its start seed, then labels the shipped observations with its actions (a whole open-loop replay diverges between
    machines: these bodies are chaotic, and float noise grows to metres within 50 steps). The point mazes
    (``pointmaze``, ``pointmaze_medium``) alike, with ``demos/make_maze_demos.py``'s graph expert (MuJoCo versions'
    wall contacts drift apart by centimetres over an episode). Navigation:
    replays the PPO expert that ``demos/make_navigation_demos.py`` saved (``expert_path``; rerunning that
    script retrains the same expert bit for bit on this stack) from the demos' start seeds. Pendulum and cartpole:
    the actions are recovered from the shipped observations by inverting the env's known dynamics
    (:func:`pendulum_actions`, :func:`cartpole_actions`), so no expert is needed; every step is checked against the
    exact model. Highway in traffic, the racetrack, the highway without traffic and parking: replays the
    scripted expert of ``demos/make_highway_traffic_demos.py`` (highway-env's IDM/MOBIL driver),
    ``demos/make_racetrack_demos.py`` (highway-env's lane keeping) or ``demos/make_parking_demos.py`` (MPPI on the exact
    model, its episodes rerun in order: :func:`_parking_demo_actions`) from the demos' reset seeds.

    :param env: ``navigation``, ``pendulum``, ``cartpole``, ``highway_traffic``, ``pointmaze``, ``racetrack``,
        ``highway``, ``parking`` or a MuJoCo task's name
    :param expert_path: the navigation or MuJoCo expert
    :param out_dir: where the files go
    :raises RuntimeError: the actions do not reproduce a shipped demo
    """
    env_id = env_id_of(env)
    name = env_name_of(env_id)
    gym_env = gym.make(env_id)
    sizes = [int(n) for family, n in (shipped.rsplit("_", 1) for shipped in list_shipped_demos()) if family == name]
    if not sizes:
        raise FileNotFoundError(f"No {name}_<n> demo set is shipped ({', '.join(list_shipped_demos())}).")
    episodes = [trajectory.obs for trajectory in shipped_demos(name, max(sizes))]
    if env_id in LOCOMOTION_TASKS or name in POINT_MAZE_DEMO_SETS:
        # MuJoCo: float noise between machines and MuJoCo versions grows within an open-loop replay (to metres within 50
        # steps on the walkers, to centimetres over 200 steps of the maze's wall contacts), so the replay checks each
        # demo's first step (the right expert) and the expert, acting on the observation alone, labels the shipped
        # observations themselves
        experts = _demo_experts(name, env_id, gym_env, expert_path, len(episodes))
        reproduced = [_replay(gym_env, act, seed, 1)[0] for seed, act in experts]
        actions = [np.stack([act(obs) for obs in episode[:-1]]).astype(np.float32)
                   for (_, act), episode in zip(experts, episodes)]
    elif name in REPLAYED_EXPERTS:
        experts = _demo_experts(name, env_id, gym_env, expert_path, len(episodes))
        replays = [_replay(gym_env, act, seed, len(episode) - 1) for (seed, act), episode in zip(experts, episodes)]
        reproduced, actions = [obs for obs, _ in replays], [acts for _, acts in replays]
    elif name in INVERSE_DYNAMICS:
        # both are unstable upright, so float32 actions replayed open loop drift: check each step instead
        recover, model = INVERSE_DYNAMICS[name]
        actions = [recover(observations) for observations in episodes]
        reproduced = [np.concatenate([observations[:1], model(th.as_tensor(observations[:-1]), th.as_tensor(acts)).numpy()])
                      for observations, acts in zip(episodes, actions)]  # fmt: skip
    else:
        raise ValueError(f"No action labels known for {env!r}.")
    checked = [(replayed, episode[: len(replayed)]) for replayed, episode in zip(reproduced, episodes)]
    if not all(np.allclose(replayed, shipped, atol=1e-4) for replayed, shipped in checked):
        error = max(float(np.abs(replayed - shipped).max()) for replayed, shipped in checked)
        raise RuntimeError(f"The actions do not reproduce {name}_{max(sizes)} (max error {error}).")
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    written = []
    for n in sorted(sizes):
        written.append(action_demos_path(f"{name}_{n}", out_dir))
        lengths = [len(episode) for episode in episodes[:n]]
        if len(set(lengths)) == 1:
            np.savez_compressed(written[-1], obs=np.stack(episodes[:n]), acts=np.stack(actions[:n]))
        else:  # episodes of several lengths (an expert's falls), concatenated as the shipped demos store them
            np.savez_compressed(written[-1], obs=np.concatenate(episodes[:n]), acts=np.concatenate(actions[:n]),
                                episode_lengths=np.asarray(lengths))  # fmt: skip
    return written


def main(argv: Optional[Sequence[str]] = None) -> None:
    """
    ``make-action-demos``: the action-labelled demos for BC.

    :param argv: command-line arguments
    """
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    make = commands.add_parser("make-action-demos", help="write benchmarks/action_demos/<env>_<n>_actions.npz for BC")
    make.add_argument("--env", required=True, choices=sorted(ENV_NAMES.values()))
    make.add_argument("--expert", type=Path, default=None, help="navigation: the saved PPO expert; MuJoCo: the TD3 or SAC one")
    make.add_argument("--out-dir", type=Path, default=ACTION_DEMO_DIR)
    args = parser.parse_args(argv)
    for path in make_action_demos(args.env, args.expert, args.out_dir):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
