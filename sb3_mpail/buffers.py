"""Rollout storage for MPAIL: SB3's ``RolloutBuffer`` (and its GAE) plus the true next state of every step."""

import numpy as np
from stable_baselines3.common.buffers import RolloutBuffer


class TransitionRolloutBuffer(RolloutBuffer):
    """
    Stores ``(s, a, s')`` per env step during collection; rewards and values are filled afterwards for the whole
    rollout at once (the discriminator and value do not change while collecting), then SB3's
    ``compute_returns_and_advantage`` gives the GAE returns.

    ``next_observations`` holds the real successor of each step, the terminal observation at episode ends, so the
    learned reward is always ``d_theta(s_t, s_{t+1})`` and never ``(s_t, s_t)`` or a reset state.
    """

    def reset(self) -> None:
        super().reset()
        self.next_observations = np.zeros_like(self.observations)
        self.timeouts = np.zeros((self.buffer_size, self.n_envs), dtype=np.float32)

    def add_transition(
        self,
        observations: np.ndarray,
        actions: np.ndarray,
        next_observations: np.ndarray,
        episode_starts: np.ndarray,
        timeouts: np.ndarray,
    ) -> None:
        """
        :param observations: ``(n_envs, obs_dim)``
        :param actions: ``(n_envs, action_dim)``
        :param next_observations: true successors (terminal observations where an episode ended)
        :param episode_starts: whether ``observations`` start an episode
        :param timeouts: whether the episode was cut by a time limit at this step (its value is bootstrapped)
        """
        self.observations[self.pos] = observations
        self.actions[self.pos] = actions
        self.next_observations[self.pos] = next_observations
        self.episode_starts[self.pos] = episode_starts
        self.timeouts[self.pos] = timeouts
        self.pos += 1
        self.full = self.pos == self.buffer_size

    def flat(self, name: str) -> np.ndarray:
        """A stored array with the (step, env) axes merged, e.g. ``flat("observations")`` is ``(steps * envs, obs_dim)``."""
        array = getattr(self, name)
        return array.reshape(self.buffer_size * self.n_envs, *array.shape[2:])
