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
"""

import argparse
import runpy
import sys
from pathlib import Path
from typing import List, Sequence

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


def with_default_hyperparams(argv: Sequence[str]) -> List[str]:
    """
    The zoo's command line, with ``-conf`` naming :data:`HYPERPARAMS` for ``train --algo mpail`` when it names no file
    (rl_zoo3 would look for ``mpail.yml`` among its own hyperparameter files).

    :param argv: the arguments after the program name, the zoo's script first (``train``, ``enjoy``, ...)
    """
    if list(argv[:1]) != ["train"]:
        return list(argv)
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--algo")
    parser.add_argument("-conf", "--conf-file")
    known, _ = parser.parse_known_args(argv[1:])
    if known.algo == "mpail" and known.conf_file is None:
        return [*argv, "--conf-file", str(HYPERPARAMS)]
    return list(argv)


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
        sys.argv[1:] = with_default_hyperparams(sys.argv[1:])
        rl_zoo3.cli.main()


if __name__ == "__main__":
    main()
