"""
rl_zoo3's own ``train``, ``enjoy`` and ``record_video`` with MPAIL registered in its algorithm table.

    python -m sb3_mpail.zoo train --algo mpail --env Pendulum-v1 -conf zoo_configs/mpail.yml
    python -m sb3_mpail.zoo enjoy --algo mpail --env Pendulum-v1 -f logs/ --no-render
    python -m sb3_mpail.zoo record_video --algo mpail --env sb3_mpail/Navigation-v0 -f logs/ -n 100

``record_video`` writes an mp4 under ``logs/mpail/<run>/videos/`` (SB3's ``VecVideoRecorder``, which needs moviepy:
the ``video`` extra).

Hyperparameter files follow rl_zoo3's YAML layout; ``demos:`` is passed to :class:`~sb3_mpail.MPAIL` like any other
constructor argument, and the logs land in the zoo's layout, so its plotting scripts read them.
"""

import runpy
import sys

from rl_zoo3.cli import main as zoo_main
from rl_zoo3.utils import ALGOS

from sb3_mpail.mpail import MPAIL


def register() -> None:
    """Adds ``mpail`` to rl_zoo3's algorithm table (the dict its train, enjoy and experiment manager read)."""
    ALGOS["mpail"] = MPAIL


def main() -> None:
    register()
    if sys.argv[1:2] == ["record_video"]:
        # rl_zoo3's record_video is a script (no function to call, and not in its cli): run it as one
        del sys.argv[1]
        runpy.run_module("rl_zoo3.record_video", run_name="__main__", alter_sys=True)
    else:
        zoo_main()


if __name__ == "__main__":
    main()
