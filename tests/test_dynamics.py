"""Dynamics models: exact where the simulator is known, learnable where it is not, clear errors otherwise."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_mpail.mppi import KinematicBicycle, LearnedDynamics, PendulumDynamics, TransitionReplayBuffer, make_dynamics
from sb3_mpail.mppi.dynamics import ParkingKinematics, PointMassDynamics
from sb3_mpail.mppi.highway_dynamics import HighwayKinematics
from sb3_mpail.mppi.planner import rollout


def test_pendulum_model_predicts_gymnasium_pendulum_exactly():
    env = gym.make("Pendulum-v1")
    observation, _ = env.reset(seed=0)
    model = PendulumDynamics()
    rng = np.random.default_rng(0)
    for _ in range(200):
        action = rng.uniform(-3, 3, size=1).astype(np.float32)  # out-of-range torques are clipped by both
        predicted = model(th.as_tensor(observation[None]), th.as_tensor(action[None]))[0].numpy()
        observation, *_ = env.step(action)
        np.testing.assert_allclose(predicted, observation, atol=1e-5)


def test_bicycle_drives_straight_and_turns_left_for_positive_steering():
    model = KinematicBicycle(wheelbase=0.325, max_speed=3.0, max_steer=0.488, dt=0.1)
    state = th.zeros(2, 12)
    next_state = model(state, th.tensor([[1.0, 0.0], [1.0, 1.0]]))
    assert next_state[0, 0].item() == pytest.approx(0.3)  # 3 m/s for 0.1 s along x
    assert next_state[0, 1].item() == pytest.approx(0.0)
    assert next_state[1, 5].item() == pytest.approx(3.0 * np.tan(0.488) / 0.325 * 0.1, rel=1e-5)
    assert next_state[1, 11].item() == pytest.approx(3.0 * np.tan(0.488) / 0.325, rel=1e-5)
    assert next_state[:, 6].tolist() == pytest.approx([3.0, 3.0])


def test_learned_dynamics_fits_a_known_linear_system():
    rng = np.random.default_rng(0)
    a_matrix = np.array([[0.9, 0.1], [-0.2, 0.95]], np.float32)
    b_matrix = np.array([[0.5], [1.0]], np.float32)
    states = rng.normal(size=(2000, 2)).astype(np.float32)
    actions = rng.uniform(-1, 1, size=(2000, 1)).astype(np.float32)
    next_states = states @ a_matrix.T + actions @ b_matrix.T
    model = LearnedDynamics(2, 1, hidden_sizes=(64, 64), n_epochs=30, batch_size=256, seed=0)
    th.manual_seed(0)
    model.fit(states, actions, next_states)
    test_states = th.as_tensor(rng.normal(size=(500, 2)).astype(np.float32))
    test_actions = th.as_tensor(rng.uniform(-1, 1, size=(500, 1)).astype(np.float32))
    with th.no_grad():
        error = model(test_states, test_actions) - (
            test_states @ th.as_tensor(a_matrix).T + test_actions @ th.as_tensor(b_matrix).T
        )
    assert error.abs().mean().item() < 0.05
    assert model.current_learning_rate() == pytest.approx(1e-3 * 0.9**2)  # 30 epochs, decay every 15


def test_replay_buffer_keeps_several_episodes_and_replaces_old_ones_at_random():
    buffer = TransitionReplayBuffer(capacity=100, state_dim=1, action_dim=1, seed=0)
    for episode in range(3):  # 3 x 40 transitions: the third overflows the capacity
        marks = np.full((40, 1), episode, np.float32)
        buffer.add(marks, marks, marks)
    kept = buffer.states[:, 0]
    assert buffer.size == 100
    assert set(np.unique(kept)) == {0.0, 1.0, 2.0}
    assert (kept == 2).sum() == 40
    # the last 20 of episode 2 replaced random old entries, not simply the oldest ones
    assert 0 < (kept[:40] == 0).sum() < 40 or 0 < (kept[40:80] == 1).sum() < 40


def test_missing_dynamics_names_how_to_give_one():
    box = spaces.Box(-1, 1, (3,))
    with pytest.raises(ValueError, match="policy_kwargs=dict\\(dynamics=...\\)"):
        make_dynamics(None, box, spaces.Box(-1, 1, (1,)))


def test_dynamics_returning_the_wrong_shape_is_rejected():
    with pytest.raises(ValueError, match="must return next states"):
        make_dynamics(lambda s, a: s[:, :2], spaces.Box(-1, 1, (3,)), spaces.Box(-1, 1, (1,)))


def test_plain_callable_is_used_as_dynamics():
    model = make_dynamics(lambda s, a: s + a, spaces.Box(-1, 1, (2,)), spaces.Box(-1, 1, (2,)))
    assert th.equal(model(th.ones(1, 2), th.ones(1, 2)), th.full((1, 2), 2.0))


@pytest.mark.parametrize(
    "model, state_dim, action_dim",
    [(KinematicBicycle(), 12, 2), (ParkingKinematics(), 12, 2), (PointMassDynamics(), 6, 2), (HighwayKinematics(), 6, 2)],
)
def test_models_keep_the_state_dims_they_declare_held(model, state_dim, action_dim):
    # the planner's kernel costs these dimensions at their initial values: they must not move, bit for bit
    generator = th.Generator().manual_seed(0)
    initial_states = th.randn(3, state_dim, generator=generator)
    actions = th.rand(10, 3, 8, action_dim, generator=generator) * 2.4 - 1.2  # some beyond the bounds
    with th.no_grad():
        states = rollout(model, initial_states, actions)
    held = list(model.held_state_dims)
    assert all(0 <= dim < state_dim for dim in held)
    assert th.equal(states[..., held], initial_states[:, None, held].expand_as(states[..., held]))
    moving = [dim for dim in range(state_dim) if dim not in held]
    assert not th.equal(states[..., moving], initial_states[:, None, moving].expand_as(states[..., moving]))
