"""
First learning check: MPAIL on gymnasium's Pendulum-v1 from 4 observation-only expert demos, planning with the
exact pendulum model. Trains over several seeds, evaluates the deterministic planner along the way, and reports the
final return next to the expert's and a random policy's (normalised score: random = 0, expert = 1).

Run: ``python -m benchmarks.pendulum`` (``--seeds 0 1 2 --timesteps 50000``); writes the ``pendulum`` section of
BENCHMARKS.md and ``benchmarks/figures/pendulum.png``.
"""

import argparse
import time
from pathlib import Path
from typing import Dict, List

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

from benchmarks.report import machine_description, write_section
from sb3_mpail import MPAIL
from sb3_mpail.demos import shipped_demo_info
from sb3_mpail.evaluation import evaluate_episodes, normalised_score

DEMOS = "pendulum_4"
EXPERT_STATS = shipped_demo_info("pendulum")

# Settings of this benchmark. The planner is lighter than the paper's N=512/J=5 so three seeds fit in minutes on a
# 2-core CPU; the algorithm updates more often than the paper's 3:1 ratio because the budget is only 50k steps.
SETTINGS = dict(
    n_steps=100,
    discriminator_update_interval=1,
    policy_kwargs=dict(n_samples=256, horizon=10, n_iterations=3),
)
N_ENVS = 4


class EvaluationCurve(BaseCallback):
    """Deterministic evaluation of the planner every ``eval_every`` env steps, on fixed evaluation seeds."""

    def __init__(self, eval_every: int, n_episodes: int):
        super().__init__()
        self.eval_every = eval_every
        self.n_episodes = n_episodes
        self.next_eval = eval_every
        self.curve: List[Dict[str, float]] = []

    def evaluate(self) -> float:
        mean_return = evaluate_episodes(self.model, "Pendulum-v1", self.n_episodes, seed=10_000).mean_return
        score = normalised_score(mean_return, EXPERT_STATS)
        self.curve.append({"timesteps": self.num_timesteps, "return": mean_return, "score": score})
        return mean_return

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next_eval:
            self.next_eval += self.eval_every
            self.evaluate()
            if self.verbose:
                point = self.curve[-1]
                print(f"  {self.num_timesteps:>7} steps: return {point['return']:8.1f}, score {point['score']:.3f}")
        return True


def run_seed(seed: int, timesteps: int, eval_every: int, n_eval_episodes: int) -> Dict:
    model = MPAIL("MlpMPPI", make_vec_env("Pendulum-v1", n_envs=N_ENVS, seed=seed), DEMOS, seed=seed, **SETTINGS)
    curve = EvaluationCurve(eval_every, n_eval_episodes)
    curve.verbose = 1
    start = time.time()
    model.learn(timesteps, callback=curve)
    seconds = time.time() - start
    if not curve.curve or curve.curve[-1]["timesteps"] < model.num_timesteps:
        curve.evaluate()
    return {"seed": seed, "curve": curve.curve, "final_return": curve.curve[-1]["return"],
            "final_score": curve.curve[-1]["score"], "seconds": seconds}


def plot(results: List[Dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.array([point["timesteps"] for point in results[0]["curve"]])
    scores = np.array([[point["score"] for point in result["curve"]] for result in results])
    figure, axis = plt.subplots(figsize=(6, 4))
    axis.plot(steps, scores.mean(0), label=f"MPAIL (mean of {len(results)} seeds)")
    axis.fill_between(steps, scores.min(0), scores.max(0), alpha=0.3, label="min-max over seeds")
    axis.axhline(1.0, color="k", linestyle="--", label="expert (SAC)")
    axis.axhline(0.9, color="gray", linestyle=":", label="0.9")
    axis.set_xlabel("env steps")
    axis.set_ylabel("normalised score")
    axis.set_title("Pendulum-v1, 4 observation-only demos, exact model")
    axis.legend()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120, bbox_inches="tight")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--timesteps", type=int, default=50_000)
    parser.add_argument("--eval-every", type=int, default=5_000)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1, help="torch threads per run")
    parser.add_argument("--no-write", action="store_true", help="print only; leave BENCHMARKS.md alone")
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    results = []
    for seed in args.seeds:
        print(f"seed {seed}")
        results.append(run_seed(seed, args.timesteps, args.eval_every, args.eval_episodes))
    scores = np.array([result["final_score"] for result in results])
    returns = np.array([result["final_return"] for result in results])
    reached = [next((p["timesteps"] for p in result["curve"] if p["score"] >= 0.9), None) for result in results]
    command = f"python -m benchmarks.pendulum --seeds {' '.join(map(str, args.seeds))} --timesteps {args.timesteps}"
    rows = "\n".join(
        f"| {r['seed']} | {r['final_return']:.1f} | {r['final_score']:.3f} | {reach or 'not reached'} | {r['seconds']:.0f} |"
        for r, reach in zip(results, reached)
    )
    markdown = f"""## Pendulum-v1: the first learning check

MPAIL from 4 observation-only demos (the shipped `pendulum_4`), exact pendulum model, {N_ENVS} envs,
{args.timesteps} env steps, settings `{SETTINGS}`. Deterministic evaluation on {args.eval_episodes} episodes
(fixed seeds) every {args.eval_every} steps. Normalised score: random = 0 ({EXPERT_STATS['random_return_mean']:.1f}),
expert = 1 (SAC, {EXPERT_STATS['expert_return_mean']:.1f}).

| seed | final return | normalised score | env steps to reach 0.9 | train seconds |
|---|---|---|---|---|
{rows}

**Final normalised score: {scores.mean():.3f} ± {scores.std():.3f}** (mean ± std over seeds {args.seeds});
final return {returns.mean():.1f} ± {returns.std():.1f}, expert {EXPERT_STATS['expert_return_mean']:.1f},
random {EXPERT_STATS['random_return_mean']:.1f}. Curve: `benchmarks/figures/pendulum.png`.

Command: `{command}` on {machine_description()}.
"""
    print(markdown)
    if not args.no_write:
        plot(results, Path(__file__).resolve().parent / "figures" / "pendulum.png")
        write_section("pendulum", markdown)


if __name__ == "__main__":
    main()
