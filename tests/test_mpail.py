"""MPAIL honours Stable-Baselines3's algorithm contract and refuses bad input with a clear error."""

import json
import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from imitation.data.types import Trajectory
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_mpail import MPAIL
from sb3_mpail.mppi import ConcaveValue, DiscriminatorEnsemble, ValueEnsemble, make_value_network
from sb3_mpail.mppi.costs import member_values
from sb3_mpail.mppi.fused import Workspace
from sb3_mpail.mppi.reward_forms import REWARD_FORMS

TINY_PLANNER = dict(n_samples=16, horizon=3, n_iterations=2)


def pendulum_trajectories(n=2, length=30, seed=0):
    env = gym.make("Pendulum-v1")
    env.action_space.seed(seed)
    trajectories = []
    for index in range(n):
        observations = [env.reset(seed=seed + index)[0]]
        for _ in range(length):
            observations.append(env.step(env.action_space.sample())[0])
        trajectories.append(
            Trajectory(obs=np.array(observations), acts=np.zeros((length, 1), np.float32), infos=None, terminal=False)
        )
    return trajectories


@pytest.fixture(scope="module")
def demos():
    return pendulum_trajectories()


def make_model(demos, n_envs=1, seed=0, **kwargs):
    settings = dict(n_steps=16, seed=seed, policy_kwargs=dict(TINY_PLANNER))
    settings.update(kwargs)
    return MPAIL("MlpMPPI", make_vec_env("Pendulum-v1", n_envs=n_envs, seed=seed), demos, **settings)


def test_learn_on_two_envs_counts_exactly_the_requested_steps(demos):
    model = make_model(demos, n_envs=2).learn(64)
    assert model.num_timesteps == 64


def test_a_rollout_cut_short_by_the_budget_trains_the_value_but_not_the_discriminator(demos):
    model = make_model(demos, discriminator_update_interval=1).learn(16)
    discriminator = [p.detach().clone() for p in model.policy.discriminator.parameters()]
    value = [p.detach().clone() for p in model.policy.value_net.parameters()]
    model.learn(8, reset_num_timesteps=False)  # half a rollout: only the start of the episode
    assert model.num_timesteps == 24
    assert all(th.equal(before, after) for before, after in zip(discriminator, model.policy.discriminator.parameters()))
    assert not all(th.equal(before, after) for before, after in zip(value, model.policy.value_net.parameters()))
    model.learn(16, reset_num_timesteps=False)  # a whole rollout trains it again
    assert not all(th.equal(before, after) for before, after in zip(discriminator, model.policy.discriminator.parameters()))


def test_predict_returns_actions_of_the_right_shape_inside_the_bounds(demos):
    model = make_model(demos)
    single = np.array([1.0, 0.0, 0.5], np.float32)
    action, plan = model.predict(single)
    assert action.shape == (1,) and plan.shape == (1, 3, 1)
    batch = np.stack([single] * 5)
    actions, plans = model.predict(batch, deterministic=True)
    assert actions.shape == (5, 1) and plans.shape == (5, 3, 1)
    assert np.all(np.abs(actions) <= 2.0)
    # the plan is the recurrent state: passing it back warm-starts, episode_start resets it
    actions, _ = model.predict(batch, state=plans, episode_start=np.ones(5, bool), deterministic=True)
    assert actions.shape == (5, 1)


def test_predict_rejects_a_state_that_is_not_a_plan(demos):
    model = make_model(demos)
    with pytest.raises(ValueError, match="state must be the plans"):
        model.predict(np.zeros((2, 3), np.float32), state=np.zeros((3, 3, 1)))


def test_evaluate_policy_runs_the_planner_with_its_plans_as_state(demos):
    model = make_model(demos)
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=1)
    mean_return, std_return = evaluate_policy(model, env, n_eval_episodes=2)
    assert np.isfinite(mean_return) and -2000 < mean_return <= 0


@pytest.mark.parametrize("dynamics", ["pendulum", "learned"])
def test_same_seed_gives_same_actions_and_same_learning(demos, dynamics):
    policy_kwargs = dict(TINY_PLANNER, dynamics=dynamics)
    # 3 fits of the learned model on a buffer that overflows: replacement positions and minibatch order are seeded
    if dynamics == "learned":
        policy_kwargs["dynamics_kwargs"] = dict(buffer_size=40, batch_size=8, n_epochs=2)
    first = make_model(demos, seed=7, policy_kwargs=policy_kwargs).learn(48)
    second = make_model(demos, seed=7, policy_kwargs=policy_kwargs).learn(48)
    for (name, a), (_, b) in zip(first.policy.state_dict().items(), second.policy.state_dict().items()):
        assert th.equal(a, b), name
    observation = np.array([[0.0, 1.0, 0.0]], np.float32)
    first.set_random_seed(3)
    second.set_random_seed(3)
    assert np.array_equal(first.predict(observation)[0], second.predict(observation)[0])


def test_save_and_load_give_identical_deterministic_actions_without_demos_or_env(demos, tmp_path):
    model = make_model(demos, policy_kwargs=dict(TINY_PLANNER, dynamics="learned", dynamics_kwargs=dict(n_epochs=1)))
    model.learn(32)
    model.save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model")
    assert loaded.expert is None and loaded.env is None
    for (name, a), (_, b) in zip(model.policy.state_dict().items(), loaded.policy.state_dict().items()):
        assert th.equal(a, b), name
    assert loaded.policy.temperature.item() == pytest.approx(model.temperature())
    assert loaded.value_optimizer.state_dict()["state"], "value optimizer state was not restored"
    assert loaded.policy.dynamics.optimizer.state_dict()["state"], "dynamics optimizer state was not restored"
    observations = np.random.default_rng(0).normal(size=(4, 3)).astype(np.float32)
    model.set_random_seed(5)
    loaded.set_random_seed(5)
    np.testing.assert_array_equal(
        model.predict(observations, deterministic=True)[0], loaded.predict(observations, deterministic=True)[0]
    )
    with pytest.raises(ValueError, match="needs expert demos"):
        loaded.set_env(make_vec_env("Pendulum-v1", n_envs=1))
        loaded.learn(16)


def test_demos_are_not_written_into_the_saved_file(demos, tmp_path):
    import zipfile

    model = make_model(demos)
    model.save(tmp_path / "model.zip")
    with zipfile.ZipFile(tmp_path / "model.zip") as archive:
        saved = json.loads(archive.read("data"))
        assert "expert" not in saved and model.expert is not None  # the attribute that holds the demos is left out


def test_a_crash_while_saving_keeps_the_previous_checkpoint(demos, tmp_path, monkeypatch):
    from stable_baselines3.common.base_class import BaseAlgorithm

    model = make_model(demos)
    model.save(tmp_path / "model.zip")
    before = (tmp_path / "model.zip").read_bytes()

    def crash(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(BaseAlgorithm, "save", crash)
    with pytest.raises(RuntimeError, match="disk full"):
        model.save(tmp_path / "model.zip")
    assert (tmp_path / "model.zip").read_bytes() == before
    assert sorted(path.name for path in tmp_path.iterdir()) == ["model.zip"]


def test_checkpoint_and_eval_callbacks_work(demos, tmp_path):
    model = make_model(demos)
    eval_env = make_vec_env("Pendulum-v1", n_envs=1, seed=3)
    callbacks = [
        CheckpointCallback(save_freq=16, save_path=str(tmp_path / "checkpoints")),
        EvalCallback(eval_env, n_eval_episodes=1, eval_freq=32, log_path=str(tmp_path / "eval"), verbose=0),
    ]
    model.learn(32, callback=callbacks)
    assert sorted(path.name for path in (tmp_path / "checkpoints").iterdir()) == [
        "rl_model_16_steps.zip",
        "rl_model_32_steps.zip",
    ]
    assert MPAIL.load(tmp_path / "checkpoints" / "rl_model_32_steps.zip").num_timesteps == 32
    assert np.load(tmp_path / "eval" / "evaluations.npz")["timesteps"].tolist() == [32]


def test_a_callback_returning_false_stops_training(demos):
    class StopAfterFour(BaseCallback):
        def _on_step(self) -> bool:
            return self.n_calls < 4

    model = make_model(demos).learn(1000, callback=StopAfterFour())
    assert model.num_timesteps == 4


def test_set_env_with_a_different_number_of_envs_fails(demos):
    model = make_model(demos, n_envs=2)
    with pytest.raises(AssertionError, match="number of environments"):
        model.set_env(make_vec_env("Pendulum-v1", n_envs=3))


def test_rewards_are_the_discriminator_logit_of_the_true_transition(demos):
    model = make_model(demos, n_steps=210)  # crosses the 200-step time limit
    model.train = lambda: None  # keep the discriminator as it was when the rollout was labelled
    model.learn(210)
    buffer = model.rollout_buffer
    observations, next_observations = buffer.observations[:, 0], buffer.next_observations[:, 0]
    # inside an episode s' is the next stored s; at the time limit it is the terminal observation, not the reset one
    np.testing.assert_array_equal(next_observations[:199], observations[1:200])
    assert not np.array_equal(next_observations[199], observations[200])
    assert buffer.timeouts[199, 0] == 1 and buffer.timeouts[:199, 0].sum() == 0
    with th.no_grad():
        logits = model.policy.discriminator(
            th.as_tensor(observations[:199]), None, th.as_tensor(next_observations[:199]), None
        )
    np.testing.assert_allclose(buffer.rewards[:199, 0], logits.numpy(), rtol=1e-5, atol=1e-6)


def test_agent_reward_mean_shifts_the_priors_reward_to_that_rollout_mean_and_leaves_the_planners_costs(demos, tmp_path):
    planner = dict(TINY_PLANNER, policy_prior=True, n_proposals=2, prior_kwargs=dict(net_arch=(8,)))
    settings = dict(discriminator_update_interval=1, prior_batch_size=8, policy_kwargs=planner)
    model = make_model(demos, agent_reward_mean=0.3, **settings).learn(32)
    buffer = model.rollout_buffer
    observations, next_observations = (th.as_tensor(buffer.flat(name)) for name in ("observations", "next_observations"))
    with th.no_grad():
        trained = model._learned_reward(observations, next_observations)
        planned = -model.policy.planner.step_cost(observations, next_observations)
    assert trained.mean().item() == pytest.approx(0.3, abs=1e-5)
    assert model.reward_shift != 0.0 and th.allclose(trained, planned + model.reward_shift)
    model.save(tmp_path / "model")
    assert MPAIL.load(tmp_path / "model").reward_shift == model.reward_shift
    unshifted = make_model(demos, **settings).learn(32)
    assert unshifted.reward_shift == 0.0
    assert th.allclose(unshifted._learned_reward(observations, next_observations),
                       unshifted.policy.learned_reward(observations, next_observations))  # fmt: skip


def test_agent_reward_mean_shifts_the_rewards_the_value_learns_from(demos):
    model = make_model(demos, agent_reward_mean=0.3).learn(16)
    shift = model.reward_shift
    model.train = lambda: None  # keep the discriminator and the shift as they were when the rollout was labelled
    model.learn(16, reset_num_timesteps=False)  # inside the 200-step episode: no time-limit bootstrap
    buffer = model.rollout_buffer
    with th.no_grad():
        rewards = model.policy.learned_reward(th.as_tensor(buffer.flat("observations")),
                                              th.as_tensor(buffer.flat("next_observations")))  # fmt: skip
    assert shift != 0.0
    np.testing.assert_allclose(buffer.rewards.reshape(-1), rewards.numpy() + shift, rtol=1e-5, atol=1e-6)


def test_temperature_decays_per_episode_to_its_floor(demos):
    model = make_model(demos, temperature_decay=0.5, min_temperature=0.3)
    assert model.temperature() == 1.0
    model.episodes_completed = 1
    assert model.temperature() == pytest.approx(0.5)
    model.episodes_completed = 10
    assert model.temperature() == pytest.approx(0.3)


def test_demos_with_another_observation_shape_are_refused():
    wrong = [Trajectory(obs=np.zeros((5, 4), np.float32), acts=np.zeros((4, 1), np.float32), infos=None, terminal=True)]
    with pytest.raises(ValueError, match=r"shape \(4,\) but the environment's observation space has shape \(3,\)"):
        MPAIL("MlpMPPI", "Pendulum-v1", wrong, policy_kwargs=TINY_PLANNER)


def test_env_without_a_known_dynamics_model_is_refused(demos):
    with pytest.raises(ValueError, match="none was given for this environment"):
        MPAIL("MlpMPPI", "MountainCarContinuous-v0", None)


def test_discrete_action_space_is_refused():
    with pytest.raises(ValueError, match="continuous actions.*Discrete"):
        MPAIL("MlpMPPI", "CartPole-v1", None, policy_kwargs=dict(dynamics=lambda s, a: s))


def test_learn_with_progress_bar_and_logger_records_training_figures(demos, tmp_path):
    from stable_baselines3.common.logger import configure

    model = make_model(demos, discriminator_update_interval=1)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(32, progress_bar=True)
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    for key in ("train/discriminator_loss", "train/discriminator_accuracy", "train/value_loss", "train/temperature",
                "rollout/learned_reward_mean", "time/total_timesteps"):
        assert key in header, key


def test_shipped_pendulum_demos_match_the_environment():
    from sb3_mpail import load_demos

    transitions = load_demos("pendulum_4", gym.make("Pendulum-v1").observation_space)
    assert transitions.observations.shape == (4 * 200, 3)


def test_deterministic_predictions_during_training_leave_the_learning_unchanged(demos):
    observation = np.array([[0.0, 1.0, 0.0]], np.float32)
    models = []
    for evaluate in (False, True):
        model = make_model(demos, seed=5).learn(24)
        if evaluate:  # as an evaluation callback would, between two parts of training
            model.predict(observation, deterministic=True)
        models.append(model.learn(24, reset_num_timesteps=False))
    for (name, a), (_, b) in zip(models[0].policy.state_dict().items(), models[1].policy.state_dict().items()):
        assert th.equal(a, b), name


class Float64Observation(gym.ObservationWrapper):
    """The env's observations and observation space in float64, as gymnasium's MuJoCo envs give them."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        space = env.observation_space
        self.observation_space = gym.spaces.Box(space.low.astype(np.float64), space.high.astype(np.float64), dtype=np.float64)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return observation.astype(np.float64)


def test_float64_observations_train_and_plan_in_float32(demos):
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=0, wrapper_class=Float64Observation)
    assert env.observation_space.dtype == np.float64
    model = MPAIL("MlpMPPI", env, demos, n_steps=16, seed=0, policy_kwargs=dict(TINY_PLANNER, dynamics="learned"))
    model.learn(64)
    actions, plan = model.predict(env.reset(), deterministic=True)
    assert actions.shape == (2, 1) and np.isfinite(actions).all() and plan.dtype == np.float32


def test_learned_temperature_falls_as_the_weights_sharpen_and_is_saved(demos, tmp_path):
    model = make_model(demos, temperature="learned", temperature_learning_rate=0.05, min_temperature=0.02)
    assert model.temperature() == 1.0
    model.learn(32)
    learned = model.temperature()
    assert 0.02 <= learned < 0.5 and model.policy.temperature.item() == pytest.approx(learned)
    model.save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model")
    assert loaded.temperature() == pytest.approx(learned) and loaded.policy.temperature.item() == pytest.approx(learned)
    assert loaded.temperature_optimizer.state_dict()["state"], "the RMSprop state is saved with the model"


def test_learned_temperature_never_goes_below_its_floor(demos):
    model = make_model(demos, temperature="learned", temperature_learning_rate=0.5, min_temperature=0.2).learn(32)
    assert model.temperature() == pytest.approx(0.2)


def test_an_unknown_temperature_mode_is_refused(demos):
    with pytest.raises(ValueError, match="temperature must be one of"):
        make_model(demos, temperature="annealed")


def test_discriminator_replay_feeds_earlier_rollouts_to_later_updates_and_is_not_saved(demos, tmp_path, monkeypatch):
    model = make_model(demos, discriminator_update_interval=1, discriminator_replay_size=40)
    batch_sizes = []
    discriminator = model.policy.discriminator
    original = discriminator.forward

    def recording_forward(state, action, next_state, done):
        if discriminator.training:  # the updates, not the labelling of rewards
            batch_sizes.append(len(state))
        return original(state, action, next_state, done)

    monkeypatch.setattr(discriminator, "forward", recording_forward)
    model.learn(16)  # first rollout: nothing to replay yet
    assert model.discriminator_replay.size() == 16
    first = list(batch_sizes)
    batch_sizes.clear()
    model.learn(32, reset_num_timesteps=False)
    # every agent minibatch of a later update holds as many replayed transitions as current ones
    assert max(batch_sizes) == 2 * max(first)
    assert model.discriminator_replay.size() == 40  # FIFO capacity
    model.save(tmp_path / "model")
    assert MPAIL.load(tmp_path / "model").discriminator_replay is None


def test_the_gradient_penalty_is_the_squared_distance_of_the_discriminators_slope_from_one(demos):
    planner = dict(TINY_PLANNER, discriminator_hidden_sizes=(), use_spectral_norm=False)  # a linear logit: one slope
    model = make_model(demos, discriminator_gradient_penalty=10.0, policy_kwargs=planner)
    (layer,) = [module for module in model.policy.discriminator.modules() if isinstance(module, th.nn.Linear)]
    generator = th.Generator().manual_seed(0)
    expert, agent = [tuple(th.randn(8, 3, generator=generator) for _ in range(2)) for _ in range(2)]
    expected = (layer.weight.detach().norm() - 1) ** 2
    assert model._gradient_penalty(expert, agent).item() == pytest.approx(expected.item(), rel=1e-5)


def test_the_gradient_penalty_enters_every_discriminator_update_only_when_set(demos, monkeypatch):
    calls = []
    for weight in (0.0, 10.0):
        model = make_model(demos, discriminator_update_interval=1, discriminator_gradient_penalty=weight)
        original = model._gradient_penalty
        monkeypatch.setattr(model, "_gradient_penalty", lambda *pairs, original=original: calls.append(1) or original(*pairs))
        model.learn(16)
        assert len(calls) == (0 if weight == 0 else model.n_epochs * model.n_minibatches)
        calls.clear()


def test_a_layer_normalised_value_levels_off_far_from_the_data(demos):
    th.manual_seed(0)
    plain, bounded = make_value_network(3, (32, 32)), make_value_network(3, (32, 32), layer_norm=True)
    directions = th.randn(16, 3)
    with th.no_grad():
        plain_growth = (plain(1e6 * directions) - plain(1e3 * directions)).abs()
        bounded_growth = (bounded(1e6 * directions) - bounded(1e3 * directions)).abs()
    assert plain_growth.max() > 1e3  # a ReLU network extrapolates its slope
    assert bounded_growth.max() < 1e-3
    model = make_model(demos, policy_kwargs=dict(TINY_PLANNER, value_layer_norm=True, value_features=[0, 1]))
    assert any(isinstance(module, th.nn.LayerNorm) for module in model.policy.value_net.modules())


def test_a_concave_value_never_rises_away_from_its_peak():
    th.manual_seed(0)
    value = make_value_network(3, (32, 32), concave=True)
    points, directions = th.randn(64, 3), th.randn(64, 3)
    with th.no_grad():
        along = th.stack([value(points + step * directions).squeeze(-1) for step in th.linspace(0.0, 50.0, 26)])
    increments = along.diff(dim=0)
    # concave along every line: the increments never grow, so once the value falls it keeps falling
    assert (increments.diff(dim=0) <= 1e-4).all()
    assert (along[-1] < along.max(dim=0).values).any()


def test_a_concave_value_plans_behind_a_feature_map_and_refuses_layer_norm(demos):
    model = make_model(demos, policy_kwargs=dict(TINY_PLANNER, concave_value=True, value_features=[0, 1])).learn(16)
    assert any(isinstance(module, ConcaveValue) for module in model.policy.value_net.modules())
    with pytest.raises(ValueError, match="set value_layer_norm or concave_value, not both"):
        make_model(demos, policy_kwargs=dict(TINY_PLANNER, concave_value=True, value_layer_norm=True))


def test_a_value_ensemble_values_states_at_its_mean_less_its_spread_and_regresses_every_member(demos, tmp_path):
    planner = dict(TINY_PLANNER, value_ensemble_size=3, value_disagreement=2.0, value_features=[0, 1])
    model = make_model(demos, policy_kwargs=planner)
    ensemble = model.policy.value_net.network
    assert isinstance(ensemble, ValueEnsemble) and len(ensemble.members) == 3
    states = th.randn(5, 3)
    before = [th.cat([p.detach().flatten().clone() for p in member.parameters()]) for member in ensemble.members]
    model.learn(32)
    after = [th.cat([p.detach().flatten() for p in member.parameters()]) for member in ensemble.members]
    assert all(not th.equal(old, new) for old, new in zip(before, after))
    model.policy.set_training_mode(False)
    with th.no_grad():
        members = th.stack([member(states[:, :2])[:, 0] for member in ensemble.members])
        assert not th.allclose(members[0], members[1])  # each from its own initialisation
        assert th.allclose(member_values(model.policy.value_net, states), members)
        expected = members.mean(0) - 2.0 * members.std(0, unbiased=False)
        assert th.allclose(model.policy.value_net(states)[:, 0], expected)
        assert th.allclose(model.policy.planner.terminal_value(states), expected)
    observation = np.array([[0.5, 0.5, 0.1]], np.float32)
    action, _ = model.predict(observation, deterministic=True)
    model.save(tmp_path / "model")
    assert np.array_equal(MPAIL.load(tmp_path / "model").predict(observation, deterministic=True)[0], action)


def test_a_discriminator_ensemble_costs_its_mean_logit_less_its_spread_and_trains_every_member(demos, tmp_path):
    planner = dict(TINY_PLANNER, discriminator_ensemble_size=3, discriminator_disagreement=2.0)
    model = make_model(demos, discriminator_update_interval=1, policy_kwargs=planner)
    ensemble = model.policy.discriminator
    assert isinstance(ensemble, DiscriminatorEnsemble) and len(ensemble.members) == 3
    before = [th.cat([p.detach().flatten().clone() for p in member.parameters()]) for member in ensemble.members]
    model.learn(16)
    after = [th.cat([p.detach().flatten() for p in member.parameters()]) for member in ensemble.members]
    assert all(not th.equal(old, new) for old, new in zip(before, after))
    states, next_states = th.randn(5, 3), th.randn(5, 3)
    model.policy.set_training_mode(False)
    with th.no_grad():
        members = th.stack([member(states, None, next_states, None) for member in ensemble.members])
        expected = members.mean(0) - 2.0 * members.std(0, unbiased=False)
        assert th.allclose(ensemble(states, None, next_states, None), expected)
        assert th.allclose(model.policy.planner.step_cost(states, next_states), -expected)
    observation = np.array([[0.5, 0.5, 0.1]], np.float32)
    action, _ = model.predict(observation, deterministic=True)
    model.save(tmp_path / "model")
    assert np.array_equal(MPAIL.load(tmp_path / "model").predict(observation, deterministic=True)[0], action)


def rewards_of_a_reward_setting(demos, tmp_path, **setting) -> tuple:
    """
    Trains a tiny model with the prior under a reward ``setting`` (a policy kwarg), checks what every setting must
    hold (the planner's costs are the learned reward's negation, on the module path and summed over a horizon on the
    fast path; the setting survives save/load) and returns the discriminator's logits and the learned rewards of the
    same random transitions.
    """
    planner = dict(TINY_PLANNER, **setting, policy_prior=True, n_proposals=2, prior_kwargs=dict(net_arch=(8,)))
    model = make_model(demos, discriminator_update_interval=1, prior_batch_size=8, policy_kwargs=planner).learn(16)
    model.policy.set_training_mode(False)
    states, next_states = th.randn(2, 5, 3), th.randn(2, 5, 3)
    with th.no_grad():
        logits = model.policy.discriminator(states.view(10, 3), None, next_states.view(10, 3), None)
        rewards = model._learned_reward(states.view(10, 3), next_states.view(10, 3))
        step_costs = model.policy.planner.step_cost(states, next_states)
        horizon_states, markups = th.randn(4, 2, 5, 3), 1.1 ** th.arange(3.0)
        summed = (markups[:, None, None] * model.policy.planner.step_cost(horizon_states[:-1], horizon_states[1:])).sum(0)
        fast_path = model.policy.planner.step_cost.planning_view(3)(horizon_states, markups, Workspace())
    assert th.allclose(step_costs, -rewards.view(2, 5))
    assert th.allclose(fast_path, summed, atol=1e-5)
    model.save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model").policy
    for name, value in setting.items():
        assert getattr(loaded, name) == value
    return logits, rewards


def test_the_softplus_reward_form_pays_softplus_of_the_logit_in_planning_the_value_and_the_prior(demos, tmp_path):
    logits, rewards = rewards_of_a_reward_setting(demos, tmp_path, reward_form="softplus")
    assert (rewards > 0).all()
    assert th.allclose(rewards, th.nn.functional.softplus(logits))


def test_the_capped_reward_form_follows_the_logit_below_and_levels_off_at_log_2_above(demos, tmp_path):
    logits, rewards = rewards_of_a_reward_setting(demos, tmp_path, reward_form="capped")
    assert th.allclose(rewards, th.log(2 * th.sigmoid(logits)), atol=1e-6)
    capped = REWARD_FORMS["capped"](th.tensor([-30.0, 0.0, 30.0]))
    assert th.allclose(capped, th.tensor([-30.0 + math.log(2.0), 0.0, math.log(2.0)]))


def test_a_reward_offset_adds_to_the_learned_reward_in_planning_the_value_and_the_prior(demos, tmp_path):
    logits, rewards = rewards_of_a_reward_setting(demos, tmp_path, reward_offset=1.5)
    assert th.allclose(rewards, logits + 1.5)
