"""
rl_zoo3's own ``train``, ``enjoy`` and ``record_video`` with MPAIL registered in its algorithm table (needs the ``zoo``
extra).

    python -m sb3_mpail.zoo train --algo mpail --env Pendulum-v1          # the shipped hyperparameters (HYPERPARAMS)
    python -m sb3_mpail.zoo train --algo mpail --env Pendulum-v1 -conf my_mpail.yml
    python -m sb3_mpail.zoo enjoy --algo mpail --env Pendulum-v1 -f logs/ --no-render
    python -m sb3_mpail.zoo record_video --algo mpail --env sb3_mpail/Navigation-v0 -f logs/ -n 100

``record_video`` writes an mp4 under ``logs/mpail/<run>/videos/`` (SB3's ``VecVideoRecorder``, which needs moviepy:
the ``video`` extra).

``sb3-mpail-zoo`` is the same command as an installed console script. Hyperparameter files follow rl_zoo3's YAML
layout; ``demos:`` is passed to :class:`~sb3_mpail.MPAIL` like any other constructor argument (a shipped demo set's
name or a path), and the logs land in the zoo's layout, so its plotting scripts read them.

``train --algo mpail`` is quiet by default: MPAIL logs a table at every iteration (hundreds in a run), so the command
prints one every :data:`QUIET_LOG_INTERVAL` iterations unless ``--log-interval`` says otherwise. Its last line scores
the saved model over ``--score-episodes`` deterministic episodes (default :data:`SCORE_EPISODES`, 0: none) against
the shipped expert of its demos, as ``python -m sb3_mpail.train_navigation`` does.
"""

import argparse
import os
import runpy
import sys
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

from sb3_mpail.demos import shipped_demo_info, shipped_family
from sb3_mpail.evaluation import evaluate_episodes, normalised_score, reference_returns
from sb3_mpail.mpail import MPAIL

#: MPAIL's hyperparameters for every env it is benchmarked on, shipped with the package; ``train --algo mpail``
#: reads them unless ``-conf`` names another file
HYPERPARAMS = Path(__file__).resolve().parent / "hyperparams" / "mpail.yml"


def _import_rl_zoo3():
    try:
        import rl_zoo3.cli
        import rl_zoo3.utils
    except ImportError as error:
        raise ImportError(
            "sb3_mpail.zoo needs rl_zoo3, which is not installed: pip install 'sb3-mpail[zoo]' (or pip install rl_zoo3)."
        ) from error
    return rl_zoo3


def register() -> None:
    """Adds ``mpail`` to rl_zoo3's algorithm table (the dict its train, enjoy and experiment manager read)."""
    _import_rl_zoo3().utils.ALGOS["mpail"] = MPAIL


#: iterations between the tables ``train --algo mpail`` prints unless ``--log-interval`` is given
QUIET_LOG_INTERVAL = 25
#: deterministic episodes the model is scored on after ``train --algo mpail`` unless ``--score-episodes`` is given
SCORE_EPISODES = 10
#: the scoring episodes start from the training seed plus this, so they never replay the training starts
SCORE_SEED_OFFSET = 10_000


def _train_arguments(argv: Sequence[str]) -> Tuple[argparse.Namespace, List[str]]:
    """The options of rl_zoo3's ``train`` that sb3-mpail reads or adds, and the arguments without ``--score-episodes``."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--algo")
    parser.add_argument("--env", default="CartPole-v1")  # rl_zoo3's default
    parser.add_argument("-conf", "--conf-file")
    parser.add_argument("--log-interval", type=int)
    parser.add_argument("-f", "--log-folder", default="logs")
    parser.add_argument("--score-episodes", type=int, default=SCORE_EPISODES)
    known, _ = parser.parse_known_args(argv)
    if known.score_episodes < 0:
        raise SystemExit(f"--score-episodes must be >= 0 (0: no score); got {known.score_episodes}")
    passed, skip = [], False
    for argument in argv:  # --score-episodes is sb3-mpail's: rl_zoo3 would refuse it
        if skip or argument == "--score-episodes" or argument.startswith("--score-episodes="):
            skip = argument == "--score-episodes"
            continue
        passed.append(argument)
    return known, passed


def with_default_hyperparams(argv: Sequence[str]) -> List[str]:
    """
    The zoo's command line with sb3-mpail's defaults for ``train --algo mpail``: ``-conf`` naming :data:`HYPERPARAMS`
    when it names no file (rl_zoo3 would look for ``mpail.yml`` among its own hyperparameter files), and
    ``--log-interval`` :data:`QUIET_LOG_INTERVAL` when none is given; ``--score-episodes`` (sb3-mpail's own) removed.

    :param argv: the arguments after the program name, the zoo's script first (``train``, ``enjoy``, ...)
    """
    if list(argv[:1]) != ["train"]:
        return list(argv)
    known, passed = _train_arguments(argv[1:])
    if known.algo != "mpail":
        return list(argv)
    defaults = [] if known.conf_file is not None else ["--conf-file", str(HYPERPARAMS)]
    defaults += [] if known.log_interval is not None else ["--log-interval", str(QUIET_LOG_INTERVAL)]
    return [argv[0], *passed, *defaults]


def score_line(log_folder: str, env_id: str, n_episodes: int) -> Optional[str]:
    """
    Scores the model ``train --algo mpail`` saved last for ``env_id`` under ``log_folder`` (rl_zoo3's layout) over
    ``n_episodes`` deterministic episodes of the env it trained on (its ``env_kwargs``), from the training seed plus
    :data:`SCORE_SEED_OFFSET`, against the shipped expert of its demos.

    :param log_folder: rl_zoo3's ``--log-folder``
    :param env_id: the env trained on
    :param n_episodes: episodes to score (0: none)
    :return: the line to print, or ``None`` without episodes or without a saved model
    """
    import yaml
    from rl_zoo3.utils import EnvironmentName, get_latest_run_id, get_saved_hyperparams  # the zoo's own run naming

    env_name = EnvironmentName(env_id)
    algo_folder = os.path.join(log_folder, "mpail")
    run = os.path.join(algo_folder, f"{env_name}_{get_latest_run_id(algo_folder, env_name)}")
    model_path = os.path.join(run, f"{env_name}.zip")
    if n_episodes == 0 or not os.path.isfile(model_path):
        return None
    hyperparams, _ = get_saved_hyperparams(os.path.join(run, env_name))
    with open(os.path.join(run, env_name, "args.yml")) as file:
        arguments = yaml.load(file, Loader=yaml.UnsafeLoader)  # rl_zoo3's own file, read as its enjoy reads it
    model = MPAIL.load(model_path, device="cpu")
    episodes = evaluate_episodes(
        model, env_id, n_episodes, seed=int(arguments["seed"]) + SCORE_SEED_OFFSET, env_kwargs=arguments.get("env_kwargs")
    )
    line = f"{env_id}: deterministic planner over {n_episodes} episodes: return {episodes.mean_return:.1f} +- "
    line += f"{episodes.std_return:.1f}"
    family = shipped_family(hyperparams.get("demos"))
    if family is None:
        return line + " (no normalised score: the demos are not a shipped set, whose expert it is measured against)"
    reference = shipped_demo_info(family)
    try:
        random_return, expert_return = reference_returns(reference)
    except ValueError as error:  # a shipped set measured otherwise, e.g. the lap's path
        return line + f" (no normalised score: {error})"
    score = normalised_score(episodes.mean_return, reference)
    return line + f" (expert {expert_return:.1f}, random {random_return:.1f}), normalised score {score:.3f}"


#: the zoo's scripts this command runs: rl_zoo3's command line's, and its record_video
SCRIPTS = ("train", "enjoy", "record_video", "plot_train", "plot_from_file", "all_plots")


def main() -> None:
    """Runs rl_zoo3's command line (``sys.argv``) with MPAIL registered and its shipped hyperparameters as default."""
    rl_zoo3 = _import_rl_zoo3()
    register()
    script = sys.argv[1] if len(sys.argv) > 1 else None
    if script not in SCRIPTS:
        usage = f"usage: python -m sb3_mpail.zoo {{{','.join(SCRIPTS)}}} [the script's options; --help after it lists them]"
        if script in ("-h", "--help"):
            print(usage + "\n" + __doc__)
            return
        raise SystemExit(usage + ("\nno script given" if script is None else f"\nunknown script {script!r}"))
    if script == "record_video":
        # rl_zoo3's record_video is a script (no function to call, and not in its cli): run it as one
        del sys.argv[1]
        runpy.run_module("rl_zoo3.record_video", run_name="__main__", alter_sys=True)
    else:
        scored = script == "train" and _train_arguments(sys.argv[2:])[0]
        sys.argv[1:] = with_default_hyperparams(sys.argv[1:])
        rl_zoo3.cli.main()
        if scored and scored.algo == "mpail":
            line = score_line(scored.log_folder, scored.env, scored.score_episodes)
            if line is not None:
                print(line)


if __name__ == "__main__":
    main()
