"""A deployed planner: ``predict`` is a pure function of its inputs when deterministic, and correct from many threads."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from test_mpail import make_model, pendulum_trajectories

from sb3_mpail import MPAIL
from sb3_mpail.mppi import fused
from sb3_mpail.mppi.sampling import ActionSampler

N_THREADS = 4
N_CALLS = 24


@pytest.fixture(scope="module")
def demos():
    return pendulum_trajectories()


@pytest.fixture(scope="module")
def model(demos):
    return make_model(demos, n_envs=2, policy_kwargs=dict(n_samples=64, horizon=5, n_iterations=3))


@pytest.fixture(params=["kernel", "torch"])
def planning_path(request, monkeypatch):
    """Plans through the C kernel where it is built, and through torch alone."""
    if request.param == "torch":
        monkeypatch.setattr(fused, "native_mlp", lambda mlp: None)
    return request.param


def observation_batches(n_calls=N_CALLS, n_envs=3, seed=0):
    rng = np.random.default_rng(seed)
    angles = rng.uniform(-np.pi, np.pi, (n_calls, n_envs))
    speeds = rng.uniform(-8, 8, (n_calls, n_envs))
    return np.stack([np.cos(angles), np.sin(angles), speeds], axis=-1).astype(np.float32)


def test_deterministic_predict_gives_the_same_action_for_the_same_inputs_whatever_was_planned_before(model, planning_path):
    observations = observation_batches(n_calls=3)
    first, first_plan = model.predict(observations[0], deterministic=True)
    for other in observations[1:]:  # other calls, deterministic and not, in between
        model.predict(other, deterministic=True)
        model.predict(other, deterministic=False)
    again, again_plan = model.predict(observations[0], deterministic=True)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first_plan, again_plan)
    _, plan = model.predict(observations[1], deterministic=True)
    continued = model.predict(observations[2], state=plan, episode_start=np.zeros(3, bool), deterministic=True)
    model.predict(observations[0])
    np.testing.assert_array_equal(
        continued[0], model.predict(observations[2], state=plan, episode_start=np.zeros(3, bool), deterministic=True)[0]
    )


def test_deterministic_predict_samples_afresh_for_new_inputs_and_alike_for_the_same(model, monkeypatch):
    seeds = []
    generator = model.policy.generator

    def recording_generator(deterministic=False, seed=None):
        seeds.append(seed)
        return generator(deterministic, seed)

    monkeypatch.setattr(model.policy, "generator", recording_generator)
    first, second = observation_batches(n_calls=2)
    _, plan = model.predict(first, deterministic=True)
    model.predict(second, state=plan, episode_start=np.zeros(3, bool), deterministic=True)  # the next step
    model.predict(first, deterministic=True)
    model.predict(first, state=plan, deterministic=True)  # the same observations, another plan
    # one noise sample for every step would move a warm-started plan by the same perturbations step after step
    assert seeds[0] == seeds[2] and len({seeds[0], seeds[1], seeds[3]}) == 3 and None not in seeds


def test_deterministic_predict_does_not_depend_on_the_models_seed_or_on_evaluations_during_training(
    demos, tmp_path, planning_path
):
    observations = observation_batches(n_calls=1)[0]
    # each model is made right before it learns: making one seeds the global generators the other learns with
    trained = make_model(demos, seed=1).learn(32)
    evaluation = EvalCallback(make_vec_env("Pendulum-v1", n_envs=1, seed=5), eval_freq=8, n_eval_episodes=1, verbose=0)
    evaluated = make_model(demos, seed=1).learn(32, callback=evaluation)
    actions = trained.predict(observations, deterministic=True)[0]
    np.testing.assert_array_equal(actions, evaluated.predict(observations, deterministic=True)[0])
    trained.save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model")  # unseeded: deterministic planning needs no seed
    np.testing.assert_array_equal(actions, loaded.predict(observations, deterministic=True)[0])  # bit for bit, either path


@pytest.mark.parametrize("deterministic", [True, False])
def test_predict_from_several_threads_gives_what_sequential_calls_give(model, planning_path, deterministic):
    batches = observation_batches()
    if deterministic:
        expected = [model.predict(batch, deterministic=True) for batch in batches]
    with ThreadPoolExecutor(N_THREADS) as pool:
        results = list(pool.map(lambda batch: model.predict(batch, deterministic=deterministic), batches))
    if deterministic:
        for (actions, plan), (expected_actions, expected_plan) in zip(results, expected):
            np.testing.assert_array_equal(actions, expected_actions)
            np.testing.assert_array_equal(plan, expected_plan)
    else:  # stochastic plans race for the noise stream, but each is a whole, finite plan within the bounds
        for actions, plan in results:
            assert np.isfinite(plan).all() and np.all(np.abs(actions) <= 2.0)


def test_an_empty_batch_of_observations_gets_an_empty_answer(model):
    actions, plans = model.predict(np.zeros((0, 3), np.float32))
    assert actions.shape == (0, 1) and plans.shape == (0, 5, 1)


def test_an_empty_batch_still_checks_its_state_and_episode_start(model):
    empty = np.zeros((0, 3), np.float32)
    _, plans = model.predict(np.zeros((2, 3), np.float32))
    with pytest.raises(ValueError, match=r"state must be the plans returned by predict, numbers of shape \(0, 5, 1\); got "
                                         r"float32 of shape \(2, 5, 1\)"):  # fmt: skip
        model.predict(empty, state=plans)
    with pytest.raises(ValueError, match=r"episode_start must hold one flag per env \(0, shape \(0,\)\)"):
        model.predict(empty, episode_start=[True, False])
    actions, plans = model.predict(empty, state=plans[:0], episode_start=np.zeros(0, bool))
    assert actions.shape == (0, 1) and plans.shape == (0, 5, 1)


class UnclampedSampler(ActionSampler):
    """A user's sampler that forgets to clamp its samples to the bounds: the plan plus 3 N(0, 1)."""

    def forward(self, plan, n_samples, generator):
        return self.standard_noise(plan, n_samples, generator).mul_(3.0).add_(plan.transpose(0, 1).unsqueeze(2))


@pytest.mark.parametrize("deterministic", [True, False])
def test_actions_and_plans_stay_within_the_bounds_whatever_the_sampler(demos, deterministic):
    sampler = UnclampedSampler(np.array([-2.0]), np.array([2.0]))
    model = make_model(demos, policy_kwargs=dict(n_samples=2, horizon=4, n_iterations=2, sampler=sampler))
    plans = None
    for observations in observation_batches(n_calls=4):
        actions, plans = model.predict(observations, state=plans, deterministic=deterministic)
        assert np.abs(actions).max() <= 2.0 and np.abs(plans).max() <= 2.0


def test_predict_plans_in_evaluation_mode_even_after_a_submodule_was_put_in_training_mode(model):
    """Setting the mode is skipped where every module already has it, so a submodule switched alone must be found."""
    observations = observation_batches(n_calls=1)[0]
    expected, _ = model.predict(observations, deterministic=True)
    discriminator = model.policy.discriminator
    discriminator.train()  # spectral norm's power iteration would move on every call in training mode
    assert discriminator.training
    for _ in range(3):
        actions, _ = model.predict(observations, deterministic=True)
        np.testing.assert_array_equal(actions, expected)
    assert not any(module.training for module in model.policy.modules())
