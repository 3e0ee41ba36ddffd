"""The one evaluation helper: episodes measured one by one, in the envs' order, as SB3's evaluate_policy counts them."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

import sb3_mpail.envs  # noqa: F401  (registers the environments)
from sb3_mpail.evaluation import evaluate_episodes, normalised_score

CARTPOLE = "sb3_mpail/ContinuousCartPole-v0"


class PushRight:
    """Full force to the right: the cartpole falls within a few dozen steps, at a different step for each start."""

    def predict(self, observation, state=None, episode_start=None, deterministic=False):
        return np.ones((len(observation), 1), np.float32), state


class CountingPlan:
    """Carries a per-env step count as its recurrent state, restarted with each episode."""

    def __init__(self):
        self.seen = []

    def predict(self, observation, state=None, episode_start=None, deterministic=False):
        state = np.zeros(len(observation), int) if state is None else np.where(episode_start, 0, state + 1)
        self.seen.append(state.copy())
        return np.zeros((len(observation), 1), np.float32), state


def episode_by_hand(seed: int):
    """Return, length and observations of one PushRight episode from ``reset(seed=seed)``."""
    env = gym.make(CARTPOLE)
    observation, _ = env.reset(seed=seed)
    observations, total, done = [observation], 0.0, False
    while not done:
        observation, reward, terminated, truncated, _ = env.step(np.ones(1, np.float32))
        observations.append(observation)
        total += reward
        done = terminated or truncated
    return total, len(observations) - 1, np.stack(observations)


def test_one_episode_per_env_in_env_order_with_final_infos_and_observations():
    steps = []
    episodes = evaluate_episodes(PushRight(), CARTPOLE, 4, seed=100, on_step=lambda info, done: steps.append(done),
                                 record_observations=True)  # fmt: skip
    by_hand = [episode_by_hand(100 + i) for i in range(4)]
    assert len({length for _, length, _ in by_hand}) > 1  # the episodes end at different steps, yet keep the envs' order
    np.testing.assert_allclose(episodes.returns, [total for total, _, _ in by_hand])
    assert episodes.lengths.tolist() == [length for _, length, _ in by_hand]
    for observations, (_, length, expected) in zip(episodes.observations, by_hand):
        assert observations.shape == (length + 1, 4)
        np.testing.assert_allclose(observations, expected, rtol=1e-6)
    assert len(episodes.final_infos) == 4 and all("episode" in info for info in episodes.final_infos)
    assert sum(steps) == 4 and len(steps) == episodes.lengths.sum()  # the hook saw every counted step
    assert episodes.mean_return == pytest.approx(np.mean(episodes.returns))


def test_returns_are_evaluate_policy_s_and_episodes_may_share_an_env():
    env = make_vec_env(CARTPOLE, n_envs=2, seed=7)
    returns, lengths = evaluate_policy(PushRight(), env, n_eval_episodes=5, deterministic=True, return_episode_rewards=True)
    episodes = evaluate_episodes(PushRight(), CARTPOLE, 5, seed=7, n_envs=2)
    assert sorted(episodes.returns.tolist()) == sorted(returns) and sorted(episodes.lengths.tolist()) == sorted(lengths)
    assert episodes.observations is None


def test_the_recurrent_state_is_carried_and_restarted_with_each_episode():
    planner = CountingPlan()
    episodes = evaluate_episodes(planner, CARTPOLE, 2, seed=0, n_envs=1)
    first, second = episodes.lengths.tolist()
    assert np.concatenate(planner.seen).tolist() == list(range(first)) + list(range(second))


def test_normalised_score_is_0_at_the_random_return_and_1_at_the_expert_s():
    reference = dict(random_return_mean=-100.0, expert_return_mean=300.0)
    assert normalised_score(-100.0, reference) == 0.0 and normalised_score(300.0, reference) == 1.0
    assert normalised_score(100.0, reference) == pytest.approx(0.5)
