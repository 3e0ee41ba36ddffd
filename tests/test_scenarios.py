"""Smoke tests of the scenarios: each trains from its shipped demos with its entry of the shipped zoo hyperparameters."""

import subprocess
import sys
from pathlib import Path

import pytest

from sb3_mpail import MPAIL
from sb3_mpail.mppi.constraints import RectangleObstacles
from sb3_mpail.mppi.costs import FeatureSelection, GoalFrameFeatures, LaneFrameFeatures, MazeFrameFeatures
from sb3_mpail.mppi.dynamics import LearnedDynamics, PointMassDynamics
from sb3_mpail.mppi.highway_dynamics import HighwayKinematics, RacetrackKinematics


def zoo_train(env_id: str, timesteps: int, logs: Path) -> MPAIL:
    trained = subprocess.run(
        [sys.executable, "-m", "sb3_mpail.zoo", "train", "--algo", "mpail", "--env", env_id,
         "-f", str(logs), "--seed", "0", "-n", str(timesteps)],
        capture_output=True, text=True, timeout=300, cwd=logs,
    )
    assert trained.returncode == 0, trained.stderr[-3000:]
    name = env_id.replace("/", "-")
    model = MPAIL.load(logs / "mpail" / f"{name}_1" / f"{name}.zip")
    assert model.num_timesteps == timesteps
    return model


def test_cartpole_mpail_om_trains_with_the_shipped_zoo_entry(tmp_path):
    model = zoo_train("sb3_mpail/ContinuousCartPole-v0", 800, tmp_path)
    # MPAIL-OM: no prior model, the planner's dynamics were fitted online to the agent's own transitions
    assert isinstance(model.policy.dynamics, LearnedDynamics)
    assert int(model.policy.dynamics.epochs_trained) > 0


def test_lap_from_one_noisy_partial_demo_trains_with_the_shipped_zoo_entry(tmp_path):
    model = zoo_train("sb3_mpail/NavigationLap-v0", 960, tmp_path)
    assert model.demos_are_features
    # the demo holds x, y, vx, vy; the discriminator sees the car from the demo's path (offset, vx, vy); the value sees
    # the whole 12-D state
    selection, path_frame = model.policy.discriminator_features
    assert isinstance(selection, FeatureSelection) and selection.indices.tolist() == [0, 1, 6, 7]
    assert isinstance(path_frame, LaneFrameFeatures) and path_frame.keep == [2, 3]
    assert model.policy.demo_feature_space.shape == (4,) and model.policy.feature_space.shape == (3,)
    assert model.policy.value_net[0].in_features == 12


@pytest.mark.parametrize(
    "env_id, model_class", [("sb3_mpail/Racetrack-v0", RacetrackKinematics), ("sb3_mpail/Highway-v0", HighwayKinematics)]
)
def test_road_scenario_trains_with_the_shipped_zoo_entry_through_highway_envs_kinematics(tmp_path, env_id, model_class):
    pytest.importorskip("highway_env")
    model = zoo_train(env_id, 400, tmp_path)  # one rollout of 4 envs x 100 steps, one update
    # no dynamics in the zoo entry: the env's default, highway-env's kinematic bicycle in the observation's units
    assert type(model.policy.dynamics) is model_class


def test_ant_mpail_om_trains_with_the_shipped_zoo_entry_learning_the_27d_model_online(tmp_path):
    pytest.importorskip("mujoco")
    model = zoo_train("sb3_mpail/Ant-v0", 800, tmp_path)
    # MPAIL-OM on the Ant: the planner's model of the 27-D state under the 8-D action was fitted to the agent's steps
    assert isinstance(model.policy.dynamics, LearnedDynamics)
    assert model.policy.dynamics.net[0].in_features == 27 + 8
    assert int(model.policy.dynamics.epochs_trained) > 0


def test_point_maze_trains_with_the_shipped_zoo_entry_planning_through_the_point_mass_with_the_walls_as_a_cost(tmp_path):
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium_robotics")
    model = zoo_train("sb3_mpail/PointMaze-v0", 400, tmp_path)
    assert isinstance(model.policy.dynamics, PointMassDynamics)
    assert isinstance(model.policy.planner.constraint_cost, RectangleObstacles)
    # the discriminator sees the ball from the goal (its offset and velocity); the value the whole state
    assert isinstance(model.policy.discriminator_features, GoalFrameFeatures)
    assert model.policy.discriminator_features.indices == {"position": [0, 1], "goal_position": [4, 5], "velocity": [2, 3]}
    assert model.policy.value_net[0].in_features == 6


def test_medium_maze_trains_with_the_shipped_zoo_entry_seeing_the_ball_along_the_mazes_shortest_paths(tmp_path):
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium_robotics")
    model = zoo_train("sb3_mpail/PointMazeMedium-v0", 800, tmp_path)  # one rollout of 4 envs x 200 steps
    assert isinstance(model.policy.dynamics, PointMassDynamics)
    assert isinstance(model.policy.planner.constraint_cost, RectangleObstacles)
    # discriminator: offset to the next waypoint, path length left, velocity; value: the same without the velocity
    assert isinstance(model.policy.discriminator_features, MazeFrameFeatures)
    assert model.policy.feature_space.shape == (5,)
    value = model.policy.value_net
    assert isinstance(value.features, MazeFrameFeatures) and value.network[0].in_features == 3
