"""
What makes MPAIL's navigation planner reach the goal from out-of-distribution starts: one training setting changed at
a time around the main command's planner with one discriminator, each over several seeds, each model measured in
distribution and from the 40 x 40 m box of the paper's OOD test.

Every variant trains as ``python -m sb3_mpail.train_navigation`` does (its defaults, :func:`make_model`) with one
discriminator (:data:`BASE_POLICY_KWARGS`) and the changes listed in :data:`VARIANTS`, then is evaluated
deterministically: in distribution on 50 episodes (score against the demos' own expert), and from 200 starts uniform
in the 40 x 40 m box with uniform heading (the same starts for every variant and seed), measured as the grid runner
measures every algorithm (:func:`benchmarks.runner.ood_measures`) plus the share of episodes that end circling (yaw
rate above 2 rad/s over the last 50 steps). Results go to ``benchmarks/results/navigation_ablations/<variant>_seed<N>.json``
(a rerun skips finished runs), the table to the ``navigation-ablations`` section of BENCHMARKS.md.

Usage::

    python -m benchmarks.navigation_ablations --seeds 0 1 2 --workers 2          # every variant
    python -m benchmarks.navigation_ablations --variants one-discriminator stopping-demos --seeds 0 1 2
    python -m benchmarks.navigation_ablations --report-only
    python -m benchmarks.navigation_ablations --variants concave-value --reevaluate   # saved models, evaluated again
"""

import argparse
import json
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence

import numpy as np
import torch as th

from benchmarks.report import DETERMINISTIC_NOISE, SAME_NOISE, commands_of, machine_description, machines_of, write_section
from benchmarks.runner import (
    CIRCLING_AWAY,
    CIRCLING_YAW_RATE,
    GOAL_RADIUS,
    OOD_SEED,
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
from sb3_mpail.demos import shipped_demos
from sb3_mpail.evaluation import evaluate_episodes, normalised_score
from sb3_mpail.mppi import AngleFeatures
from sb3_mpail.mppi.costs import StandardisedFeatures
from sb3_mpail.train_navigation import (
    DEFAULT_DEMOS,
    DEFAULT_N_ENVS,
    DEFAULT_TIMESTEPS,
    ENV_ID,
    PAPER_ALGORITHM_KWARGS,
    PAPER_N_ENVS,
    PAPER_POLICY_KWARGS,
    PAPER_TIMESTEPS,
    make_model,
    reference_of,
)

RESULTS_DIR = Path(__file__).resolve().parent / "results" / "navigation_ablations"
MODELS_DIR = Path(__file__).resolve().parent.parent / "runs" / "benchmarks" / "navigation_ablations"
#: in-distribution evaluation episodes start from ``reset(seed=ID_SEED + i)``
ID_SEED = 30_000
N_ID_EPISODES, N_OOD_STARTS = 50, 200


@dataclass(frozen=True)
class Variant:
    """
    One training setting against the base (:data:`BASE_POLICY_KWARGS`).

    :param question: what the row tests, as the table says it
    :param policy_kwargs: planner settings replacing the main command's, built per run (modules are not shared)
    :param algorithm_kwargs: MPAIL arguments replacing the main command's
    :param demos: the shipped demo set trained on
    :param timesteps: env steps
    :param n_envs: training envs
    :param env_kwargs: the training envs' keyword arguments (a wider start region)
    :param counts: whether the row trains as the paper does (the 1 x 1 m start region, the shipped demos): rows that
        do not are reported apart and never count for the out-of-distribution target
    """

    question: str
    policy_kwargs: Callable[[], Dict[str, Any]] = dict
    algorithm_kwargs: Dict[str, Any] = field(default_factory=dict)
    demos: str = DEFAULT_DEMOS
    timesteps: int = DEFAULT_TIMESTEPS
    n_envs: int = DEFAULT_N_ENVS
    env_kwargs: Dict[str, Any] | None = None
    counts: bool = True


def standardised_headings() -> Dict[str, Any]:
    """Both networks on the heading as cosine and sine, standardised with the default demos' statistics."""
    family, n_demos = DEFAULT_DEMOS.rsplit("_", 1)
    standardised = StandardisedFeatures(AngleFeatures([5]), 13, min_scale=1.0)  # 12-D state, the heading as cos, sin
    standardised.fit(th.as_tensor(np.concatenate([t.obs for t in shipped_demos(family, int(n_demos))])))
    return dict(discriminator_features=standardised, value_features=standardised)


#: what every variant changes besides its own settings: the main command's planner with one discriminator, the
#: defaults these rows were measured against before the ensemble became one
BASE_POLICY_KWARGS: Dict[str, Any] = dict(discriminator_ensemble_size=1)

#: every variant, by name
VARIANTS: Dict[str, Variant] = {
    "one-discriminator": Variant(
        "one discriminator: the main command's planner before its ensemble, and every other row's base"
    ),
    "stopping-demos": Variant("demos of an expert that stops on the goal (navigation_4)", demos="navigation_4"),
    "gaussian-sampler": Variant(
        "Gaussian sampling (the paper's) instead of delta sampling",
        lambda: dict(sampler="gaussian", noise_std=0.3, sampler_kwargs=None),
    ),
    "raw-heading": Variant("the discriminator sees the raw wrapped yaw", lambda: dict(discriminator_features=None)),
    "heading-for-the-value-too": Variant(
        "the value sees the heading as cosine and sine too", lambda: dict(value_features=dict(angles=[5]))
    ),
    "delta-steps-0.2": Variant(
        "delta sampling with the authors' step limit, 0.2, instead of 0.5", lambda: dict(sampler_kwargs=dict(max_delta=0.2))
    ),
    "standardised-inputs": Variant(
        "both networks' inputs standardised with the demos' statistics (scale floored at 1)", standardised_headings
    ),
    "standardised-inputs-option": Variant(
        "the library's standardise_inputs: both networks' inputs (the value's on the heading as cosine and sine too) "
        "standardised with the demos' statistics of s and s'",
        lambda: dict(value_features=dict(angles=[5]), standardise_inputs=True),
    ),
    "value-layer-norm": Variant(
        "the value's hidden layers layer-normalised, which bounds it (it levels off far from the data)",
        lambda: dict(value_layer_norm=True),
    ),
    "concave-value": Variant(
        "a value concave in the state (a negated input-convex network): one peak region, falling away in every direction",
        lambda: dict(concave_value=True),
    ),
    "concave-value-on-angles": Variant(
        "the concave value on the heading as cosine and sine",
        lambda: dict(concave_value=True, value_features=dict(angles=[5])),
    ),
    "capped-reward": Variant(
        "the learned reward log 2D (reward_form='capped'): flat at log 2 where transitions look like the expert's, so "
        "the discriminator's upward extrapolation (hard left turns, the diagonal behind the start) earns nothing more",
        lambda: dict(reward_form="capped"),
    ),
    "capped-reward-ensemble": Variant(
        "both: the capped reward on the 5-discriminator ensemble with its disagreement term",
        lambda: dict(reward_form="capped", discriminator_ensemble_size=5, discriminator_disagreement=1.0),
    ),
    "value-ensemble": Variant(
        "5 value networks, the terminal value their mean less their standard deviation (disagreement lowers the value "
        "where the networks extrapolate differently: past the goal, far from the visited states)",
        lambda: dict(value_ensemble_size=5, value_disagreement=1.0),
    ),
    "both-ensembles": Variant(
        "5 discriminators and 5 value networks, each ensemble its mean less its standard deviation",
        lambda: dict(discriminator_ensemble_size=5, discriminator_disagreement=1.0, value_ensemble_size=5,
                     value_disagreement=1.0),
    ),
    "discriminator-ensemble": Variant(
        "5 discriminators, the cost their mean logit less their standard deviation (disagreement as an OOD penalty): the "
        "main command's defaults",
        lambda: dict(discriminator_ensemble_size=5, discriminator_disagreement=1.0),
    ),
    "discriminator-ensemble-mean": Variant(
        "5 discriminators, the cost their mean logit alone (no disagreement term: does the averaging or the penalty help?)",
        lambda: dict(discriminator_ensemble_size=5, discriminator_disagreement=0.0),
    ),
    "discriminator-ensemble-10": Variant(
        "10 discriminators, the cost their mean logit less their standard deviation (does a larger ensemble help more?)",
        lambda: dict(discriminator_ensemble_size=10, discriminator_disagreement=1.0),
    ),
    "discriminator-ensemble-disagreement-2": Variant(
        "5 discriminators, the cost their mean logit less twice their standard deviation (a stronger OOD penalty)",
        lambda: dict(discriminator_ensemble_size=5, discriminator_disagreement=2.0),
    ),
    "discriminator-ensemble-standardised": Variant(
        "both: the 5-discriminator ensemble with its disagreement term and the standardised inputs",
        lambda: dict(standardised_headings(), discriminator_ensemble_size=5, discriminator_disagreement=1.0),
    ),
    "gradient-penalty": Variant(
        "a gradient penalty on the discriminator (weight 10, WGAN-GP's, between expert and agent) beside spectral norm",
        algorithm_kwargs=dict(discriminator_gradient_penalty=10.0),
    ),
    "gradient-penalty-instead-of-spectral-norm": Variant(
        "the gradient penalty (weight 10) instead of spectral norm",
        lambda: dict(use_spectral_norm=False),
        algorithm_kwargs=dict(discriminator_gradient_penalty=10.0),
    ),
    "discriminator-replay": Variant(
        "the discriminator also sees the last 10 rollouts (8000 agent transitions)",
        algorithm_kwargs=dict(discriminator_replay_size=8000),
    ),
    "learned-temperature": Variant(
        "the authors' learned temperature (RMSprop on log lambda, weight entropy)",
        algorithm_kwargs=dict(temperature="learned"),
    ),
    "horizon-20": Variant("horizon 20 instead of 10", lambda: dict(horizon=20)),
    "authors-planner": Variant(
        "the authors' code: horizon 20, K 1024, J 2, delta steps 0.2, discriminator 16 x 16 with L2 1e-3",
        lambda: dict(horizon=20, n_samples=1024, n_iterations=2, sampler_kwargs=dict(max_delta=0.2),
                     discriminator_hidden_sizes=(16, 16)),  # fmt: skip
        algorithm_kwargs=dict(discriminator_l2=1e-3),
    ),
    "cost-only-h5": Variant("cost only (no terminal value), horizon 5", lambda: dict(use_terminal_value=False, horizon=5)),
    "cost-only-h10": Variant("cost only (no terminal value), horizon 10", lambda: dict(use_terminal_value=False)),
    "cost-only-h20": Variant("cost only (no terminal value), horizon 20", lambda: dict(use_terminal_value=False, horizon=20)),
    "value-only-h5": Variant("value only (no step costs), horizon 5", lambda: dict(use_step_cost=False, horizon=5)),
    "value-only-h10": Variant("value only (no step costs), horizon 10", lambda: dict(use_step_cost=False)),
    "value-only-h20": Variant("value only (no step costs), horizon 20", lambda: dict(use_step_cost=False, horizon=20)),
    "wide-starts": Variant(
        "training starts anywhere in a 10 x 10 m box (not the paper's training: reported apart)",
        env_kwargs=dict(start_region=5.0),
        counts=False,
    ),
    "paper-scale": Variant(
        "the paper's planner and budget: Gaussian samples, N 512, H 10, J 5, 64 envs x 200 steps, discriminator every "
        "3rd iteration, 1M steps",
        lambda: dict(PAPER_POLICY_KWARGS),
        algorithm_kwargs=dict(PAPER_ALGORITHM_KWARGS),
        timesteps=PAPER_TIMESTEPS,
        n_envs=PAPER_N_ENVS,
    ),
    "paper-scale-every-iteration": Variant(
        "the paper's planner and budget with the discriminator updated every iteration",
        lambda: dict(PAPER_POLICY_KWARGS),
        algorithm_kwargs=dict(PAPER_ALGORITHM_KWARGS, discriminator_update_interval=1),
        timesteps=PAPER_TIMESTEPS,
        n_envs=PAPER_N_ENVS,
    ),
}


def result_path(variant: str, seed: int, results_dir: Path = RESULTS_DIR) -> Path:
    return Path(results_dir) / f"{variant}_seed{seed}.json"


#: what the report quotes for the runs stored before each run recorded its command: their variants and seeds are the table's
UNRECORDED_COMMAND = "python -m benchmarks.navigation_ablations --variants <variant> --seeds <seeds>"


def run_variant(
    name: str, seed: int, command: str, results_dir: Path = RESULTS_DIR, models_dir: Path = MODELS_DIR
) -> Path:
    """
    Trains one variant on one seed, evaluates it and writes its result (skipped when the file exists).

    :param name: a key of :data:`VARIANTS`
    :param seed: training seed
    :param command: the command line that asked for it, quoted by the report
    :return: the result file
    """
    path = result_path(name, seed, results_dir)
    if path.exists():
        return path
    th.set_num_threads(1)
    variant = VARIANTS[name]
    model = make_model(variant.demos, n_envs=variant.n_envs, seed=seed,
                       policy_kwargs={**BASE_POLICY_KWARGS, **variant.policy_kwargs()},
                       env_kwargs=variant.env_kwargs, **variant.algorithm_kwargs)  # fmt: skip
    started = time.perf_counter()
    model.learn(variant.timesteps)
    train_seconds = time.perf_counter() - started
    model.save(Path(models_dir) / f"{name}_seed{seed}.zip")
    result = dict(
        variant=name, seed=seed, question=variant.question, counts=variant.counts, demos=variant.demos,
        timesteps=variant.timesteps, n_envs=variant.n_envs, train_seconds=round(train_seconds, 1),
        machine=machine_description(), deterministic_noise=DETERMINISTIC_NOISE, command=command,
        **evaluation(model, variant, seed),
    )  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result))
    return path


def evaluation(model: MPAIL, variant: Variant, seed: int) -> Dict[str, Any]:
    """A trained model's figures: in distribution (return, score) and out of distribution (record and measures)."""
    in_distribution = evaluate_episodes(model, ENV_ID, N_ID_EPISODES, ID_SEED + seed, n_envs=10)
    record = ood_record(ood_episodes(model, N_OOD_STARTS))
    return dict(
        id_return=in_distribution.mean_return, ood=record, **ood_measures(record),
        id_score=normalised_score(in_distribution.mean_return, reference_of(variant.demos)),
    )  # fmt: skip


def reevaluate_variant(name: str, seed: int, results_dir: Path = RESULTS_DIR, models_dir: Path = MODELS_DIR) -> Path:
    """
    Evaluates a stored run's saved model again and replaces the figures of its result (its training figures stay),
    marking it ``reevaluated`` with the machine and the planner's deterministic noise of now.

    :param name: a key of :data:`VARIANTS`
    :param seed: training seed
    :return: the result file
    """
    path, model_file = result_path(name, seed, results_dir), Path(models_dir) / f"{name}_seed{seed}.zip"
    th.set_num_threads(1)
    result = json.loads(path.read_text())
    result.update(evaluation(MPAIL.load(model_file, device="cpu"), VARIANTS[name], seed))
    result["reevaluated"] = dict(machine=machine_description(), deterministic_noise=DETERMINISTIC_NOISE)
    path.write_text(json.dumps(result))
    return path


def evaluation_noise(run: Dict[str, Any]) -> Optional[str]:
    """How the deterministic planning that scored a run drew its samples (``None``: not recorded, before the field)."""
    return run["reevaluated"]["deterministic_noise"] if "reevaluated" in run else run.get("deterministic_noise")


def report(results_dir: Path, names: Sequence[str]) -> str:
    """
    The ``navigation-ablations`` section: per variant, means and 95% CIs over its seeds, with the command lines that
    made the runs.

    :param results_dir: where the results are
    :param names: the variants, in table order
    """
    columns = ("id_score", "reached_reachable", "final_reward", "progress", "circling", "circling_away")
    ceiling = ood_measures(true_reward_record(N_OOD_STARTS, Path(results_dir).parent))
    header = [
        "| variant | what changes | seeds | in-distribution score | OOD: within 2 m, reachable starts | OOD: mean final "
        f"reward | OOD: mean progress | OOD: ends circling | OOD: ... farther than {CIRCLING_AWAY:g} m from the goal |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    rows: Dict[bool, List[str]] = {True: [], False: []}
    every_run: List[Dict[str, Any]] = []
    for name in names:
        runs = [json.loads(p.read_text()) for p in sorted(Path(results_dir).glob(f"{name}_seed*.json"))]
        if not runs:
            continue
        every_run += runs
        cells = [format_ci(*mean_ci([run[column] for run in runs])) for column in columns]
        variant = VARIANTS[name]
        same_noise = sum(evaluation_noise(run) == SAME_NOISE for run in runs)
        seeds = f"{len(runs)}" + (f" ({same_noise} †)" if same_noise else "")
        rows[variant.counts].append(f"| `{name}` | {variant.question} | {seeds} | " + " | ".join(cells) + " |")
    lines = [
        "## Navigation ablations: what makes the planner generalise",
        "",
        "Each variant changes one setting of `one-discriminator`: the main command (`python -m sb3_mpail.train_navigation`: "
        f"{DEFAULT_TIMESTEPS} env steps, {DEFAULT_N_ENVS} envs, demos `{DEFAULT_DEMOS}` unless a row says otherwise) "
        "with one discriminator, its defaults before `discriminator-ensemble` became them. "
        f"In distribution: the deterministic planner's normalised score on {N_ID_EPISODES} episodes from the training "
        f"start region, against the demos' own expert. Out of distribution: {N_OOD_STARTS} deterministic 100-step "
        f"episodes from starts uniform in the 40 x 40 m box with uniform heading (seeds {OOD_SEED}+, the same starts "
        f"for every row); within {GOAL_RADIUS:g} m of the goal among the starts within 32 m (reachable at the 3 m/s "
        "top speed), mean final reward (sqrt(200) - final distance), mean progress ((start - final distance) / start "
        f"distance), share of episodes ending in a circle (yaw rate > {CIRCLING_YAW_RATE:g} rad/s over their last "
        f"half), anywhere and farther than {CIRCLING_AWAY:g} m from the goal. Means ± 95% CI (Student's t) over seeds.",
        "",
        *header,
        *rows[True],
        f"| {TRUE_REWARD_LABEL} | no learning: the untrained planner's costs are the true reward's | – | – | "
        + " | ".join(f"{ceiling[column]:.2f}" for column in columns[1:]) + " |",
        "",
        TRUE_REWARD_NOTE,
    ]
    if rows[False]:
        lines += ["", "Not trained as the paper trains (reported apart; these never count for the OOD target):", "",
                  *header, *rows[False]]  # fmt: skip
    reevaluated = [f"`{run['variant']}` seed {run['seed']}" for run in every_run if "reevaluated" in run]
    commands = commands_of(every_run, unrecorded=UNRECORDED_COMMAND)
    lines += ["", f"Command{'s' if len(commands) > 1 else ''}: " + "; ".join(f"`{command}`" for command in commands)
              + f" on {machines_of(every_run)}."]  # fmt: skip
    if any(evaluation_noise(run) == SAME_NOISE for run in every_run):
        lines += ["", "†: runs evaluated by a version whose deterministic planning drew the same samples at every step "
                      "(a worse planner); `--reevaluate` scores their saved models again."]  # fmt: skip
    if reevaluated:
        lines += ["", f"Evaluated again from their saved models (`--reevaluate`) with deterministic planning drawing fresh "
                      f"noise at every step, after a version that drew the same noise at every step: "
                      f"{', '.join(reevaluated)}."]  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--workers", type=int, default=1, help="runs trained at once, one torch thread each")
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    parser.add_argument("--report-only", action="store_true", help="only rewrite the section from stored results")
    parser.add_argument("--reevaluate", action="store_true",
                        help="evaluate the saved models of stored runs again (none is trained), then rewrite the section")
    args = parser.parse_args()
    if args.reevaluate:
        jobs = [(name, seed) for name in args.variants for seed in args.seeds
                if result_path(name, seed, args.results_dir).exists() and (MODELS_DIR / f"{name}_seed{seed}.zip").exists()]
        print(f"{len(jobs)} runs to evaluate again", flush=True)
        with ProcessPoolExecutor(max(1, args.workers), mp_context=multiprocessing.get_context("spawn")) as pool:
            for future in [pool.submit(reevaluate_variant, name, seed, args.results_dir) for name, seed in jobs]:
                print("wrote", future.result(), flush=True)
    elif not args.report_only:
        jobs = [(name, seed) for name in args.variants for seed in args.seeds
                if not result_path(name, seed, args.results_dir).exists()]  # fmt: skip
        print(f"{len(jobs)} runs to do", flush=True)
        with ProcessPoolExecutor(max(1, args.workers), mp_context=multiprocessing.get_context("spawn")) as pool:
            command = "python -m benchmarks.navigation_ablations " + " ".join(sys.argv[1:])
            futures = [pool.submit(run_variant, name, seed, command, args.results_dir) for name, seed in jobs]
            for future in futures:
                print("wrote", future.result(), flush=True)
    th.set_num_threads(1)  # the runs' setting, quoted in the report
    names = [name for name in VARIANTS if name in args.variants or any(Path(args.results_dir).glob(f"{name}_seed*.json"))]
    write_section("navigation-ablations", report(args.results_dir, names))


if __name__ == "__main__":
    main()
