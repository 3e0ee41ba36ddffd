"""
Console scripts of ``[project.scripts]`` for the commands whose ``main`` returns what it made (results a caller
may read): each drops it, since a console script exits with what its function returns. ``sb3-mpail-zoo`` is
``sb3_mpail.zoo.main`` itself.
"""


def train_navigation() -> None:
    """``sb3-mpail-train-navigation``: ``python -m sb3_mpail.train_navigation``."""
    from sb3_mpail.train_navigation import main

    main()


def inspect() -> None:
    """``sb3-mpail-inspect``: ``python -m sb3_mpail.inspect``, the figures of a saved model's cost, value and plans."""
    from sb3_mpail.inspect import main

    main()
