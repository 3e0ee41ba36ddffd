"""
Does planning with a slow average of the prior's Q networks help? A ``locomotion_ablations`` run whose prior keeps one
(``prior_kwargs=dict(value_tau=...)``) is scored again, final model and every checkpoint, with the planner's terminal
value read from the online Q networks instead: the same trained weights, only the value the planner bootstraps with
differs, so the pair is the average's effect on that run.

Results go to ``<variant>_seed<N>_checkpoints/value_source.json`` (a rerun skips models already scored), the table to
the ``locomotion-value-source`` section of BENCHMARKS.md.

Usage::

    python -m benchmarks.locomotion_value_source --env Hopper-v4 --variant ensemble-slow-value --seeds 0 1 2 3 4
    python -m benchmarks.locomotion_value_source --report-only
"""

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import torch as th

from benchmarks.locomotion_ablations import (
    RESULTS_DIR,
    add_grid_arguments,
    checkpoint_file,
    checkpoints_dir_of,
    demos_reference,
    grid_dir,
    score_model,
    stored_run,
)
from benchmarks.report import format_ci, machine_description, mean_ci, write_section
from sb3_mpail import MPAIL

#: the final model's key in a run's ``value_source.json`` (checkpoints are keyed by their env steps)
FINAL = "final"


def plan_with_online_q(model: MPAIL) -> MPAIL:
    """``model`` with its prior's slow average of the Q networks replaced by the online ones, in place."""
    prior = model.policy.prior
    if prior is None or prior.planning_critic is None:
        raise ValueError("The model's policy prior keeps no slow average of its Q networks (prior_kwargs value_tau unset)")
    prior.planning_critic.load_state_dict(prior.sac.critic.state_dict())
    return model


def online_value_scores(
    env_id: str, variant: str, seed: int, n_eval_episodes: int, results_dir: Path, command: str
) -> Path:
    """
    Scores the run's final model and each of its checkpoints planning with the online Q networks.

    :param results_dir: the ablation results of the task and budget (``grid_dir``)
    :return: the run's ``value_source.json``
    """
    run = stored_run(results_dir, variant, seed)
    reference = demos_reference(run["settings"])
    checkpoints_dir = checkpoints_dir_of(results_dir, variant, seed)
    path = checkpoints_dir / "value_source.json"
    rows: Dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    models = {FINAL: Path(results_dir) / f"{variant}_seed{seed}.zip"}
    models.update({str(steps): checkpoint_file(checkpoints_dir, steps) for steps, *_ in run.get("checkpoint_scores", [])})
    th.set_num_threads(1)
    for key, model_file in models.items():
        if key in rows:
            continue
        score, length, speed_ratio = score_model(plan_with_online_q(MPAIL.load(model_file, device="cpu")), env_id,
                                                 n_eval_episodes, seed, reference)  # fmt: skip
        rows[key] = dict(score=score, length=length, speed_ratio=speed_ratio, command=command, machine=machine_description())
        checkpoints_dir.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(rows))
    return path


def report(results_dir: Path = RESULTS_DIR) -> str:
    """The ``locomotion-value-source`` section: each run's scores with the slow average and with the online Q."""
    lines = [
        "## Locomotion value source: the prior's slow Q average against its online Q networks",
        "",
        "Each model of a run whose prior keeps a slow average of its Q networks (`value_tau`), scored as the runner "
        "scores its models, planning with that average (as it trained) and with the online Q networks (the same "
        "weights otherwise). Checkpoints are the model as it collected that env step.",
    ]
    for grid in sorted(Path(results_dir).glob("*steps")):
        pairs: List[tuple] = []
        table: List[str] = []
        for path in sorted(grid.glob("*_checkpoints/value_source.json")):
            online = json.loads(path.read_text())
            run = json.loads((grid / f"{path.parent.name.removesuffix('_checkpoints')}.json").read_text())
            slow = {FINAL: run["score"], **{str(steps): score for steps, score, *_ in run.get("checkpoint_scores", [])}}
            keys = [key for key in slow if key in online]
            if FINAL in online:
                pairs.append((slow[FINAL], online[FINAL]["score"]))
            cells = [f"{slow[key]:.2f} / {online[key]['score']:.2f}" for key in keys]
            header = [key if key == FINAL else f"{int(key) // 1000}k" for key in keys]
            command = next(iter(online.values()))["command"]
            table += ["", f"`{run['variant']}` seed {run['seed']} (slow average / online Q; command `{command}`):", "",
                      "| " + " | ".join(header) + " |", "|---" * len(header) + "|",
                      "| " + " | ".join(cells) + " |"]  # fmt: skip
        if not table:
            continue
        lines += ["", f"### {grid.name}", *table]
        if len(pairs) > 1:
            slow_scores, online_scores = zip(*pairs)
            lines += ["", f"Final models over {len(pairs)} seeds: slow average {format_ci(*mean_ci(slow_scores))}, online "
                      f"Q {format_ci(*mean_ci(online_scores))}, paired difference (slow less online) "
                      f"{format_ci(*mean_ci([s - o for s, o in pairs]))}."]  # fmt: skip
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_grid_arguments(parser, variant="ensemble-slow-value")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    args = parser.parse_args(argv)
    if not args.report_only:
        command = "python -m benchmarks.locomotion_value_source " + " ".join(argv if argv is not None else sys.argv[1:])
        for seed in args.seeds:
            path = online_value_scores(args.env, args.variant, seed, args.eval_episodes,
                                       grid_dir(args.env, args.timesteps, args.results_dir), command)  # fmt: skip
            print("wrote", path, flush=True)
    write_section("locomotion-value-source", report(args.results_dir))


if __name__ == "__main__":
    main()
