"""
What a trained planner sees and decides over a plane of states: the learned step cost of a chosen move, the value,
the planner's first move from a grid of states, and a few episodes' sampled roll-outs coloured by their MPPI weights.

Any env whose state holds a planar position can be inspected: the position's indices (and the heading's and speed's,
where there are such) are arguments, and every other state dimension comes from a template state. The fields use the
planner's own parts, so a hand-made ``step_cost``, ``terminal_value`` or dynamics model shows as it is planned with.

Usage::

    python -m sb3_mpail.inspect runs/navigation/model.zip                     # sb3_mpail/Navigation-v0, OOD starts
    python -m sb3_mpail.inspect MODEL.zip --heading 2.36 --speed 3 --extent -20 20 -20 20 --out inspect.png
"""

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_vec_env

from sb3_mpail.console import HelpFormatter, program_name
from sb3_mpail.mppi.planner import rollout

#: planar extent of the navigation figures: the 40 x 40 m box of the out-of-distribution starts, with a margin
NAVIGATION_EXTENT = (-22.0, 22.0, -22.0, 22.0)

Extent = Tuple[float, float, float, float]


@dataclass(frozen=True)
class PlaneAxes:
    """
    Where the plane lies in the state: the indices of its two coordinates and, optionally, of the heading (for the
    decision field's headings) and of the forward speed (for the template of a move).

    :param x_index: state index of the first planar coordinate
    :param y_index: state index of the second planar coordinate
    :param heading_index: state index of the heading angle, or ``None``
    :param speed_index: state index of the forward speed, or ``None``
    """

    x_index: int = 0
    y_index: int = 1
    heading_index: Optional[int] = None
    speed_index: Optional[int] = None


#: the navigation car's 12-D state: x, y, yaw at 5, body-frame forward speed at 6
NAVIGATION_AXES = PlaneAxes(x_index=0, y_index=1, heading_index=5, speed_index=6)


def grid_coordinates(extent: Extent, resolution: int) -> Tuple[np.ndarray, np.ndarray]:
    """``xs`` and ``ys``, ``resolution`` evenly spaced points each across ``extent = (x_min, x_max, y_min, y_max)``."""
    return (
        np.linspace(extent[0], extent[1], resolution, dtype=np.float32),
        np.linspace(extent[2], extent[3], resolution, dtype=np.float32),
    )


def plane_states(template: np.ndarray, xs: np.ndarray, ys: np.ndarray, axes: PlaneAxes) -> np.ndarray:
    """
    ``template`` placed at every point of the ``xs`` x ``ys`` grid.

    :param template: a full state, ``(state_dim,)``
    :param xs: first coordinates, ``(nx,)``
    :param ys: second coordinates, ``(ny,)``
    :param axes: where the coordinates go in the state
    :return: states ``(ny, nx, state_dim)``, indexed ``[y, x]``
    """
    template = np.asarray(template, dtype=np.float32)
    states = np.broadcast_to(template, (len(ys), len(xs), template.shape[-1])).copy()
    states[..., axes.x_index] = np.asarray(xs, dtype=np.float32)[None, :]
    states[..., axes.y_index] = np.asarray(ys, dtype=np.float32)[:, None]
    return states


def _tensor(model, array: np.ndarray) -> th.Tensor:
    return th.as_tensor(np.asarray(array, dtype=np.float32), device=model.policy.device)


def _planning_parts(model):
    """
    The planner ``predict`` uses (the average of the weights where the model keeps one), in eval mode (in training mode
    spectral norm would move on every call).
    """
    policy = model.deployed_policy()
    policy.set_training_mode(False)
    return policy.planner


@th.no_grad()
def step_cost_field(
    model, template: np.ndarray, action: Sequence[float], xs: np.ndarray, ys: np.ndarray, axes: PlaneAxes = PlaneAxes()
) -> np.ndarray:
    """
    The planner's step cost ``c(s, f(s, a))`` of applying ``action`` once from every grid state, ``f`` the planner's
    dynamics model (for MPAIL, ``c = -d_theta``: low where the move looks like the expert's).

    :param model: a trained (or loaded) :class:`~sb3_mpail.MPAIL` model
    :param template: the state's other dimensions, ``(state_dim,)``
    :param action: the move, ``(action_dim,)``
    :return: costs ``(ny, nx)``, indexed ``[y, x]``
    """
    planner = _planning_parts(model)
    states = _tensor(model, plane_states(template, xs, ys, axes)).view(-1, len(template))
    actions = _tensor(model, action).expand(len(states), -1)
    next_states = planner.dynamics(states, actions)
    return planner.step_cost(states, next_states).view(len(ys), len(xs)).cpu().numpy()


@th.no_grad()
def value_field(model, template: np.ndarray, xs: np.ndarray, ys: np.ndarray, axes: PlaneAxes = PlaneAxes()) -> np.ndarray:
    """
    The planner's terminal value ``V(s)`` at every grid state.

    :param model: a trained (or loaded) :class:`~sb3_mpail.MPAIL` model
    :param template: the state's other dimensions, ``(state_dim,)``
    :return: values ``(ny, nx)``, indexed ``[y, x]``
    """
    planner = _planning_parts(model)
    states = _tensor(model, plane_states(template, xs, ys, axes)).view(-1, len(template))
    return planner.terminal_value(states).view(len(ys), len(xs)).cpu().numpy()


@th.no_grad()
def decision_field(
    model,
    template: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    headings: Sequence[float] = (0.0,),
    axes: PlaneAxes = PlaneAxes(),
    n_steps: int | None = None,
    batch_size: int = 256,
) -> np.ndarray:
    """
    Where the planner means to go from every grid state: one deterministic planning step from a fresh plan (as at
    the start of an episode), the plan's first ``n_steps`` actions rolled out through the planner's dynamics model.
    (A car's first step only moves it along its heading; the plan shows where it turns to.)

    :param model: a trained (or loaded) :class:`~sb3_mpail.MPAIL` model
    :param template: the state's other dimensions, ``(state_dim,)``
    :param headings: headings to plan from (written at ``axes.heading_index``; with no heading index only one)
    :param n_steps: plan steps rolled out (``None``: the whole horizon)
    :param batch_size: states planned at once (memory grows with it)
    :return: planar displacements ``(n_headings, ny, nx, 2)``
    """
    if axes.heading_index is None and len(headings) != 1:
        raise ValueError("Several headings need axes.heading_index, the state index they are written at.")
    planner = _planning_parts(model)
    policy = model.deployed_policy()
    templates = np.repeat(np.asarray(template, dtype=np.float32)[None], len(headings), axis=0)
    if axes.heading_index is not None:
        templates[:, axes.heading_index] = headings
    states = np.stack([plane_states(t, xs, ys, axes) for t in templates]).reshape(-1, len(template))
    planar = [axes.x_index, axes.y_index]
    moves = []
    for batch in np.array_split(states, max(1, math.ceil(len(states) / batch_size))):
        batch_states = _tensor(model, batch)
        _, plan = policy.act(batch_states, policy.initial_plan(len(batch)), deterministic=True)
        steps = plan[:, :n_steps].transpose(0, 1).unsqueeze(2)  # time-major, one "sample" per state
        reached = rollout(planner.dynamics, batch_states, steps)[-1, :, 0]
        moves.append((reached[:, planar] - batch_states[:, planar]).cpu().numpy())
    return np.concatenate(moves).reshape(len(headings), len(ys), len(xs), 2)


@dataclass
class PlannedEpisode:
    """
    One deterministic episode, with the sampled roll-outs of some of its planning steps.

    :param path: planar positions over the episode, ``(T + 1, 2)``
    :param sample_steps: the steps whose samples are kept
    :param samples: per kept step, the last MPPI iteration's sampled roll-outs, planar, ``(n_samples, H + 1, 2)``
    :param weights: per kept step, their MPPI weights, ``(n_samples,)`` (summing to 1)
    """

    path: np.ndarray
    sample_steps: List[int] = field(default_factory=list)
    samples: List[np.ndarray] = field(default_factory=list)
    weights: List[np.ndarray] = field(default_factory=list)


@th.no_grad()
def planned_episodes(
    model,
    env_id: str,
    n_episodes: int,
    seed: int,
    env_kwargs: Dict[str, Any] | None = None,
    every: int = 20,
    axes: PlaneAxes = PlaneAxes(),
) -> List[PlannedEpisode]:
    """
    Drives ``n_episodes`` deterministic episodes at once (one env each), planning exactly as ``predict(...,
    deterministic=True)`` with the plan carried, and keeps the sampled roll-outs of every ``every``-th step.

    :param model: a trained (or loaded) :class:`~sb3_mpail.MPAIL` model
    :param env_id: registered env id
    :param seed: seed of the envs' start draws
    :param env_kwargs: keyword arguments of the env (e.g. ``start_region="ood"``)
    :param every: keep the samples of steps 0, ``every``, ``2 every``, ...
    """
    planner = _planning_parts(model)
    policy = model.deployed_policy()
    planar = [axes.x_index, axes.y_index]
    env = make_vec_env(env_id, n_envs=n_episodes, seed=seed, env_kwargs=env_kwargs)
    observations = env.reset()
    episodes = [PlannedEpisode(path=np.empty(0)) for _ in range(n_episodes)]
    paths: List[List[np.ndarray]] = [[obs[planar]] for obs in observations]
    finished = np.zeros(n_episodes, dtype=bool)
    plan = policy.initial_plan(n_episodes)
    generator = policy.generator(deterministic=True)
    step = 0
    while not finished.all():
        states = _tensor(model, observations)
        plan, samples, weights, _ = planner.optimise(states, plan, policy.temperature, generator)
        if step % every == 0:
            visited = rollout(planner.dynamics, states, samples)[..., planar].permute(1, 2, 0, 3).cpu().numpy()
            for index in np.flatnonzero(~finished):
                episodes[index].sample_steps.append(step)
                episodes[index].samples.append(visited[index])
                episodes[index].weights.append(weights[index].cpu().numpy())
        observations, _, dones, infos = env.step(plan[:, 0].cpu().numpy())
        for index in np.flatnonzero(~finished):
            last = infos[index]["terminal_observation"] if dones[index] else observations[index]
            paths[index].append(last[planar])
        finished |= dones
        step += 1
    env.close()
    for episode, path in zip(episodes, paths):
        episode.path = np.stack(path)
    return episodes


@dataclass
class Inspection:
    """Everything :func:`inspect_model` computes, as plain arrays (``[y, x]`` grids)."""

    xs: np.ndarray
    ys: np.ndarray
    forward_cost: np.ndarray
    reverse_cost: np.ndarray
    value: np.ndarray
    arrow_xs: np.ndarray
    arrow_ys: np.ndarray
    headings: np.ndarray
    moves: np.ndarray
    episodes: List[PlannedEpisode]
    description: Dict[str, Any]


def inspect_model(
    model,
    template: np.ndarray,
    forward_action: Sequence[float],
    reverse_action: Sequence[float],
    axes: PlaneAxes = NAVIGATION_AXES,
    speed: float = 0.0,
    extent: Extent = NAVIGATION_EXTENT,
    resolution: int = 61,
    arrow_resolution: int = 15,
    headings: Sequence[float] = (0.0, math.pi / 2, math.pi, -math.pi / 2),
    env_id: str | None = None,
    env_kwargs: Dict[str, Any] | None = None,
    n_episodes: int = 4,
    seed: int = 0,
    every: int = 20,
) -> Inspection:
    """
    The fields and episodes of one figure.

    :param model: a trained (or loaded) :class:`~sb3_mpail.MPAIL` model
    :param template: the state's other dimensions, ``(state_dim,)``; its heading is used for the cost and value
    :param forward_action: the move of the forward-cost field (e.g. ``[1, 0]``: full speed, straight)
    :param reverse_action: the move of the reverse-cost field (e.g. ``[-1, 0]``)
    :param axes: where position, heading and speed are in the state
    :param speed: forward speed written into the template at ``axes.speed_index`` (negated for the reverse field,
        so a reversing car reverses on)
    :param extent: ``(x_min, x_max, y_min, y_max)`` of the fields
    :param resolution: grid points per axis of the cost and value fields
    :param arrow_resolution: grid points per axis of the decision field
    :param headings: headings of the decision field
    :param env_id: env of the planned episodes (``None``: no episodes)
    :param env_kwargs: its keyword arguments
    :param n_episodes: planned episodes
    :param seed: seed of their starts
    :param every: steps between kept samples in the episodes
    """
    template = np.asarray(template, dtype=np.float32)
    forward_template, reverse_template = template.copy(), template.copy()
    if axes.speed_index is not None:
        forward_template[axes.speed_index], reverse_template[axes.speed_index] = speed, -speed
    xs, ys = grid_coordinates(extent, resolution)
    arrow_xs, arrow_ys = grid_coordinates(extent, arrow_resolution)
    episodes = [] if env_id is None else planned_episodes(model, env_id, n_episodes, seed, env_kwargs, every, axes)
    return Inspection(
        xs=xs,
        ys=ys,
        forward_cost=step_cost_field(model, forward_template, forward_action, xs, ys, axes),
        reverse_cost=step_cost_field(model, reverse_template, reverse_action, xs, ys, axes),
        value=value_field(model, template, xs, ys, axes),
        arrow_xs=arrow_xs,
        arrow_ys=arrow_ys,
        headings=np.asarray(headings, dtype=np.float32),
        moves=decision_field(model, template, arrow_xs, arrow_ys, headings, axes),
        episodes=episodes,
        description=dict(
            heading=None if axes.heading_index is None else float(template[axes.heading_index]),
            speed=None if axes.speed_index is None else speed,
            forward_action=list(map(float, forward_action)),
            reverse_action=list(map(float, reverse_action)),
            env_id=env_id,
            env_kwargs=env_kwargs or {},
            every=every,
            template=[float(value) for value in template],
        ),
    )


def inspection_figure(
    inspection: Inspection,
    demo_paths: Sequence[np.ndarray] = (),
    goal: Tuple[float, float] | None = None,
    title: str | None = None,
    axis_labels: Tuple[str, str] = ("x", "y"),
):
    """
    The figure of an inspection, to read without the docs: the forward and the reverse step cost, the value, the
    decision field (arrows, one colour per heading), the episodes' paths with their sampled roll-outs coloured by MPPI
    weight, and a panel that says how the fields were made (the template state) and how to read them.

    :param inspection: what :func:`inspect_model` returned
    :param demo_paths: planar demo paths ``(T + 1, 2)`` drawn in white (cost panels) or grey
    :param goal: a point to mark, e.g. the navigation goal
    :param title: the figure's title (``None``: a generic one)
    :param axis_labels: the names of the plane's two coordinates (with their units)
    :return: a matplotlib figure
    """
    from sb3_mpail.plotting import import_pyplot

    plt = import_pyplot()
    figure, panels = plt.subplots(2, 3, figsize=(19, 12.5), layout="constrained")
    panels = panels.ravel()
    described = inspection.description
    speed, heading = described["speed"], described["heading"]

    def state_said(speed_value: float | None) -> str:
        said = [] if speed_value is None else [f"speed {speed_value:g}"]
        said += [] if heading is None else [f"heading {heading:.2f} rad"]
        return f"\n(from {', '.join(said)})" if said else ""

    fields = [
        (inspection.forward_cost, f"Step cost of the move {described['forward_action']}" + state_said(speed),
         "step cost c(s, f(s, a)): low = expert-like"),
        (inspection.reverse_cost, f"Step cost of the move {described['reverse_action']}" + state_said(speed and -speed),
         "step cost c(s, f(s, a)): low = expert-like"),
        (inspection.value, "Terminal value V(s)" + state_said(None if speed is None else 0.0),
         "value V(s): high = the planner heads there"),
    ]  # fmt: skip
    for panel, (values, name, label) in zip(panels, fields):
        image = panel.pcolormesh(inspection.xs, inspection.ys, values, cmap="viridis", shading="auto")
        figure.colorbar(image, ax=panel, label=label, shrink=0.85)
        panel.set_title(name)
        for index, demo in enumerate(demo_paths):
            panel.plot(demo[:, 0], demo[:, 1], color="w", lw=1, alpha=0.8, label="demos" if index == 0 else None)
    arrows = panels[3]
    grid_x, grid_y = np.meshgrid(inspection.arrow_xs, inspection.arrow_ys)
    colours = plt.get_cmap("tab10")
    for index, heading_value in enumerate(inspection.headings):
        move = inspection.moves[index]
        length = np.linalg.norm(move, axis=-1, keepdims=True)
        unit = np.divide(move, length, out=np.zeros_like(move), where=length > 1e-6)
        arrows.quiver(
            grid_x, grid_y, unit[..., 0], unit[..., 1], color=colours(index % 10), angles="xy", scale=40, width=0.003,
            label=f"starting at heading {heading_value:.2f} rad",
        )
    arrows.set_title("Where the first plan from each state leads\n(one arrow colour per start heading; length not to scale)")
    arrows.legend(loc="lower right", fontsize=8, framealpha=0.9)
    episodes_panel = panels[4]
    weight_map = plt.get_cmap("plasma")
    for episode in inspection.episodes:
        for samples, weights in zip(episode.samples, episode.weights):
            order = np.argsort(weights)[-64:]  # the 64 heaviest samples, lightest drawn first
            scale = weights[order] / max(float(weights.max()), 1e-12)
            for sample, weight in zip(samples[order], scale):
                episodes_panel.plot(sample[:, 0], sample[:, 1], color=weight_map(weight), lw=0.6, alpha=0.3 + 0.7 * weight)
        episodes_panel.plot(episode.path[:, 0], episode.path[:, 1], color="k", lw=1.2)
        episodes_panel.plot(*episode.path[0], "o", color="k", ms=4)
        episodes_panel.plot(*episode.path[-1], "x", color="k", ms=7, mew=2)
    starts = ", ".join(f"{key}={value}" for key, value in described["env_kwargs"].items()) or "default starts"
    episodes_panel.set_title(
        f"{len(inspection.episodes)} deterministic episodes ({starts}),\n"
        f"with the roll-outs sampled every {described['every']} steps"
    )
    weights_bar = figure.colorbar(
        plt.cm.ScalarMappable(cmap=weight_map), ax=episodes_panel, shrink=0.85,
        label="roll-out weight / the step's heaviest weight",
    )  # fmt: skip
    weights_bar.ax.set_ylim(0, 1)
    episodes_panel.plot([], [], color="k", lw=1.2, label="path driven")
    episodes_panel.plot([], [], "o", color="k", ms=4, label="start")
    episodes_panel.plot([], [], "x", color="k", ms=7, mew=2, label="end")
    for panel in panels[:5]:
        if goal is not None:
            panel.plot(*goal, marker="*", color="gold", mec="k", ms=16, ls="none", label="goal")
        panel.set_xlim(inspection.xs[0], inspection.xs[-1])
        panel.set_ylim(inspection.ys[0], inspection.ys[-1])
        panel.set_aspect("equal")
        panel.set_xlabel(axis_labels[0])
        panel.set_ylabel(axis_labels[1])
        panel.grid(alpha=0.3)
    episodes_panel.legend(loc="lower right", fontsize=8, framealpha=0.9)
    if demo_paths or goal is not None:
        panels[0].legend(loc="lower right", fontsize=8, framealpha=0.9, facecolor="lightgrey")
    _describe(panels[5], inspection)
    figure.suptitle(title or "What a trained MPAIL planner has learned", fontsize=15)
    return figure


def _describe(panel, inspection: Inspection) -> None:
    """The figure's reading guide: what was held fixed (the template state), and what each panel shows."""
    described = inspection.description
    template = ", ".join(f"{value:.3g}" for value in described["template"])
    lines = [
        "How to read this figure",
        "",
        "Every field varies only the position on the plane. The state's other",
        "dimensions are those of one template state:",
        f"[{template}]",
    ]
    if described["speed"] is not None:
        lines.append(f"(the cost fields' forward speed {described['speed']:g}, or {-described['speed']:g} reversing)")
    lines += [
        "",
        "Step costs: the learned cost c = -d(s, s') of applying the move once",
        "from each position, through the planner's dynamics model.",
        "Value: the learned terminal value at the end of each roll-out.",
        "The planner prefers low cost and high value.",
        "",
        "Arrows: one deterministic planning step from a fresh plan at each",
        "position, rolled out through the model: where it means to go.",
        "",
        "Episodes: the planner driving from the env's starts, with the",
        "64 heaviest of its sampled roll-outs at every kept step.",
    ]
    if described["env_id"]:
        lines += ["", f"env: {described['env_id']}"]
    panel.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", fontsize=11, transform=panel.transAxes, wrap=True)
    panel.axis("off")


def plot_inspection(
    inspection: Inspection,
    path: Union[str, Path],
    demo_paths: Sequence[np.ndarray] = (),
    goal: Tuple[float, float] | None = None,
    title: str | None = None,
    axis_labels: Tuple[str, str] = ("x", "y"),
) -> Path:
    """
    Writes :func:`inspection_figure` as a PNG.

    :param inspection: what :func:`inspect_model` returned
    :param path: where to write the PNG
    :param demo_paths: planar demo paths ``(T + 1, 2)`` drawn in white (cost panels) or grey
    :param goal: a point to mark, e.g. the navigation goal
    :param title: the figure's title
    :param axis_labels: the names of the plane's two coordinates (with their units)
    :return: the path written
    """
    from sb3_mpail.plotting import save_figure

    return save_figure(inspection_figure(inspection, demo_paths, goal, title, axis_labels), path)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """
    The command line.

    :param argv: arguments (``None``: ``sys.argv``)
    """
    parser = argparse.ArgumentParser(
        prog=program_name("sb3_mpail.inspect", "sb3-mpail-inspect"),
        description="Draw a saved MPAIL model's learned step cost, value, decisions and sampled roll-outs over a plane.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("model", help="a saved MPAIL model (.zip)")
    parser.add_argument("--out", default=None, help="the PNG to write (default: beside the model, <name>_inspect.png)")
    parser.add_argument("--env-id", default="sb3_mpail/Navigation-v0", help="env of the planned episodes ('' for none)")
    parser.add_argument("--start-region", default="ood", help="the navigation env's start_region for the episodes")
    parser.add_argument("--episodes", type=int, default=4, help="planned episodes drawn with their roll-outs")
    parser.add_argument("--seed", type=int, default=0, help="reset seed of the first episode")
    parser.add_argument("--x-index", type=int, default=NAVIGATION_AXES.x_index, help="state dimension of the plane's x")
    parser.add_argument("--y-index", type=int, default=NAVIGATION_AXES.y_index, help="state dimension of the plane's y")
    parser.add_argument("--heading-index", type=int, default=NAVIGATION_AXES.heading_index,
                        help="state dimension of the heading (-1: none)")  # fmt: skip
    parser.add_argument("--speed-index", type=int, default=NAVIGATION_AXES.speed_index,
                        help="state dimension of the forward speed (-1: none)")  # fmt: skip
    parser.add_argument("--heading", type=float, default=math.pi / 4, help="heading of the cost and value fields (rad)")
    parser.add_argument("--speed", type=float, default=3.0, help="forward speed of the cost fields' template")
    parser.add_argument("--forward-action", type=float, nargs="+", default=[1.0, 0.0], help="the action of driving forward")
    parser.add_argument("--reverse-action", type=float, nargs="+", default=[-1.0, 0.0], help="the action of reversing")
    parser.add_argument("--extent", type=float, nargs=4, default=list(NAVIGATION_EXTENT), metavar=("X0", "X1", "Y0", "Y1"),
                        help="the plane drawn (metres)")  # fmt: skip
    parser.add_argument("--resolution", type=int, default=61, help="grid points per side of the cost and value fields")
    parser.add_argument("--arrow-resolution", type=int, default=15, help="arrows per side of the decision field")
    parser.add_argument("--n-headings", type=int, default=4, help="decision-field headings, evenly spaced from 0")
    parser.add_argument("--goal", type=float, nargs=2, default=[10.0, 10.0], help="point to mark")
    parser.add_argument("--axis-names", nargs=2, default=["x (m)", "y (m)"], metavar=("X", "Y"),
                        help="the plane's axis labels")  # fmt: skip
    parser.add_argument("--demos", default=None, help="demos (.npz) to draw (default: none)")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> Path:
    """
    Runs the command.

    :param argv: command-line arguments (``None``: ``sys.argv``)
    :return: the figure written
    """
    from sb3_mpail.demos import load_demo_episodes
    from sb3_mpail.mpail import MPAIL

    args = parse_args(argv)
    model = MPAIL.load(args.model, device="cpu")
    axes = PlaneAxes(
        args.x_index,
        args.y_index,
        None if args.heading_index < 0 else args.heading_index,
        None if args.speed_index < 0 else args.speed_index,
    )
    template = np.zeros(model.observation_space.shape, dtype=np.float32)
    if axes.heading_index is not None:
        template[axes.heading_index] = args.heading
    headings = [2 * math.pi * k / args.n_headings for k in range(args.n_headings)] if axes.heading_index is not None else [0]
    headings = [(h + math.pi) % (2 * math.pi) - math.pi for h in headings]
    env_kwargs = {"start_region": args.start_region} if args.start_region and args.env_id.endswith("Navigation-v0") else None
    inspection = inspect_model(
        model,
        template,
        args.forward_action,
        args.reverse_action,
        axes,
        args.speed,
        tuple(args.extent),
        args.resolution,
        args.arrow_resolution,
        headings,
        args.env_id or None,
        env_kwargs,
        args.episodes,
        args.seed,
    )
    demo_paths = []
    if args.demos:
        demo_paths = [episode[:, [axes.x_index, axes.y_index]] for episode in load_demo_episodes(args.demos)]
    out = Path(args.out) if args.out else Path(args.model).with_name(Path(args.model).stem + "_inspect.png")
    title = f"What the planner in {Path(args.model).name} has learned"
    figure = plot_inspection(inspection, out, demo_paths, tuple(args.goal), title, tuple(args.axis_names))
    print(f"figure: {figure}")
    return figure


if __name__ == "__main__":
    main()
