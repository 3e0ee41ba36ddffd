"""
Which part of a trained locomotion model decides its score: a checkpoint of a ``locomotion_ablations`` run (one kept
with ``--checkpoint-every``) given one component of another checkpoint of the same run, and scored as the runner scores
its models. Where a run's score swings between checkpoints, the component whose swap carries the swing is what moves.

Results go to ``<variant>_seed<N>_checkpoints/swaps.json`` beside the checkpoints (a rerun skips pairs already
scored), the table to the ``locomotion-swaps`` section of BENCHMARKS.md.

Usage::

    python -m benchmarks.locomotion_swaps --env Hopper-v4 --variant ensemble-reward-mean --seed 0 --steps 150000 125000
    python -m benchmarks.locomotion_swaps --report-only
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
from benchmarks.report import machine_description, write_section
from sb3_mpail import MPAIL

#: the parts of ``MPAIL.policy`` swapped, by their names in it: modules, or the planner's temperature (a buffer)
COMPONENTS = ("discriminator", "dynamics", "prior.sac.actor", "prior.sac.critic", "temperature")


def swap_component(model: MPAIL, donor: MPAIL, component: str) -> None:
    """Gives ``model`` the ``component`` of ``donor`` (weights and buffers), in place."""
    buffers = dict(model.policy.named_buffers())
    if component in buffers:
        buffers[component].copy_(donor.policy.get_buffer(component))
    else:
        model.policy.get_submodule(component).load_state_dict(donor.policy.get_submodule(component).state_dict())


def swap_scores(
    env_id: str, variant: str, seed: int, steps: Sequence[int], n_eval_episodes: int, results_dir: Path, command: str
) -> Path:
    """
    Scores both checkpoints of the pair as they are, then each with every one of the other's :data:`COMPONENTS`.

    :param steps: the two checkpoints' env steps
    :param results_dir: the ablation results of the task and budget (``grid_dir``)
    :return: the swaps file of the run
    """
    reference = demos_reference(stored_run(results_dir, variant, seed)["settings"])
    checkpoints_dir = checkpoints_dir_of(results_dir, variant, seed)
    path = checkpoints_dir / "swaps.json"
    rows: List[Dict[str, Any]] = json.loads(path.read_text()) if path.exists() else []
    done = {(row["model"], row["donor"], row["component"]) for row in rows}
    th.set_num_threads(1)
    for model_steps, donor_steps in ((steps[0], steps[1]), (steps[1], steps[0])):
        donor = MPAIL.load(checkpoint_file(checkpoints_dir, donor_steps), device="cpu")  # read, never changed
        for component in (None, *COMPONENTS):
            key = (model_steps, donor_steps if component else None, component)
            if key in done:
                continue
            model = MPAIL.load(checkpoint_file(checkpoints_dir, model_steps), device="cpu")
            if component:
                swap_component(model, donor, component)
            score, length, _ = score_model(model, env_id, n_eval_episodes, seed, reference)
            rows.append(dict(env_id=env_id, variant=variant, seed=seed, model=model_steps, component=component,
                             donor=key[1], score=score, length=length, n_eval_episodes=n_eval_episodes, command=command,
                             machine=machine_description()))  # fmt: skip
            path.write_text(json.dumps(rows))
            done.add(key)
    return path


def report(results_dir: Path = RESULTS_DIR) -> str:
    """The ``locomotion-swaps`` section: every scored pair of checkpoints, each with every component of the other."""
    lines = [
        "## Locomotion swaps: which component carries a run's swing in score",
        "",
        "A checkpoint of a `locomotion_ablations` run given one component of another checkpoint of the same run, "
        "scored as the runner scores its models (deterministic episodes from the same seeds; normalised score, mean "
        "episode length in parentheses).",
    ]
    for path in sorted(Path(results_dir).glob("*/*_checkpoints/swaps.json")):
        rows = json.loads(path.read_text())
        first = rows[0]
        own = {row["model"]: row for row in rows if row["component"] is None}
        lines += ["", f"### {first['env_id']}, `{first['variant']}` seed {first['seed']}", "",
                  f"{first['n_eval_episodes']} evaluation episodes each, on {first['machine']}. Command: "
                  f"`{first['command']}`", "",
                  "| model | as it is | " + " | ".join(f"with the other's `{name}`" for name in COMPONENTS) + " |",
                  "|---" * (len(COMPONENTS) + 2) + "|"]  # fmt: skip
        for steps, row in own.items():
            swapped = {swap["component"]: swap for swap in rows if swap["model"] == steps and swap["component"]}
            cells = [f"{swapped[name]['score']:.2f} ({swapped[name]['length']:.0f})" if name in swapped else ""
                     for name in COMPONENTS]  # fmt: skip
            lines.append(f"| {steps // 1000}k | {row['score']:.2f} ({row['length']:.0f}) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_grid_arguments(parser, variant="ensemble-reward-mean")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, nargs=2, default=[150_000, 125_000], help="the two checkpoints' env steps")
    args = parser.parse_args(argv)
    if not args.report_only:
        command = "python -m benchmarks.locomotion_swaps " + " ".join(argv if argv is not None else sys.argv[1:])
        path = swap_scores(args.env, args.variant, args.seed, args.steps, args.eval_episodes,
                           grid_dir(args.env, args.timesteps, args.results_dir), command)  # fmt: skip
        print("wrote", path, flush=True)
    write_section("locomotion-swaps", report(args.results_dir))


if __name__ == "__main__":
    main()
