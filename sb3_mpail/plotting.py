"""
Figures for the navigation experiment: the trained planner's paths over the demos, and the learned cost map.

matplotlib is an optional dependency (the ``plot`` extra); it is imported only when a figure is drawn.
"""

import math
from pathlib import Path
from typing import Sequence, Tuple, Union

import numpy as np
import torch as th

#: planar extent of the cost map when none is given: the demos' square plus a margin
DEFAULT_EXTENT = (-3.0, 14.0, -3.0, 14.0)


def import_pyplot():
    """matplotlib's pyplot on the non-interactive Agg backend, or an ImportError that names the ``plot`` extra."""
    try:
        import matplotlib
    except ImportError as error:
        raise ImportError(
            "Plotting needs matplotlib, which is not installed: pip install 'sb3-mpail[plot]' (or pip install matplotlib)."
        ) from error
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure, path: Union[str, Path]) -> Path:
    """Writes ``figure`` to ``path`` as a PNG (creating its folder) and closes it; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    import_pyplot().close(figure)
    return path


def typical_demo_speed(demo_observations: np.ndarray) -> float:
    """The median forward speed (observation index 6) of the demo states in which the car is moving (> 0.5 m/s)."""
    speeds = np.asarray(demo_observations)[..., 6].ravel()
    moving = speeds[np.abs(speeds) > 0.5]
    return float(np.median(moving)) if len(moving) else 0.0


@th.no_grad()
def learned_cost_map(
    model,
    speed: float,
    extent: Tuple[float, float, float, float] = DEFAULT_EXTENT,
    resolution: int = 61,
    n_headings: int = 16,
) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    The learned step cost ``c(s, s') = -d_theta(s, s')`` over the x-y plane: at every grid point and for each of
    ``n_headings`` headings, ``s`` is the car at rest pose (z, roll, pitch 0) moving straight at ``speed`` and ``s'``
    is one step of the planner's own dynamics model with the matching straight action; the map holds the minimum
    over headings (the cheapest way to drive through that point).

    :param model: a trained :class:`~sb3_mpail.MPAIL` model on the 12-D navigation state
    :param speed: forward speed in m/s (e.g. :func:`typical_demo_speed`)
    :param extent: ``(x_min, x_max, y_min, y_max)`` in metres
    :param resolution: grid points per axis
    :param n_headings: headings tried per point, evenly spaced in ``[-pi, pi)``
    :return: ``xs`` (resolution,), ``ys`` (resolution,), ``costs`` (resolution, resolution) indexed ``[y, x]``
    """
    from sb3_mpail.inspect import NAVIGATION_AXES, grid_coordinates, step_cost_field

    policy = model.policy
    xs, ys = grid_coordinates(extent, resolution)
    max_speed = float(getattr(policy.dynamics, "max_speed", 3.0))
    action = np.zeros(policy.action_space.shape, dtype=np.float32)
    action[0] = np.clip(speed / max_speed, -1.0, 1.0)
    template = np.zeros(policy.observation_space.shape, dtype=np.float32)
    template[NAVIGATION_AXES.speed_index] = speed
    fields = []
    for heading in -math.pi + 2 * math.pi * np.arange(n_headings) / n_headings:
        template[NAVIGATION_AXES.heading_index] = heading
        fields.append(step_cost_field(model, template, action, xs, ys, NAVIGATION_AXES))
    return xs, ys, np.min(fields, axis=0)


def plot_navigation(
    model,
    demo_observations: np.ndarray,
    trajectories: Sequence[np.ndarray],
    path: Union[str, Path],
    goal: Tuple[float, float] = (10.0, 10.0),
    title: str | None = None,
    resolution: int = 61,
) -> Path:
    """
    Two panels: left, the planner's x-y paths (``trajectories``) over the demo paths and the goal; right, the learned
    step cost over the x-y plane (see :func:`learned_cost_map`).

    :param model: the trained MPAIL model
    :param demo_observations: expert observations, ``(n_demos, T + 1, 12)``
    :param trajectories: the planner's episodes, each ``(T + 1, 12)`` observations
    :param path: where to write the PNG
    :param goal: goal position
    :param title: figure title
    :param resolution: cost-map grid points per axis
    :return: the path written
    """
    plt = import_pyplot()
    demo_observations = np.asarray(demo_observations)
    points = [demo_observations[..., :2].reshape(-1, 2), *[np.asarray(t)[:, :2] for t in trajectories]]
    low = np.minimum(np.min(np.concatenate(points), axis=0) - 1.5, DEFAULT_EXTENT[0])
    high = np.maximum(np.max(np.concatenate(points), axis=0) + 1.5, DEFAULT_EXTENT[1])
    extent = (float(low[0]), float(high[0]), float(low[1]), float(high[1]))
    speed = typical_demo_speed(demo_observations)

    figure, (left, right) = plt.subplots(1, 2, figsize=(13, 6), constrained_layout=True)
    for index, demo in enumerate(demo_observations):
        left.plot(demo[:, 0], demo[:, 1], color="0.55", lw=5, alpha=0.5, label="expert demos" if index == 0 else None)
    colors = plt.get_cmap("tab10")
    for index, trajectory in enumerate(trajectories):
        trajectory = np.asarray(trajectory)
        left.plot(
            trajectory[:, 0], trajectory[:, 1], color=colors(index % 10), lw=1.5, label="MPAIL planner" if index == 0 else None
        )
        left.plot(trajectory[0, 0], trajectory[0, 1], "o", color=colors(index % 10), ms=5)
        left.plot(trajectory[-1, 0], trajectory[-1, 1], "x", color=colors(index % 10), ms=7, mew=2)
    for axis in (left, right):
        axis.plot(*goal, marker="*", color="gold", mec="k", ms=20, ls="none", label="goal (10, 10)")
        axis.set_xlim(extent[0], extent[1])
        axis.set_ylim(extent[2], extent[3])
        axis.set_aspect("equal")
        axis.set_xlabel("x (m)")
        axis.set_ylabel("y (m)")
        axis.grid(alpha=0.3)
    left.set_title(f"x-y paths: {len(trajectories)} deterministic episodes of the planner (o start, x end)")
    left.legend(loc="upper left")

    xs, ys, costs = learned_cost_map(model, speed, extent, resolution)
    image = right.pcolormesh(xs, ys, costs, cmap="viridis", shading="auto")
    for demo in demo_observations:
        right.plot(demo[:, 0], demo[:, 1], color="w", lw=1, alpha=0.7)
    figure.colorbar(image, ax=right, label="learned step cost  -d(s, s')  (low = expert-like)")
    right.set_title(
        f"learned cost c(s, s') = -d(s, s') of a straight {speed:.1f} m/s bicycle step,\nminimum over 16 headings "
        "(white: demos)"
    )
    if title:
        figure.suptitle(title)
    return save_figure(figure, path)


def plot_learning_curves(
    curves: Sequence[Tuple[np.ndarray, np.ndarray]],
    path: Union[str, Path],
    labels: Sequence[str] | None = None,
    title: str = "",
    target: float | None = 0.9,
) -> Path:
    """
    Normalised score against env steps: one thin line per run, the mean over runs and its min-max spread.

    :param curves: per run, ``(steps, scores)``; runs are interpolated onto the first run's steps for the mean
    :param path: where to write the PNG
    :param labels: per run legend labels
    :param title: figure title
    :param target: a horizontal reference line (``None`` for none)
    :return: the path written
    """
    plt = import_pyplot()
    figure, axis = plt.subplots(figsize=(8, 5), constrained_layout=True)
    steps = np.asarray(curves[0][0], dtype=float)
    stacked = np.stack([np.interp(steps, np.asarray(s, float), np.asarray(v, float)) for s, v in curves])
    for index, (run_steps, scores) in enumerate(curves):
        axis.plot(run_steps, scores, lw=1, alpha=0.6, label=labels[index] if labels else None)
    axis.plot(steps, stacked.mean(0), color="k", lw=2.5, label=f"mean of {len(curves)}")
    axis.fill_between(steps, stacked.min(0), stacked.max(0), color="k", alpha=0.12, label="min-max")
    if target is not None:
        axis.axhline(target, color="r", ls="--", lw=1, label=f"target {target}")
    axis.axhline(1.0, color="0.4", ls=":", lw=1, label="expert (1.0)")
    axis.set_xlabel("env steps")
    axis.set_ylabel("normalised score  (R - random) / (expert - random)")
    axis.set_title(title)
    axis.grid(alpha=0.3)
    axis.legend(loc="lower right")
    return save_figure(figure, path)
