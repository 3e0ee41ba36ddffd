"""
Observation-only expert demonstrations: load them from any of the formats users have, as ``(s, s')`` pairs, and the
demo sets shipped with the package.

Accepted: a sequence of imitation ``Trajectory`` objects, imitation ``Transitions``, an ``.npz`` file, a directory
written by ``imitation.data.serialize.save``, the name of a shipped demo set (``"pendulum_4"``, see
:func:`list_shipped_demos`), or a Minari dataset (Farama's offline-data format; the ``minari`` extra): a
``minari.MinariDataset``, or the id of a dataset in the local Minari root (``"navigation/expert-v0"``,
``[namespace/]name-v<version>``; the root is ``$MINARI_DATASETS_PATH``, by default ``~/.minari/datasets``). A string
is read as a path if that path exists, else as a shipped demo set's name, else, if it has an id's form, as a Minari
id. Only observations are read; expert actions are never needed. An ``.npz`` file holds ``obs`` of shape
``(n_demos, T + 1, obs_dim)`` (equal-length episodes), or ``obs`` of shape ``(sum of T_i + 1, obs_dim)`` with
``episode_lengths`` giving each episode's ``T_i + 1`` observations.

The shipped demo sets are package data: ``<name>_<n>.npz`` holds ``n`` expert episodes and ``<name>.json`` the
expert's and a random policy's returns (the normalised score's 1 and 0, see
:func:`~sb3_mpail.evaluation.normalised_score`) and how the demos were made. Dropping such a pair of files into the
package's ``data`` folder ships a new set.
"""

import json
import os
import re
import sys
import warnings
import zipfile
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, List, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np
from gymnasium import spaces
from imitation.data.types import Trajectory, Transitions

if TYPE_CHECKING:
    from minari import MinariDataset

DemoSource = Union[str, os.PathLike, Sequence[Trajectory], Transitions, "MinariDataset"]

#: the shipped demo sets and their information files (package data)
SHIPPED_DEMO_DIR = Path(__file__).resolve().parent / "data"
#: a shipped demo set's name: the demos' family (its information file's name) and the number of episodes
_DEMO_SET_NAME = re.compile(r"^(?P<family>.+)_(?P<n_demos>\d+)$")
#: a Minari dataset id as Minari writes them: namespaces, a name and its version, e.g. ``"navigation/expert-v0"``
_MINARI_ID = re.compile(r"^(?:[-\w]+/)*[-\w]+-v\d+$")
#: the dtype kinds demos may hold: booleans, integers and floats
_NUMERIC_KINDS = "biuf"
#: demo values of larger magnitude are warned of: the discriminator's loss explodes on them
HUGE_DEMO_VALUE = 1e6


class ExpertTransitions(NamedTuple):
    """Expert state transitions ``(s, s')``, float32 arrays of shape ``(n_transitions, obs_dim)``."""

    observations: np.ndarray
    next_observations: np.ndarray


def _pairs_from_episodes(episodes: Sequence[np.ndarray]) -> ExpertTransitions:
    return ExpertTransitions(
        np.concatenate([episode[:-1] for episode in episodes]), np.concatenate([episode[1:] for episode in episodes])
    )


def _check_numeric(dtype: np.dtype, what: str) -> None:
    """
    Refuses observations that are not real numbers (strings, Python objects, complex numbers), naming their dtype.

    :param dtype: the observations' dtype
    :param what: what holds them, as the message names it (e.g. ``"Demo file demos/pendulum_4.npz: obs"``)
    :raises ValueError: the dtype is not boolean, integer or floating
    """
    if dtype.kind == "c":
        raise ValueError(
            f"{what} has complex dtype {dtype}, but demos must be numeric observations of real numbers: converting them "
            "to float32 would drop their imaginary parts. Store real values (e.g. the real and imaginary parts as "
            "separate observation dimensions, as the environment returns them)."
        )
    if dtype.kind not in _NUMERIC_KINDS:
        raise ValueError(
            f"{what} has dtype {dtype}, but demos must be numeric observations (floats or integers): check that the demos "
            "hold the recorded observations, and store them as numbers (e.g. array.astype(np.float32))."
        )


def _float32(array: np.ndarray, what: str) -> np.ndarray:
    """
    ``array`` as float32, refusing finite values beyond float32's range, which the cast would make infinite (NaN and
    infinite values are left to the finiteness check that follows).

    :param array: numeric observations
    :param what: what holds them, as the message names it
    :raises ValueError: a finite value lies beyond float32's range
    """
    array = np.asarray(array)
    largest = float(np.finfo(np.float32).max)
    if array.dtype.kind == "f" and array.dtype.itemsize > 4:
        magnitudes = np.abs(array[np.isfinite(array)])
        if magnitudes.size > 0 and magnitudes.max() > largest:
            raise ValueError(
                f"{what} holds values beyond float32's range (+-{largest:.2g}), up to {magnitudes.max():g}: the networks "
                "compute in float32, where they are infinite. Check the demos' units, and that they were recorded in "
                "this environment."
            )
    return array.astype(np.float32)


def _checked_episodes(episodes: Sequence[np.ndarray], source: str) -> List[np.ndarray]:
    """
    The episodes as float32 arrays, refusing none at all, non-numeric observations, episodes of fewer than two
    observations and episodes whose observations differ in size.

    :param episodes: observation arrays, ``(T_i + 1, obs_dim)`` each
    :param source: where they come from, as error messages name it (e.g. ``"Demo file demos/pendulum_4.npz"``)
    """
    if len(episodes) == 0:
        raise ValueError(f"{source} holds no episodes: expert demos need at least one episode of two or more observations.")
    episodes = [np.asarray(episode) for episode in episodes]
    episodes_by_size: Dict[int, List[int]] = {}
    for index, episode in enumerate(episodes):
        _check_numeric(episode.dtype, f"{source}: episode {index}")
        if episode.ndim != 2 or len(episode) < 2:
            raise ValueError(
                f"{source}: episode {index} must hold at least two observations as a (T + 1, obs_dim) array; "
                f"got shape {episode.shape}."
            )
        episodes_by_size.setdefault(episode.shape[1], []).append(index)
    if len(episodes_by_size) > 1:
        sizes = "; ".join(f"obs_dim {size} in episodes {indices}" for size, indices in episodes_by_size.items())
        raise ValueError(
            f"{source}: the episodes' observations differ in size ({sizes}). Every episode must come from the same "
            "environment, with the same observation space: drop the episodes recorded from another one."
        )
    return [_float32(episode, f"{source}: episode {index}") for index, episode in enumerate(episodes)]


def _read_npz(path: Path) -> Dict[str, np.ndarray]:
    """
    The arrays of an ``.npz`` demo file, refusing a file numpy cannot read as one with its name and the problem, and
    arrays of Python objects (which numpy loads only by unpickling) as not numeric.

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
        if "Object arrays cannot be loaded" in str(error):  # Python objects, which numpy loads only by unpickling
            _check_numeric(np.dtype(object), f"Demo file {path}: one of its arrays")
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
    _check_numeric(observations.dtype, f"Demo file {path}: obs")
    if "episode_lengths" in data:
        if observations.ndim != 2:
            raise ValueError(f"Demo file {path}: with episode_lengths, obs must be 2-D; got shape {observations.shape}.")
        lengths = data["episode_lengths"].reshape(-1)
        _check_numeric(lengths.dtype, f"Demo file {path}: episode_lengths")
        if not np.all((lengths >= 1) & (lengths == np.round(lengths))):
            raise ValueError(
                f"Demo file {path}: episode_lengths must be positive whole numbers (each episode's number of observations, "
                f"T + 1); got {lengths.tolist()}."
            )
        lengths = lengths.astype(int)
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


def _demo_set_order(name: str) -> Tuple[str, int]:
    match = _DEMO_SET_NAME.match(name)
    return (name, -1) if match is None else (match["family"], int(match["n_demos"]))


def list_shipped_demos() -> List[str]:
    """
    The names of the shipped demo sets, ``<family>_<n_demos>`` (e.g. ``"pendulum_4"``), by family and size: what
    :func:`shipped_demos`, :func:`load_demos`, :class:`~sb3_mpail.MPAIL` and a zoo file's ``demos:`` accept.
    """
    return sorted((path.stem for path in SHIPPED_DEMO_DIR.glob("*.npz")), key=_demo_set_order)


def _shipped_demo_path(name: str) -> Path:
    path = SHIPPED_DEMO_DIR / f"{name}.npz"
    if not path.is_file():
        shipped = ", ".join(list_shipped_demos())
        raise FileNotFoundError(f"No shipped demo set is named {name!r}; the shipped ones are {shipped}.")
    return path


def shipped_demos(name: str, n_demos: int) -> List[Trajectory]:
    """
    A shipped demo set as imitation ``Trajectory`` objects, ready for ``MPAIL(..., demos=...)``.

    The trajectories hold the expert's observations only: their ``acts`` have zero width, ``(T, 0)``, since the demos
    hold no actions (BC-style learners that need them cannot use these).

    :param name: the demos' family, e.g. ``"pendulum"`` or ``"navigation"``
    :param n_demos: how many episodes the set holds (``list_shipped_demos()`` names the sets, ``<name>_<n_demos>``)
    :raises FileNotFoundError: no such set is shipped (the message lists those that are)
    """
    episodes = _episodes_from_npz(_shipped_demo_path(f"{name}_{n_demos}"))
    return [
        Trajectory(obs=episode, acts=np.zeros((len(episode) - 1, 0), np.float32), infos=None, terminal=True)
        for episode in episodes
    ]


def shipped_demo_info(name: str) -> Dict[str, Any]:
    """
    A shipped demo family's information file: the expert's and a random policy's mean returns
    (``expert_return_mean``, ``random_return_mean``, the normalised score's reference), the expert and the command
    that made the demos.

    :param name: the demos' family, e.g. ``"navigation"``
    :raises FileNotFoundError: no such family is shipped (the message lists those that are)
    """
    path = SHIPPED_DEMO_DIR / f"{name}.json"
    if not path.is_file():
        families = sorted(info.stem for info in SHIPPED_DEMO_DIR.glob("*.json"))
        raise FileNotFoundError(f"No shipped demo family is named {name!r}; the shipped ones are {', '.join(families)}.")
    return json.loads(path.read_text())


def shipped_family(demos: Any) -> Optional[str]:
    """
    The shipped demo family of ``demos`` when they name a shipped set (``"navigation_circling_4"`` ->
    ``"navigation_circling"``), whose information file (:func:`shipped_demo_info`) the normalised score is measured
    against; ``None`` for anything else (a path, a dataset, trajectories).

    :param demos: demos as :class:`~sb3_mpail.MPAIL` takes them
    """
    if isinstance(demos, str) and demos in list_shipped_demos():
        return _demo_set_order(demos)[0]
    return None


def _is_minari_dataset(demos: Any) -> bool:
    minari = sys.modules.get("minari")  # a MinariDataset exists only once minari is imported
    return minari is not None and isinstance(demos, minari.MinariDataset)


def _minari_episodes(dataset: "MinariDataset") -> List[np.ndarray]:
    """
    The observations of a Minari dataset's episodes, refusing observation spaces that are not a flat ``Box``.

    :param dataset: a ``minari.MinariDataset``
    :raises ValueError: its observations are not a ``Box`` (a ``Dict`` or ``Tuple`` space), or it has no usable episodes
    """
    source = f"Minari dataset {dataset.spec.dataset_id}"
    if not isinstance(dataset.observation_space, spaces.Box):
        raise ValueError(
            f"{source} has a {type(dataset.observation_space).__name__} observation space, but demos must be flat "
            "Box observations: record the dataset from the env wrapped in gymnasium's FlattenObservation, and train on "
            "the env wrapped the same way."
        )
    return _checked_episodes([episode.observations for episode in dataset.iterate_episodes()], source)


def _local_minari_dataset(dataset_id: str) -> "MinariDataset":
    """
    The dataset of that id in the local Minari root.

    :param dataset_id: ``[namespace/]name-v<version>``
    :raises ImportError: minari is not installed (the message names the extra)
    :raises FileNotFoundError: the local root has no such dataset (the message names the root and the datasets in it)
    """
    try:
        import minari
    except ImportError as error:
        raise ImportError(
            f"Demo source {dataset_id!r} is not an existing path or a shipped demo set, and reading it as a Minari dataset "
            "id needs minari, which is not installed: pip install 'sb3-mpail[minari]'."
        ) from error
    try:
        return minari.load_dataset(dataset_id)
    except FileNotFoundError:
        from minari.storage import get_dataset_path

        local = ", ".join(minari.list_local_datasets()) or "none"
        raise FileNotFoundError(
            f"Demo source {dataset_id!r} is not an existing path or a shipped demo set, nor a dataset in the local Minari "
            f"root {get_dataset_path()} (set by MINARI_DATASETS_PATH), which holds: {local}. A remote dataset is "
            "downloaded with `minari download <id>`."
        ) from None


def load_demo_episodes(demos: DemoSource) -> List[np.ndarray]:
    """
    The demos' episodes as observation arrays, ``(T_i + 1, obs_dim)`` each.

    :param demos: trajectories, an ``.npz`` path, an imitation ``serialize`` directory, the name of a shipped demo
        set, a ``minari.MinariDataset`` or a local Minari dataset's id (not ``Transitions``, which hold no episode
        boundaries); a string is a path if it exists, else a shipped name, else, of the form
        ``[namespace/]name-v<version>``, a Minari id
    :raises FileNotFoundError: the path does not exist, no shipped demo set has that name and no local Minari dataset
        that id
    :raises ImportError: a Minari id is given and minari is not installed
    :raises ValueError: the file cannot be read, or there are no episodes, or an episode has fewer than two
        observations, or observations are not real numbers or differ in size between episodes, or a Minari dataset's
        observations are not a ``Box``
    """
    if _is_minari_dataset(demos):
        return _minari_episodes(demos)
    if isinstance(demos, (str, os.PathLike)):
        path = Path(demos)
        if not path.exists():
            if str(demos) in list_shipped_demos():
                path = SHIPPED_DEMO_DIR / f"{demos}.npz"
            elif isinstance(demos, str) and _MINARI_ID.match(demos):
                return _minari_episodes(_local_minari_dataset(demos))
            else:
                raise FileNotFoundError(
                    f"Demo path {path} does not exist, and it is not the name of a shipped demo set "
                    f"({', '.join(list_shipped_demos())}) or a Minari dataset id ([namespace/]name-v<version>)."
                )
        if path.is_dir():
            from imitation.data import serialize

            return _checked_episodes([trajectory.obs for trajectory in serialize.load(path)], f"Demo directory {path}")
        return _checked_episodes(_episodes_from_npz(path), f"Demo file {path}")
    if isinstance(demos, Sequence) and all(isinstance(item, Trajectory) for item in demos):
        return _checked_episodes([trajectory.obs for trajectory in demos], "The sequence of demo trajectories")
    raise TypeError(
        "demos must be a sequence of imitation Trajectory objects, imitation Transitions, an .npz file, a "
        f"directory saved by imitation.data.serialize or a Minari dataset; got {type(demos).__name__}."
    )


def load_demos(
    demos: DemoSource, observation_space: spaces.Box, space_name: str = "the environment's observation space"
) -> ExpertTransitions:
    """
    Reads expert observations and checks them against the environment's observation space, warning of values that
    hint at demos of another environment (:func:`check_demos_fit_space`).

    :param demos: trajectories, transitions, an ``.npz`` path, an imitation ``serialize`` directory, the name of a
        shipped demo set (:func:`list_shipped_demos`), a ``minari.MinariDataset`` or a local Minari dataset's id
        (:func:`load_demo_episodes` tells them apart)
    :param observation_space: the environment's observation space (or the space the demos must have)
    :param space_name: how error messages name that space
    :return: the expert's ``(s, s')`` pairs
    :raises FileNotFoundError: the path does not exist, no shipped demo set has that name and no local Minari dataset
        that id
    :raises ImportError: a Minari id is given and minari is not installed
    :raises ValueError: shapes differ from the observation space or between episodes, values are not finite or not
        real numbers, or the data is empty
    """
    if isinstance(demos, Transitions):
        for name in ("obs", "next_obs"):
            _check_numeric(np.asarray(getattr(demos, name)).dtype, f"The demo transitions' {name}")
        transitions = ExpertTransitions(
            *(_float32(getattr(demos, name), f"The demo transitions' {name}") for name in ("obs", "next_obs"))
        )
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
    check_demos_fit_space(transitions, observation_space, space_name)
    return transitions


def check_demos_fit_space(
    transitions: ExpertTransitions, observation_space: spaces.Box, space_name: str = "the environment's observation space"
) -> None:
    """
    Warns of demo values that hint the demos do not belong to the environment (or are in other units): values outside
    the space's finite bounds, and values of a magnitude above :data:`HUGE_DEMO_VALUE`.

    :param transitions: finite expert ``(s, s')`` pairs of the space's shape
    :param observation_space: the space the demos must lie in
    :param space_name: how warnings name that space
    """
    values = np.concatenate(transitions).reshape(2 * len(transitions.observations), -1)
    # the bounds as float32, as the demos are, so that a value on a float64 bound is not pushed past it by rounding
    low, high = (bound.astype(np.float32).reshape(-1) for bound in (observation_space.low, observation_space.high))
    outside = (values < low) | (values > high)
    if outside.any():
        dimensions = np.flatnonzero(outside.any(axis=0))
        first = dimensions[0]
        warnings.warn(
            f"{np.count_nonzero(outside)} of the {outside.size} values in the demos' (s, s') pairs lie outside "
            f"{space_name}, in dimensions {dimensions.tolist()}: e.g. dimension {first} is bounded to "
            f"[{low[first]:g}, {high[first]:g}] but the demos range over [{values[:, first].min():g}, "
            f"{values[:, first].max():g}]. The demos may have been recorded in another environment, or in other units: "
            "check that they match this one.",
            UserWarning,
            stacklevel=3,
        )
    magnitudes = np.abs(values)
    huge = magnitudes > HUGE_DEMO_VALUE
    if huge.any():
        warnings.warn(
            f"{np.count_nonzero(huge)} of the values in the demos' (s, s') pairs exceed {HUGE_DEMO_VALUE:g} in magnitude "
            f"(up to {magnitudes.max():g}): such values make the discriminator's loss explode (to 4.6e24 on demos "
            "of 1e30). Check the demos' units, and that they were recorded in this environment.",
            UserWarning,
            stacklevel=3,
        )
