"""The running average of the policy's weights that ``predict`` deploys while training goes on with the live weights."""

import numpy as np
import pytest
import torch as th
from test_mpail import make_model, pendulum_trajectories

from sb3_mpail import MPAIL
from sb3_mpail.averaging import PolicyAverage


@pytest.fixture(scope="module")
def demos():
    return pendulum_trajectories()


def parameters_of(policy):
    return [parameter.detach().clone() for parameter in policy.parameters()]


def test_the_average_starts_at_the_first_update_then_moves_by_its_rate_and_copies_the_buffers(demos):
    policy = make_model(demos).policy
    average = PolicyAverage(policy, rate=0.25)
    assert not average.is_started
    snapshots = []
    for step in range(3):
        with th.no_grad():
            for parameter in policy.parameters():
                parameter.add_(th.randn_like(parameter))
        policy.temperature.fill_(0.5 - 0.1 * step)
        snapshots.append(parameters_of(policy))
        average.update(policy)
    assert average.is_started
    for index, parameter in enumerate(average.policy.parameters()):
        first, second, third = (snapshot[index] for snapshot in snapshots)
        th.testing.assert_close(parameter, 0.75 * (0.75 * first + 0.25 * second) + 0.25 * third)
    assert average.policy.temperature.item() == pytest.approx(0.3)  # the live one's, not an average
    assert all(th.equal(mine, live) for mine, live in zip(average.policy.buffers(), policy.buffers()))


def test_predict_plans_with_the_average_while_training_goes_on_with_the_live_weights(demos):
    averaged = make_model(demos, n_envs=2, policy_average_rate=0.3)
    assert averaged.deployed_policy() is averaged.policy  # nothing to average before the first update
    averaged.learn(96)
    plain = make_model(demos, n_envs=2).learn(96)
    assert all(th.equal(a, b) for a, b in zip(averaged.policy.parameters(), plain.policy.parameters()))
    assert averaged.deployed_policy() is averaged.policy_average.policy
    assert any(not th.equal(a, b) for a, b in zip(averaged.policy_average.policy.parameters(), averaged.policy.parameters()))
    observations = averaged.env.reset()
    actions, plans = averaged.predict(observations, deterministic=True)
    expected_actions, expected_plans = averaged.policy_average.policy.predict(observations, deterministic=True)
    np.testing.assert_array_equal(actions, expected_actions)
    np.testing.assert_array_equal(plans, expected_plans)


def test_the_average_is_saved_and_loaded_with_the_model(demos, tmp_path):
    model = make_model(demos, policy_average_rate=0.3).learn(48)
    model.save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model", device="cpu")
    assert loaded.policy_average_rate == 0.3 and loaded.policy_average.is_started
    for mine, saved in zip(loaded.policy_average.state_dict().values(), model.policy_average.state_dict().values()):
        assert th.equal(mine, saved)
    observations = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, -0.5]], np.float32)
    np.testing.assert_array_equal(loaded.predict(observations, deterministic=True)[0],
                                  model.predict(observations, deterministic=True)[0])  # fmt: skip


def test_a_model_saved_without_an_average_loads_with_one_that_starts_at_the_next_update(demos, tmp_path):
    make_model(demos).learn(32).save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model", env=make_model(demos).env, device="cpu", policy_average_rate=0.5)
    assert loaded.policy_average_rate == 0.5 and loaded.deployed_policy() is loaded.policy
    loaded.set_demos(demos)
    loaded.learn(16, reset_num_timesteps=False)
    assert loaded.deployed_policy() is loaded.policy_average.policy
    assert all(th.equal(a, b) for a, b in zip(loaded.policy_average.policy.parameters(), loaded.policy.parameters()))


def test_loading_with_another_rate_keeps_the_saved_average_and_none_drops_it(demos, tmp_path):
    model = make_model(demos, policy_average_rate=0.3).learn(48)
    model.save(tmp_path / "model")
    faster = MPAIL.load(tmp_path / "model", device="cpu", policy_average_rate=0.6)
    assert faster.policy_average.rate == 0.6 and faster.policy_average.is_started
    saved = model.policy_average.policy.parameters()
    assert all(th.equal(a, b) for a, b in zip(faster.policy_average.policy.parameters(), saved))
    live = MPAIL.load(tmp_path / "model", device="cpu", policy_average_rate=None)
    assert live.policy_average is None and live.deployed_policy() is live.policy
    with pytest.raises(ValueError, match=r"policy_average_rate.*a number in \(0, 1\] or None"):
        MPAIL.load(tmp_path / "model", device="cpu", policy_average_rate=0.0)
