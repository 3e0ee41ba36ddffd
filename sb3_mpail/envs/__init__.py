"""Environments for the MPAIL experiments, registered with gymnasium on import."""

import gymnasium as gym

from sb3_mpail.envs.navigation import NavigationEnv

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
        entry_point="sb3_mpail.envs.navigation:NavigationEnv",
        max_episode_steps=240,
    )

# highway-env's parking-v0 with a flat observation (ego state + goal); needs the `scenarios` extra, and making it
# without highway-env raises an ImportError saying what to install.
if "sb3_mpail/Parking-v0" not in gym.registry:
    gym.register(id="sb3_mpail/Parking-v0", entry_point="sb3_mpail.envs.highway:FlatParkingEnv")
