"""Bad feature maps and dynamics models are refused with errors that name the setting, what it got and what is expected."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_mpail.mppi import AngleFeatures, make_dynamics
from sb3_mpail.mppi.costs import FeatureMap, FeatureSelection
from sb3_mpail.mppi.dynamics import LearnedDynamics

STATES_3D = spaces.Box(-np.inf, np.inf, (3,), np.float32)
ACTIONS_1D = spaces.Box(-2, 2, (1,), np.float32)
ACTIONS_2D = spaces.Box(-1, 1, (2,), np.float32)


def features_space(features, name: str) -> spaces.Box:
    """What the policy does with ``discriminator_features`` or ``value_features``: wrap, then size on a 3-D state."""
    return FeatureMap.space(FeatureMap.wrap(features, name), STATES_3D, name)


# --- feature maps


def test_state_indices_out_of_range_are_refused_naming_the_setting():
    with pytest.raises(ValueError, match=r"discriminator_features holds state indices \[5\] out of range for the 3-D state; "
                                         r"they must be in \[-3, 3\)"):  # fmt: skip
        features_space([0, 5], "discriminator_features")


def test_angle_features_out_of_range_are_refused_naming_value_features():
    with pytest.raises(ValueError, match=r"value_features holds state indices \[7\] out of range .* in \[0, 3\)"):
        features_space({"angles": [7]}, "value_features")
    with pytest.raises(ValueError, match=r"value_features holds state indices \[7\]"):  # a module given as it is
        features_space(AngleFeatures([7]), "value_features")


def test_negative_angle_indices_are_refused_naming_value_features():
    with pytest.raises(ValueError, match=r"value_features\['angles'\] must be distinct angle indices >= 0; got \[-1\]"):
        FeatureMap.wrap({"angles": [-1]}, "value_features")


def test_an_empty_list_of_indices_is_refused_naming_the_setting():
    with pytest.raises(ValueError, match=r"value_features must be a non-empty list of state indices; got \[\]"):
        FeatureMap.wrap([], "value_features")
    with pytest.raises(ValueError, match=r"discriminator_features\['angles'\] must be a non-empty list .* got \[\]"):
        FeatureMap.wrap({"angles": []}, "discriminator_features")


def test_non_integer_indices_are_refused_naming_the_setting():
    with pytest.raises(ValueError, match=r"value_features must hold integer state indices; got \[0, 1.5\]"):
        FeatureMap.wrap([0, 1.5], "value_features")


def test_numpy_integer_indices_are_accepted_as_ints():
    selection = FeatureMap.wrap([np.int64(0), np.int32(2)], "discriminator_features")
    assert isinstance(selection, FeatureSelection) and features_space(selection, "discriminator_features").shape == (2,)
    assert th.equal(selection(th.tensor([[1.0, 2.0, 3.0]])), th.tensor([[1.0, 3.0]]))
    angles = FeatureMap.wrap({"angles": [np.int64(1)]}, "value_features")
    assert angles.angle_indices == [1] and type(angles.angle_indices[0]) is int


def test_negative_state_indices_count_from_the_end_as_in_python():
    selection = FeatureMap.wrap([-1], "discriminator_features")
    assert th.equal(selection(th.tensor([[1.0, 2.0, 3.0]])), th.tensor([[3.0]]))


@pytest.mark.parametrize(
    "features, dtype", [(lambda states: states[:, :2].double(), "torch.float64"), (lambda states: states > 0, "torch.bool")]
)
def test_feature_maps_of_another_dtype_than_the_states_are_refused_naming_the_setting_and_the_dtype(features, dtype):
    with pytest.raises(ValueError, match=rf"discriminator_features must return features of the states' dtype \(torch.float32 "
                                         rf"here\); for float32 states it gave {dtype}"):  # fmt: skip
        features_space(features, "discriminator_features")


def test_a_bad_feature_map_is_reported_under_the_setting_it_was_given_as():
    with pytest.raises(TypeError, match="value_features must be an nn.Module, a callable or a list of state indices"):
        FeatureMap.wrap(3.0, "value_features")
    with pytest.raises(ValueError, match=r"value_features must map \(batch, 3\) states to a \(batch, n_features\)"):
        features_space(lambda states: states[:, 0], "value_features")
    with pytest.raises(ValueError, match="A dict of value_features takes one key, 'angles'"):
        FeatureMap.wrap({"angle": [1]}, "value_features")


# --- learned dynamics


@pytest.mark.parametrize(
    "setting, value, expected",
    [
        ("hidden_sizes", (0,), r"hidden_sizes must be a sequence of positive integers; got \(0,\)"),
        ("n_epochs", -1, "n_epochs must be a positive integer; got -1"),
        ("n_epochs", 0, "n_epochs must be a positive integer; got 0"),
    ],
)
def test_learned_dynamics_that_would_never_be_fitted_are_refused_naming_the_setting(setting, value, expected):
    with pytest.raises(ValueError, match=expected):
        make_dynamics("learned", STATES_3D, ACTIONS_1D, {setting: value})


@pytest.mark.parametrize(
    "setting, value, expected",
    [
        ("learning_rate", 0.0, "learning_rate must be a finite number > 0; got 0.0"),
        ("learning_rate", -1e-3, "learning_rate must be a finite number > 0; got -0.001"),
        ("learning_rate", "1e-3", "learning_rate must be a finite number > 0; got '1e-3'"),  # what YAML makes of 1e-3
        ("lr_decay", 2.0, r"lr_decay must be a number in \(0, 1\]; got 2.0"),
        ("lr_decay", 0.0, r"lr_decay must be a number in \(0, 1\]; got 0.0"),
    ],
)
def test_learned_dynamics_rates_that_cannot_train_or_that_grow_are_refused_naming_the_setting(setting, value, expected):
    with pytest.raises(ValueError, match=expected):
        make_dynamics("learned", STATES_3D, ACTIONS_1D, {setting: value})


def test_a_pendulum_gravity_that_is_not_a_number_is_refused_naming_it():
    with pytest.raises(ValueError, match="gravity must be a finite number; got '10'"):
        make_dynamics("pendulum", STATES_3D, ACTIONS_1D, dict(gravity="10"))


# --- a user's dynamics function


def numpy_dynamics(states: th.Tensor, actions: th.Tensor) -> np.ndarray:
    return states.numpy() + 1


def first_four_rows(states: th.Tensor, actions: th.Tensor) -> th.Tensor:
    return states[:4] + actions[:4]


def adds_in_place(states: th.Tensor, actions: th.Tensor) -> th.Tensor:
    states[:, 2] += actions[:, 0]
    return states


def clamps_actions_in_place(states: th.Tensor, actions: th.Tensor) -> th.Tensor:
    return states + actions.clamp_(-0.1, 0.1)


def test_dynamics_taking_the_wrong_number_of_arguments_are_refused_naming_dynamics_and_the_signature():
    with pytest.raises(TypeError, match=r"dynamics must be a callable f\(states, actions\) -> next_states; "
                                        r".*<lambda>\(states\) cannot be called so"):  # fmt: skip
        make_dynamics(lambda states: states, STATES_3D, ACTIONS_1D)


def test_dynamics_returning_a_numpy_array_are_refused_naming_the_function():
    with pytest.raises(TypeError, match=r"The dynamics function numpy_dynamics must return next states as a torch tensor; "
                                        r"for states \(2, 3\) and actions \(2, 1\) it returned a numpy.ndarray"):  # fmt: skip
        make_dynamics(numpy_dynamics, STATES_3D, ACTIONS_1D)


def test_dynamics_of_the_wrong_shape_for_some_batch_sizes_are_refused_when_called_with_them():
    model = make_dynamics(first_four_rows, STATES_3D, ACTIONS_1D)  # right for the probe's batch of 2
    assert model(th.ones(4, 3), th.ones(4, 1)).shape == (4, 3)
    with pytest.raises(ValueError, match=r"The dynamics function first_four_rows maps states of shape \(16, 3\) "
                                         r"\(with actions \(16, 1\)\) to \(4, 3\); it must return next states of the "
                                         r"states' shape \(16, 3\)"):  # fmt: skip
        model(th.ones(16, 3), th.ones(16, 1))


@pytest.mark.parametrize("function, modified", [(adds_in_place, "states"), (clamps_actions_in_place, "actions")])
def test_dynamics_that_modify_their_inputs_in_place_are_refused_naming_what_they_modified(function, modified):
    with pytest.raises(ValueError, match=f"The dynamics function {function.__name__} modified the {modified} it was given "
                                         "in place; it must leave its inputs unchanged"):  # fmt: skip
        make_dynamics(function, STATES_3D, ACTIONS_1D)


# --- named and declared models on the wrong environment


@pytest.mark.parametrize(
    "name, states, actions, expected",
    [
        ("pendulum", 12, 1, r"PendulumDynamics \('pendulum'\) is written for 3-D states and 1-D actions, but the "
                            r"environment's observations are 12-D and its actions 1-D"),
        ("bicycle", 3, 2, r"KinematicBicycle \('bicycle'\) is written for 12-D states and 2-D actions, but the "
                          r"environment's observations are 3-D"),
        ("point_mass", 12, 2, r"PointMassDynamics \('point_mass'\) is written for 6-D states .* observations are 12-D"),
        ("parking", 6, 2, r"ParkingKinematics \('parking'\) is written for 12-D states .* observations are 6-D"),
        ("highway", 12, 2, r"HighwayKinematics \('highway'\) is written for 6-D states .* observations are 12-D"),
        ("racetrack", 6, 2, r"RacetrackKinematics \('racetrack'\) is written for 6-D states and 1-D actions, .* actions 2-D"),
    ],
)  # fmt: skip
def test_a_named_model_on_an_env_of_other_sizes_is_refused_naming_the_model_and_the_sizes(name, states, actions, expected):
    box = spaces.Box(-np.inf, np.inf, (states,), np.float32)
    with pytest.raises(ValueError, match=expected):
        make_dynamics(name, box, spaces.Box(-1, 1, (actions,), np.float32))


def test_two_dimensional_actions_through_a_one_action_model_are_refused():
    with pytest.raises(ValueError, match=r"PendulumDynamics \('pendulum'\) is written for 3-D states and 1-D actions, .* "
                                         r"its actions 2-D"):  # fmt: skip
        make_dynamics("pendulum", STATES_3D, ACTIONS_2D)


def test_a_learned_model_built_for_other_sizes_is_refused_naming_the_sizes():
    with pytest.raises(ValueError, match=r"LearnedDynamics is written for 3-D states and 1-D actions, .* its actions 2-D"):
        make_dynamics(LearnedDynamics(3, 1), STATES_3D, ACTIONS_2D)
