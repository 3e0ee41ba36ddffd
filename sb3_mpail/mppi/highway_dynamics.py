"""
Planning models of the highway-env road scenarios (:mod:`sb3_mpail.envs.highway_roads`), registered by name in
:data:`~sb3_mpail.mppi.dynamics.DYNAMICS_MODELS` and as their environments' defaults.
"""

from typing import Any

import torch as th

from sb3_mpail.mppi.dynamics import DEFAULT_DYNAMICS, DYNAMICS_MODELS, ParkingKinematics

RACETRACK_ID = "sb3_mpail/Racetrack-v0"
HIGHWAY_ID = "sb3_mpail/Highway-v0"


def with_zero_acceleration(steering: th.Tensor) -> th.Tensor:
    """``[steering]`` actions (any leading shape) as ``[acceleration, steering]`` with no acceleration."""
    return th.cat((th.zeros_like(steering[..., :1]), steering), dim=-1)


class HighwayKinematics(ParkingKinematics):
    """
    highway-env 1.9.1's ego car on ``sb3_mpail/Highway-v0``'s observation ``[x/10, y/10, vx/10, vy/10, cos h, sin h]``
    with ``[acceleration, steering]`` actions: :class:`~sb3_mpail.mppi.dynamics.ParkingKinematics`'s kinematic
    bicycle (15 Hz Euler steps, 3 per action: the env runs at 5 Hz like parking) in the road scenarios' units.

    :param position_scale: the observation's scale of ``x`` and ``y``
    :param velocity_scale: the observation's scale of ``vx`` and ``vy``
    :param kwargs: the other parameters of :class:`~sb3_mpail.mppi.dynamics.ParkingKinematics`
    """

    held_state_dims = ()  # the road scenarios' observations have no goal
    state_dim = 6

    def __init__(self, position_scale: float = 10.0, velocity_scale: float = 10.0, **kwargs: Any):
        super().__init__(position_scale=position_scale, velocity_scale=velocity_scale, **kwargs)


class RacetrackKinematics(HighwayKinematics):
    """
    highway-env 1.9.1's ego car on ``sb3_mpail/Racetrack-v0``'s observation ``[x/10, y/10, vx/10, vy/10, cos h,
    sin h]``, with racetrack's steering-only action ``[steering]`` in ``[-1, 1]``: :class:`HighwayKinematics` (15 Hz
    Euler steps, 3 per action) with the acceleration that highway-env applies when only steering is controlled, zero,
    so the speed is held. Takes :class:`HighwayKinematics`'s parameters.
    """

    action_dim = 1

    def forward(self, states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        return super().forward(states, with_zero_acceleration(actions))

    def rollout(self, initial_states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """
        :meth:`~sb3_mpail.mppi.dynamics.ParkingKinematics.rollout` with no acceleration.

        :param initial_states: current state per env, ``(n_envs, 6)``
        :param actions: time-major steering sequences, ``(horizon, n_envs, n_samples, 1)``
        :return: states ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, 6)``
        """
        return super().rollout(initial_states, with_zero_acceleration(actions))


# Named so zoo configs can say dynamics="racetrack", and their envs' defaults so they need not.
DYNAMICS_MODELS["racetrack"] = RacetrackKinematics
DYNAMICS_MODELS["highway"] = HighwayKinematics
DEFAULT_DYNAMICS[RACETRACK_ID] = "racetrack"
DEFAULT_DYNAMICS[HIGHWAY_ID] = "highway"
