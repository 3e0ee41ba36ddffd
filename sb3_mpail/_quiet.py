"""
Keeps third-party notices that do not concern sb3-mpail's users off the terminal.

gymnasium-robotics 1.2.1 to 1.4.2 print to stderr, whenever they are imported, that the rewards of their AdroitHand
environments changed. sb3-mpail makes none of them (its PointMaze is unaffected), yet the notice showed on every run:
gymnasium 0.29 imports each installed plugin, gymnasium-robotics included (twice, as ``gymnasium_robotics`` and
``gymnasium_robotics.__init__``), as soon as gymnasium itself is imported; with gymnasium 1.x, sb3-mpail imports
gymnasium-robotics only when its PointMaze is made. So the package, imported before gymnasium, removes that one notice
from Farama's notification table, which gymnasium-robotics reads on import. Every other notice is kept.
"""


def drop_unrelated_notices() -> None:
    """Removes gymnasium-robotics' AdroitHand notice from ``farama_notifications`` (nothing if it is not installed)."""
    try:
        from farama_notifications import notifications
    except ImportError:
        return
    robotics = notifications.get("gymnasium_robotics") if isinstance(notifications, dict) else None
    if isinstance(robotics, dict):
        for version in [version for version, text in robotics.items() if "AdroitHand" in str(text)]:
            del robotics[version]


drop_unrelated_notices()
