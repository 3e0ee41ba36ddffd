"""
The command lines' shared parts: their help formatter, and the console scripts of ``[project.scripts]`` for the
commands whose ``main`` returns what it made (results a caller may read): each drops it, since a console script exits
with what its function returns. ``sb3-mpail-zoo`` is ``sb3_mpail.zoo.main`` itself.
"""

import argparse
import sys
from pathlib import Path


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """argparse's ``(default: ...)`` after each help text, except where the text says its own default or there is none."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or action.default is False or "default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


def train_navigation() -> None:
    """``sb3-mpail-train-navigation``: ``python -m sb3_mpail.train_navigation``."""
    from sb3_mpail.train_navigation import main

    main()


def inspect() -> None:
    """``sb3-mpail-inspect``: ``python -m sb3_mpail.inspect``, the figures of a saved model's cost, value and plans."""
    from sb3_mpail.inspect import main

    main()


def program_name(module: str, script: str) -> str:
    """
    A command's name for its usage line: the console script's when it runs as one, else ``python -m <module>``.

    :param module: the module run with ``python -m``
    :param script: its console script in ``[project.scripts]``
    """
    return script if Path(sys.argv[0]).name == script else f"python -m {module}"

