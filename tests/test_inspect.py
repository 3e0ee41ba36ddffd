"""The inspection figures' data: fields over the plane, the planner's decisions and the sampled roll-outs it weighs."""

import math

import numpy as np
import pytest
import torch as th
from torch import nn

from sb3_mpail import MPAIL
from sb3_mpail.inspect import (
    NAVIGATION_AXES,
    decision_field,
    grid_coordinates,
    inspect_model,
    inspection_figure,
    main,
    plane_states,
    planned_episodes,
    step_cost_field,
    value_field,
)

TARGET = (4.0, -3.0)


class DistanceToTarget(nn.Module):
    """A hand-made step cost: how far the move ends from a target point."""

    def forward(self, states: th.Tensor, next_states: th.Tensor) -> th.Tensor:
        return th.linalg.vector_norm(next_states[..., :2] - next_states.new_tensor(TARGET), dim=-1)


def navigation_model(**policy_kwargs) -> MPAIL:
    settings = {**dict(n_samples=64, horizon=10, n_iterations=2), **policy_kwargs}
    model = MPAIL("MlpMPPI", "sb3_mpail/Navigation-v0", policy_kwargs=settings, seed=0)
    model.policy.temperature.fill_(0.05)
    return model


@pytest.fixture(scope="module")
def hand_made():
    return navigation_model(step_cost=DistanceToTarget(), use_terminal_value=False)


def test_plane_states_place_the_template_at_every_grid_point():
    template = np.arange(12, dtype=np.float32)
    xs, ys = grid_coordinates((-1.0, 1.0, 0.0, 4.0), 3)
    states = plane_states(template, xs, ys, NAVIGATION_AXES)
    assert states.shape == (3, 3, 12)
    assert np.array_equal(states[2, 0, :2], [-1.0, 4.0]) and np.array_equal(states[0, 2, :2], [1.0, 0.0])
    assert np.array_equal(states[1, 1, 2:], template[2:])


def test_cost_and_value_fields_are_the_planners_own_on_every_grid_state(hand_made):
    model = navigation_model()
    xs, ys = grid_coordinates((-5.0, 5.0, -4.0, 4.0), 7)
    template = np.zeros(12, np.float32)
    template[5], template[6] = 0.5, 3.0
    costs = step_cost_field(model, template, [1.0, 0.0], xs, ys, NAVIGATION_AXES)
    values = value_field(model, template, xs, ys, NAVIGATION_AXES)
    assert costs.shape == values.shape == (7, 7) and np.isfinite(costs).all() and np.isfinite(values).all()
    states = th.as_tensor(plane_states(template, xs, ys, NAVIGATION_AXES)[3, 5][None])
    with th.no_grad():
        moved = model.policy.dynamics(states, th.tensor([[1.0, 0.0]]))
        expected_cost = -model.policy.discriminator(states, None, moved, None)
        expected_value = model.policy.value_net(states)
    assert costs[3, 5] == pytest.approx(float(expected_cost), rel=1e-5)
    assert values[3, 5] == pytest.approx(float(expected_value), rel=1e-5)
    # a hand-made cost is what the planner plans with, so it is what the field shows
    hand_costs = step_cost_field(hand_made, template, [1.0, 0.0], xs, ys, NAVIGATION_AXES)
    with th.no_grad():
        moved = hand_made.policy.dynamics(states, th.tensor([[1.0, 0.0]]))
    assert hand_costs[3, 5] == pytest.approx(float(np.hypot(*(moved[0, :2].numpy() - TARGET))), rel=1e-5)


def test_decision_arrows_follow_a_hand_made_cost_towards_its_target(hand_made):
    xs, ys = grid_coordinates((-12.0, 12.0, -12.0, 12.0), 7)
    headings = (0.0, math.pi / 2, math.pi, -math.pi / 2)
    moves = decision_field(hand_made, np.zeros(12, np.float32), xs, ys, headings, NAVIGATION_AXES)
    assert moves.shape == (4, 7, 7, 2) and np.isfinite(moves).all()
    starts = np.stack(np.meshgrid(xs, ys), axis=-1)[None].repeat(4, axis=0)
    before = np.linalg.norm(starts - TARGET, axis=-1)
    after = np.linalg.norm(starts + moves - TARGET, axis=-1)
    far = before > 4.0
    assert (after[far] < before[far]).all(), "from every state and heading the first plan leads towards the target"
    assert (before[far] - after[far]).mean() > 0.5


def test_several_headings_need_a_heading_index(hand_made):
    xs, ys = grid_coordinates((-1.0, 1.0, -1.0, 1.0), 2)
    with pytest.raises(ValueError, match="heading_index"):
        decision_field(hand_made, np.zeros(12, np.float32), xs, ys, (0.0, 1.0), NAVIGATION_AXES.__class__())


def test_planned_episodes_keep_weighted_samples_of_the_planning_steps(hand_made):
    episodes = planned_episodes(hand_made, "sb3_mpail/Navigation-v0", 2, seed=3, every=40, axes=NAVIGATION_AXES)
    assert len(episodes) == 2
    for episode in episodes:
        assert episode.path.shape == (101, 2) and episode.sample_steps == [0, 40, 80]
        for samples, weights in zip(episode.samples, episode.weights):
            assert samples.shape == (64, 11, 2) and weights.shape == (64,)
            assert weights.sum() == pytest.approx(1.0, abs=1e-5) and (weights >= 0).all()
    # the episodes are the ones predict plans: the same path from the same start
    env_path = episodes[0].path
    assert np.linalg.norm(env_path[-1] - TARGET) < np.linalg.norm(env_path[0] - TARGET)


def test_inspect_model_gathers_every_field_with_a_reversing_template(hand_made):
    template = np.zeros(12, np.float32)
    template[5] = 0.3
    inspection = inspect_model(
        hand_made, template, [1.0, 0.0], [-1.0, 0.0], speed=3.0, extent=(-6.0, 6.0, -6.0, 6.0), resolution=9,
        arrow_resolution=3, headings=(0.0, math.pi), env_id=None,
    )  # fmt: skip
    assert inspection.forward_cost.shape == inspection.reverse_cost.shape == inspection.value.shape == (9, 9)
    assert inspection.moves.shape == (2, 3, 3, 2) and inspection.episodes == []
    assert inspection.description["heading"] == pytest.approx(0.3)


def test_command_line_draws_a_saved_model(tmp_path):
    model = navigation_model(n_samples=16, horizon=3, n_iterations=1)
    model.save(tmp_path / "model.zip")
    figure = main([str(tmp_path / "model.zip"), "--episodes", "1", "--resolution", "11", "--arrow-resolution", "3"])
    assert figure == tmp_path / "model_inspect.png" and figure.stat().st_size > 20_000


def test_inspection_figure_reads_without_the_docs(hand_made):
    """Every panel has content, axis labels and a title inside the figure that overlaps no other text."""
    template = np.zeros(12, np.float32)
    template[5] = 0.3
    inspection = inspect_model(
        hand_made, template, [1.0, 0.0], [-1.0, 0.0], speed=3.0, extent=(-6.0, 6.0, -6.0, 6.0), resolution=9,
        arrow_resolution=3, headings=(0.0, math.pi), env_id="sb3_mpail/Navigation-v0", n_episodes=1, every=50,
    )  # fmt: skip
    demo = np.stack([np.linspace(0, 4, 10), np.linspace(0, -3, 10)], axis=1)
    figure = inspection_figure(inspection, [demo], goal=TARGET, axis_labels=("x (m)", "y (m)"))
    renderer = figure.canvas.get_renderer()
    figure.draw(renderer)
    box = figure.bbox
    panels = [axes for axes in figure.axes if axes.get_label() != "<colorbar>"]
    assert len(panels) == 6
    texts = [figure._suptitle] + [axes.title for axes in panels if axes.get_title()]
    assert len(texts) == 6 and "MPAIL" in figure._suptitle.get_text()  # five panel titles and the figure's own
    extents = [text.get_window_extent(renderer) for text in texts]
    for text, extent in zip(texts, extents):
        assert box.x0 <= extent.x0 and extent.x1 <= box.x1 and extent.y1 <= box.y1, text.get_text()
    for first in range(len(extents)):
        for second in range(first + 1, len(extents)):
            assert not extents[first].overlaps(extents[second]), (texts[first].get_text(), texts[second].get_text())
    for axes in panels[:5]:
        assert axes.get_xlabel() == "x (m)" and axes.get_ylabel() == "y (m)"
    guide = panels[5].texts[0].get_text()  # the sixth panel explains the template state and how to read the rest
    assert "template state" in guide and "0.3" in guide
    assert all(axes.get_ylabel() for axes in figure.axes if axes.get_label() == "<colorbar>")  # every colour bar says what
