"""Bad expert demos are refused, or warned of, with a message that names the problem: never silently trained on."""

import dataclasses
import re
import warnings

import numpy as np
import pytest
from gymnasium import spaces
from imitation.data.rollout import flatten_trajectories
from imitation.data.types import Trajectory

from sb3_mpail.demos import load_demos

UNBOUNDED = spaces.Box(-np.inf, np.inf, (3,), np.float32)


def trajectory(observations: np.ndarray) -> Trajectory:
    return Trajectory(obs=observations, acts=np.zeros((len(observations) - 1, 1), np.float32), infos=None, terminal=True)


def episodes(n: int = 2, obs_dim: int = 3, length: int = 5) -> list:
    rng = np.random.default_rng(0)
    return [rng.uniform(-1, 1, (length + 1, obs_dim)).astype(np.float32) for _ in range(n)]


def test_demos_with_episodes_of_different_observation_sizes_are_refused_naming_them():
    first, _, third = episodes(3)
    demos = [trajectory(first), trajectory(np.zeros((6, 4), np.float32)), trajectory(third)]
    with pytest.raises(
        ValueError,
        match=re.escape(
            "The sequence of demo trajectories: the episodes' observations differ in size "
            "(obs_dim 3 in episodes [0, 2]; obs_dim 4 in episodes [1])."
        )
        + " .*same environment",
    ):
        load_demos(demos, UNBOUNDED)


def test_an_npz_of_string_observations_is_refused_as_not_numeric_naming_the_dtype(tmp_path):
    path = tmp_path / "demos.npz"
    np.savez(path, obs=np.full((2, 5, 3), "1.5"))  # numbers as text: once silently read as floats
    with pytest.raises(
        ValueError, match=re.escape(f"Demo file {path}: obs has dtype <U3, but demos must be numeric observations")
    ):
        load_demos(path, UNBOUNDED)


def test_an_npz_of_python_object_observations_is_refused_as_not_numeric_naming_the_dtype(tmp_path):
    path = tmp_path / "demos.npz"
    np.savez(path, obs=np.zeros((2, 5, 3)).astype(object))
    with pytest.raises(
        ValueError,
        match=re.escape(f"Demo file {path}: one of its arrays has dtype object, but demos must be numeric observations"),
    ):
        load_demos(path, UNBOUNDED)


def test_trajectories_and_transitions_of_string_observations_are_refused_naming_the_dtype():
    demos = [trajectory(np.full((6, 3), "a"))]
    with pytest.raises(ValueError, match=r"trajectories: episode 0 has dtype <U1, but demos must be numeric observations"):
        load_demos(demos, UNBOUNDED)
    transitions = flatten_trajectories([trajectory(first) for first in episodes()])
    transitions = dataclasses.replace(transitions, obs=transitions.obs.astype(str), next_obs=transitions.next_obs.astype(str))
    with pytest.raises(ValueError, match=r"The demo transitions' obs has dtype <U\d+, but demos must be numeric"):
        load_demos(transitions, UNBOUNDED)


def test_complex_observations_are_refused_rather_than_losing_their_imaginary_parts(tmp_path):
    complex_episodes = [episode + 1j for episode in episodes()]
    with pytest.raises(
        ValueError, match="episode 0 has complex dtype complex64, but demos must be numeric observations of real"
    ):
        load_demos([trajectory(episode) for episode in complex_episodes], UNBOUNDED)
    path = tmp_path / "demos.npz"
    np.savez(path, obs=np.stack(complex_episodes))
    with pytest.raises(ValueError, match=f"Demo file {re.escape(str(path))}: obs has complex dtype complex64.*imaginary"):
        load_demos(path, UNBOUNDED)


def test_demos_outside_a_bounded_observation_space_are_warned_of_naming_how_many_and_the_range():
    first, second = episodes()
    second[2, 1] = 5.0  # one value far outside [-1, 1], in s' of one pair and s of the next
    space = spaces.Box(np.array([-1, -1, -np.inf], np.float32), np.array([1, 1, np.inf], np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        unbounded_but_not_huge = first * np.array([1, 1, 1e5], np.float32)
        load_demos([trajectory(first), trajectory(unbounded_but_not_huge)], space)
    with pytest.warns(
        UserWarning,
        match=re.escape(
            "2 of the 60 values in the demos' (s, s') pairs lie outside the environment's observation space, in "
            "dimensions [1]: e.g. dimension 1 is bounded to [-1, 1] but the demos range over ["
        )
        + r".*, 5\]\. The demos may have been recorded in another environment, or in other units",
    ):
        load_demos([trajectory(first), trajectory(second)], space)


def test_demos_of_huge_magnitude_are_warned_of_as_exploding_the_discriminator_s_loss():
    first, second = episodes()
    first[3, 0] = 1e30
    with pytest.warns(
        UserWarning,
        match=r"2 of the values in the demos' \(s, s'\) pairs exceed 1e\+06 in magnitude \(up to 1e\+30\): such values make "
        r"the discriminator's loss explode .* Check the demos' units",
    ):
        load_demos([trajectory(first), trajectory(second)], UNBOUNDED)


@pytest.mark.parametrize("lengths", [[-2, 14], [0, 12], [6, 5.5, 0.5]], ids=["negative", "zero", "fractional"])
def test_npz_episode_lengths_that_are_not_positive_whole_numbers_are_refused_naming_them(tmp_path, lengths):
    path = tmp_path / "demos.npz"
    np.savez(path, obs=np.concatenate(episodes()), episode_lengths=np.array(lengths))  # 12 rows, as the lengths sum to
    with pytest.raises(ValueError, match=re.escape(f"Demo file {path}: episode_lengths must be positive whole numbers (each "
                                                   "episode's number of observations, T + 1); got [")):  # fmt: skip
        load_demos(path, UNBOUNDED)


def test_demo_values_beyond_float32_s_range_are_refused_saying_so_rather_than_called_infinite():
    first, second = (episode.astype(np.float64) for episode in episodes())
    first[3, 2] = 1e39  # finite in float64, infinite in float32
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nor numpy's overflow warning
        with pytest.raises(ValueError, match=r"The sequence of demo trajectories: episode 0 holds values beyond float32's "
                                             r"range \(\+-3.4e\+38\), up to 1e\+39"):  # fmt: skip
            load_demos([trajectory(first), trajectory(second)], UNBOUNDED)
