"""Observation-only demos load from every supported format and bad demos are refused with a clear reason."""

import numpy as np
import pytest
from gymnasium import spaces
from imitation.data import serialize
from imitation.data.rollout import flatten_trajectories
from imitation.data.types import Trajectory

from sb3_mpail.demos import SHIPPED_DEMO_DIR, list_shipped_demos, load_demos, shipped_demo_info, shipped_demos
from sb3_mpail.evaluation import reference_returns

SPACE = spaces.Box(-np.inf, np.inf, (3,), np.float32)


def make_trajectories(n=2, length=5):
    rng = np.random.default_rng(0)
    return [
        Trajectory(
            obs=rng.normal(size=(length + 1, 3)).astype(np.float32),
            acts=np.zeros((length, 1), np.float32),
            infos=None,
            terminal=True,
        )
        for _ in range(n)
    ]


def expected_pairs(trajectories):
    return (np.concatenate([t.obs[:-1] for t in trajectories]), np.concatenate([t.obs[1:] for t in trajectories]))


def test_trajectories_transitions_npz_and_serialized_directory_give_the_same_pairs(tmp_path):
    trajectories = make_trajectories()
    observations, next_observations = expected_pairs(trajectories)
    np.savez(tmp_path / "equal.npz", obs=np.stack([t.obs for t in trajectories]))
    np.savez(tmp_path / "ragged.npz", obs=np.concatenate([t.obs for t in trajectories]), episode_lengths=[6, 6])
    serialize.save(tmp_path / "serialized", trajectories)
    sources = [
        trajectories,
        flatten_trajectories(trajectories),
        tmp_path / "equal.npz",
        str(tmp_path / "ragged.npz"),
        tmp_path / "serialized",
    ]
    for source in sources:
        loaded = load_demos(source, SPACE)
        np.testing.assert_allclose(loaded.observations, observations, err_msg=str(type(source)))
        np.testing.assert_allclose(loaded.next_observations, next_observations, err_msg=str(type(source)))


def test_observation_shape_mismatch_names_both_shapes():
    with pytest.raises(ValueError, match=r"shape \(3,\) but the environment's observation space has shape \(4,\)"):
        load_demos(make_trajectories(), spaces.Box(-1, 1, (4,)))


def test_nan_in_demos_is_refused():
    trajectories = make_trajectories()
    trajectories[1].obs.setflags(write=True)
    trajectories[1].obs[2, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        load_demos(trajectories, SPACE)


def test_missing_path_raises_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_demos(tmp_path / "nowhere.npz", SPACE)


def test_npz_without_obs_or_with_wrong_layout_is_refused(tmp_path):
    np.savez(tmp_path / "acts.npz", acts=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="no 'obs' array"):
        load_demos(tmp_path / "acts.npz", SPACE)
    np.savez(tmp_path / "flat.npz", obs=np.zeros((10, 3)))
    with pytest.raises(ValueError, match="episode_lengths"):
        load_demos(tmp_path / "flat.npz", SPACE)


def test_unsupported_demo_type_is_refused():
    with pytest.raises(TypeError, match="demos must be"):
        load_demos(np.zeros((5, 3)), SPACE)


def test_shipped_demos_are_listed_by_family_and_size_and_load_as_observation_only_trajectories():
    names = list_shipped_demos()
    assert {"pendulum_4", "navigation_1", "navigation_4", "navigation_16", "cartpole_4", "lap_1"} <= set(names)
    assert names.index("navigation_4") < names.index("navigation_16")  # by size, not as strings
    trajectories = shipped_demos("navigation", 4)
    assert len(trajectories) == 4 and all(isinstance(trajectory, Trajectory) for trajectory in trajectories)
    assert trajectories[0].obs.shape == (101, 12) and trajectories[0].acts.shape == (100, 0)
    # the same pairs as the set's name and as its file
    observation_space = spaces.Box(-np.inf, np.inf, (12,), np.float32)
    by_trajectories = load_demos(trajectories, observation_space)
    for source in ("navigation_4", SHIPPED_DEMO_DIR / "navigation_4.npz"):
        np.testing.assert_array_equal(load_demos(source, observation_space).observations, by_trajectories.observations)


def test_every_shipped_demo_set_has_its_family_s_reference_returns_but_the_lap_s():
    for name in list_shipped_demos():
        family = name.rsplit("_", 1)[0]
        if family == "lap":  # measured by its cross-track error: no expert return to score against
            with pytest.raises(ValueError, match="NavigationLap-v0.*no random_return_mean or expert_return_mean"):
                reference_returns(shipped_demo_info(family))
            continue
        random_return, expert_return = reference_returns(shipped_demo_info(family))
        assert expert_return > random_return, name


def test_an_unknown_demo_name_lists_the_shipped_ones(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"not the name of a shipped demo set \(.*pendulum_4"):
        load_demos("pendulum_5", SPACE)
    with pytest.raises(FileNotFoundError, match=r"No shipped demo set is named 'pendulum_5'.*navigation_16"):
        shipped_demos("pendulum", 5)
    with pytest.raises(FileNotFoundError, match=r"No shipped demo family is named 'pendulums'.*pendulum"):
        shipped_demo_info("pendulums")
    # an existing file wins over a shipped set of the same name
    np.savez(tmp_path / "pendulum_4", obs=np.zeros((1, 3, 3)))
    assert len(load_demos(tmp_path / "pendulum_4.npz", SPACE).observations) == 2
