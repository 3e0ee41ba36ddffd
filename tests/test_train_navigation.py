"""The navigation training command end to end in a tiny configuration, and planning with the model it saves."""

import json

import gymnasium as gym
import numpy as np
import pytest

from sb3_mpail import MPAIL
from sb3_mpail.demos import SHIPPED_DEMO_DIR, load_demos
from sb3_mpail.envs.navigation import OOD_HALF_WIDTH
from sb3_mpail.evaluation import normalised_score, reference_returns
from sb3_mpail.train_navigation import (
    DEFAULT_DEMOS,
    DEFAULT_POLICY_KWARGS,
    PAPER_POLICY_KWARGS,
    main,
    parse_args,
    reference_of,
    settings_from_args,
)

TINY = [
    "--timesteps", "200", "--n-envs", "2", "--n-steps", "50",
    "--n-samples", "8", "--horizon", "3", "--n-iterations", "1",
    "--n-eval-episodes", "2", "--n-plot-episodes", "2", "--eval-freq", "100", "--no-progress-bar",
]  # fmt: skip


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out_dir = tmp_path_factory.mktemp("navigation")
    results = main([*TINY, "--out-dir", str(out_dir)])
    return out_dir, results


def test_main_command_trains_evaluates_saves_and_plots(trained):
    out_dir, results = trained
    assert (out_dir / "model.zip").is_file()
    assert (out_dir / "navigation.png").stat().st_size > 10_000
    written = json.loads((out_dir / "results.json").read_text())
    assert written["timesteps"] == 200 and written["n_envs"] == 2
    assert written["policy_kwargs"] == dict(DEFAULT_POLICY_KWARGS, n_samples=8, horizon=3, n_iterations=1)
    assert written["algorithm_kwargs"]["n_steps"] == 50
    assert np.isfinite(written["mean_return"])
    assert written["demos"] == DEFAULT_DEMOS == "navigation_circling_4"  # the shipped demo set, by name
    assert written["normalised_score"] == pytest.approx(normalised_score(written["mean_return"], reference_of(DEFAULT_DEMOS)))
    # learning curve every 100 steps, ending with the final model's evaluation
    assert [point["steps"] for point in written["learning_curve"]] == [100, 200]
    assert written["learning_curve"][-1]["normalised_score"] == written["normalised_score"]


def test_saved_model_loads_without_demos_or_env_and_plans_in_and_out_of_distribution(trained):
    out_dir, _ = trained
    model = MPAIL.load(out_dir / "model.zip")
    assert model.expert is None and model.env is None
    for start_region in ("default", "ood"):
        env = gym.make("sb3_mpail/Navigation-v0", start_region=start_region)
        observation, _ = env.reset(seed=3)
        if start_region == "ood":
            assert np.max(np.abs(observation[:2])) <= OOD_HALF_WIDTH
        plan = None
        for step in range(5):
            action, plan = model.predict(observation, state=plan, episode_start=np.array([step == 0]), deterministic=True)
            assert action.shape == (2,) and plan.shape == (1, 3, 2)
            assert np.all(np.abs(action) <= 1.0)
            observation, *_ = env.step(action)
        assert np.all(np.isfinite(observation))


@pytest.mark.parametrize("n_demos", [1, 4, 16])
def test_shipped_demos_load_against_the_registered_env_observation_space(n_demos):
    path = SHIPPED_DEMO_DIR / f"navigation_{n_demos}.npz"
    with np.load(path, allow_pickle=False) as data:
        demo_observations = data["obs"]
    assert demo_observations.shape == (n_demos, 101, 12)
    observation_space = gym.make("sb3_mpail/Navigation-v0").observation_space
    pairs = load_demos(str(path), observation_space)
    assert len(pairs.observations) == len(pairs.next_observations) == n_demos * 100
    assert all(observation_space.contains(observation) for observation in pairs.next_observations)
    # the demos end near the goal (10, 10), as the expert's do
    assert np.all(np.hypot(demo_observations[:, -1, 0] - 10, demo_observations[:, -1, 1] - 10) < 2.0)


def test_normalised_score_is_0_for_random_and_1_for_the_expert():
    reference = reference_of(DEFAULT_DEMOS)
    random_return, expert_return = reference_returns(reference)
    assert expert_return > 1000 > 0 > random_return
    assert normalised_score(random_return, reference) == pytest.approx(0.0)
    assert normalised_score(expert_return, reference) == pytest.approx(1.0)


def test_paper_settings_and_overrides():
    paper = settings_from_args(parse_args(["--paper-settings", "--n-iterations", "2"]))
    assert paper["n_envs"] == 64
    assert paper["policy_kwargs"] == dict(PAPER_POLICY_KWARGS, n_iterations=2)
    assert paper["policy_kwargs"]["sampler"] == "gaussian"  # the paper's samples
    on_gpu = settings_from_args(parse_args(["--device", "cuda"]))
    assert on_gpu["timesteps"] == 1_000_000 and on_gpu["policy_kwargs"]["n_samples"] == 512
    default = settings_from_args(parse_args([]))
    assert default["policy_kwargs"]["n_samples"] < 512
    # the CPU defaults cost transitions with an ensemble of discriminators, the paper's settings with one
    sizes = [settings["policy_kwargs"]["discriminator_ensemble_size"] for settings in (default, paper)]
    assert sizes == [5, 1]
    single = settings_from_args(parse_args(["--discriminator-ensemble-size", "1", "--discriminator-disagreement", "1.5"]))
    expected = dict(DEFAULT_POLICY_KWARGS, discriminator_ensemble_size=1, discriminator_disagreement=1.5)
    assert single["policy_kwargs"] == expected


def test_help_says_what_each_setting_is_without_its_flag(capsys):
    with pytest.raises(SystemExit):
        parse_args(["--help"])
    help_text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    cpu, paper = DEFAULT_POLICY_KWARGS["n_samples"], PAPER_POLICY_KWARGS["n_samples"]
    assert f"--n-samples N_SAMPLES default {cpu}; paper {paper}" in help_text
    assert "--seed SEED seed of the envs, networks and planner noise (default: 0)" in help_text
    assert "(default: None)" not in help_text and "(default: False)" not in help_text


def test_missing_matplotlib_is_reported_with_the_plot_extra(monkeypatch):
    import builtins

    from sb3_mpail import plotting

    real_import = builtins.__import__

    def no_matplotlib(name, *args, **kwargs):
        if name == "matplotlib" or name.startswith("matplotlib."):
            raise ImportError("No module named 'matplotlib'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    with pytest.raises(ImportError, match=r"sb3-mpail\[plot\]"):
        plotting.import_pyplot()


def test_the_console_script_names_itself_in_its_usage_line(capsys):
    import subprocess
    import sys
    from pathlib import Path

    script = Path(sys.executable).parent / "sb3-mpail-train-navigation"  # installed by pip install -e . or the wheel
    helped = subprocess.run([str(script), "--help"], capture_output=True, text=True, timeout=120)
    assert helped.returncode == 0 and helped.stdout.startswith("usage: sb3-mpail-train-navigation ")
    with pytest.raises(SystemExit):  # from anything else (here pytest), the python -m command
        parse_args(["--help"])
    assert capsys.readouterr().out.startswith("usage: python -m sb3_mpail.train_navigation ")
