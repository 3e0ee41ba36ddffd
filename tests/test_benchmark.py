"""The benchmark runner: its grid, resuming, and the report it writes."""

import json

import numpy as np
import pytest
import torch as th
from test_baselines import tiny_configs

from benchmarks import runner
from benchmarks.report import DETERMINISTIC_NOISE, SAME_NOISE
from benchmarks.runner import TRUE_REWARD_LABEL, main, make_jobs, mean_ci, ood_measures, steps_summary
from sb3_mpail import MPAIL
from sb3_mpail.demos import shipped_demo_info
from sb3_mpail.evaluation import normalised_score


def test_gail_and_irl_mpc_share_a_run_and_seeds_come_first():
    jobs = make_jobs(["pendulum"], ["bc", "irl_mpc", "gail", "mpail"], [4], [0, 1])
    assert [(job["algos"], job["seed"]) for job in jobs] == [
        (("mpail",), 0), (("bc",), 0), (("gail", "irl_mpc"), 0), (("mpail",), 1), (("bc",), 1), (("gail", "irl_mpc"), 1),
    ]  # fmt: skip
    assert {job["env_id"] for job in jobs} == {"Pendulum-v1"}


def test_statistics():
    mean, half_width = mean_ci([1.0, 2.0, 3.0])
    assert mean == 2.0 and half_width == pytest.approx(4.303 / 3**0.5, rel=1e-3)  # t(0.975, 2) = 4.303
    runs = [dict(steps_to_target=s) for s in (1000, None, 3000)]
    assert steps_summary(runs) == "2000 (2/3)" and steps_summary(runs[1:2]) == "not reached (0/1)"


def test_runner_writes_results_and_report(tmp_path):
    configs, results, report = tiny_configs(tmp_path / "configs"), tmp_path / "results", tmp_path / "BENCHMARKS.md"
    arguments = ["--envs", "pendulum", "navigation", "--algos", "gail", "irl_mpc", "bc", "--demos", "4", "--seeds", "1",
                 "--config-dir", str(configs), "--results-dir", str(results), "--report-file", str(report),
                 "--figures-dir", str(tmp_path / "figures"), "--eval-episodes", "2", "--ood-episodes", "3"]  # fmt: skip
    main(arguments)
    written = sorted(path.relative_to(results).as_posix() for path in results.rglob("*.json"))
    assert written == sorted(
        [f"{env}/{algo}_4demos_seed0.json" for env in ("navigation", "pendulum") for algo in ("bc", "gail", "irl_mpc")]
        + ["navigation_true_reward/3starts.json"]
    )
    gail = json.loads((results / "navigation" / "gail_4demos_seed0.json").read_text())
    assert gail["shared_run"] == ["gail", "irl_mpc"] and gail["curve"][-1][0] == 64
    assert len(gail["ood"]["final_positions"]) == 3 and 0 <= gail["ood"]["reached"] <= 1
    text = report.read_text()
    assert "<!-- baselines-pendulum:start -->" in text and "<!-- baselines-navigation-ood:start -->" in text
    assert "| BC (uses expert actions) | 4 | 1/1 |" in text
    assert "‡" not in text  # every run trained with its config's entry as it stands, GAIL's inside IRL-MPC's shared run
    # the OOD table's last row: the untrained planner on the true reward, from the same 3 starts
    ceiling = json.loads((results / "navigation_true_reward" / "3starts.json").read_text())
    assert len(ceiling["final_positions"]) == 3
    assert f"| {TRUE_REWARD_LABEL} | – | {ood_measures(ceiling)['reached_reachable']:.2f} |" in text
    assert (tmp_path / "figures" / "baselines_navigation_ood.png").exists()


def bc_grid_on_pendulum(tmp_path):
    """A one-seed BC grid on the pendulum in ``tmp_path``: its tiny configs, results folder, report and command line."""
    configs, results, report = tiny_configs(tmp_path / "configs"), tmp_path / "results", tmp_path / "B.md"
    arguments = ["--envs", "pendulum", "--algos", "bc", "--demos", "4", "--seeds", "1", "--config-dir", str(configs),
                 "--results-dir", str(results), "--report-file", str(report), "--figures-dir", str(tmp_path / "figures"),
                 "--eval-episodes", "2"]  # fmt: skip
    return configs, results, report, arguments


def test_runs_trained_with_an_earlier_entry_of_their_config_are_marked_in_the_report(tmp_path):
    configs, results, report, arguments = bc_grid_on_pendulum(tmp_path)
    main(arguments)
    assert "| BC (uses expert actions) | 4 | 1/1 |" in report.read_text()
    bc = configs / "bc.yml"
    bc.write_text(bc.read_text().replace("n_epochs: 1", "n_epochs: 2"))
    main([*arguments, "--report-only"])
    text = report.read_text()
    assert "| BC (uses expert actions) | 4 | 1/1 (1 ‡) |" in text and runner.EARLIER_SETTINGS_NOTE in text


def test_a_second_invocation_trains_nothing(tmp_path, monkeypatch, capsys):
    configs, results, _, arguments = bc_grid_on_pendulum(tmp_path)
    main(arguments)
    before = (results / "pendulum" / "bc_4demos_seed0.json").read_text()

    def refuse(*args, **kwargs):
        raise AssertionError("a finished run was trained again")

    monkeypatch.setattr(runner, "train_baseline", refuse)
    main(arguments)
    assert "0 runs to do" in capsys.readouterr().out
    assert (results / "pendulum" / "bc_4demos_seed0.json").read_text() == before
    main([*arguments[:7], "2", *arguments[8:], "--report-only"])  # a second seed asked for, not run
    assert "| BC (uses expert actions) | 4 | 1/2 **incomplete** |" in (tmp_path / "B.md").read_text()
    # a report for other algorithms keeps the stored BC row: a partial rerun must not drop the rest of the grid
    main([*arguments[:3], "gail", *arguments[4:], "--report-only"])
    text = (tmp_path / "B.md").read_text()
    assert "| BC (uses expert actions) | 4 | 1/1 |" in text and "| GAIL (state-only) | 4 | 0/1 **incomplete** |" in text
    monkeypatch.undo()
    main([*arguments, "--timesteps", "5"])  # overridden budgets are a grid of their own, reported apart
    assert (results / "pendulum_5steps" / "bc_4demos_seed0.json").exists()
    assert "<!-- baselines-pendulum_5steps:start -->" in (tmp_path / "B.md").read_text()


def test_a_section_filled_by_two_invocations_quotes_both_commands(tmp_path):
    configs, results, report, arguments = bc_grid_on_pendulum(tmp_path)
    main(arguments)
    main([*arguments[:7], "2", *arguments[8:]])  # runs seed 1 only
    first, second = ("python -m benchmarks.runner --envs pendulum --algos bc --demos 4 --seeds " + n for n in "12")
    assert json.loads((results / "pendulum" / "bc_4demos_seed0.json").read_text())["command"] == first
    assert f"Commands: `{first}`; `{second}` on " in report.read_text()


def test_ray_is_optional_and_named_when_missing(tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray":
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    job = dict(env_id="Pendulum-v1", demo_set="pendulum", algos=("bc",), n_demos=4, seed=0)
    with pytest.raises(SystemExit, match="pip install"):
        runner.run_grid([job], dict(results_dir=tmp_path, threads=1), ray_address="auto")


def test_cartpole_runs_are_scored_against_its_expert_and_random_returns(tmp_path):
    results, report = tmp_path / "results", tmp_path / "BENCHMARKS.md"
    main(["--envs", "cartpole", "--algos", "gail", "--demos", "4", "--seeds", "1", "--config-dir",
          str(tiny_configs(tmp_path / "configs")), "--results-dir", str(results), "--report-file", str(report),
          "--figures-dir", str(tmp_path / "figures"), "--eval-episodes", "2"])  # fmt: skip
    gail = json.loads((results / "cartpole" / "gail_4demos_seed0.json").read_text())
    stats = shipped_demo_info("cartpole")
    assert gail["final_score"] == pytest.approx(normalised_score(gail["final_return"], stats))
    assert "## Baselines on sb3_mpail/ContinuousCartPole-v0" in report.read_text()


def test_lap_runs_are_measured_by_cross_track_error_beside_mpail_s_scenario_runs(tmp_path, monkeypatch):
    mpail_runs = [dict(seed=seed, cte_mean=0.3, cte_max=2.0 + seed, speed=1.0, seconds=1.0) for seed in range(2)]
    scenarios = tmp_path / "scenarios.json"
    scenarios.write_text(
        json.dumps(dict(lap=dict(runs=mpail_runs, timesteps=144000, command="python -m benchmarks.scenarios lap")))
    )
    monkeypatch.setattr(runner, "SCENARIO_RESULTS", scenarios)
    results, report = tmp_path / "results", tmp_path / "BENCHMARKS.md"
    main(["--envs", "lap", "--algos", "gail", "--demos", "1", "--seeds", "1", "--config-dir",
          str(tiny_configs(tmp_path / "configs")), "--results-dir", str(results), "--report-file", str(report),
          "--figures-dir", str(tmp_path / "figures")])  # fmt: skip
    gail = json.loads((results / "lap" / "gail_1demos_seed0.json").read_text())
    assert set(gail["lap"]) == {"cte_mean", "cte_max", "speed"} and "final_score" not in gail
    assert gail["lap"]["cte_mean"] <= gail["lap"]["cte_max"] and gail["curve"][-1][0] == 64
    text = report.read_text()
    assert "| MPAIL | 1 | 2 | **0.300 ± 0.000** (0.300, 0.300) | **2.500 ± 0.500** (2.000, 3.000) |" in text
    assert "| GAIL (state-only) | 1 | 1/1 |" in text and "`python -m benchmarks.scenarios lap`" in text
    assert (tmp_path / "figures" / "baselines_lap.png").exists() and "baselines_lap.png" in text


def test_curve_points_average_exactly_one_episode_per_seed():
    import gymnasium as gym

    class PushRight:  # falls in a few dozen steps, so the envs' episodes end at different times
        def predict(self, observation, state=None, episode_start=None, deterministic=False):
            return np.ones((len(observation), 1), np.float32), state

    env = gym.make("sb3_mpail/ContinuousCartPole-v0")
    lengths = []
    for i in range(4):
        env.reset(seed=runner.EVAL_SEED + i)
        steps, done = 0, False
        while not done:
            steps, (_, _, terminated, truncated, _) = steps + 1, env.step(np.ones(1, np.float32))
            done = terminated or truncated
        lengths.append(steps)
    stats = shipped_demo_info("cartpole")
    _, score, mean_return = runner.curve_point(PushRight(), "sb3_mpail/ContinuousCartPole-v0", 7, 4, stats)
    assert len(set(lengths)) > 1 and mean_return == pytest.approx(np.mean(lengths))
    assert score == pytest.approx(normalised_score(mean_return, stats))


def test_ood_measures_count_only_reachable_starts_progress_relative_to_the_start_distance_and_circles_away_from_the_goal():
    offset = runner.REWARD_OFFSET
    # starts 10 m, 20 m and 40 m (unreachable in 100 steps) from the goal; final distances 1, 10 and 1 m
    starts = [[0.0, 10.0, 0.0], [10.0, -10.0, 1.0], [10.0, -30.0, 2.0]]
    record = dict(start_poses=starts, final_rewards=[offset - 1.0, offset - 10.0, offset - 1.0], circling=[True, True, False])
    measures = runner.ood_measures(record)
    assert measures["reached"] == pytest.approx(2 / 3)
    assert measures["reached_reachable"] == pytest.approx(1 / 2)
    assert measures["progress"] == pytest.approx(np.mean([9 / 10, 10 / 20, 39 / 40]))
    assert measures["final_reward"] == pytest.approx(offset - 4.0)
    assert measures["circling"] == pytest.approx(2 / 3)
    assert measures["circling_away"] == pytest.approx(1 / 3)  # the circle 1 m from the goal is the expert's


def test_an_ablation_report_names_the_machine_its_runs_ran_on(tmp_path):
    from benchmarks import locomotion_ablations

    grid = tmp_path / "Hopper-v4_100steps"
    grid.mkdir()
    for seed, machine in enumerate(["machine A", "machine B"]):
        run = dict(env_id="Hopper-v4", variant="defaults", seed=seed, timesteps=100, n_eval_episodes=2, command="c",
                   train_seconds=1.0, score=0.1, speed_ratio=0.2, length=30.0, machine=machine, **{"return": 5.0})  # fmt: skip
        (grid / f"defaults_seed{seed}.json").write_text(json.dumps(run))
    text = locomotion_ablations.report(tmp_path)
    assert "2 evaluation episodes per run, on machine A; machine B." in text


def test_an_ablation_report_lists_the_scores_along_a_run_that_kept_checkpoints(tmp_path):
    from benchmarks import locomotion_ablations

    grid = tmp_path / "Hopper-v4_100steps"
    grid.mkdir()
    for seed, checkpoints in enumerate([[[50_000, 0.25, 300.0, 1.1], [100_000, 0.5, 500.0, 1.2]], None]):
        run = dict(env_id="Hopper-v4", variant="defaults", seed=seed, timesteps=100, n_eval_episodes=2, command="c",
                   train_seconds=1.0, score=0.75, speed_ratio=0.2, length=30.0, machine="m", checkpoint_scores=checkpoints,
                   **{"return": 5.0})  # fmt: skip
        (grid / f"defaults_seed{seed}.json").write_text(json.dumps(run))
    text = locomotion_ablations.report(tmp_path)
    assert "- `defaults` seed 0: 50k 0.25, 100k 0.50; final 0.75" in text
    assert "seed 1:" not in text
    header, row = (next(line for line in text.splitlines() if line.startswith(start)) for start in ("| variant", "| `"))
    assert row.endswith("|  |") and row.count("|") == header.count("|")  # no curves recorded: the collapses cell is blank


def test_an_ablation_report_gives_each_variants_score_less_the_entrys_on_the_seeds_both_ran(tmp_path):
    from benchmarks import locomotion_ablations

    grid = tmp_path / "Hopper-v4_100steps"
    grid.mkdir()
    scores = dict(defaults=[0.5, 0.7, 0.2], capped_reward=[0.6, 0.9, None, 0.9], alive_bonus=[None, None, None, 0.4])
    for name, by_seed in scores.items():
        variant = name.replace("_", "-")
        for seed, score in enumerate(by_seed):
            if score is not None:
                run = dict(env_id="Hopper-v4", variant=variant, seed=seed, timesteps=100, n_eval_episodes=2, command="c",
                           train_seconds=1.0, score=score, speed_ratio=0.2, length=30.0, machine="m", **{"return": 5.0})
                (grid / f"{variant}_seed{seed}.json").write_text(json.dumps(run))
    lines = locomotion_ablations.report(tmp_path).splitlines()
    cells = [[cell.strip(" `") for cell in line.split("|")] for line in lines if line.startswith("| `")]
    rows = {row[1]: row for row in cells}
    header = next(line for line in lines if line.startswith("| variant"))
    column = [cell.strip() for cell in header.split("|")].index("score less the entry's, same seeds")
    assert rows["capped-reward"][column] == "+0.15 ± 0.64 (2)"  # +0.1 and +0.2: t(0.975, 1) 12.71 x 0.05
    assert rows["alive-bonus"][column] == "" and rows["defaults"][column] == ""  # no seed shared; the entry itself


def test_an_ablation_report_gives_each_weight_averages_score_and_its_difference_from_the_live_weights(tmp_path):
    from benchmarks import locomotion_ablations

    grid = tmp_path / "Hopper-v4_100steps"
    grid.mkdir()
    for seed, (live, averaged) in enumerate([(0.5, [0.75, 0.25]), (0.25, [0.75, 0.5]), (0.5, None)]):
        run = dict(env_id="Hopper-v4", variant="weight-averages", seed=seed, timesteps=100, n_eval_episodes=2, command="c",
                   train_seconds=1.0, score=live, speed_ratio=0.2, length=30.0, machine="m", n_envs=4,
                   settings=dict(n_steps=250), **{"return": 5.0})  # fmt: skip
        if averaged is not None:
            run["average_scores"] = [[rate, score, 300.0, 1.0] for rate, score in zip((0.05, 0.2), averaged)]
        (grid / f"weight-averages_seed{seed}.json").write_text(json.dumps(run))
    text = locomotion_ablations.report(tmp_path)
    assert "rate per rollout of 1000 env steps" in text
    assert "- `weight-averages` seed 0: live weights 0.50; rate 0.05 0.75, rate 0.2 0.25" in text
    assert "seed 2:" not in text
    assert "- rate 0.05, score less the live weights': +0.38 ± 1.59 (2 runs)" in text  # +0.25, +0.5: 12.71 x 0.125
    assert "- rate 0.2, score less the live weights': +0.00 ± 3.18 (2 runs)" in text


@pytest.mark.parametrize(
    "lengths, collapsed",
    [([50, 300, 500, 90], True), ([50, 300, 500, 110], False), ([20, 80, 10], False), ([50, 300, 40, 400], True)],
)
def test_a_training_collapses_when_its_episodes_fall_below_a_fifth_of_their_peak_past_100_steps(lengths, collapsed):
    from benchmarks import locomotion_ablations

    curve = [[1000 * (index + 1), length, 0.0, 0.0] for index, length in enumerate(lengths)]
    assert locomotion_ablations.training_collapsed(curve) is collapsed


def test_a_locomotion_ablation_run_records_its_training_curve(tmp_path):
    from benchmarks import locomotion_ablations

    path = locomotion_ablations.run_variant("Hopper-v4", "defaults", 0, 1000, 1, tmp_path, "c")
    result = json.loads(path.read_text())
    curve = result["training_curve"]
    assert [point[0] for point in curve] == [1000]  # one rollout of 4 envs x 250 steps
    steps, length, episode_return, learned_reward = curve[0]
    assert 0 < length <= 250 and np.isfinite(episode_return) and np.isfinite(learned_reward)
    assert "checkpoint_scores" not in result


def test_a_scenario_seed_that_already_ran_with_the_same_settings_is_read_back_not_retrained(tmp_path, monkeypatch):
    from benchmarks import scenarios

    trained = []

    class CountingMPAIL:
        def __init__(self, *args, **kwargs):
            trained.append(kwargs["seed"])

        def learn(self, timesteps):
            return self

        def save(self, path):
            saved.append(path)

    saved = []
    monkeypatch.setattr(scenarios, "MPAIL", CountingMPAIL)
    monkeypatch.setattr(scenarios, "MODELS_DIR", tmp_path / "models")
    monkeypatch.setattr(scenarios, "make_vec_env", lambda *args, **kwargs: None)
    monkeypatch.setitem(scenarios.SCENARIOS, "cartpole", scenarios.SCENARIOS["cartpole"]._replace(
        figures=lambda model, stats, n_episodes: {"return": 1.0, "score": 0.5}))  # fmt: skip
    first = scenarios.run_seed("cartpole", {}, 3, tmp_path)
    again = scenarios.run_seed("cartpole", {}, 3, tmp_path)
    assert trained == [3] and again == first and first["score"] == 0.5
    assert saved == [tmp_path / "models" / "cartpole_seed3.zip"]
    stored = json.loads((tmp_path / "cartpole_seed3.json").read_text())
    stored["settings"]["n_eval_episodes"] += 1  # the settings changed since: the seed runs again
    (tmp_path / "cartpole_seed3.json").write_text(json.dumps(stored))
    scenarios.run_seed("cartpole", {}, 3, tmp_path)
    assert trained == [3, 3]


def test_evaluating_a_navigation_ablation_again_replaces_its_figures_keeps_its_training_and_says_so(tmp_path, monkeypatch):
    from benchmarks import navigation_ablations

    stored = dict(variant="one-discriminator", seed=1, train_seconds=12.5, id_score=0.1, reached_reachable=0.2, machine="A")
    (tmp_path / "one-discriminator_seed1.json").write_text(json.dumps(stored))
    (tmp_path / "one-discriminator_seed1.zip").write_text("a saved model")
    loaded = []
    monkeypatch.setattr(navigation_ablations.MPAIL, "load", lambda path, device: loaded.append(path) or "model")
    monkeypatch.setattr(navigation_ablations, "evaluation",
                        lambda model, variant, seed: dict(id_score=0.9, reached_reachable=0.6))  # fmt: skip
    navigation_ablations.reevaluate_variant("one-discriminator", 1, tmp_path, tmp_path)
    result = json.loads((tmp_path / "one-discriminator_seed1.json").read_text())
    assert loaded == [tmp_path / "one-discriminator_seed1.zip"]
    assert (result["id_score"], result["reached_reachable"], result["train_seconds"]) == (0.9, 0.6, 12.5)
    assert result["reevaluated"]["deterministic_noise"] == DETERMINISTIC_NOISE


def test_scenario_runs_record_the_scenario_s_own_figures_beside_mpail_s_scenario_runs(tmp_path, monkeypatch):
    mpail_runs = [dict(seed=seed, on_road=1.0, score=0.9 + 0.1 * seed, speed=10.0, seconds=1.0, **{"return": 160.0})
                  for seed in range(2)]  # fmt: skip
    scenarios = tmp_path / "scenarios.json"
    scenarios.write_text(json.dumps(dict(racetrack=dict(runs=mpail_runs, command="python -m benchmarks.scenarios racetrack"))))
    monkeypatch.setattr(runner, "SCENARIO_RESULTS", scenarios)
    results, report = tmp_path / "results", tmp_path / "BENCHMARKS.md"
    main(["--envs", "racetrack", "--algos", "gail", "--demos", "4", "--seeds", "1", "--config-dir",
          str(tiny_configs(tmp_path / "configs")), "--results-dir", str(results), "--report-file", str(report),
          "--figures-dir", str(tmp_path / "figures"), "--eval-episodes", "1"])  # fmt: skip
    gail = json.loads((results / "racetrack" / "gail_4demos_seed0.json").read_text())
    assert set(gail["scenario_figures"]) == {"return", "score", "on_road", "speed"}
    assert 0.0 <= gail["scenario_figures"]["on_road"] <= 1.0
    text = report.read_text()
    assert "| algorithm | demos | seeds | return | normalised score | share of steps on the road | source |" in text
    assert "| MPAIL | 4 | 2 | 160.000 ± 0.000 | 0.950 ± 0.635 | 1.000 ± 0.000 | `python -m benchmarks.scenarios" in text
    assert "| GAIL (state-only) | 4 | 1/1 |" in text


def test_a_navigation_ablation_scored_by_the_same_samples_planner_is_marked_until_evaluated_again(tmp_path, monkeypatch):
    from benchmarks import navigation_ablations

    figures = dict(id_score=0.9, reached_reachable=0.3, final_reward=7.0, progress=0.5, circling=0.2, circling_away=0.1,
                   machine="A")
    for seed in range(2):
        run = dict(figures, variant="concave-value", seed=seed, deterministic_noise=SAME_NOISE)
        (tmp_path / f"concave-value_seed{seed}.json").write_text(json.dumps(run))
    monkeypatch.setattr(navigation_ablations, "true_reward_record", lambda n_starts, results_dir: {})
    monkeypatch.setattr(navigation_ablations, "ood_measures", lambda record: dict(figures, reached_reachable=0.95))
    assert "| 2 (2 †) |" in navigation_ablations.report(tmp_path, ["concave-value"])
    monkeypatch.setattr(navigation_ablations.MPAIL, "load", lambda path, device: "model")
    monkeypatch.setattr(navigation_ablations, "evaluation", lambda model, variant, seed: {})
    (tmp_path / "concave-value_seed1.zip").write_text("a saved model")
    navigation_ablations.reevaluate_variant("concave-value", 1, tmp_path, tmp_path)
    text = navigation_ablations.report(tmp_path, ["concave-value"])
    assert "| 2 (1 †) |" in text and "†: runs evaluated by a version whose deterministic planning drew the same" in text


def test_the_navigation_ablations_report_quotes_each_runs_own_command(tmp_path, monkeypatch):
    from benchmarks import navigation_ablations

    figures = dict(id_score=0.9, reached_reachable=0.3, final_reward=7.0, progress=0.5, circling=0.2, circling_away=0.1,
                   machine="A")
    commands = {0: "python -m benchmarks.navigation_ablations --variants concave-value --seeds 0", 1: None}
    for seed, command in commands.items():
        run = dict(figures, variant="concave-value", seed=seed, **({"command": command} if command else {}))
        (tmp_path / f"concave-value_seed{seed}.json").write_text(json.dumps(run))
    monkeypatch.setattr(navigation_ablations, "true_reward_record", lambda n_starts, results_dir: {})
    monkeypatch.setattr(navigation_ablations, "ood_measures", lambda record: dict(figures, reached_reachable=0.95))
    text = navigation_ablations.report(tmp_path, ["concave-value"])
    # the run that recorded its command is quoted as it ran; the one stored before the record, as the placeholder
    assert f"`{commands[0]}`" in text and f"`{navigation_ablations.UNRECORDED_COMMAND}`" in text


def test_every_scenario_names_its_experts_figures_from_its_shipped_demo_information():
    from benchmarks.scenarios import SCENARIOS

    for name, scenario in SCENARIOS.items():
        stats = shipped_demo_info(scenario.demos)
        assert stats["env_id"] == scenario.env_id, name
        assert scenario.reference(stats), name  # every figure it quotes is in the information file


def test_a_plain_dynamics_function_plans_as_the_built_in_bicycle_and_is_compared_with_the_reference_through_it():
    import torch as th

    from benchmarks import planner_speed

    states = planner_speed.random_states(3, "cpu")
    plans = []
    for dynamics in ("bicycle", planner_speed.user_bicycle()):
        planner = planner_speed.make_policy("cpu", dynamics=dynamics).planner
        with th.no_grad():
            result = planner(states, planner.initial_plan(3), th.tensor(0.1), th.Generator().manual_seed(0))
        plans.append(result.plan)
    th.testing.assert_close(plans[0], plans[1], rtol=1e-5, atol=1e-5)

    def case(implementation, seconds):
        return dict(implementation=implementation, n_envs=64, device="cpu", threads=1, ms_per_step=1e3 * seconds,
                    env_steps_per_second=64 / seconds, peak_mib=1.0)  # fmt: skip

    rows = planner_speed.table([case("reference", 0.6), case("callable", 0.2), case("callable-reference", 1.0)])
    callable_row = next(line for line in rows.splitlines() if "user's plain function" in line)
    assert "| 5.0x |" in callable_row  # against the reference through the same function, not the built-in's 3.0x


def test_the_simulator_dynamics_step_a_locomotion_observation_as_the_env_does():
    pytest.importorskip("mujoco", reason="the MuJoCo tasks need mujoco (the scenarios extra)")
    import gymnasium as gym

    from benchmarks.locomotion_diagnosis import SimulatorDynamics

    env = gym.make("Hopper-v4")
    observation, _ = env.reset(seed=0)
    env.action_space.seed(0)
    states, actions, next_states = [], [], []
    for _ in range(20):
        action = env.action_space.sample()
        next_observation, _, terminated, _, _ = env.step(action)
        states.append(observation), actions.append(action), next_states.append(next_observation)
        observation = next_observation
        if terminated:
            break
    predicted = SimulatorDynamics("Hopper-v4")(th.as_tensor(np.array(states)), th.as_tensor(np.array(actions)))
    np.testing.assert_allclose(predicted.numpy(), np.array(next_states), atol=1e-9)


def test_a_diagnosis_plays_a_saved_model_each_way_and_reports_each_row(tmp_path):
    from benchmarks import locomotion_ablations, locomotion_diagnosis

    ablations, out_dir = tmp_path / "ablations", tmp_path / "Hopper-v4_1000steps"
    locomotion_ablations.run_variant("Hopper-v4", "defaults", 0, 1000, 1, ablations, "c")
    for player in locomotion_diagnosis.PLAYERS:
        path = locomotion_diagnosis.diagnose("Hopper-v4", "defaults", 0, player, 1, ablations, out_dir, "d")
        result = json.loads(path.read_text())
        assert result["player"] == player and result["length"] > 0 and np.isfinite(result["score"])
    text = locomotion_diagnosis.report(tmp_path)
    assert "models trained for 1000 env steps" in text
    assert sum(line.startswith("| `defaults` |") for line in text.splitlines()) == len(locomotion_diagnosis.PLAYERS)


def test_the_simulator_player_plans_through_mujoco_and_the_actor_player_without_a_planner():
    from benchmarks import locomotion_diagnosis

    planner = dict(dynamics="learned", n_samples=4, horizon=2, n_iterations=1, policy_prior=True, n_proposals=2)
    model = MPAIL("MlpMPPI", "Hopper-v4", demos="hopper_16", n_steps=8, seed=0, device="cpu", policy_kwargs=planner)
    assert locomotion_diagnosis.player_of(model, "Hopper-v4", "learned-model") is model
    assert isinstance(locomotion_diagnosis.player_of(model, "Hopper-v4", "actor"), locomotion_diagnosis.PriorActor)
    simulated = locomotion_diagnosis.player_of(model, "Hopper-v4", "simulator")
    assert isinstance(simulated.policy.planner.dynamics, locomotion_diagnosis.SimulatorDynamics)


def test_a_run_with_checkpoints_scores_them_with_swapped_components_and_with_its_online_q(tmp_path):
    from benchmarks import locomotion_ablations, locomotion_swaps, locomotion_value_source

    grid = tmp_path / "Hopper-v4_2000steps"
    variant = "ensemble-slow-value"  # its prior keeps a slow average of the Q networks for planning
    path = locomotion_ablations.run_variant("Hopper-v4", variant, 0, 2000, 1, grid, "c", checkpoint_every=1000)
    scores = json.loads(path.read_text())["checkpoint_scores"]
    assert [point[0] for point in scores] == [1000, 2000]
    for _, score, length, speed_ratio in scores:
        assert np.isfinite(score) and 0 < length <= 1000 and np.isfinite(speed_ratio)
    checkpoints = locomotion_ablations.checkpoints_dir_of(grid, variant, 0)
    # either side of the first rollout's update
    late, early = (MPAIL.load(locomotion_ablations.checkpoint_file(checkpoints, steps)) for steps in (2000, 1000))
    locomotion_swaps.swap_component(late, early, "discriminator")
    swapped, kept = late.policy.discriminator.state_dict(), late.policy.dynamics.state_dict()
    assert all(th.equal(swapped[key], value) for key, value in early.policy.discriminator.state_dict().items())
    assert not all(th.equal(kept[key], value) for key, value in early.policy.dynamics.state_dict().items())

    path = locomotion_swaps.swap_scores("Hopper-v4", variant, 0, (2000, 1000), 1, grid, "c")
    rows = json.loads(path.read_text())
    assert len(rows) == 2 * (1 + len(locomotion_swaps.COMPONENTS))
    assert {(row["model"], row["donor"]) for row in rows if row["component"]} == {(2000, 1000), (1000, 2000)}
    locomotion_swaps.swap_scores("Hopper-v4", variant, 0, (2000, 1000), 1, grid, "c")
    assert json.loads(path.read_text()) == rows  # a rerun scores nothing again
    table = [line for line in locomotion_swaps.report(tmp_path).splitlines() if line.startswith("|")]
    assert len(table) == 4 and table[2].startswith("| 2k |")
    assert len({line.count("|") for line in table}) == 1  # every row as wide as the header

    path = locomotion_value_source.online_value_scores("Hopper-v4", variant, 0, 1, grid, "c")
    online = json.loads(path.read_text())
    assert set(online) == {"final", "1000", "2000"}
    locomotion_value_source.online_value_scores("Hopper-v4", variant, 0, 1, grid, "c")
    assert json.loads(path.read_text()) == online  # a rerun scores nothing again
    table = [line for line in locomotion_value_source.report(tmp_path).splitlines() if line.startswith("|")]
    assert len(table) == 3 and len({line.count("|") for line in table}) == 1
    assert table[0] == "| final | 1k | 2k |"
    planned = locomotion_value_source.plan_with_online_q(late).policy.prior
    assert all(th.equal(online_q, averaged) for online_q, averaged in zip(planned.sac.critic.parameters(),
                                                                          planned.planning_critic.parameters()))  # fmt: skip


def test_planning_with_the_online_q_is_refused_for_a_prior_without_a_slow_average():
    from benchmarks import locomotion_value_source

    planner = dict(dynamics="learned", n_samples=4, horizon=2, n_iterations=1, policy_prior=True, n_proposals=2)
    model = MPAIL("MlpMPPI", "Hopper-v4", demos="hopper_16", n_steps=8, seed=0, device="cpu", policy_kwargs=planner)
    with pytest.raises(ValueError, match="value_tau"):
        locomotion_value_source.plan_with_online_q(model)


def test_the_weight_averages_of_an_ablation_run_are_the_ones_mpail_keeps_at_each_rate():
    from test_mpail import make_model, pendulum_trajectories

    from benchmarks.locomotion_ablations import WeightAverages

    demos = pendulum_trajectories()
    averages = WeightAverages((0.2, 1.0))
    live = make_model(demos, n_envs=2).learn(96, callback=averages)
    for rate, average in averages.averages.items():
        kept = make_model(demos, n_envs=2, policy_average_rate=rate).learn(96).policy_average
        assert all(th.equal(a, b) for a, b in zip(average.state_dict().values(), kept.state_dict().values()))
    assert all(th.equal(a, b) for a, b in zip(averages.averages[1.0].policy.parameters(), live.policy.parameters()))
