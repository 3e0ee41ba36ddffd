"""The baselines of the benchmark grid: configs, demos for them, and one tiny training round each."""

from pathlib import Path

import numpy as np
import pytest
import torch as th
import yaml

from benchmarks.baselines import (
    ACTION_DEMO_DIR,
    ALGOS,
    META_KEYS,
    FeatureMappedRewardNet,
    action_demos_path,
    action_transitions,
    cartpole_actions,
    config_path,
    load_config,
    make_action_demos,
    make_adversarial,
    observation_only_transitions,
    pendulum_actions,
    train_baseline,
)
from sb3_mpail.demos import list_shipped_demos, shipped_demos
from sb3_mpail.evaluation import evaluate_episodes
from sb3_mpail.mppi.dynamics import PendulumDynamics
from sb3_mpail.zoo import HYPERPARAMS

ENVS = ("Pendulum-v1", "sb3_mpail/Navigation-v0")
CARTPOLE, LAP, RACETRACK = "sb3_mpail/ContinuousCartPole-v0", "sb3_mpail/NavigationLap-v0", "sb3_mpail/Racetrack-v0"
#: per algorithm, overrides that shrink a real config entry to one round of a few dozen env steps
TINY = {
    "mpail": dict(n_envs=2, n_steps=16, policy_kwargs="dict(n_samples=16, horizon=3, n_iterations=1)"),
    "mpail_om": dict(n_envs=2, n_steps=16, policy_kwargs="dict(dynamics='learned', n_samples=16, horizon=3, n_iterations=1)"),
    "mpail_one_discriminator": dict(n_envs=2, n_steps=16, policy_kwargs="dict(n_samples=16, horizon=3, n_iterations=1)"),
    "gail": dict(n_envs=2, n_steps=16, batch_size=32, n_epochs=1, n_timesteps=64),
    "airl": dict(n_envs=2, n_steps=16, batch_size=32, n_epochs=1, n_timesteps=64),
    "bc": dict(n_epochs=1),
    "irl_mpc": dict(n_envs=2, n_timesteps=64, policy_kwargs="dict(n_samples=16, horizon=3, n_iterations=1)"),
}


def tiny_configs(directory: Path) -> Path:
    """Every algorithm's hyperparameter file in ``directory``, every entry shrunk by :data:`TINY`."""
    directory.mkdir(parents=True, exist_ok=True)
    for algo in ALGOS:
        entries = yaml.safe_load(config_path(algo).read_text())
        for entry in entries.values():
            entry.update(TINY[algo])
        (directory / f"{algo}.yml").write_text(yaml.safe_dump(entries))
    return directory


def test_every_algorithm_s_config_is_in_zoo_configs_and_mpail_s_is_the_shipped_file_itself():
    assert all(config_path(algo).is_file() for algo in ALGOS)
    assert config_path("mpail").samefile(HYPERPARAMS)  # a link: no second copy to drift


#: every entry of every algorithm's file
CONFIG_ENTRIES = [(algo, env_id) for algo in ALGOS for env_id in yaml.safe_load(config_path(algo).read_text())]


@pytest.mark.parametrize("algo, env_id", CONFIG_ENTRIES)
def test_every_config_has_the_zoo_keys_and_mpail_s_budget(algo, env_id):
    entry = load_config(algo, env_id)
    assert {"n_timesteps", "n_envs", "policy", "policy_kwargs", "demos"} <= set(entry)
    assert isinstance(entry["policy_kwargs"], dict)  # a string in the file, evaluated as rl_zoo3 does
    assert entry["demos"] in list_shipped_demos()
    mpail = load_config("mpail", env_id)
    if algo != "bc":  # BC takes no env steps
        assert entry["n_timesteps"] == mpail["n_timesteps"] and entry["demos"] == mpail["demos"]


def test_irl_mpc_config_carries_and_checks_its_gail_run(tmp_path):
    entry = load_config("irl_mpc", "Pendulum-v1")
    assert entry["gail"] == load_config("gail", "Pendulum-v1")
    ensemble = ("discriminator_ensemble_size", "discriminator_disagreement")  # IRL-MPC's cost is GAIL's one reward net
    for env_id in ENVS:  # IRL-MPC plans with MPAIL's planner
        mpail = {k: v for k, v in load_config("mpail", env_id)["policy_kwargs"].items() if k not in ensemble}
        assert load_config("irl_mpc", env_id)["policy_kwargs"] == mpail
    configs = tiny_configs(tmp_path)
    irl_mpc = yaml.safe_load((configs / "irl_mpc.yml").read_text())
    irl_mpc["Pendulum-v1"]["n_timesteps"] = 999
    (configs / "irl_mpc.yml").write_text(yaml.safe_dump(irl_mpc))
    with pytest.raises(ValueError, match="n_timesteps"):
        load_config("irl_mpc", "Pendulum-v1", configs)
    with pytest.raises(ValueError, match="no entry"):
        load_config("gail", "CartPole-v1")


def test_pendulum_actions_invert_the_exact_dynamics():
    generator = th.Generator().manual_seed(0)
    angles, speeds = th.rand(50, generator=generator) * 6 - 3, th.rand(50, generator=generator) * 4 - 2
    states = th.stack([th.cos(angles), th.sin(angles), speeds], 1)
    torques = th.rand(50, 1, generator=generator) * 4 - 2
    next_states = PendulumDynamics()(states, torques)
    recovered = np.concatenate([pendulum_actions(np.stack([s, n])) for s, n in zip(states.numpy(), next_states.numpy())])
    np.testing.assert_allclose(recovered, torques.numpy(), atol=1e-4)


def test_cartpole_actions_invert_the_exact_dynamics():
    from sb3_mpail.envs.cartpole import cartpole_dynamics

    generator = th.Generator().manual_seed(0)
    states = (th.rand(50, 4, generator=generator) - 0.5) * th.tensor([4.0, 2.0, 0.4, 2.0])
    actions = th.rand(50, 1, generator=generator) * 2 - 1
    next_states = cartpole_dynamics(states, actions)
    recovered = np.concatenate([cartpole_actions(np.stack([s, n])) for s, n in zip(states.numpy(), next_states.numpy())])
    np.testing.assert_allclose(recovered, actions.numpy(), atol=1e-3)
    assert load_config("bc", CARTPOLE)["demos"] == load_config("mpail", CARTPOLE)["demos"]


def test_action_demos_match_the_shipped_observation_only_demos(tmp_path):
    labelled_sets = [name for name in list_shipped_demos() if action_demos_path(name).exists()]
    assert {"navigation_1", "navigation_4", "navigation_16", "pendulum_4", "cartpole_4"} <= set(labelled_sets)
    for name in labelled_sets:
        family, n_demos = name.rsplit("_", 1)
        episodes = [trajectory.obs for trajectory in shipped_demos(family, int(n_demos))]
        with np.load(action_demos_path(name)) as labelled:
            if "episode_lengths" in labelled:  # episodes of several lengths, concatenated
                np.testing.assert_array_equal(labelled["obs"], np.concatenate(episodes))
                assert labelled["episode_lengths"].tolist() == [len(episode) for episode in episodes]
                assert len(labelled["acts"]) == len(labelled["obs"]) - len(episodes)
            else:
                np.testing.assert_array_equal(labelled["obs"], np.stack(episodes))
                assert labelled["acts"].shape[:2] == (labelled["obs"].shape[0], labelled["obs"].shape[1] - 1)
    for env in ("pendulum", "cartpole"):  # their labels need no expert: remade from the demos
        (written,) = make_action_demos(env, out_dir=tmp_path)
        assert written == tmp_path / f"{env}_4_actions.npz"
        np.testing.assert_allclose(np.load(written)["acts"], np.load(ACTION_DEMO_DIR / f"{env}_4_actions.npz")["acts"])
    transitions = action_transitions("navigation_4")
    assert len(transitions) == 400 and np.abs(transitions.acts).sum() > 0
    hopper = action_transitions("hopper_16")  # episodes of several lengths: each step's action, no cross-episode pair
    episodes = [trajectory.obs for trajectory in shipped_demos("hopper", 16)]
    assert len(hopper) == sum(len(episode) - 1 for episode in episodes)
    np.testing.assert_array_equal(hopper.next_obs[: len(episodes[0]) - 1], episodes[0][1:])


@pytest.mark.parametrize(
    "env, demo_set",
    [("highway_traffic", "highway_traffic_16"), ("pointmaze", "pointmaze_4"), ("pointmaze_medium", "pointmaze_medium_32"),
     ("racetrack", "racetrack_4"), ("highway", "highway_4")],  # fmt: skip
)
def test_scripted_experts_action_demos_replay_through_the_shipped_observations(tmp_path, env, demo_set):
    # highway-env's IDM/MOBIL driver and lane keeping and the maze's graph expert, replayed from the demos' reset seeds,
    # reproduce every shipped observation (make_action_demos checks it) with the actions of the committed file
    (written,) = make_action_demos(env, out_dir=tmp_path / "new")
    assert written == tmp_path / "new" / f"{demo_set}_actions.npz"
    actions = np.load(written)["acts"]
    np.testing.assert_allclose(actions, np.load(ACTION_DEMO_DIR / f"{demo_set}_actions.npz")["acts"], atol=1e-4)
    assert np.abs(actions).max() <= 1.0


def test_a_mujoco_expert_checked_on_each_demos_first_step_labels_the_shipped_observations(tmp_path):
    pytest.importorskip("mujoco", reason="the MuJoCo tasks need mujoco (the scenarios extra)")
    expert = Path(__file__).parents[1] / "benchmarks" / "experts" / "halfcheetah_td3.zip"
    (written,) = make_action_demos("halfcheetah", expert_path=expert, out_dir=tmp_path)
    with np.load(written) as labelled, np.load(ACTION_DEMO_DIR / "halfcheetah_16_actions.npz") as committed:
        np.testing.assert_array_equal(labelled["obs"], committed["obs"])
        np.testing.assert_allclose(labelled["acts"], committed["acts"], atol=1e-4)


def test_a_mujoco_expert_that_did_not_make_the_demos_is_refused(tmp_path):
    pytest.importorskip("mujoco", reason="the MuJoCo tasks need mujoco (the scenarios extra)")
    from stable_baselines3 import TD3

    untrained = tmp_path / "untrained_td3.zip"
    TD3("MlpPolicy", "HalfCheetah-v4", seed=0, device="cpu").save(untrained)
    with pytest.raises(RuntimeError, match="do not reproduce halfcheetah_16"):
        make_action_demos("halfcheetah", expert_path=untrained, out_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_observation_only_transitions_pair_consecutive_states():
    from stable_baselines3.common.env_util import make_vec_env

    transitions = observation_only_transitions("navigation_1", make_vec_env("sb3_mpail/Navigation-v0", 1))
    obs = shipped_demos("navigation", 1)[0].obs
    np.testing.assert_array_equal(transitions.obs, obs[:-1])
    np.testing.assert_array_equal(transitions.next_obs, obs[1:])
    assert not transitions.acts.any()


@pytest.mark.parametrize("algo", ALGOS)
def test_each_baseline_trains_one_tiny_round_and_plans_or_acts(algo, tmp_path):
    configs = tiny_configs(tmp_path)
    hyperparams = load_config(algo, "Pendulum-v1", configs)
    evaluations = []

    def on_eval(steps, found):
        evaluations.append((steps, sorted(found)))

    predictor = train_baseline(algo, "pendulum", "pendulum_4", 0, hyperparams, 32, on_eval, timesteps=64)
    episodes = evaluate_episodes(predictor, "Pendulum-v1", 2, seed=0)
    assert episodes.lengths.tolist() == [200, 200] and np.all(np.isfinite(episodes.returns))
    if algo == "bc":
        assert evaluations == [(0, ["bc"])]
    else:
        assert evaluations[-1][0] == 64 and len(evaluations) >= 2
        assert evaluations[-1][1] == (["gail", "irl_mpc"] if algo == "irl_mpc" else [algo])


def test_adversarial_runs_are_reproducible_from_the_seed(tmp_path):
    configs = tiny_configs(tmp_path)
    runs = {}
    for algo in ("gail", "airl", "gail"):
        model = train_baseline(algo, "Pendulum-v1", "pendulum_4", 3, load_config(algo, "Pendulum-v1", configs))
        runs.setdefault(algo, []).append(th.cat([p.detach().flatten() for p in model.policy.parameters()]))
    assert th.equal(runs["gail"][0], runs["gail"][1])
    assert not th.equal(runs["gail"][0], runs["airl"][0])


def test_mpail_s_last_evaluation_sees_the_model_after_its_last_update(tmp_path):
    hyperparams = load_config("mpail", "Pendulum-v1", tiny_configs(tmp_path))
    evaluated_values = []

    def on_eval(steps, found):
        evaluated_values.append([p.detach().clone() for p in found["mpail"].policy.value_net.parameters()])

    model = train_baseline("mpail", "pendulum", "pendulum_4", 0, hyperparams, 32, on_eval, timesteps=64)
    final_values = list(model.policy.value_net.parameters())
    assert all(th.equal(evaluated, final) for evaluated, final in zip(evaluated_values[-1], final_values))


@pytest.mark.parametrize("algo, env_id", [("gail", CARTPOLE), ("airl", CARTPOLE), ("gail", LAP), ("gail", RACETRACK)])
def test_scenario_baselines_have_mpail_s_budget_demos_and_discriminator_features(algo, env_id):
    entry, mpail = load_config(algo, env_id), load_config("mpail", env_id)
    assert entry["n_timesteps"] == mpail["n_timesteps"] and entry["demos"] == mpail["demos"]
    assert entry.get("demos_are_features", False) == mpail.get("demos_are_features", False)
    assert entry["reward_net_kwargs"].get("features") == mpail["policy_kwargs"].get("discriminator_features")


def test_feature_mapped_discriminator_reads_only_its_features():
    from gymnasium import spaces

    observation_space = spaces.Box(-np.inf, np.inf, (12,), np.float32)
    # eval mode: in training mode every call takes a power-iteration step of the spectral norm
    net = FeatureMappedRewardNet(observation_space, spaces.Box(-1, 1, (2,)), [0, 1, 6, 7]).eval()
    states, next_states = th.randn(5, 12), th.randn(5, 12)
    logits = net(states, None, next_states, None)
    others = [index for index in range(12) if index not in (0, 1, 6, 7)]
    changed, changed_next = states.clone(), next_states.clone()
    changed[:, others], changed_next[:, others] = 100.0, -100.0
    assert th.equal(net(changed, None, changed_next, None), logits)
    changed[:, 6] += 1.0
    assert not th.equal(net(changed, None, changed_next, None), logits)


def test_feature_demos_are_written_at_their_indices_of_zero_states():
    from stable_baselines3.common.env_util import make_vec_env

    transitions = observation_only_transitions("lap_1", make_vec_env(LAP, 1), [0, 1, 6, 7])
    features = shipped_demos("lap", 1)[0].obs
    assert transitions.obs.shape == (len(features) - 1, 12)
    np.testing.assert_array_equal(transitions.obs[:, [0, 1, 6, 7]], features[:-1])
    np.testing.assert_array_equal(transitions.next_obs[:, [0, 1, 6, 7]], features[1:])
    assert not transitions.obs[:, [2, 3, 4, 5, 8, 9, 10, 11]].any()


def test_only_gail_reads_feature_demos():
    from stable_baselines3.common.env_util import make_vec_env

    hyperparams = {k: v for k, v in load_config("gail", LAP).items() if k not in META_KEYS}
    env = make_vec_env(LAP, 1)
    with pytest.raises(ValueError, match="Only GAIL"):
        make_adversarial("airl", env, "lap_1", 0, hyperparams)
    with pytest.raises(ValueError, match="needs reward_net_kwargs features"):
        make_adversarial("gail", env, "lap_1", 0, {**hyperparams, "reward_net_kwargs": {}})


@pytest.mark.parametrize(
    "algo, env_id, demos",
    [("gail", CARTPOLE, "cartpole_4"), ("airl", CARTPOLE, "cartpole_4"), ("gail", LAP, "lap_1")],
)
def test_cartpole_s_falling_episodes_and_the_lap_s_feature_demos_train(algo, env_id, demos, tmp_path):
    # a barely trained cartpole generator falls within 64 steps: imitation refuses that unless the config allows it
    hyperparams = load_config(algo, env_id, tiny_configs(tmp_path))
    model = train_baseline(algo, env_id, demos, 0, hyperparams, timesteps=64)
    assert model.num_timesteps == 64 and len(evaluate_episodes(model, env_id, 1, seed=0).returns) == 1
