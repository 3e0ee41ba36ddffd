"""Environments for the MPAIL experiments, registered with gymnasium on import."""

import gymnasium as gym

from sb3_mpail.envs.navigation import NavigationEnv

#: how to install the simulators of the highway-env, MuJoCo and gymnasium-robotics scenarios (the ``scenarios`` extra)
SCENARIOS_INSTALL_HINT = 'pip install "sb3-mpail[scenarios]" (in a checkout: pip install -e ".[scenarios]")'

# Guard against re-registration warnings when the module is reloaded.
if "sb3_mpail/Navigation-v0" not in gym.registry:
    gym.register(
        id="sb3_mpail/Navigation-v0",
        entry_point="sb3_mpail.envs.navigation:NavigationEnv",
        max_episode_steps=100,
    )

__all__ = ["NavigationEnv"]

# Continuous-action cartpole (gymnasium CartPole-v1 physics, force action in [-1, 1] x 10 N), 200-step episodes.
if "sb3_mpail/ContinuousCartPole-v0" not in gym.registry:
    gym.register(
        id="sb3_mpail/ContinuousCartPole-v0",
        entry_point="sb3_mpail.envs.cartpole:ContinuousCartPoleEnv",
        max_episode_steps=200,
    )

# The navigation car for one lap of sb3_mpail.envs.lap's closed track: 240 steps.
if "sb3_mpail/NavigationLap-v0" not in gym.registry:
    gym.register(
        id="sb3_mpail/NavigationLap-v0",
        entry_point="sb3_mpail.envs.lap:NavigationLapEnv",
        max_episode_steps=240,
    )

# highway-env's parking-v0 with a flat observation (ego state + goal); needs the `scenarios` extra, and making it
# without highway-env raises an ImportError saying what to install.
if "sb3_mpail/Parking-v0" not in gym.registry:
    gym.register(id="sb3_mpail/Parking-v0", entry_point="sb3_mpail.envs.highway:FlatParkingEnv")

# gymnasium's MuJoCo Ant-v4 (27-D observation) with 200-step episodes; needs the `scenarios` extra, and making it
# without mujoco raises an ImportError saying what to install.
if "sb3_mpail/Ant-v0" not in gym.registry:
    gym.register(id="sb3_mpail/Ant-v0", entry_point="sb3_mpail.envs.ant:make_ant", max_episode_steps=200)

# gymnasium-robotics' PointMaze U-maze with fixed start and goal cells, flat observation, 20 Hz actions, 100 steps;
# needs the `scenarios` extra, and making it without gymnasium-robotics raises an ImportError saying what to install.
if "sb3_mpail/PointMaze-v0" not in gym.registry:
    gym.register(id="sb3_mpail/PointMaze-v0", entry_point="sb3_mpail.envs.maze:FlatPointMazeEnv", max_episode_steps=100)
# gymnasium-robotics' PointMaze Medium (8 x 8) with its stock random start and goal cells, the same observation and
# rate, 200 steps (10 s); needs the `scenarios` extra.
if "sb3_mpail/PointMazeMedium-v0" not in gym.registry:
    gym.register(
        id="sb3_mpail/PointMazeMedium-v0",
        entry_point="sb3_mpail.envs.maze:FlatPointMazeEnv",
        kwargs={"maze_map": "medium"},
        max_episode_steps=200,
    )

# highway-env's racetrack-v0 without other vehicles, observed through the ego car's flat state (200 steps, one lap);
# needs the `scenarios` extra, and making it without highway-env raises an ImportError saying what to install.
if "sb3_mpail/Racetrack-v0" not in gym.registry:
    gym.register(id="sb3_mpail/Racetrack-v0", entry_point="sb3_mpail.envs.highway_roads:EgoRacetrackEnv")

# highway-env's highway-v0 without other vehicles, continuous [acceleration, steering], the same flat ego observation
# (200 steps at 5 Hz); needs the `scenarios` extra, and making it without highway-env raises an ImportError.
if "sb3_mpail/Highway-v0" not in gym.registry:
    gym.register(id="sb3_mpail/Highway-v0", entry_point="sb3_mpail.envs.highway_roads:EgoHighwayEnv")

# highway-env's highway-fast-v0 in traffic (3 lanes, 20 vehicles), continuous [acceleration, steering] at 5 Hz, observed
# as the ego's state and the 5 nearest vehicles' (151 steps); needs the `scenarios` extra, and making it without
# highway-env raises an ImportError. The Dense variant drives in highway-v0's traffic (4 lanes, 50 vehicles, 200 steps).
if "sb3_mpail/HighwayTraffic-v0" not in gym.registry:
    gym.register(id="sb3_mpail/HighwayTraffic-v0", entry_point="sb3_mpail.envs.highway_traffic:EgoTrafficEnv")
if "sb3_mpail/HighwayTrafficDense-v0" not in gym.registry:
    gym.register(
        id="sb3_mpail/HighwayTrafficDense-v0",
        entry_point="sb3_mpail.envs.highway_traffic:EgoTrafficEnv",
        kwargs={"base": "highway"},
    )
