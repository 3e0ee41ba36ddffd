"""
MPAIL on ``sb3_mpail/Navigation-v0``: learning curves of the main command's default settings over several seeds.

Each seed runs ``python -m sb3_mpail.train_navigation`` (default settings, the given demos) with a deterministic
evaluation every ``--eval-freq`` env steps; the models stay in ``--out-dir/seed<N>/model.zip`` for
``benchmarks/navigation_ood.py``. Writes the learning-curve figure to ``benchmarks/figures/`` and the
``navigation`` section of BENCHMARKS.md.

Usage::

    python -m benchmarks.navigation                    # 3 seeds x 4 demos, one seed after the other
    python -m benchmarks.navigation --report-only      # rewrite the section from the saved results
"""

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import torch as th

from benchmarks.report import machine_description, write_section
from sb3_mpail.train_navigation import DEFAULT_DEMOS

REPO_ROOT = Path(__file__).resolve().parent.parent
FIGURES = REPO_ROOT / "benchmarks" / "figures"
DEFAULT_OUT_DIR = REPO_ROOT / "runs" / "benchmarks" / "navigation"
TARGET = 0.9
#: the final models are re-evaluated from seed ``REEVALUATION_SEED + training seed`` (starts and planner noise)
REEVALUATION_SEED = 30_000


def run_seed(seed: int, args: argparse.Namespace) -> subprocess.Popen:
    """
    Starts the main command for one seed, its output going to ``<out-dir>/seed<N>/train.log``.

    :param seed: training seed
    :param args: this benchmark's command line
    """
    out_dir = Path(args.out_dir) / f"seed{seed}"
    command = [
        sys.executable, "-W", "ignore", "-m", "sb3_mpail.train_navigation",
        "--demos", args.demos, "--seed", str(seed), "--out-dir", str(out_dir),
        "--eval-freq", str(args.eval_freq), "--n-eval-episodes", str(args.n_eval_episodes),
        "--threads", str(args.threads), "--no-progress-bar", *args.extra,
    ]  # fmt: skip
    if args.timesteps is not None:
        command += ["--timesteps", str(args.timesteps)]
    out_dir.mkdir(parents=True, exist_ok=True)
    log = open(out_dir / "train.log", "w")
    print(" ".join(command[3:]), f"> {out_dir / 'train.log'}", flush=True)
    return subprocess.Popen(command, cwd=REPO_ROOT, stdout=log, stderr=subprocess.STDOUT)


def steps_to_reach(curve: List[Dict[str, float]], target: float = TARGET) -> int | None:
    """
    The first evaluated step count at which the normalised score reached ``target`` (``None``: never).

    :param curve: a ``results.json`` learning curve
    :param target: normalised score to reach
    """
    for point in curve:
        if point["normalised_score"] >= target:
            return int(point["steps"])
    return None


def reevaluate(model_path: Path, n_episodes: int, seed: int, demos: str) -> Tuple[float, float]:
    """
    The saved final model's deterministic mean return over ``n_episodes`` fresh episodes, with the planner's noise
    seeded too, so the figure does not hang on the few episodes of the learning curve.

    :param model_path: a ``model.zip`` written by the main command
    :param n_episodes: evaluation episodes
    :param seed: seed of the starts and of the planner's sampling noise
    :param demos: the demos trained on (their expert is the score's 1)
    :return: mean return and its normalised score
    """
    from sb3_mpail import MPAIL
    from sb3_mpail.evaluation import normalised_score
    from sb3_mpail.train_navigation import evaluate, reference_of

    model = MPAIL.load(model_path, device="cpu")
    model.set_random_seed(seed)
    mean_return, _ = evaluate(model, n_episodes, seed)
    return mean_return, normalised_score(mean_return, reference_of(demos))


def report(args: argparse.Namespace, wall_seconds: float | None) -> str:
    """
    Draws the learning curves and returns the BENCHMARKS.md section, from the seeds' ``results.json``.

    :param args: this benchmark's command line
    :param wall_seconds: the whole benchmark's wall-clock (``None``: not measured, e.g. ``--report-only``)
    """
    from sb3_mpail.evaluation import reference_returns
    from sb3_mpail.plotting import plot_learning_curves
    from sb3_mpail.train_navigation import reference_family, reference_of

    results = []
    for seed in args.seeds:
        path = Path(args.out_dir) / f"seed{seed}" / "results.json"
        if not path.exists():
            raise SystemExit(f"{path} is missing: run the benchmark for seed {seed} first.")
        results.append(json.loads(path.read_text()))
    final = [
        reevaluate(Path(args.out_dir) / f"seed{seed}" / "model.zip", args.final_eval_episodes, REEVALUATION_SEED + seed,
                   args.demos)  # fmt: skip
        for seed in args.seeds
    ]
    returns, scores = np.array([r for r, _ in final]), np.array([s for _, s in final])
    demos_name = Path(args.demos).name
    figure = FIGURES / f"navigation_learning_curves_{Path(args.demos).stem}.png"
    curves = [
        (np.array([p["steps"] for p in r["learning_curve"]]), np.array([p["normalised_score"] for p in r["learning_curve"]]))
        for r in results
    ]
    plot_learning_curves(
        curves,
        figure,
        labels=[f"seed {r['seed']}" for r in results],
        title=f"MPAIL on Navigation-v0, {demos_name}, default CPU settings ({len(results)} seeds; deterministic eval, "
        f"{results[0]['n_eval_episodes']} episodes)",
    )
    example = Path(args.out_dir) / f"seed{args.seeds[0]}" / "navigation.png"
    example_figure = FIGURES / f"navigation_seed{args.seeds[0]}_{Path(args.demos).stem}.png"
    if example.exists():
        shutil.copyfile(example, example_figure)
    first = results[0]
    random_return, expert_return = reference_returns(reference_of(args.demos))
    command = "python -m benchmarks.navigation " + " ".join(option for option in sys.argv[1:] if option != "--report-only")
    lines = [
        "## Navigation (`sb3_mpail/Navigation-v0`): learning with the default CPU settings",
        "",
        f"Command: `{command.strip()}` (each seed runs `{first['command'].split(' --demos')[0]} --demos {args.demos} "
        f"--seed N --eval-freq {args.eval_freq} ...`). Machine: {machine_description()}; the CPU was shared with "
        "other jobs, so wall-clock figures are upper bounds.",
        "",
        f"Settings (the main command's defaults): {first['timesteps']} env steps, {first['n_envs']} envs, planner "
        f"`{first['policy_kwargs']}` (bicycle model), algorithm `{first['algorithm_kwargs']}`, every other setting "
        "the paper's. Score = (R - random) / (expert - random) with R the deterministic planner's mean return "
        f"({first['n_eval_episodes']} episodes per learning-curve point); expert {expert_return:.1f}, random "
        f"{random_return:.1f} "
        f"(`sb3_mpail/data/{reference_family(args.demos)}.json`).",
        "",
        f"**Final normalised score: {scores.mean():.3f} ± {scores.std():.3f}** (mean ± std over {len(scores)} seeds of "
        f"the final models, each re-evaluated on {args.final_eval_episodes} fresh episodes; return "
        f"{returns.mean():.0f} ± {returns.std():.0f}); target >= {TARGET}: "
        f"**{'met' if scores.mean() >= TARGET else 'not met'}**. The learning curve's points (and its last one, "
        f"{first['n_eval_episodes']} episodes at the end of training) are noisier: the deterministic planner still "
        "samples, and one update can move the score by 0.1 or more.",
        "",
        f"| seed | final score ({args.final_eval_episodes} episodes) | last curve point ({first['n_eval_episodes']} episodes) "
        f"| best curve point | env steps to first reach {TARGET} | training wall-clock (s, evals excluded) |",
        "|---|---|---|---|---|---|",
    ]
    for r, score in zip(results, scores):
        reach = steps_to_reach(r["learning_curve"])
        best = max(r["learning_curve"], key=lambda point: point["normalised_score"])
        lines.append(
            f"| {r['seed']} | {score:.3f} | {r['normalised_score']:.3f} | {best['normalised_score']:.3f} "
            f"({best['steps']} steps) | {reach if reach is not None else 'not reached'} | {r['train_seconds']:.0f} |"
        )
    if wall_seconds is not None:
        lines += ["", f"Whole benchmark wall-clock (training, evaluations, figures): {wall_seconds / 60:.1f} min."]
    lines += [
        "",
        f"Learning curves (thin: seeds; thick: mean; band: min-max): `{figure.relative_to(REPO_ROOT)}`; "
        f"the planner's paths and learned cost map of seed {args.seeds[0]}: `{example_figure.relative_to(REPO_ROOT)}`.",
        "",
        f"![navigation learning curves]({figure.relative_to(REPO_ROOT).as_posix()})",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--demos", default=DEFAULT_DEMOS, help="a shipped demo set's name or a demo file")
    parser.add_argument("--timesteps", type=int, default=None, help="default: the main command's")
    parser.add_argument("--eval-freq", type=int, default=10000)
    parser.add_argument("--n-eval-episodes", type=int, default=10, help="episodes per learning-curve point")
    parser.add_argument("--final-eval-episodes", type=int, default=50, help="episodes re-evaluating each final model")
    parser.add_argument("--jobs", type=int, default=1, help="seeds trained at once")
    parser.add_argument("--threads", type=int, default=1, help="torch threads per seed")
    parser.add_argument("--out-dir", default=str(DEFAULT_OUT_DIR))
    parser.add_argument("--report-only", action="store_true", help="rewrite the section from saved results")
    parser.add_argument("--section", default="navigation", help="BENCHMARKS.md section to write")
    parser.add_argument("extra", nargs="*", help="further train_navigation options, after --")
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    started = time.perf_counter()
    wall_seconds = None
    if not args.report_only:
        pending, running = list(args.seeds), []
        while pending or running:
            while pending and len(running) < args.jobs:
                seed = pending.pop(0)
                running.append((seed, run_seed(seed, args)))
            time.sleep(5)
            for seed, process in list(running):
                if process.poll() is not None:
                    running.remove((seed, process))
                    if process.returncode != 0:
                        raise SystemExit(f"seed {seed} failed (exit {process.returncode}); see its train.log")
                    result = json.loads((Path(args.out_dir) / f"seed{seed}" / "results.json").read_text())
                    print(f"seed {seed}: score {result['normalised_score']:.3f}, {result['train_seconds']:.0f} s", flush=True)
        wall_seconds = time.perf_counter() - started
    markdown = report(args, wall_seconds)
    write_section(args.section, markdown)
    print(markdown)


if __name__ == "__main__":
    main()
