"""
Observation-only expert demonstrations: load them from any of the formats users have, as ``(s, s')`` pairs.

Accepted: a sequence of imitation ``Trajectory`` objects, imitation ``Transitions``, an ``.npz`` file, or a
directory written by ``imitation.data.serialize.save``. Only observations are read; expert actions are never
needed. An ``.npz`` file holds ``obs`` of shape ``(n_demos, T + 1, obs_dim)`` (equal-length episodes), or ``obs``
of shape ``(sum of T_i + 1, obs_dim)`` with ``episode_lengths`` giving each episode's ``T_i + 1`` observations.
"""

import os
import zipfile
import zlib
from pathlib import Path
from typing import Any, Dict, List, NamedTuple, Sequence, Union

import numpy as np
from gymnasium import spaces
from imitation.data.types import Trajectory, Transitions

DemoSource = Union[str, os.PathLike, Sequence[Trajectory], Transitions]


class ExpertTransitions(NamedTuple):
    """Expert state transitions ``(s, s')``, float32 arrays of shape ``(n_transitions, obs_dim)``."""

    observations: np.ndarray
    next_observations: np.ndarray


def _pairs_from_episodes(episodes: Sequence[np.ndarray]) -> ExpertTransitions:
    return ExpertTransitions(
        np.concatenate([episode[:-1] for episode in episodes]), np.concatenate([episode[1:] for episode in episodes])
    )


def _checked_episodes(episodes: Sequence[np.ndarray], source: str) -> List[np.ndarray]:
    """
    The episodes as float32 arrays, refusing none at all and episodes of fewer than two observations.

    :param episodes: observation arrays, ``(T_i + 1, obs_dim)`` each
    :param source: where they come from, as error messages name it (e.g. ``"Demo file demos/pendulum_4.npz"``)
    """
    if len(episodes) == 0:
        raise ValueError(f"{source} holds no episodes: expert demos need at least one episode of two or more observations.")
    episodes = [np.asarray(episode, dtype=np.float32) for episode in episodes]
    for index, episode in enumerate(episodes):
        if episode.ndim != 2 or len(episode) < 2:
            raise ValueError(
                f"{source}: episode {index} must hold at least two observations as a (T + 1, obs_dim) array; "
                f"got shape {episode.shape}."
            )
    return episodes


def _read_npz(path: Path) -> Dict[str, np.ndarray]:
    """
    The arrays of an ``.npz`` demo file, refusing a file numpy cannot read as one with its name and the problem.

    :param path: an existing file
    """
    if path.stat().st_size == 0:
        raise ValueError(f"Demo file {path} is empty (0 bytes): it holds no demos.")
    try:
        data = np.load(path, allow_pickle=False)
        arrays = None
        if not isinstance(data, np.ndarray):  # an .npy file loads as one array
            with data:
                arrays = {name: data[name] for name in data.files}
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error) as error:
        raise ValueError(
            f"Demo file {path} is not a readable .npz archive (truncated, or not written by numpy.savez): {error}"
        ) from error
    if arrays is None:
        raise ValueError(f"Demo file {path} is a single .npy array, not an .npz archive with an 'obs' array.")
    return arrays


def _episodes_from_npz(path: Path) -> List[np.ndarray]:
    data = _read_npz(path)
    if "obs" not in data:
        raise ValueError(f"Demo file {path} has no 'obs' array (it has {sorted(data)}).")
    observations = data["obs"]
    if "episode_lengths" in data:
        if observations.ndim != 2:
            raise ValueError(f"Demo file {path}: with episode_lengths, obs must be 2-D; got shape {observations.shape}.")
        lengths = data["episode_lengths"].astype(int)
        if lengths.sum() != len(observations):
            raise ValueError(
                f"Demo file {path}: episode_lengths sum to {lengths.sum()}, but obs has {len(observations)} rows."
            )
        return np.split(observations, np.cumsum(lengths)[:-1])
    if observations.ndim != 3:
        raise ValueError(
            f"Demo file {path}: obs must have shape (n_demos, T + 1, obs_dim), or come with episode_lengths; "
            f"got shape {observations.shape}."
        )
    return list(observations)


def load_demo_episodes(demos: DemoSource) -> List[np.ndarray]:
    """
    The demos' episodes as observation arrays, ``(T_i + 1, obs_dim)`` each.

    :param demos: trajectories, an ``.npz`` path or an imitation ``serialize`` directory (not ``Transitions``, which
        hold no episode boundaries)
    :raises FileNotFoundError: the path does not exist
    :raises ValueError: the file cannot be read, or there are no episodes, or an episode has fewer than two observations
    """
    if isinstance(demos, (str, os.PathLike)):
        path = Path(demos)
        if not path.exists():
            raise FileNotFoundError(f"Demo path {path} does not exist.")
        if path.is_dir():
            from imitation.data import serialize

            return _checked_episodes([trajectory.obs for trajectory in serialize.load(path)], f"Demo directory {path}")
        return _checked_episodes(_episodes_from_npz(path), f"Demo file {path}")
    if isinstance(demos, Sequence) and all(isinstance(item, Trajectory) for item in demos):
        return _checked_episodes([trajectory.obs for trajectory in demos], "The sequence of demo trajectories")
    raise TypeError(
        "demos must be a sequence of imitation Trajectory objects, imitation Transitions, an .npz file or a "
        f"directory saved by imitation.data.serialize; got {type(demos).__name__}."
    )


def load_demos(
    demos: DemoSource, observation_space: spaces.Box, space_name: str = "the environment's observation space"
) -> ExpertTransitions:
    """
    Reads expert observations and checks them against the environment's observation space.

    :param demos: trajectories, transitions, an ``.npz`` path or an imitation ``serialize`` directory
    :param observation_space: the environment's observation space (or the space the demos must have)
    :param space_name: how error messages name that space
    :return: the expert's ``(s, s')`` pairs
    :raises FileNotFoundError: the path does not exist
    :raises ValueError: shapes differ from the observation space, values are not finite, or the data is empty
    """
    if isinstance(demos, Transitions):
        transitions = ExpertTransitions(np.asarray(demos.obs, np.float32), np.asarray(demos.next_obs, np.float32))
    else:
        transitions = _pairs_from_episodes(load_demo_episodes(demos))
    expected = tuple(observation_space.shape)
    if transitions.observations.shape[1:] != expected:
        raise ValueError(
            f"Demo observations have shape {transitions.observations.shape[1:]} but {space_name} has shape {expected}."
        )
    if len(transitions.observations) == 0:
        raise ValueError("The demos contain no transitions.")
    for name, array in transitions._asdict().items():
        if not np.all(np.isfinite(array)):
            rows = np.unique(np.nonzero(~np.isfinite(array))[0])
            raise ValueError(f"Demo {name} contain NaN or infinite values (in {len(rows)} transitions, first at {rows[0]}).")
    return transitions


def normalised_score(episode_return: float, reference: Dict[str, Any]) -> float:
    """
    ``(R - random) / (expert - random)``: 0 is the random policy, 1 the expert.

    :param episode_return: an undiscounted (mean) episode return ``R``
    :param reference: a demos information file's contents (``demos/<env>.json``), with ``random_return_mean`` and
        ``expert_return_mean``
    """
    random_return, expert_return = reference["random_return_mean"], reference["expert_return_mean"]
    return float((episode_return - random_return) / (expert_return - random_return))
