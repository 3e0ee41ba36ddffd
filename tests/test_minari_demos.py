"""Demos from Minari datasets: a dataset recorded here with minari's DataCollector loads as the dataset object and by
its id in the local Minari root, trains MPAIL, and every way of getting it wrong is named; without minari, an id names
the extra to install."""

import importlib.util
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from imitation.data import serialize
from imitation.data.types import Trajectory

from sb3_mpail import MPAIL
from sb3_mpail.demos import load_demo_episodes, load_demos

PENDULUM_SPACE = gym.make("Pendulum-v1").observation_space
DATASET_ID = "pendulum/random-v0"
#: steps of each recorded episode (unequal, so that episode boundaries matter)
EPISODE_STEPS = (5, 8, 12)

needs_minari = pytest.mark.skipif(
    importlib.util.find_spec("minari") is None or importlib.util.find_spec("jax") is None,
    reason="minari and its DataCollector's jax are not installed (the test install has them: minari[create])",
)


def record(dataset_id, env, episode_steps=EPISODE_STEPS):
    """
    Records random-action episodes with minari's DataCollector into the local Minari root.

    :return: the dataset, and the list of observations each episode saw, as the env returned them
    """
    from minari import DataCollector

    collector = DataCollector(env)
    collector.action_space.seed(0)
    observed = []
    for seed, steps in enumerate(episode_steps):
        observations = [collector.reset(seed=seed)[0]]
        for _ in range(steps):
            observations.append(collector.step(collector.action_space.sample())[0])
        observed.append(observations)
    dataset = collector.create_dataset(
        dataset_id=dataset_id, eval_env=env.spec, algorithm_name="random", description="random actions",
        author="sb3-mpail's tests", author_email="none@example.invalid", code_permalink="tests/test_minari_demos.py",
    )  # fmt: skip
    collector.close()
    return dataset, observed


@pytest.fixture
def minari_root(tmp_path, monkeypatch):
    """An empty local Minari root of the test's own."""
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    return tmp_path / "minari"


@pytest.fixture
def recorded(minari_root):
    """Three Pendulum-v1 episodes recorded as the dataset :data:`DATASET_ID`, and their observations."""
    return record(DATASET_ID, gym.make("Pendulum-v1"))


@needs_minari
def test_a_recorded_dataset_loads_as_the_object_and_by_id_with_each_episode_s_observations(recorded):
    dataset, observed = recorded
    expected_observations = np.concatenate([np.array(episode[:-1], np.float32) for episode in observed])
    expected_next_observations = np.concatenate([np.array(episode[1:], np.float32) for episode in observed])
    assert len(expected_observations) == sum(EPISODE_STEPS)
    for source in (dataset, DATASET_ID):
        episodes = load_demo_episodes(source)
        assert [len(episode) for episode in episodes] == [steps + 1 for steps in EPISODE_STEPS]
        transitions = load_demos(source, PENDULUM_SPACE)
        np.testing.assert_array_equal(transitions.observations, expected_observations)
        np.testing.assert_array_equal(transitions.next_observations, expected_next_observations)


@needs_minari
def test_mpail_trains_on_a_minari_dataset_given_by_id(recorded):
    model = MPAIL("MlpMPPI", "Pendulum-v1", DATASET_ID, n_steps=16, seed=0,
                  policy_kwargs=dict(n_samples=16, horizon=3, n_iterations=1))  # fmt: skip
    assert len(model.expert.observations) == sum(EPISODE_STEPS)
    model.learn(32)
    assert model.num_timesteps == 32


@needs_minari
def test_an_unknown_id_names_the_local_root_and_the_datasets_in_it(recorded, minari_root):
    with pytest.raises(FileNotFoundError) as error:
        load_demos("pendulum/expert-v3", PENDULUM_SPACE)
    message = str(error.value)
    assert "'pendulum/expert-v3'" in message and str(minari_root) in message and DATASET_ID in message


@needs_minari
def test_a_dataset_of_another_observation_shape_names_both_shapes(recorded):
    with pytest.raises(ValueError, match=r"shape \(3,\) but the environment's observation space has shape \(4,\)"):
        load_demos(recorded[0], spaces.Box(-1, 1, (4,)))


class DictObservation(gym.ObservationWrapper):
    """Pendulum-v1 with its observation under a ``"state"`` key."""

    def __init__(self, env):
        super().__init__(env)
        self.observation_space = spaces.Dict(state=env.observation_space)

    def observation(self, observation):
        return {"state": observation}


@needs_minari
def test_a_dict_observation_dataset_is_refused_with_the_wrapper_that_flattens_it(minari_root):
    dataset, _ = record("pendulum/dict-v0", DictObservation(gym.make("Pendulum-v1")), (3,))
    refusal = "Minari dataset pendulum/dict-v0 has a Dict observation space.*FlattenObservation"
    for source in (dataset, "pendulum/dict-v0"):
        with pytest.raises(ValueError, match=refusal):
            load_demos(source, PENDULUM_SPACE)


def test_without_minari_an_id_names_the_extra_and_paths_and_shipped_sets_still_load(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "minari", None)  # `import minari` now fails as if it were not installed
    with pytest.raises(ImportError, match=r"'pendulum/random-v0'.*pip install 'sb3-mpail\[minari\]'"):
        load_demos(DATASET_ID, PENDULUM_SPACE)
    # an existing path shaped like an id is a path, a shipped set's name a shipped set, a missing file a missing file
    monkeypatch.chdir(tmp_path)
    observations = np.zeros((4, 3), np.float32)
    serialize.save("pendulum/saved-v0", [Trajectory(obs=observations, acts=np.zeros((3, 1)), infos=None, terminal=True)])
    np.testing.assert_array_equal(load_demos("pendulum/saved-v0", PENDULUM_SPACE).observations, observations[:-1])
    assert len(load_demo_episodes("pendulum_4")) == 4
    with pytest.raises(FileNotFoundError, match="nowhere.npz does not exist.*Minari dataset id"):
        load_demos("nowhere.npz", PENDULUM_SPACE)
