"""The policy prior of learned-model MPAIL: its proposals join MPPI's samples, its Q ensemble is the value, SAC trains it."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from test_mpail import make_model, pendulum_trajectories

from sb3_mpail import MPAIL
from sb3_mpail.prior import PolicyPrior, PriorReplay, PriorValue

PRIOR_PLANNER = dict(
    dynamics="learned",
    dynamics_kwargs=dict(hidden_sizes=(16,), n_epochs=1),
    n_samples=16,
    horizon=3,
    n_iterations=2,
    policy_prior=True,
    n_proposals=4,
    prior_kwargs=dict(net_arch=(16, 16)),
)


@pytest.fixture(scope="module")
def demos():
    return pendulum_trajectories()


def prior_model(demos, prior_kwargs=None, **kwargs):
    planner = dict(PRIOR_PLANNER, prior_kwargs=dict(PRIOR_PLANNER["prior_kwargs"], **(prior_kwargs or {})))
    return make_model(demos, n_envs=2, policy_kwargs=planner, discriminator_update_interval=1, **kwargs)


def test_the_priors_proposals_join_every_iterations_samples_inside_the_bounds(demos):
    model = prior_model(demos)
    observations = th.as_tensor(model.env.reset(), dtype=th.float32)
    last = model.policy.planner.optimise(observations, model.policy.initial_plan(2), th.tensor(1.0), th.Generator())
    assert last.samples.shape == (3, 2, 16 + 4, 1)
    proposals = last.samples[:, :, 16:]
    assert (proposals >= -2.0).all() and (proposals <= 2.0).all()
    assert not th.equal(proposals, last.samples[:, :, :4])  # drawn by the actor, not the sampler


def test_the_priors_q_ensemble_is_the_planners_value_over_any_leading_shape(demos):
    model = prior_model(demos)
    assert isinstance(model.policy.planner.terminal_value, PriorValue)
    states = th.randn(5, 2, 7, 3)
    values = model.policy.planner.terminal_value(states)
    assert values.shape == (5, 2, 7)
    np.testing.assert_allclose(values[1, 0].detach(), model.policy.prior.value(states[1, 0]).detach(), rtol=1e-6)


def test_sac_updates_fit_the_q_ensemble_to_the_learned_reward():
    prior = PolicyPrior(spaces.Box(-1, 1, (2,)), spaces.Box(-1, 1, (1,)), net_arch=(32,), learning_rate=1e-2)
    generator = th.Generator().manual_seed(0)
    states = th.randn(64, 2, generator=generator)
    actions = th.rand(64, 1, generator=generator) * 2 - 1
    rewards = states[:, :1] * 2.0  # terminal transitions: Q(s, a) should become r(s)
    dones = th.ones(64, 1)
    before = th.stack([q.detach() for q in prior.sac.critic(states, actions)])
    for _ in range(300):
        prior.update(states, actions, states, rewards, dones)
    after = th.stack([q.detach() for q in prior.sac.critic(states, actions)])
    assert (after - rewards).abs().mean() < 0.2 < (before - rewards).abs().mean()


@pytest.mark.parametrize("value_tau, weights", [(0.01, (1 / 3, 1 / 3, 1 / 3)), (0.5, (0.25, 0.25, 0.5))])
def test_a_slow_value_plans_with_the_running_mean_of_the_q_weights_then_their_polyak_average(value_tau, weights):
    prior = PolicyPrior(spaces.Box(-1, 1, (2,)), spaces.Box(-1, 1, (1,)), net_arch=(8,), value_tau=value_tau)
    generator = th.Generator().manual_seed(0)
    states, actions = th.randn(16, 2, generator=generator), th.rand(16, 1, generator=generator) * 2 - 1
    online = []
    for _ in weights:
        prior.update(states, actions, states, states[:, :1], th.ones(16, 1))
        online.append([q.detach().clone() for q in prior.sac.critic.parameters()])
    for average, *updates in zip(prior.planning_critic.parameters(), *online):
        expected = sum(weight * update for weight, update in zip(weights, updates))
        assert th.allclose(average, expected, atol=1e-6)
    mean_actions = th.tanh(prior.sac.actor.get_action_dist_params(states)[0])
    slow = th.cat(prior.planning_critic(states, mean_actions), dim=1).mean(dim=1)
    assert th.allclose(prior.value(states), slow)
    assert not th.allclose(slow, th.cat(prior.sac.critic(states, mean_actions), dim=1).mean(dim=1))


def test_a_layer_norm_critic_bounds_q_far_from_its_training_states_and_trains_its_norms():
    observation_space, action_space = spaces.Box(-1, 1, (2,)), spaces.Box(-1, 1, (1,))
    plain = PolicyPrior(observation_space, action_space, net_arch=(8, 8))
    normed = PolicyPrior(observation_space, action_space, net_arch=(8, 8), critic_layer_norm=True)
    for critic in (normed.sac.critic, normed.sac.critic_target):
        assert [sum(isinstance(layer, th.nn.LayerNorm) for layer in q) for q in critic.q_networks] == [2, 2]
    far, actions = th.full((1, 2), 1e6), th.zeros(1, 1)
    for q_network, q_value in zip(normed.sac.critic.q_networks, normed.sac.critic(far, actions)):
        last = q_network[-1]  # |Q| <= |w| sqrt(width) + |b|: a normalised feature's norm is at most sqrt(width)
        assert q_value.abs().item() <= last.weight.norm().item() * 8**0.5 + last.bias.abs().item() + 1e-4
    assert max(q.abs().item() for q in plain.sac.critic(far, actions)) > 1e3  # the plain critic extrapolates linearly
    norms = [layer.weight.detach().clone() for layer in normed.sac.critic.modules() if isinstance(layer, th.nn.LayerNorm)]
    states = th.randn(16, 2, generator=th.Generator().manual_seed(0))
    normed.update(states, th.zeros(16, 1), states, states[:, :1], th.ones(16, 1))
    trained = [layer.weight for layer in normed.sac.critic.modules() if isinstance(layer, th.nn.LayerNorm)]
    assert all(not th.equal(before, after) for before, after in zip(norms, trained))


def test_a_subset_target_is_the_minimum_of_that_many_q_networks_drawn_at_random_and_the_actor_climbs_their_mean():
    observation_space, action_space = spaces.Box(-1, 1, (2,)), spaces.Box(-1, 1, (1,))
    q_values = th.arange(5.0).repeat(3, 1)  # every row: Q networks 0..4 valued 0..4
    sac = PolicyPrior(observation_space, action_space, n_critics=5)
    assert th.equal(sac.target_minimum(q_values), th.zeros(3, 1)) and th.equal(sac.actor_q(q_values), th.zeros(3, 1))
    prior = PolicyPrior(observation_space, action_space, n_critics=5, target_critics=2)
    th.manual_seed(0)
    draws = th.cat([prior.target_minimum(q_values).T for _ in range(2000)])
    assert (draws == draws[:, :1]).all()  # one draw for the whole minibatch
    # the minimum of 2 of 5 distinct networks is network k with probability (4 - k) / 10, never the largest
    frequencies = th.stack([(draws[:, 0] == k).float().mean() for k in range(5)])
    assert th.allclose(frequencies, th.tensor([0.4, 0.3, 0.2, 0.1, 0.0]), atol=0.04)
    assert th.equal(prior.actor_q(q_values), th.full((3, 1), 2.0))  # the actor climbs the ensemble's mean, not its minimum


def test_learning_with_a_prior_trains_it_off_policy_on_every_transition_and_not_the_on_policy_value(demos):
    model = prior_model(demos, prior_batch_size=8)
    prior = [p.detach().clone() for p in model.policy.prior.parameters()]
    value = [p.detach().clone() for p in model.policy.value_net.parameters()]
    model.learn(64)
    assert model.prior_replay is not None and model.prior_replay.buffer.size() * 2 == 64  # every step of both envs
    assert not all(th.equal(before, after) for before, after in zip(prior, model.policy.prior.parameters()))
    assert all(th.equal(before, after) for before, after in zip(value, model.policy.value_net.parameters()))


@pytest.mark.parametrize(
    "prior_kwargs, settings",
    [
        ({}, {}),
        (dict(value_tau=0.1), {}),
        (dict(critic_layer_norm=True), {}),
        (dict(n_critics=5, target_critics=2), {}),
        ({}, dict(prior_return_steps=3)),
    ],
)
def test_a_seeded_run_with_a_prior_is_reproducible_and_its_reloaded_copy_plans_the_same(
    demos, tmp_path, prior_kwargs, settings
):
    first, second = (prior_model(demos, prior_kwargs, prior_batch_size=8, **settings).learn(48) for _ in range(2))
    observations = first.env.reset()
    actions = first.predict(observations, deterministic=True)[0]
    np.testing.assert_array_equal(actions, second.predict(observations, deterministic=True)[0])
    first.save(tmp_path / "prior")
    loaded = MPAIL.load(tmp_path / "prior")
    np.testing.assert_array_equal(actions, loaded.predict(observations, deterministic=True)[0])
    first.predict(observations)  # a stochastic call in between changes nothing deterministic
    np.testing.assert_array_equal(actions, first.predict(observations, deterministic=True)[0])


class RecordingPrior(PolicyPrior):
    """A prior that records the rewards, termination flags and next states its updates are given."""

    def update(self, states, unit_actions, next_states, rewards, dones, discounts=None):
        self.seen = dict(rewards=rewards.squeeze(1), dones=dones.squeeze(1), next_states=next_states, discounts=discounts)
        return {}


@pytest.mark.parametrize(
    "terminations, flags_terminations, terminal_reward_factor",
    [("cut", True, 1.0), ("bootstrap", False, 1.0), ("absorbing", True, 1 / (1 - 0.99))],
)
def test_the_priors_targets_cut_bootstrap_or_repeat_the_terminal_reward_at_terminations(
    terminations, flags_terminations, terminal_reward_factor
):
    observation_space, action_space = spaces.Box(-1, 1, (2,)), spaces.Box(-1, 1, (1,))
    prior = RecordingPrior(observation_space, action_space, net_arch=(4,), gamma=0.99)
    replay = PriorReplay(observation_space, action_space, 1, 64, 16, 1.0, th.device("cpu"), terminations)
    for terminated in [True, False] * 8:  # falls (terminations, not time-limit cuts) end in (1, 1), other steps (0.5, 0.5)
        next_state = np.full((1, 2), 1.0 if terminated else 0.5)
        replay.add(prior, np.zeros((1, 2)), next_state, np.zeros((1, 1)), np.array([terminated]), [{}])
    replay.train(prior, lambda states, next_states: next_states.sum(1), n_new_steps=1)  # 2 for a fall, 1 otherwise
    terminal = prior.seen["next_states"][:, 0] == 1.0
    assert terminal.any() and not terminal.all()
    assert th.equal(prior.seen["dones"], (terminal & flags_terminations).float())
    expected = th.where(terminal, 2.0 * terminal_reward_factor, 1.0)
    assert th.allclose(prior.seen["rewards"], expected)
    assert th.allclose(prior.seen["discounts"], th.full((16, 1), 0.99))  # one-step targets: one discount


def test_one_step_samples_are_sb3s_replay_samples_labelled_with_the_learned_reward():
    observation_space, action_space = spaces.Box(-1, 1, (3,)), spaces.Box(-1, 1, (2,))
    prior = PolicyPrior(observation_space, action_space, net_arch=(4,), gamma=0.9)
    replay = PriorReplay(observation_space, action_space, 2, 40, 16, 1.0, th.device("cpu"))
    rng = np.random.default_rng(0)
    for step in range(25):  # past the buffer's 20 steps per env: it wraps
        done = np.array([step % 7 == 6, step % 5 == 4])
        infos = [{}, {"TimeLimit.truncated": step % 10 == 4}]
        replay.add(prior, rng.normal(size=(2, 3)), rng.normal(size=(2, 3)), rng.uniform(-1, 1, (2, 2)), done, infos)

    def reward(states, next_states):
        return next_states.sum(1) - states[:, 0]

    np.random.seed(3)
    expected = replay.buffer.sample(16)
    np.random.seed(3)
    batch = replay.sample(0.9, reward)
    states, next_states = expected.observations.float(), expected.next_observations.float()
    assert th.equal(batch.states, states) and th.equal(batch.bootstrap_states, next_states)
    assert th.equal(batch.unit_actions, expected.actions.float()) and th.equal(batch.dones, expected.dones.float())
    assert th.equal(batch.returns, reward(states, next_states)[:, None])
    assert th.allclose(batch.discounts, th.full((16, 1), 0.9))


@pytest.mark.parametrize("terminations", ["cut", "bootstrap", "absorbing"])
def test_n_step_targets_sum_rewards_to_the_episode_end_or_the_newest_step_and_bootstrap_from_there(terminations):
    observation_space, action_space = spaces.Box(-100, 100, (1,)), spaces.Box(-1, 1, (1,))
    prior, gamma, n_steps = PolicyPrior(observation_space, action_space, net_arch=(4,)), 0.9, 3
    replay = PriorReplay(observation_space, action_space, 1, 12, 64, 1.0, th.device("cpu"), terminations, n_steps)
    terminal, cut_by_time_limit, newest = {4, 13}, {9}, 14
    for t in range(newest + 1):  # step t goes from state t to t + 1; 15 steps in a buffer of 12 (t = 3..14 kept)
        done, infos = np.array([t in terminal | cut_by_time_limit]), [{"TimeLimit.truncated": t in cut_by_time_limit}]
        replay.add(prior, np.array([[t]]), np.array([[t + 1.0]]), np.zeros((1, 1)), done, infos)
    np.random.seed(0)
    batch = replay.sample(gamma, lambda states, next_states: next_states[:, 0])  # step t earns t + 1
    starts = batch.states[:, 0].long().tolist()
    assert set(starts) == set(range(3, newest + 1))
    for row, t in enumerate(starts):
        end = min([e for e in terminal | cut_by_time_limit if e >= t] + [newest])
        length = min(n_steps, end - t + 1)
        last = t + length - 1
        expected = sum(gamma**k * (t + k + 1) for k in range(length))
        terminated = last in terminal
        if terminations == "absorbing" and terminated:
            expected += gamma**length * (last + 1) / (1 - gamma)
        assert batch.returns[row, 0].item() == pytest.approx(expected, rel=1e-5)
        assert batch.bootstrap_states[row, 0].item() == last + 1
        assert batch.discounts[row, 0].item() == pytest.approx(gamma**length)
        assert batch.dones[row, 0].item() == float(terminated and terminations != "bootstrap")


@pytest.mark.parametrize("used, meant", [(True, "cut"), (False, "bootstrap")])
def test_a_model_saved_before_the_termination_setting_was_renamed_and_n_step_targets_loads_with_what_it_meant(
    demos, tmp_path, used, meant
):
    import json
    import zipfile

    saved, former = tmp_path / "saved.zip", tmp_path / "former.zip"
    prior_model(demos, prior_terminations="absorbing", prior_return_steps=3).save(saved)
    with zipfile.ZipFile(saved) as archive, zipfile.ZipFile(former, "w") as rewritten:
        for member in archive.namelist():
            content = archive.read(member)
            if member == "data":
                data = json.loads(content)
                del data["prior_terminations"], data["prior_return_steps"]
                data["prior_use_terminations"] = used
                content = json.dumps(data).encode()
            rewritten.writestr(member, content)
    loaded = MPAIL.load(former)
    assert loaded.prior_terminations == meant and not hasattr(loaded, "prior_use_terminations")
    assert loaded.prior_return_steps == 1  # one-step targets, all that such a file could have trained


@pytest.mark.parametrize(
    "policy_kwargs, settings, named",
    [
        (dict(prior_kwargs=dict(n_critics=0)), {}, "n_critics"),
        (dict(prior_kwargs=dict(tau=1.5)), {}, "tau"),
        (dict(prior_kwargs=dict(value_tau=-0.1)), {}, "value_tau"),
        (dict(prior_kwargs=dict(critic_layer_norm="yes")), {}, "critic_layer_norm"),
        (dict(prior_kwargs=dict(target_critics=0)), {}, "target_critics"),
        (dict(prior_kwargs=dict(target_critics=3)), {}, "target_critics"),
        (dict(n_proposals=-1), {}, "n_proposals"),
        (dict(policy_prior="yes"), {}, "policy_prior"),
        ({}, dict(prior_updates_per_step=-1), "prior_updates_per_step"),
        ({}, dict(prior_batch_size=0), "prior_batch_size"),
        ({}, dict(prior_terminations="never"), "prior_terminations"),
        ({}, dict(prior_return_steps=0), "prior_return_steps"),
    ],
)
def test_bad_prior_settings_are_refused_naming_them(demos, policy_kwargs, settings, named):
    with pytest.raises(ValueError, match=named):
        make_model(demos, policy_kwargs={**PRIOR_PLANNER, **policy_kwargs}, **settings)
