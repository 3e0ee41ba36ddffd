"""
What learned-model MPAIL needs on MuJoCo locomotion: one setting of a task's ``sb3_mpail/hyperparams/mpail.yml`` entry
changed at a time, each over several seeds, every model scored deterministically by its return (normalised against
the shipped demos' expert and random policy) and its forward speed.

Every variant trains ``MPAIL`` with the task's zoo entry (``n_envs``, ``n_timesteps`` unless ``--timesteps``) and
the changes listed in :data:`VARIANTS`, then plays ``--eval-episodes`` deterministic episodes from fixed seeds
(:func:`sb3_mpail.envs.locomotion.evaluate_locomotion`). Results go to
``benchmarks/results/locomotion_ablations/<task>_<steps>steps/<variant>_seed<N>.json`` (a rerun skips finished runs),
the table to the ``locomotion-ablations`` section of BENCHMARKS.md.

Usage::

    python -m benchmarks.locomotion_ablations --env Hopper-v4 --seeds 0 1 2 --workers 2
    python -m benchmarks.locomotion_ablations --env Hopper-v4 --variants defaults no-prior --timesteps 50000 --seeds 0
    python -m benchmarks.locomotion_ablations --report-only
"""

import argparse
import json
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
from stable_baselines3.common.env_util import make_vec_env

from benchmarks.report import (
    DETERMINISTIC_NOISE,
    commands_of,
    format_ci,
    machine_description,
    machines_of,
    mean_ci,
    write_section,
)
from benchmarks.scenarios import zoo_hyperparameters
from sb3_mpail import MPAIL
from sb3_mpail.averaging import PolicyAverage
from sb3_mpail.demos import shipped_demo_info
from sb3_mpail.envs.locomotion import evaluate_locomotion
from sb3_mpail.evaluation import normalised_score

RESULTS_DIR = Path(__file__).resolve().parent / "results" / "locomotion_ablations"
#: evaluation episodes start from ``reset(seed=EVAL_SEED + i)`` (disjoint from the demos' start seeds)
EVAL_SEED = 20_000

#: every variant: what the row tests, and its changes to the zoo entry (``policy_kwargs`` merged key by key)
VARIANTS: Dict[str, Dict[str, Any]] = {
    "defaults": dict(question="the task's zoo entry", changes={}),
    "with-prior": dict(
        question="the Hopper entry's policy prior added (16 proposals, half an update per env step)",
        changes=dict(prior_updates_per_step=0.5, policy_kwargs=dict(policy_prior=True, n_proposals=16)),
    ),
    "no-prior": dict(
        question="the paper's learned-model MPAIL: no policy prior, on-policy GAE value",
        changes=dict(policy_kwargs=dict(policy_prior=False)),
    ),
    "no-proposals": dict(
        question="the prior's Q ensemble as the value, but no proposals from its actor",
        changes=dict(policy_kwargs=dict(n_proposals=0)),
    ),
    "prior-bootstraps-terminations": dict(
        question="the prior's Q targets bootstrap through terminations (MPAIL2's default)",
        changes=dict(prior_terminations="bootstrap"),
    ),
    "absorbing-terminations": dict(
        question="the prior's Q targets take a termination as an absorbing state whose reward is the terminal "
        "transition's (DAC's answer to a learned reward's sign on tasks that end episodes)",
        changes=dict(prior_terminations="absorbing"),
    ),
    "softplus-reward": dict(
        question="the learned reward -log(1 - D) = softplus(d) (GAIL's form, positive everywhere) instead of the logit d: "
        "staying up always pays, so a fall forfeits the rest of the episode's reward",
        changes=dict(policy_kwargs=dict(reward_form="softplus")),
    ),
    "capped-reward": dict(
        question="the learned reward log 2D (reward_form='capped'): the logit where a transition looks like the "
        "agent's, flat at log 2 where it looks like the expert's, so running past the expert's speed earns nothing more",
        changes=dict(policy_kwargs=dict(reward_form="capped")),
    ),
    "no-alive-bonus": dict(
        question="no bonus per step alive (reward_offset=0): the learned reward is the logit d alone",
        changes=dict(policy_kwargs=dict(reward_offset=0.0)),
    ),
    "alive-bonus": dict(
        question="the logit plus 1 per step (reward_offset=1): the logit's ranking of transitions, with a bonus for "
        "staying up where softplus(d) pays even a confidently non-expert stance",
        changes=dict(policy_kwargs=dict(reward_offset=1.0)),
    ),
    "alive-bonus-2": dict(
        question="the logit plus 2 per step (reward_offset=2): does a larger bonus for staying up help more?",
        changes=dict(policy_kwargs=dict(reward_offset=2.0)),
    ),
    "alive-bonus-3": dict(
        question="the logit plus 3 per step (reward_offset=3): does the bonus's gain go on past 2?",
        changes=dict(policy_kwargs=dict(reward_offset=3.0)),
    ),
    "prior-updates-1": dict(question="one prior update per env step", changes=dict(prior_updates_per_step=1.0)),
    "prior-128": dict(
        question="the prior's actor and Q networks 128 x 128 instead of 256 x 256 (an update takes 0.6x the time)",
        changes=dict(policy_kwargs=dict(prior_kwargs=dict(net_arch=(128, 128)))),
    ),
    "prior-quarter": dict(
        question="a quarter of a prior update per env step (the networks 256 x 256): half the entry's update time",
        changes=dict(prior_updates_per_step=0.25),
    ),
    "prior-quarter-128": dict(
        question="a quarter of a prior update per env step and 128 x 128 prior networks: the prior's updates, most of "
        "a run's time, cut to about a third of the entry's",
        changes=dict(prior_updates_per_step=0.25, policy_kwargs=dict(prior_kwargs=dict(net_arch=(128, 128)))),
    ),
    "standardised-inputs": dict(
        question="the discriminator's inputs standardised with the demos' statistics, scales floored at 0.01 only (as "
        "MPAIL2 standardises its observations)",
        changes=dict(policy_kwargs=dict(standardise_inputs=True, min_input_scale=0.01)),
    ),
    "prior-128-standardised": dict(
        question="both: the prior's networks 128 x 128 and the discriminator's inputs standardised (scales >= 0.01)",
        changes=dict(policy_kwargs=dict(prior_kwargs=dict(net_arch=(128, 128)), standardise_inputs=True,
                                        min_input_scale=0.01)),  # fmt: skip
    ),
    "discriminator-replay": dict(
        question="the discriminator also sees the last 50,000 agent transitions",
        changes=dict(discriminator_replay_size=50_000),
    ),
    "slower-discriminator": dict(
        question="the discriminator updated every third rollout (the paper's 3:1 ratio) instead of every rollout: a "
        "learned reward that moves more slowly than the prior learns it",
        changes=dict(discriminator_update_interval=3),
    ),
    "ensemble-replay": dict(
        question="both: 5 discriminators (mean less standard deviation) that also see the last 50,000 agent transitions",
        changes=dict(discriminator_replay_size=50_000,
                     policy_kwargs=dict(discriminator_ensemble_size=5, discriminator_disagreement=1.0)),  # fmt: skip
    ),
    "agent-reward-mean": dict(
        question="the learned reward that trains the prior's Q shifted after every rollout so that the rollout's mean is "
        "0.2 (agent_reward_mean=0.2): staying up pays a little whatever the discriminator makes of the agent, where "
        "the logit's mean turns negative before every collapse and a constant bonus of 1 taught standing",
        changes=dict(agent_reward_mean=0.2, policy_kwargs=dict(reward_offset=0.0)),  # Walker2d's entry sets an offset
    ),
    "ensemble-reward-mean": dict(
        question="both: 5 discriminators (mean less standard deviation) and the prior's reward shifted to a rollout mean "
        "of 0.2: the best-scoring variant with the one that ends the training collapses",
        changes=dict(
            agent_reward_mean=0.2,
            policy_kwargs=dict(reward_offset=0.0, discriminator_ensemble_size=5, discriminator_disagreement=1.0),
        ),
    ),
    "discriminator-ensemble": dict(
        question="5 discriminators, the learned reward their mean logit less their standard deviation (the navigation "
        "OOD lead: a reward that stops rising where the members disagree, beyond the demos' speeds)",
        changes=dict(policy_kwargs=dict(discriminator_ensemble_size=5, discriminator_disagreement=1.0)),
    ),
    "ensemble-slow-value": dict(
        question="5 discriminators (mean less standard deviation) and the planner's terminal value read from a slow "
        "average of the prior's Q networks (value_tau=5e-5: a running mean over the first 20,000 updates, then a Polyak "
        "average over about as many), where a rollout's update of the online Q swings the score",
        changes=dict(
            policy_kwargs=dict(
                discriminator_ensemble_size=5, discriminator_disagreement=1.0, prior_kwargs=dict(value_tau=5e-5)
            )
        ),
    ),
    "critic-layer-norm": dict(
        question="a LayerNorm after each hidden layer of the prior's Q networks (TD-MPC2's and MPAIL2's critics), whose "
        "value of the horizon's last state is the planner's terminal value: Q bounded where the learned model's "
        "roll-outs leave the states it was trained on",
        changes=dict(policy_kwargs=dict(prior_kwargs=dict(critic_layer_norm=True))),
    ),
    "redq-critics": dict(
        question="5 Q networks in the prior, each Q target the minimum of 2 drawn at random and the actor climbing their "
        "mean (REDQ's and TD-MPC2's ensemble; MPAIL2 keeps 5): the planner's terminal value, the ensemble's mean, averages "
        "more networks, where the critic carries the score's swing along a run",
        changes=dict(policy_kwargs=dict(prior_kwargs=dict(n_critics=5, target_critics=2))),
    ),
    "n-step-returns": dict(
        question="the prior's Q targets sum the learned rewards of 3 stored steps before bootstrapping "
        "(prior_return_steps=3; MPAIL2's critic learns from lambda-returns): a reward the discriminator changed at the "
        "last rollout reaches the planner's terminal value in fewer updates",
        changes=dict(prior_return_steps=3),
    ),
    "weight-averages": dict(
        question="the entry scored with its live weights, and also with running averages of its policy's weights along "
        "the run (`--weight-averages`; the planner trains on the live weights): is the score's swing along a run "
        "averaged out?",
        changes={},
    ),
    "gradient-penalty": dict(
        question="a gradient penalty on the discriminator (weight 10, between expert and agent transitions) instead of "
        "spectral norm, as MPAIL2's critic bounds its slope",
        changes=dict(discriminator_gradient_penalty=10.0, policy_kwargs=dict(use_spectral_norm=False)),
    ),
}


class TrainingCurve(BaseCallback):
    """
    At every rollout's end: env steps, the mean length and return of the last 100 training episodes, and the mean
    learned reward of the rollout (is the agent paid to live or to end its episodes?).
    """

    def __init__(self) -> None:
        super().__init__()
        self.points: List[List[float]] = []

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        episodes = self.model.ep_info_buffer
        if episodes:
            lengths, returns = [episode["l"] for episode in episodes], [episode["r"] for episode in episodes]
            learned_reward = self.model.logger.name_to_value["rollout/learned_reward_mean"]
            self.points.append([
                self.num_timesteps, round(float(np.mean(lengths)), 1), round(float(np.mean(returns)), 1),
                round(float(learned_reward), 3),
            ])  # fmt: skip


class WeightAverages(BaseCallback):
    """
    :class:`~sb3_mpail.averaging.PolicyAverage` at several rates at once (``MPAIL(policy_average_rate=...)`` keeps
    one), each updated with the weights of every rollout's update; the planner in training never sees them.
    """

    def __init__(self, rates: Sequence[float]) -> None:
        super().__init__()
        self.rates = list(rates)
        self.averages: Dict[float, PolicyAverage] = {}

    def _on_step(self) -> bool:
        return True

    def _on_training_start(self) -> None:
        self.averages = {rate: PolicyAverage(self.model.policy, rate) for rate in self.rates}

    def _update(self) -> None:
        for average in self.averages.values():
            average.update(self.model.policy)

    def _on_rollout_start(self) -> None:
        if self.model.n_iterations > 0:  # after the previous rollout's update
            self._update()

    def _on_training_end(self) -> None:
        self._update()


def variant_settings(env_id: str, name: str) -> Dict[str, Any]:
    """The task's zoo entry with the variant's changes: ``MPAIL`` arguments plus ``n_envs`` and ``n_timesteps``."""
    settings = zoo_hyperparameters(env_id)
    for key, value in VARIANTS[name]["changes"].items():
        settings[key] = {**settings.get(key, {}), **value} if key == "policy_kwargs" else value
    return settings


def grid_dir(env_id: str, timesteps: Optional[int], results_dir: Path = RESULTS_DIR) -> Path:
    """The task's results at ``timesteps`` env steps, or at its zoo entry's budget where ``timesteps`` is None."""
    budget = timesteps or int(zoo_hyperparameters(env_id)["n_timesteps"])
    return Path(results_dir) / f"{env_id.split('/')[-1]}_{budget}steps"


def stored_run(results_dir: Path, name: str, seed: int) -> Dict[str, Any]:
    """The stored result of one run of a grid (what :func:`run_variant` wrote)."""
    return json.loads((Path(results_dir) / f"{name}_seed{seed}.json").read_text())


def demos_reference(settings: Dict[str, Any]) -> Dict[str, Any]:
    """The information file (expert's and random returns and speeds) of the shipped demo family a run trained on."""
    return shipped_demo_info(settings["demos"].rsplit("_", 1)[0])


def add_grid_arguments(parser: argparse.ArgumentParser, variant: str) -> None:
    """The options of a tool that reads one variant's stored runs of a task's grid."""
    parser.add_argument("--env", default="Hopper-v4")
    parser.add_argument("--variant", default=variant)
    parser.add_argument("--timesteps", type=int, default=None, help="the runs' budget (default: the zoo entry's)")
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    parser.add_argument("--report-only", action="store_true", help="only rewrite the section from stored results")


def run_variant(
    env_id: str,
    name: str,
    seed: int,
    timesteps: Optional[int],
    n_eval_episodes: int,
    out_dir: Path,
    command: str,
    checkpoint_every: int = 0,
    weight_average_rates: Sequence[float] = (),
) -> Path:
    """
    Trains one variant on one seed, evaluates it and writes its result and the trained model beside it (``.zip``; both
    skipped when the result exists).

    :param command: the command line that asked for it, quoted by the report
    :param checkpoint_every: where positive, the model is also saved every this many env steps (in
        ``<variant>_seed<N>_checkpoints/``) and each checkpoint scored as the final model is, to ``checkpoint_scores``:
        does the score move along the run as much as the training episodes do?
    :param weight_average_rates: the final model is also scored with :class:`WeightAverages`' average of its policy's
        parameters at each of these rates per rollout, to ``average_scores`` (rate, then :func:`score_model`'s figures)

    :return: the result file
    """
    path = Path(out_dir) / f"{name}_seed{seed}.json"
    if path.exists():
        return path
    th.set_num_threads(1)
    settings = variant_settings(env_id, name)
    n_envs, budget = settings.pop("n_envs"), int(settings.pop("n_timesteps"))
    budget = budget if timesteps is None else timesteps
    model = MPAIL("MlpMPPI", make_vec_env(env_id, n_envs=n_envs, seed=seed), seed=seed, device="cpu", **settings)
    curve = TrainingCurve()
    checkpoints_dir = checkpoints_dir_of(out_dir, name, seed)
    averages = WeightAverages(weight_average_rates)
    callbacks: List[BaseCallback] = [curve, averages]
    if checkpoint_every > 0:
        callbacks.append(CheckpointCallback(max(checkpoint_every // n_envs, 1), str(checkpoints_dir), name_prefix="model"))
    started = time.perf_counter()
    model.learn(budget, callback=callbacks)
    train_seconds = time.perf_counter() - started
    model.save(path.with_suffix(".zip"))  # beside the result, for evaluations to come (not committed: *.zip is ignored)
    figures = evaluate_locomotion(model, env_id, n_eval_episodes, EVAL_SEED + seed, n_envs=n_eval_episodes)
    reference = demos_reference(settings)
    result = dict(
        env_id=env_id, variant=name, seed=seed, timesteps=budget, n_envs=n_envs, train_seconds=round(train_seconds, 1),
        n_eval_episodes=n_eval_episodes, command=command, machine=machine_description(),
        score=normalised_score(figures["return"], reference), speed_ratio=figures["forward_speed"] / reference[
            "expert_forward_speed"], **figures,
    )  # fmt: skip
    result["deterministic_noise"] = DETERMINISTIC_NOISE  # how the evaluation's deterministic planning drew its samples
    result["training_curve"] = curve.points  # env steps, mean length and return of the last 100 episodes, learned reward
    result["settings"] = settings  # what the variant's name meant when it ran: the zoo entry may change later
    if checkpoint_every > 0:
        result["checkpoint_scores"] = checkpoint_scores(checkpoints_dir, env_id, n_eval_episodes, seed, reference)
    if weight_average_rates:
        result["average_scores"] = []
        for rate, average in averages.averages.items():
            model.policy_average = average  # what predict plans with
            result["average_scores"].append([rate, *score_model(model, env_id, n_eval_episodes, seed, reference)])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, default=repr))
    return path


def checkpoints_dir_of(out_dir: Path, name: str, seed: int) -> Path:
    """Where a run with ``checkpoint_every`` keeps its checkpoints."""
    return Path(out_dir) / f"{name}_seed{seed}_checkpoints"


def checkpoint_file(checkpoints_dir: Path, steps: int) -> Path:
    """The model as it collected env step ``steps`` (SB3's ``CheckpointCallback`` names it so)."""
    return Path(checkpoints_dir) / f"model_{steps}_steps.zip"


def score_model(model: MPAIL, env_id: str, n_eval_episodes: int, seed: int, reference: Dict[str, Any]) -> List[float]:
    """A model scored as a run's final one is: normalised score, mean episode length, speed / the expert's."""
    figures = evaluate_locomotion(model, env_id, n_eval_episodes, EVAL_SEED + seed, n_envs=n_eval_episodes)
    speed_ratio = figures["forward_speed"] / reference["expert_forward_speed"]
    return [round(normalised_score(figures["return"], reference), 3), round(figures["length"], 1), round(speed_ratio, 3)]


def checkpoint_scores(
    checkpoints_dir: Path, env_id: str, n_eval_episodes: int, seed: int, reference: Dict[str, Any]
) -> List[List[float]]:
    """Every checkpoint of a run scored as its final model is: env steps, then :func:`score_model`'s figures."""
    steps = sorted(int(path.stem.split("_")[1]) for path in Path(checkpoints_dir).glob("model_*_steps.zip"))
    return [[step, *score_model(MPAIL.load(checkpoint_file(checkpoints_dir, step), device="cpu"), env_id, n_eval_episodes,
                                seed, reference)] for step in steps]  # fmt: skip


def training_collapsed(curve: List[List[float]], min_peak: float = 100.0, fraction: float = 0.2) -> bool:
    """
    Whether a run's training episodes collapsed: their mean length (:class:`TrainingCurve`'s second figure), once past
    ``min_peak`` steps, later fell below ``fraction`` of the longest it had reached (the agent learned to stand or hop,
    then to fall at once).
    """
    peak = 0.0
    for _, length, *_ in curve:
        peak = max(peak, length)
        if peak > min_peak and length < fraction * peak:
            return True
    return False


def grid_runs(results_dir: Path, pattern: str = "*_seed*.json") -> List[List[Dict[str, Any]]]:
    """The stored results of each ``<task>_<steps>steps`` grid under ``results_dir`` that holds any, grid by grid."""
    grids = [[json.loads(path.read_text()) for path in sorted(grid.glob(pattern))]
             for grid in sorted(Path(results_dir).glob("*steps"))]  # fmt: skip
    return [runs for runs in grids if runs]


def checkpoint_lines(runs: List[Dict[str, Any]]) -> List[str]:
    """The scores of the runs that kept checkpoints (``--checkpoint-every``), along each run, then the final model's."""
    along = [run for run in runs if run.get("checkpoint_scores")]
    if not along:
        return []
    lines = ["", "Scores along a run (each checkpoint is the model as it collected that env step, before that rollout's "
             "update, scored as the final model is):", ""]  # fmt: skip
    for run in sorted(along, key=lambda run: (run["variant"], run["seed"])):
        scores = ", ".join(f"{steps // 1000}k {score:.2f}" for steps, score, _, _ in run["checkpoint_scores"])
        lines.append(f"- `{run['variant']}` seed {run['seed']}: {scores}; final {run['score']:.2f}")
    return lines


def average_lines(runs: List[Dict[str, Any]]) -> List[str]:
    """The scores of the runs whose final policy was also scored with weight averages (``--weight-averages``)."""
    averaged = sorted((run for run in runs if run.get("average_scores")), key=lambda run: (run["variant"], run["seed"]))
    if not averaged:
        return []
    lines = ["", "Final models scored with running averages of their policy's weights (rate per rollout of "
             f"{averaged[0]['n_envs'] * averaged[0]['settings']['n_steps']} env steps; the "
             "planner trained on the live weights):", ""]  # fmt: skip
    for run in averaged:
        scores = ", ".join(f"rate {rate} {score:.2f}" for rate, score, _, _ in run["average_scores"])
        lines.append(f"- `{run['variant']}` seed {run['seed']}: live weights {run['score']:.2f}; {scores}")
    for rate in sorted({rate for run in averaged for rate, *_ in run["average_scores"]}):
        differences = [score - run["score"] for run in averaged for each, score, *_ in run["average_scores"] if each == rate]
        lines.append(f"- rate {rate}, score less the live weights': {format_ci(*mean_ci(differences), signed=True)} "
                     f"({len(differences)} runs)")  # fmt: skip
    return lines


def paired_difference(runs: List[Dict[str, Any]], entry_scores: Dict[int, float]) -> str:
    """
    The mean and 95% CI of a variant's score less the entry's on each seed both ran (seed-to-seed spread cancels), with
    how many seeds that is; blank where they share none.
    """
    differences = [run["score"] - entry_scores[run["seed"]] for run in runs if run["seed"] in entry_scores]
    return f"{format_ci(*mean_ci(differences), signed=True)} ({len(differences)})" if differences else ""


def report(results_dir: Path) -> str:
    """The ``locomotion-ablations`` section: per task, budget and variant, means and 95% CIs over its seeds."""
    lines = [
        "## Locomotion ablations: what learned-model MPAIL needs on MuJoCo",
        "",
        "Each variant changes one setting of the task's `sb3_mpail/hyperparams/mpail.yml` entry. Every model plays "
        "deterministic episodes from fixed seeds; score = (R - random) / (expert - random) against the shipped demos' "
        "information file, speed = forward speed / the expert's. Means ± 95% CI (Student's t) over seeds.",
    ]
    for runs in grid_runs(results_dir):
        commands = commands_of(runs)
        lines += ["", f"### {runs[0]['env_id']}, {runs[0]['timesteps']} env steps", "",
                  f"{runs[0]['n_eval_episodes']} evaluation episodes per run, on {machines_of(runs)}. Commands: "
                  + "; ".join(f"`{command}`" for command in commands), "",
                  "| variant | what changes | seeds | score | score less the entry's, same seeds | return | forward speed / "
                  "expert's | episode length | training seconds | training collapses |",
                  "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        entry_scores = {run["seed"]: run["score"] for run in runs if run["variant"] == "defaults"}
        for name in VARIANTS:
            mine = [run for run in runs if run["variant"] == name]
            if not mine:
                continue
            cells = [format_ci(*mean_ci([run[key] for run in mine])) for key in ("score", "return", "speed_ratio", "length")]
            cells.insert(1, paired_difference(mine, entry_scores) if name != "defaults" else "")
            cells.append(f"{sum(run['train_seconds'] for run in mine) / len(mine):.0f}")
            curves = [run["training_curve"] for run in mine if run.get("training_curve")]
            cells.append(f"{sum(map(training_collapsed, curves))} of {len(curves)}" if curves else "")
            same_noise = sum(run.get("deterministic_noise") != DETERMINISTIC_NOISE for run in mine)
            seeds = f"{len(mine)}" + (f" ({same_noise} †)" if same_noise else "")
            lines.append(f"| `{name}` | {VARIANTS[name]['question']} | {seeds} | " + " | ".join(cells) + " |")
        lines += checkpoint_lines(runs)
        lines += average_lines(runs)
    lines += ["", "Each run on one torch thread. Training collapses: the runs whose mean training episode length (over "
              "the last 100 episodes, at each rollout's end), once past 100 steps, fell below a fifth of its peak; "
              "blank for runs that recorded no curve. †: runs evaluated by a version whose deterministic planning drew "
              "the same samples at every step, a worse planner (the lap scenario went 4.5 m off its path with it, 0.46 m "
              "without); their models were not kept, so they stand until trained again."]  # fmt: skip
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Hopper-v4", help="a task with an mpail.yml entry (default: Hopper-v4)")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--timesteps", type=int, default=None, help="override the zoo entry's budget (a separate table)")
    parser.add_argument("--eval-episodes", type=int, default=10, help="deterministic evaluation episodes (default: 10)")
    parser.add_argument("--workers", type=int, default=1, help="runs trained at once, one torch thread each")
    parser.add_argument("--checkpoint-every", type=int, default=0,
                        help="also save and score the model every this many env steps (default: 0, never)")  # fmt: skip
    parser.add_argument("--weight-averages", type=float, nargs="*", default=[],
                        help="also score each final model with running averages of its weights (rates a rollout)")  # fmt: skip
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    parser.add_argument("--report-only", action="store_true", help="only rewrite the section from stored results")
    args = parser.parse_args(argv)
    if not args.report_only:
        out_dir = grid_dir(args.env, args.timesteps, args.results_dir)
        jobs: List[tuple] = [(name, seed) for name in args.variants for seed in args.seeds
                             if not (out_dir / f"{name}_seed{seed}.json").exists()]  # fmt: skip
        print(f"{len(jobs)} runs to do", flush=True)
        with ProcessPoolExecutor(max(1, args.workers), mp_context=multiprocessing.get_context("spawn")) as pool:
            command = "python -m benchmarks.locomotion_ablations " + " ".join(argv if argv is not None else sys.argv[1:])
            futures = [pool.submit(run_variant, args.env, name, seed, args.timesteps, args.eval_episodes, out_dir, command,
                                   args.checkpoint_every, args.weight_averages) for name, seed in jobs]  # fmt: skip
            for future in futures:
                print("wrote", future.result(), flush=True)
    th.set_num_threads(1)  # the runs' setting, quoted in the report
    write_section("locomotion-ablations", report(args.results_dir))


if __name__ == "__main__":
    main()
