"""
rl_zoo3's own ``train`` and ``enjoy`` with MPAIL registered in its algorithm table.

    python -m sb3_mpail.zoo train --algo mpail --env Pendulum-v1 -conf zoo_configs/mpail.yml
    python -m sb3_mpail.zoo enjoy --algo mpail --env Pendulum-v1 -f logs/ --no-render

Hyperparameter files follow rl_zoo3's YAML layout; ``demos:`` is passed to :class:`~sb3_mpail.MPAIL` like any other
constructor argument, and the logs land in the zoo's layout, so its plotting scripts read them.
"""

from rl_zoo3.cli import main as zoo_main
from rl_zoo3.utils import ALGOS

from sb3_mpail.mpail import MPAIL


def register() -> None:
    """Adds ``mpail`` to rl_zoo3's algorithm table (the dict its train, enjoy and experiment manager read)."""
    ALGOS["mpail"] = MPAIL


def main() -> None:
    register()
    zoo_main()


if __name__ == "__main__":
    main()
