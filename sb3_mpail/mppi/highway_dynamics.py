"""
Planning models of the highway-env road scenarios (:mod:`sb3_mpail.envs.highway_roads`) and of the highway in traffic
(:mod:`sb3_mpail.envs.highway_traffic`), registered by name in
:data:`~sb3_mpail.mppi.dynamics.DYNAMICS_MODELS` and as their environments' defaults.
"""

from typing import Any

import torch as th

from sb3_mpail.envs.highway_traffic import TRAFFIC_STATE_DIM, vehicle_dims
from sb3_mpail.mppi.dynamics import DEFAULT_DYNAMICS, DYNAMICS_MODELS, ENV_DYNAMICS_KWARGS, ParkingKinematics

RACETRACK_ID = "sb3_mpail/Racetrack-v0"
HIGHWAY_ID = "sb3_mpail/Highway-v0"
TRAFFIC_IDS = ("sb3_mpail/HighwayTraffic-v0", "sb3_mpail/HighwayTrafficDense-v0")


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


class HighwayTrafficKinematics(HighwayKinematics):
    """
    ``sb3_mpail/HighwayTraffic-v0``'s observation: the ego car's ``[x/10, y/10, vx/10, vy/10, cos h, sin h]``, then
    :data:`~sb3_mpail.envs.highway_traffic.TRAFFIC_VEHICLES` other vehicles' ``[presence, x/10, y/10, vx/10,
    vy/10]``. The ego is :class:`HighwayKinematics`'s kinematic bicycle; every other vehicle drives at constant
    velocity in its lane over an env step (``x += vx * substeps * dt``, ``y`` held, as are its velocity and presence),
    the usual prior for traffic whose intentions the model cannot know. Absent vehicles are zeros and stay so. Over one
    step of highway-fast's single Euler step the prior is exact, up to its small steering, for a vehicle that keeps its
    lane whatever its acceleration; it misses lane changes, and over several steps the IDM vehicles' braking and
    accelerating. Any leading batch shape is accepted.

    The defaults are ``highway-fast-v0``'s 5 Hz simulation with one simulation step per 5 Hz action; an env chosen by
    id gives its own (``sb3_mpail/HighwayTrafficDense-v0``: highway-v0's 15 Hz, 3 substeps), read from its
    ``simulation_dt`` and ``substeps``.

    :param dt: simulation time step in seconds
    :param substeps: simulation steps per action
    :param kwargs: the other parameters of :class:`HighwayKinematics`
    """

    state_dim = TRAFFIC_STATE_DIM
    # each vehicle's presence, y, vx and vy: only its x moves
    held_state_dims = tuple(sorted(sum((vehicle_dims(name) for name in ("presence", "y", "vx", "vy")), [])))
    x_dims, vx_dims = vehicle_dims("x"), vehicle_dims("vx")

    def __init__(self, dt: float = 0.2, substeps: int = 1, **kwargs: Any):
        super().__init__(dt=dt, substeps=substeps, **kwargs)
        # observed x moves by observed vx times this per env step
        self.x_per_vx = self.velocity_scale / self.position_scale * self.dt * self.substeps

    def forward(self, states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        flat_states = states.reshape(-1, states.shape[-1])
        next_states = super().forward(flat_states, actions.reshape(-1, actions.shape[-1]))
        next_states[:, self.x_dims] = flat_states[:, self.x_dims] + self.x_per_vx * flat_states[:, self.vx_dims]
        return next_states.reshape(states.shape)

    def rollout(self, initial_states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """
        :meth:`~sb3_mpail.mppi.dynamics.ParkingKinematics.rollout` for the ego, which holds the other vehicles'
        features, then their positions ``x_k = x_0 + k * vx * substeps * dt``: the states of ``H`` calls of
        :meth:`forward` up to float rounding.

        :param initial_states: current state per env, ``(n_envs, 31)``
        :param actions: time-major sequences, ``(horizon, n_envs, n_samples, 2)``
        :return: states ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, 31)``, stored feature-major (see
            :func:`~sb3_mpail.mppi.dynamics.feature_major_states`)
        """
        states = super().rollout(initial_states, actions)
        columns = states.permute(3, 0, 1, 2)  # the feature-major storage, (31, horizon + 1, n_envs, n_samples)
        steps = th.arange(1, actions.shape[0] + 1, dtype=states.dtype, device=states.device).unsqueeze(-1)
        for x_dim, vx_dim in zip(self.x_dims, self.vx_dims):  # a few vehicles, each a whole-horizon block
            x = initial_states[:, x_dim] + steps * (self.x_per_vx * initial_states[:, vx_dim])  # (horizon, n_envs)
            columns[x_dim, 1:] = x.unsqueeze(-1)
        return states


# Named so zoo configs can say dynamics="racetrack", and their envs' defaults so they need not.
DYNAMICS_MODELS["racetrack"] = RacetrackKinematics
DYNAMICS_MODELS["highway"] = HighwayKinematics
DYNAMICS_MODELS["highway_traffic"] = HighwayTrafficKinematics
DEFAULT_DYNAMICS[RACETRACK_ID] = "racetrack"
DEFAULT_DYNAMICS[HIGHWAY_ID] = "highway"
for traffic_id in TRAFFIC_IDS:
    DEFAULT_DYNAMICS[traffic_id] = "highway_traffic"
# the traffic envs' simulation step and substeps, which differ between their highway-env bases
ENV_DYNAMICS_KWARGS["highway_traffic"] = {"dt": "simulation_dt", "substeps": "substeps"}
