"""
Out-of-distribution starts for the navigation planners trained by ``benchmarks/navigation.py`` (the main command's
defaults).

Each trained model (``--runs-dir/seed<N>/model.zip``) drives ``--n-starts`` deterministic 100-step episodes from
starts uniform in the 40 x 40 m box centred at the origin with uniform heading (the grid runner's OOD test,
:func:`benchmarks.runner.ood_episodes`: the same starts as every algorithm of the grid), and as many from the training
start region. Reports the runner's measures (:func:`benchmarks.runner.ood_measures`: within 2 m of the goal among the
starts any policy can reach, mean final reward, progress, circling anywhere and away from the goal), beside the
ceiling of the same planner on the true reward (:func:`benchmarks.runner.true_reward_record`), writes the
``navigation_ood`` section of BENCHMARKS.md and a figure of the OOD paths and final positions.

Usage::

    python -m benchmarks.navigation_ood                 # the 3 models of benchmarks/navigation.py, 200 starts each
"""

import argparse
import sys
import time
from pathlib import Path
from typing import Dict, List

import numpy as np
import torch as th

from benchmarks.report import machine_description, write_section
from benchmarks.runner import (
    CIRCLING_AWAY,
    GOAL,
    GOAL_RADIUS,
    MAX_TRAVEL,
    TRUE_REWARD_LABEL,
    TRUE_REWARD_NOTE,
    format_ci,
    mean_ci,
    ood_episodes,
    ood_measures,
    ood_record,
    true_reward_record,
)
from sb3_mpail import MPAIL
from sb3_mpail.envs.navigation import OOD_HALF_WIDTH
from sb3_mpail.evaluation import evaluate_episodes
from sb3_mpail.train_navigation import ENV_ID

REPO_ROOT = Path(__file__).resolve().parent.parent
FIGURES = REPO_ROOT / "benchmarks" / "figures"
DEFAULT_RUNS_DIR = REPO_ROOT / "runs" / "benchmarks" / "navigation"
#: in-distribution episodes start from ``reset(seed=ID_SEED + i)``
ID_SEED = 30_000
#: the table's measures of the OOD episodes (:func:`benchmarks.runner.ood_measures`), in its column order
COLUMNS = ("reached_reachable", "reached", "final_reward", "progress", "circling", "circling_away")


def plot_ood(paths: List[np.ndarray], final_positions: List[np.ndarray], reached: np.ndarray, seeds: List[int],
             path: Path) -> Path:  # fmt: skip
    """
    The first model's OOD paths (green: ended within the goal radius, red: did not) with every model's final
    positions, the 40 x 40 m box and the farthest a car reaches in 100 steps.

    :param paths: the first model's episodes, planar ``(T + 1, 2)`` each
    :param final_positions: per model, its episodes' final positions ``(n, 2)``
    :param reached: the first model's episodes' success
    :param seeds: the models' training seeds, for the legend
    :param path: where to write the PNG
    """
    from sb3_mpail.plotting import import_pyplot, save_figure

    plt = import_pyplot()
    figure, axis = plt.subplots(figsize=(8, 7.5), constrained_layout=True)
    for path_xy, success in zip(paths, reached):
        axis.plot(path_xy[:, 0], path_xy[:, 1], color="tab:green" if success else "tab:red", lw=0.7, alpha=0.5)
        axis.plot(path_xy[0, 0], path_xy[0, 1], "o", color="0.3", ms=2)
    for seed, positions in zip(seeds, final_positions):
        axis.plot(positions[:, 0], positions[:, 1], "x", ms=4, alpha=0.7, label=f"final, seed {seed}")
    axis.add_patch(
        plt.Rectangle((-OOD_HALF_WIDTH, -OOD_HALF_WIDTH), 2 * OOD_HALF_WIDTH, 2 * OOD_HALF_WIDTH, fill=False, ls="--")
    )
    axis.add_patch(plt.Circle(tuple(GOAL), MAX_TRAVEL + GOAL_RADIUS, fill=False, color="0.5", ls=":"))
    axis.plot(*GOAL, marker="*", color="gold", mec="k", ms=18, ls="none", label="goal (10, 10)")
    axis.set(xlim=(-OOD_HALF_WIDTH - 5, OOD_HALF_WIDTH + 5), ylim=(-OOD_HALF_WIDTH - 5, OOD_HALF_WIDTH + 5), aspect="equal",
             xlabel="x (m)", ylabel="y (m)")  # fmt: skip
    axis.grid(alpha=0.3)
    axis.legend(loc="lower right", fontsize=8)
    axis.set_title(
        f"OOD starts (dots) in the 40 x 40 m box (dashed); seed {seeds[0]}'s paths: green ends within {GOAL_RADIUS:g} m "
        f"of the goal, red does not;\ndotted: {MAX_TRAVEL + GOAL_RADIUS:g} m, the farthest start a car can reach in "
        "100 steps at top speed",
        fontsize=9,
    )
    return save_figure(figure, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="models seed<N> under --runs-dir")
    parser.add_argument("--runs-dir", default=str(DEFAULT_RUNS_DIR))
    parser.add_argument("--n-starts", type=int, default=200, help="episodes per model and start region")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--section", default="navigation_ood", help="BENCHMARKS.md section to write")
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    started = time.perf_counter()

    measures: List[Dict[str, float]] = []
    in_distribution: List[float] = []
    final_positions, first_paths, first_reached = [], [], np.zeros(0)
    for seed in args.seeds:
        model_path = Path(args.runs_dir) / f"seed{seed}" / "model.zip"
        if not model_path.exists():
            raise SystemExit(f"{model_path} is missing: run python -m benchmarks.navigation first.")
        model = MPAIL.load(model_path, device="cpu")
        episodes = ood_episodes(model, args.n_starts)
        record = ood_record(episodes)
        measures.append(ood_measures(record))
        final_positions.append(np.asarray(record["final_positions"]))
        if not first_paths:
            first_paths = [obs[:, :2] for obs in episodes.observations]
            first_reached = np.array([info["distance_to_goal"] < GOAL_RADIUS for info in episodes.final_infos])
        at_home = evaluate_episodes(model, ENV_ID, args.n_starts, ID_SEED + seed)
        in_distribution.append(float(np.mean([info["distance_to_goal"] < GOAL_RADIUS for info in at_home.final_infos])))
        print(f"seed {seed}: {measures[-1]}, in distribution {in_distribution[-1]:.3f}", flush=True)
    ceiling = ood_measures(true_reward_record(args.n_starts))
    wall_seconds = time.perf_counter() - started
    figure = plot_ood(first_paths, final_positions, first_reached, args.seeds, FIGURES / "navigation_ood.png")

    def summary(values: List[float]) -> str:
        return format_ci(*mean_ci(values))

    command = "python -m benchmarks.navigation_ood " + " ".join(sys.argv[1:])
    runs_dir = Path(args.runs_dir)
    shown_runs_dir = runs_dir.relative_to(REPO_ROOT) if runs_dir.is_relative_to(REPO_ROOT) else runs_dir
    lines = [
        "## Navigation out of distribution: the main command's models",
        "",
        f"Command: `{command.strip()}`, after `python -m benchmarks.navigation` (its {len(args.seeds)} models, "
        f"`{shown_runs_dir}/seed<N>/model.zip`). Machine: {machine_description()}; {wall_seconds:.0f} s in all.",
        "",
        f"Each model drives {args.n_starts} deterministic 100-step episodes from starts uniform in the 40 x 40 m box "
        'centred at the origin with uniform heading (`start_region="ood"`, the grid runner\'s starts; the demos all '
        f"start within 1 m of the origin heading towards the goal), and {args.n_starts} from the training start "
        f"region. Success: the episode ends within {GOAL_RADIUS:g} m of the goal (10, 10); reachable starts: within "
        f"{MAX_TRAVEL + GOAL_RADIUS:g} m of it (no policy arrives from farther in 100 steps at the 3 m/s top speed). "
        f"Means ± 95% CI (Student's t) over the models. {TRUE_REWARD_NOTE}",
        "",
        "| start region | within 2 m, reachable starts | within 2 m, all starts | mean final reward | mean progress "
        f"| ends circling | ends circling farther than {CIRCLING_AWAY:g} m from the goal |",
        "|---|---|---|---|---|---|---|",
        "| OOD box | " + " | ".join(summary([m[k] for m in measures]) for k in COLUMNS) + " |",
        f"| training starts | – | {summary(in_distribution)} | – | – | – | – |",
        f"| OOD box, {TRUE_REWARD_LABEL} | " + " | ".join(f"{ceiling[k]:.2f}" for k in COLUMNS) + " |",
        "",
        "Per model (OOD box): "
        + "; ".join(f"seed {seed}: {m['reached_reachable']:.3f} of reachable starts, final reward {m['final_reward']:.2f}"
                    for seed, m in zip(args.seeds, measures))
        + ".",
        "",
        f"Mean final reward = sqrt(200) - final distance (14.1 on the goal). Figure (paths of seed {args.seeds[0]}, "
        f"every model's final positions): `{figure.relative_to(REPO_ROOT)}`.",
        "",
        f"![navigation OOD]({figure.relative_to(REPO_ROOT).as_posix()})",
    ]  # fmt: skip
    markdown = "\n".join(lines)
    write_section(args.section, markdown)
    print(markdown)


if __name__ == "__main__":
    main()
