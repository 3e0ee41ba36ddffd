"""standardise_inputs: the discriminator and the value see their inputs standardised with the demos' statistics."""

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from test_mpail import pendulum_trajectories

from sb3_mpail import MPAIL
from sb3_mpail.mppi.costs import StandardisedFeatures

TINY_PLANNER = dict(n_samples=16, horizon=3, n_iterations=2)


def make_model(demos, **policy_kwargs):
    return MPAIL("MlpMPPI", make_vec_env("Pendulum-v1", n_envs=1, seed=0), demos, n_steps=16, seed=0,
                 policy_kwargs={**TINY_PLANNER, "standardise_inputs": True, **policy_kwargs})  # fmt: skip


def demo_statistics(demos, min_scale: float):
    states = np.concatenate([np.concatenate([t.obs[:-1], t.obs[1:]]) for t in demos])
    return states.mean(0), np.maximum(states.std(0, ddof=1), min_scale)


@pytest.mark.parametrize("min_scale", [1.0, 0.1])
def test_both_networks_inputs_are_standardised_with_the_demos_statistics(min_scale):
    demos = pendulum_trajectories()
    model = make_model(demos, min_input_scale=min_scale)
    mean, scale = demo_statistics(demos, min_scale)
    for standardiser in (model.policy.discriminator_features, model.policy.value_net.features):
        assert isinstance(standardiser, StandardisedFeatures) and bool(standardiser.fitted)
        np.testing.assert_allclose(standardiser.mean.numpy(), mean, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(standardiser.scale.numpy(), scale, rtol=1e-4)
    # the discriminator's expert data are the standardised demos
    first = demos[0].obs[:-1]
    np.testing.assert_allclose(model.expert.observations[: len(first)], (first - mean) / scale, rtol=1e-4, atol=1e-5)


def test_planner_costs_score_the_standardised_transitions():
    demos = pendulum_trajectories()
    model = make_model(demos)
    policy = model.policy
    policy.set_training_mode(False)  # spectral norm's power iteration would move between the two calls
    states = th.randn(5, 3) * 4
    next_states = states + th.randn(5, 3)
    standardiser = policy.discriminator_features
    with th.no_grad():
        by_hand = -policy.discriminator(standardiser(states), None, standardiser(next_states), None)
    with th.no_grad():
        th.testing.assert_close(policy.planner.step_cost(states, next_states), by_hand)


def test_the_statistics_are_saved_and_new_demos_do_not_refit_them(tmp_path):
    model = make_model(pendulum_trajectories())
    model.learn(32)
    model.save(tmp_path / "model")
    loaded = MPAIL.load(tmp_path / "model", env=make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    loaded.set_demos(pendulum_trajectories(n=3, seed=100))
    for name in ("mean", "scale"):
        for trained, reloaded in ((model.policy.discriminator_features, loaded.policy.discriminator_features),
                                  (model.policy.value_net.features, loaded.policy.value_net.features)):  # fmt: skip
            th.testing.assert_close(getattr(reloaded, name), getattr(trained, name))
    obs = np.array([[0.5, -0.8, 2.0]], np.float32)
    assert np.array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])


def test_standardising_demos_that_are_features_already_is_refused_saying_why():
    demos = pendulum_trajectories()
    with pytest.raises(ValueError, match="standardise_inputs .* demos_are_features"):
        MPAIL("MlpMPPI", make_vec_env("Pendulum-v1", n_envs=1, seed=0), demos, demos_are_features=True,
              policy_kwargs=dict(TINY_PLANNER, standardise_inputs=True))  # fmt: skip


@pytest.mark.parametrize("setting", [dict(standardise_inputs="yes"), dict(min_input_scale=0.0)])
def test_a_bad_standardisation_setting_is_named(setting):
    with pytest.raises(ValueError, match=next(iter(setting))):
        make_model(pendulum_trajectories(), **setting)
