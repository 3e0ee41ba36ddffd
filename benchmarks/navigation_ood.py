"""
Out-of-distribution starts for the navigation planners trained by ``benchmarks/navigation.py``.

Each trained model (``--runs-dir/seed<N>/model.zip``) drives ``--n-starts`` deterministic 100-step episodes from
starts uniform in the 40 x 40 m box centred at the origin with uniform heading (the env's ``start_region="ood"``),
and as many from the training start region (within 1 m of the origin, heading near 0). Reports, for both, the
fraction of episodes that end within ``--radius`` m of the goal and the mean final reward ``sqrt(200) - distance``;
writes the ``navigation_ood`` section of BENCHMARKS.md and a figure of the OOD starts, final positions and paths.

A car at the 3 m/s top speed covers at most 30 m in the 100 steps, so starts farther than ``30 + radius`` m from the
goal cannot be reached by any policy; the table also gives the fraction among the starts within that distance.

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
from sb3_mpail import MPAIL
from sb3_mpail.envs.navigation import DT, MAX_SPEED, OOD_HALF_WIDTH, REWARD_OFFSET
from sb3_mpail.train_navigation import run_episodes

REPO_ROOT = Path(__file__).resolve().parent.parent
FIGURES = REPO_ROOT / "benchmarks" / "figures"
DEFAULT_RUNS_DIR = REPO_ROOT / "runs" / "benchmarks" / "navigation"
GOAL = np.array([10.0, 10.0])
EPISODE_STEPS = 100
#: the farthest a car can drive in one episode at top speed (m)
MAX_TRAVEL = MAX_SPEED * DT * EPISODE_STEPS
#: OOD episodes are seeded from ``model seed + OOD_SEED_OFFSET`` (training used the seed, evaluation seed + 10 000)
OOD_SEED_OFFSET = 20_000


def evaluate_starts(model: MPAIL, start_region: str, n_starts: int, seed: int, radius: float) -> Dict[str, np.ndarray]:
    """
    Drives ``n_starts`` deterministic episodes from ``start_region``.

    :param model: a trained navigation model
    :param start_region: the env's ``start_region`` (``"default"`` or ``"ood"``)
    :param n_starts: episodes, all run at once
    :param seed: seed of the start draws
    :param radius: an episode succeeds when its final distance to the goal is below this (m)
    :return: per episode: ``start`` (x, y), ``start_distance``, ``final_distance``, ``final_reward``, ``reached``
        and the ``paths`` (x, y) over the episode
    """
    _, final_distance, trajectories = run_episodes(model, n_starts, seed=seed, start_region=start_region)
    starts = np.stack([trajectory[0, :2] for trajectory in trajectories])
    return dict(
        start=starts,
        start_distance=np.linalg.norm(starts - GOAL, axis=1),
        final_distance=final_distance,
        final_reward=REWARD_OFFSET - final_distance,
        reached=final_distance < radius,
        paths=np.stack([trajectory[:, :2] for trajectory in trajectories]),
    )


def plot_ood(per_seed: List[Dict[str, np.ndarray]], seeds: List[int], radius: float, path: Path) -> Path:
    """
    Two panels: left, the first model's OOD paths (green: ended within ``radius`` of the goal, red: did not) with
    every model's final positions; right, every model's final distance to the goal against the start's distance.

    :param per_seed: :func:`evaluate_starts`'s OOD results, one per model
    :param seeds: the models' training seeds, for the legend
    :param radius: success radius (m)
    :param path: where to write the PNG
    :return: the path written
    """
    from sb3_mpail.plotting import import_pyplot, save_figure

    plt = import_pyplot()
    figure, (left, right) = plt.subplots(1, 2, figsize=(14, 6.5), constrained_layout=True)
    first = per_seed[0]
    for path_xy, reached in zip(first["paths"], first["reached"]):
        left.plot(path_xy[:, 0], path_xy[:, 1], color="tab:green" if reached else "tab:red", lw=0.7, alpha=0.5)
        left.plot(path_xy[0, 0], path_xy[0, 1], "o", color="0.3", ms=2)
    for seed, results in zip(seeds, per_seed):
        left.plot(results["paths"][:, -1, 0], results["paths"][:, -1, 1], "x", ms=4, alpha=0.7, label=f"final, seed {seed}")
    left.add_patch(
        plt.Rectangle((-OOD_HALF_WIDTH, -OOD_HALF_WIDTH), 2 * OOD_HALF_WIDTH, 2 * OOD_HALF_WIDTH, fill=False, ls="--")
    )
    left.add_patch(plt.Circle(tuple(GOAL), MAX_TRAVEL + radius, fill=False, color="0.5", ls=":"))
    left.plot(*GOAL, marker="*", color="gold", mec="k", ms=18, ls="none", label="goal (10, 10)")
    left.set_xlim(-OOD_HALF_WIDTH - 5, OOD_HALF_WIDTH + 5)
    left.set_ylim(-OOD_HALF_WIDTH - 5, OOD_HALF_WIDTH + 5)
    left.set_aspect("equal")
    left.set_xlabel("x (m)")
    left.set_ylabel("y (m)")
    left.grid(alpha=0.3)
    left.legend(loc="lower right", fontsize=8)
    left.set_title(
        f"OOD starts (dots), 40 x 40 m box (dashed); seed {seeds[0]}'s paths: green\nends within {radius:g} m of the goal, "
        f"red does not; dotted: {MAX_TRAVEL + radius:g} m, 100 steps at top speed"
    )
    for seed, results in zip(seeds, per_seed):
        right.scatter(results["start_distance"], results["final_distance"], s=8, alpha=0.6, label=f"seed {seed}")
    limit = np.max([r["start_distance"].max() for r in per_seed]) + 1
    right.plot([0, limit], [0 - MAX_TRAVEL, limit - MAX_TRAVEL], color="0.5", ls=":", label="start distance - 30 m")
    right.axhline(radius, color="r", ls="--", lw=1, label=f"{radius:g} m")
    right.set_xlim(0, limit)
    right.set_ylim(0, None)
    right.set_xlabel("start distance to goal (m)  [training starts: ~14 m]")
    right.set_ylabel("final distance to goal after 100 steps (m)")
    right.grid(alpha=0.3)
    right.legend(fontsize=8)
    right.set_title("final distance against start distance, all models")
    return save_figure(figure, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="models seed<N> under --runs-dir")
    parser.add_argument("--runs-dir", default=str(DEFAULT_RUNS_DIR))
    parser.add_argument("--n-starts", type=int, default=200, help="episodes per model and start region")
    parser.add_argument("--radius", type=float, default=2.0, help="success: final distance to the goal below this (m)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--section", default="navigation_ood", help="BENCHMARKS.md section to write")
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    started = time.perf_counter()

    ood, in_distribution = [], []
    for seed in args.seeds:
        model_path = Path(args.runs_dir) / f"seed{seed}" / "model.zip"
        if not model_path.exists():
            raise SystemExit(f"{model_path} is missing: run python -m benchmarks.navigation first.")
        model = MPAIL.load(model_path, device="cpu")
        ood.append(evaluate_starts(model, "ood", args.n_starts, seed + OOD_SEED_OFFSET, args.radius))
        in_distribution.append(evaluate_starts(model, "default", args.n_starts, seed + OOD_SEED_OFFSET, args.radius))
        print(
            f"seed {seed}: within {args.radius:g} m: OOD {ood[-1]['reached'].mean():.3f}, "
            f"in-distribution {in_distribution[-1]['reached'].mean():.3f}",
            flush=True,
        )
    wall_seconds = time.perf_counter() - started
    figure = plot_ood(ood, args.seeds, args.radius, FIGURES / "navigation_ood.png")

    reachable_within = MAX_TRAVEL + args.radius

    def row(name: str, results: Dict[str, np.ndarray], reachable: np.ndarray | None) -> str:
        reachable_cell = "–" if reachable is None else f"{results['reached'][reachable].mean():.3f} ({reachable.sum()})"
        return (
            f"| {name} | {results['reached'].mean():.3f} | {reachable_cell} | {results['final_reward'].mean():.2f} | "
            f"{np.median(results['final_distance']):.2f} |"
        )

    def mean_std(values: List[float]) -> str:
        return f"{np.mean(values):.3f} ± {np.std(values):.3f}"

    ood_fractions = [r["reached"].mean() for r in ood]
    in_fractions = [r["reached"].mean() for r in in_distribution]
    ood_reachable = [r["reached"][r["start_distance"] <= reachable_within].mean() for r in ood]
    command = "python -m benchmarks.navigation_ood " + " ".join(sys.argv[1:])
    lines = [
        "## Navigation out of distribution: starts anywhere in the 40 x 40 m box",
        "",
        f"Command: `{command.strip()}`, after `python -m benchmarks.navigation` (its {len(args.seeds)} models, "
        f"`{Path(args.runs_dir).relative_to(REPO_ROOT) if Path(args.runs_dir).is_relative_to(REPO_ROOT) else args.runs_dir}"
        f"/seed<N>/model.zip`). Machine: {machine_description()}; {wall_seconds:.0f} s in all.",
        "",
        f"Each model drives {args.n_starts} deterministic 100-step episodes from starts uniform in the 40 x 40 m box "
        'centred at the origin with uniform heading (`start_region="ood"`; the demos all start within 1 m of the '
        f"origin heading towards the goal), and {args.n_starts} from the training start region. Success = final "
        f"distance to the goal (10, 10) below {args.radius:g} m after 100 steps. At the 3 m/s top speed no policy can "
        f"reach the goal from farther than {reachable_within:g} m, so the OOD fraction is also given among the starts "
        "within that distance (their count in brackets).",
        "",
        f"**Within {args.radius:g} m after 100 steps (mean ± std over models): OOD {mean_std(ood_fractions)}, "
        f"OOD among reachable starts {mean_std(ood_reachable)}; in distribution {mean_std(in_fractions)}.**",
        "",
        f"| model, start region | fraction within {args.radius:g} m | ... among starts within {reachable_within:g} m "
        "| mean final reward | median final distance (m) |",
        "|---|---|---|---|---|",
    ]
    for seed, ood_results, in_results in zip(args.seeds, ood, in_distribution):
        reachable = ood_results["start_distance"] <= reachable_within
        lines.append(row(f"seed {seed}, OOD box", ood_results, reachable))
        lines.append(row(f"seed {seed}, in distribution", in_results, None))
    lines += [
        "",
        "Mean final reward = sqrt(200) - final distance (14.1 on the goal). "
        f"Figure (paths of seed {args.seeds[0]}, every model's final positions, final against start distance): "
        f"`{figure.relative_to(REPO_ROOT)}`.",
        "",
        f"![navigation OOD]({figure.relative_to(REPO_ROOT).as_posix()})",
    ]
    markdown = "\n".join(lines)
    write_section(args.section, markdown)
    print(markdown)


if __name__ == "__main__":
    main()
