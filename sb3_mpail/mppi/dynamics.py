"""
Dynamics models ``f(states, actions) -> next_states`` used by the planner to roll out sampled action sequences.

Every model takes 2-D batches: ``states`` of shape ``(batch, state_dim)`` and ``actions`` of shape
``(batch, action_dim)``, in the environment's own observation and action units.

A model may list in ``held_state_dims`` the state dimensions it never changes (a goal, a car's height on flat
ground). The planner's CPU kernel then leaves them out of the discriminator's and the value's products for the
whole horizon and adds their part once per env, a fifth less work for the 12-D car state. The model must keep them
exactly: a dimension listed there that moves is costed at its initial value.

A model may declare in ``state_dim`` and ``action_dim`` the sizes it is written for; :func:`make_dynamics` then refuses
an environment whose observation or action has another size, which the model would otherwise read wrongly or in part.
"""

import math
from functools import cached_property
from typing import Any, Callable, Dict, Sequence, Tuple, Union

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import create_mlp
from torch import nn

from sb3_mpail.checks import (
    DECAY_FACTOR,
    FINITE_NUMBER,
    HIDDEN_SIZES,
    NON_NEGATIVE_NUMBER,
    POSITIVE_INTEGER,
    POSITIVE_NUMBER,
    check_arguments,
    check_signature,
)

DynamicsFunction = Callable[[th.Tensor, th.Tensor], th.Tensor]


def feature_major_states(initial_states: th.Tensor, actions: th.Tensor) -> Tuple[th.Tensor, th.Tensor]:
    """
    Storage for a batched roll-out: ``states`` of shape ``(horizon + 1, n_envs, n_samples, state_dim)`` backed by
    ``columns`` of shape ``(state_dim, horizon + 1, n_envs, n_samples)``, so each state dimension is one contiguous
    block a model writes with plain vector ops, and matrix products read ``states`` as a transposed matrix without a
    copy. ``states[0]`` is filled with the initial states.

    :param initial_states: ``(n_envs, state_dim)``
    :param actions: time-major sequences, ``(horizon, n_envs, n_samples, action_dim)``
    :return: ``states`` and ``columns``, two views of the same memory
    """
    horizon, n_envs, n_samples, _ = actions.shape
    columns = actions.new_empty(initial_states.shape[-1], horizon + 1, n_envs, n_samples)
    columns[:, 0] = initial_states.t().unsqueeze(-1)
    return columns.permute(1, 2, 3, 0), columns


def hold_(columns: th.Tensor, dims: slice) -> None:
    """Holds state dimensions ``dims`` of feature-major ``columns`` at their initial values over the whole horizon."""
    # copied from s_0's contiguous rows: broadcasting each env's single value over the samples is several times slower
    columns[dims, 1:] = columns[dims, :1]


def running_sum_(values: th.Tensor, dim: int) -> th.Tensor:
    """
    Cumulative sum along ``dim`` in place, as one vector addition per step in the step-by-step model's order (torch's
    CPU ``cumsum`` over a dimension that is not the last is several times slower).
    """
    steps = values.unbind(dim)
    for previous, current in zip(steps, steps[1:]):
        current.add_(previous)
    return values


class KinematicBicycle(nn.Module):
    """
    Kinematic bicycle for the 12-D car state ``[x, y, z, roll, pitch, yaw, vx, vy, vz, wx, wy, wz]``
    (world-frame pose, body-frame velocities) with normalised actions ``[speed, steering]`` in ``[-1, 1]``:
    ``v = max_speed * a0``, ``delta = max_steer * a1``, ``yaw_rate = v tan(delta) / wheelbase``, one Euler step.
    It has no actuator lag and no tyre slip; z, roll, pitch and the other velocities are held.

    :param wheelbase: distance between the axles in metres
    :param max_speed: speed in m/s for a normalised speed action of 1
    :param max_steer: steering angle in radians for a normalised steering action of 1
    :param dt: time step in seconds
    """

    held_state_dims = (2, 3, 4, 8, 9, 10)  # z, roll, pitch, vz, wx, wy
    state_dim = 12
    action_dim = 2

    def __init__(self, wheelbase: float = 0.325, max_speed: float = 3.0, max_steer: float = 0.488, dt: float = 0.1):
        super().__init__()
        self.wheelbase = wheelbase
        self.max_speed = max_speed
        self.max_steer = max_steer
        self.dt = dt

    def forward(self, states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        speed = self.max_speed * actions[:, 0]
        yaw_rate = speed * th.tan(self.max_steer * actions[:, 1]) / self.wheelbase
        yaw = states[:, 5]
        next_states = states.clone()
        next_states[:, 0] = states[:, 0] + speed * th.cos(yaw) * self.dt
        next_states[:, 1] = states[:, 1] + speed * th.sin(yaw) * self.dt
        # wrapped like the simulator's yaw so predicted and observed transitions live in the same space
        next_states[:, 5] = th.remainder(yaw + yaw_rate * self.dt + math.pi, 2 * math.pi) - math.pi
        next_states[:, 6] = speed
        next_states[:, 7] = 0.0
        next_states[:, 11] = yaw_rate
        return next_states

    def rollout(self, initial_states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """
        All ``H`` steps at once in closed form, with cumulative sums over time (as the authors' planner does):
        the states of ``H`` calls of :meth:`forward` up to float rounding.

        :param initial_states: current state per env, ``(n_envs, 12)``
        :param actions: time-major sequences, ``(horizon, n_envs, n_samples, 2)``
        :return: states ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, 12)``, stored feature-major (see
            :func:`feature_major_states`)
        """
        horizon = actions.shape[0]
        states, columns = feature_major_states(initial_states, actions)
        hold_(columns, slice(2, 5))
        hold_(columns, slice(8, 11))
        speed = th.mul(actions[..., 0], self.max_speed, out=columns[6, 1:])
        yaw_rate = th.mul(th.tan(actions[..., 1] * self.max_steer), speed, out=columns[11, 1:]).div_(self.wheelbase)
        columns[7, 1:] = 0.0
        # yaw_t = wrap(yaw_0 + sum_{i < t} yaw_rate_i dt), summed in the order of the step-by-step model
        yaw = columns[5]
        th.mul(yaw_rate, self.dt, out=yaw[1:])
        running_sum_(yaw, dim=0)
        yaw[1:].add_(math.pi).remainder_(2 * math.pi).sub_(math.pi)
        # x_t = x_0 + sum_{i < t} speed_i cos(yaw_i) dt, likewise y
        heading = yaw[:horizon]
        th.mul(th.cos(heading), speed, out=columns[0, 1:]).mul_(self.dt)
        th.mul(th.sin(heading), speed, out=columns[1, 1:]).mul_(self.dt)
        running_sum_(columns[:2], dim=1)
        return states


class PendulumDynamics(nn.Module):
    """
    The exact dynamics of gymnasium's ``Pendulum-v1`` on its observation ``[cos(theta), sin(theta), theta_dot]``.

    :param gravity: ``g`` of the environment (gymnasium's default is 10; chosen automatically for ``Pendulum-v1``, the
        model takes the env's own ``g``)
    :raises ValueError: ``gravity`` is not a finite number
    """

    state_dim = 3
    action_dim = 1
    max_speed = 8.0
    max_torque = 2.0
    dt = 0.05
    mass = 1.0
    length = 1.0

    def __init__(self, gravity: float = 10.0):
        super().__init__()
        check_arguments(gravity=(gravity, FINITE_NUMBER))
        self.gravity = gravity

    def forward(self, states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        angle = th.atan2(states[:, 1], states[:, 0])
        torque = th.clamp(actions[:, 0], -self.max_torque, self.max_torque)
        acceleration = 3 * self.gravity / (2 * self.length) * th.sin(angle) + 3.0 / (self.mass * self.length**2) * torque
        angular_velocity = th.clamp(states[:, 2] + acceleration * self.dt, -self.max_speed, self.max_speed)
        angle = angle + angular_velocity * self.dt
        return th.stack((th.cos(angle), th.sin(angle), angular_velocity), dim=1)

    def rollout(self, initial_states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """
        All ``H`` steps, carrying the angle instead of re-deriving it with ``atan2`` each step and with the torque
        term computed for every step at once: the states of ``H`` calls of :meth:`forward` up to float rounding.

        :param initial_states: current state per env, ``(n_envs, 3)``
        :param actions: time-major sequences, ``(horizon, n_envs, n_samples, 1)``
        :return: states ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, 3)``
        """
        horizon = actions.shape[0]
        states, columns = feature_major_states(initial_states, actions)
        torque_term = th.clamp(actions[..., 0], -self.max_torque, self.max_torque).mul_(3.0 / (self.mass * self.length**2))
        gravity_factor = 3 * self.gravity / (2 * self.length)
        angles = th.empty_like(columns[0])
        velocities = columns[2]
        angles[0] = th.atan2(initial_states[:, 1], initial_states[:, 0]).unsqueeze(1)
        for step in range(horizon):
            acceleration = th.sin(angles[step]).mul_(gravity_factor).add_(torque_term[step])
            velocity = th.add(velocities[step], acceleration, alpha=self.dt, out=velocities[step + 1])
            velocity.clamp_(-self.max_speed, self.max_speed)
            th.add(angles[step], velocity, alpha=self.dt, out=angles[step + 1])
        th.cos(angles[1:], out=columns[0, 1:])
        th.sin(angles[1:], out=columns[1, 1:])
        return states


class ParkingKinematics(nn.Module):
    """
    highway-env 1.9.1's ego vehicle on ``sb3_mpail/Parking-v0``'s observation: the car's
    ``[x/100, y/100, vx/5, vy/5, cos h, sin h]`` followed by the goal's six features, which are held. The car is
    highway-env's kinematic bicycle, with slip angle ``beta = arctan(tan(delta) / 2)``:
    ``x' = v cos(h + beta)``, ``y' = v sin(h + beta)``, ``h' = v sin(beta) / (length / 2)``, ``v' = a``, integrated
    with ``substeps`` Euler steps of ``dt`` during which the action is held (15 Hz simulation, 5 Hz policy). Actions
    in ``[-1, 1]`` (clipped) map to ``a = max_acceleration * a0`` and ``delta = max_steering * a1``; beyond
    ``+-max_speed`` the acceleration is limited as highway-env does. The signed speed is decoded from the
    observation as ``v = velocity_scale * (vx cos h + vy sin h)``. Collisions (which end parking-v0's episodes) are
    not modelled.

    :param length: vehicle length in metres
    :param dt: simulation time step in seconds
    :param substeps: simulation steps per action
    :param max_acceleration: acceleration in m/s^2 for a normalised action of 1
    :param max_steering: steering angle in radians for a normalised action of 1
    :param max_speed: speed limit in m/s, in both directions
    :param position_scale: the observation's scale of ``x`` and ``y`` (observed ``x / position_scale``)
    :param velocity_scale: the observation's scale of ``vx`` and ``vy``
    """

    held_state_dims = tuple(range(6, 12))  # the goal
    state_dim = 12
    action_dim = 2

    def __init__(
        self,
        length: float = 5.0,
        dt: float = 1.0 / 15.0,
        substeps: int = 3,
        max_acceleration: float = 5.0,
        max_steering: float = math.pi / 4,
        max_speed: float = 40.0,
        position_scale: float = 100.0,
        velocity_scale: float = 5.0,
    ):
        super().__init__()
        self.length = length
        self.dt = dt
        self.substeps = substeps
        self.max_acceleration = max_acceleration
        self.max_steering = max_steering
        self.max_speed = max_speed
        self.position_scale = position_scale
        self.velocity_scale = velocity_scale

    def signed_speed(self, states: th.Tensor) -> th.Tensor:
        """
        The speed decoded from observations, ``velocity_scale * (vx cos h + vy sin h)``: negative when reversing.

        :param states: observations with their features along dimension 1, any trailing dimensions
        :return: the speeds, ``states`` without dimension 1
        """
        return self.velocity_scale * (states[:, 2] * states[:, 4] + states[:, 3] * states[:, 5])

    def limit_acceleration(self, acceleration: th.Tensor, speed: th.Tensor) -> th.Tensor:
        """
        highway-env's speed limit: beyond ``+-max_speed`` the acceleration is capped to bring the speed back to it.
        highway-env overwrites the held acceleration, so a limit applied in one substep carries to the next.

        :param acceleration: the acceleration held so far in this env step
        :param speed: the signed speed at this substep, same shape
        :return: the acceleration of this substep
        """
        acceleration = th.where(speed > self.max_speed, th.minimum(acceleration, self.max_speed - speed), acceleration)
        return th.where(speed < -self.max_speed, th.maximum(acceleration, -self.max_speed - speed), acceleration)

    def speeds(self, initial_speed: th.Tensor, accelerations: th.Tensor) -> th.Tensor:
        """
        The speed at every simulation step of a roll-out. Unless the speed limit binds, ``v_k = v_0 + dt sum_{j < k}
        a_j``, one cumulative sum; once it binds, each substep depends on the last, and the speeds are integrated one
        substep after another over whole ``(n_envs, n_samples)`` blocks. The limit rarely binds (40 m/s in a 70 m
        parking lot), so eager code checks for it, a host sync (free on a CPU); compiled code always takes the
        substep loop, which has no branch to break the graph.

        :param initial_speed: ``v_0`` per sequence, ``(n_envs, n_samples, 1)``
        :param accelerations: the actions' accelerations, ``(n_envs, n_samples, horizon)``
        :return: ``v_0 .. v_{H * substeps}``, ``(n_envs, n_samples, horizon * substeps + 1)``
        """
        if not th.compiler.is_compiling():
            steps = accelerations.repeat_interleave(self.substeps, dim=-1).mul_(self.dt)
            speeds = th.cat((initial_speed, steps), dim=-1).cumsum(dim=-1)
            if not bool((speeds[..., :-1].abs() > self.max_speed).any()):
                return speeds
        # time-major, each substep written into its own contiguous block (stacking the substeps instead makes the
        # compiler inline the whole recursion into every speed: minutes of compiling)
        speeds = accelerations.new_empty(accelerations.shape[-1] * self.substeps + 1, *accelerations.shape[:-1])
        speeds[0] = initial_speed[..., 0]
        for step, acceleration in enumerate(accelerations.unbind(-1)):
            for substep in range(step * self.substeps, (step + 1) * self.substeps):
                acceleration = self.limit_acceleration(acceleration, speeds[substep])
                th.add(speeds[substep], acceleration, alpha=self.dt, out=speeds[substep + 1])
        return speeds.permute(1, 2, 0)

    def forward(self, states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        actions = actions.clamp(-1.0, 1.0)
        acceleration = self.max_acceleration * actions[:, 0]
        beta = th.atan(0.5 * th.tan(self.max_steering * actions[:, 1]))
        x = states[:, 0] * self.position_scale
        y = states[:, 1] * self.position_scale
        heading = th.atan2(states[:, 5], states[:, 4])
        speed = self.signed_speed(states)
        for _ in range(self.substeps):
            acceleration = self.limit_acceleration(acceleration, speed)
            x = x + speed * th.cos(heading + beta) * self.dt
            y = y + speed * th.sin(heading + beta) * self.dt
            heading = heading + speed * th.sin(beta) / (self.length / 2) * self.dt
            speed = speed + acceleration * self.dt
        cos_heading, sin_heading = th.cos(heading), th.sin(heading)
        next_states = states.clone()
        next_states[:, 0] = x / self.position_scale
        next_states[:, 1] = y / self.position_scale
        next_states[:, 2] = speed * cos_heading / self.velocity_scale
        next_states[:, 3] = speed * sin_heading / self.velocity_scale
        next_states[:, 4] = cos_heading
        next_states[:, 5] = sin_heading
        return next_states

    def rollout(self, initial_states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """
        All ``H`` steps at once: the speeds of the ``H * substeps`` simulation steps (see :meth:`speeds`), then heading
        and position as cumulative sums; the states of ``H`` calls of :meth:`forward` up to float rounding.

        :param initial_states: current state per env, ``(n_envs, 12)``
        :param actions: time-major sequences, ``(horizon, n_envs, n_samples, 2)``
        :return: states ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, 12)``, stored feature-major (see
            :func:`feature_major_states`)
        """
        _, n_envs, n_samples, _ = actions.shape
        states, columns = feature_major_states(initial_states, actions)
        hold_(columns, slice(6, None))  # the goal
        # Time is the last dimension here, (n_envs, n_samples, H * substeps): torch's CPU cumsum is about 10x
        # faster along it than along the first. Simulation step k runs the action of env step k // substeps.
        actions = actions.clamp(-1.0, 1.0).permute(1, 2, 0, 3)
        beta = th.atan(0.5 * th.tan(self.max_steering * actions[..., 1])).repeat_interleave(self.substeps, dim=-1)
        initial = initial_states[:, :, None, None]  # (n_envs, 12, 1, 1): per-env values broadcast over the samples
        start_shape = (n_envs, n_samples, 1)
        speeds = self.speeds(self.signed_speed(initial).expand(start_shape), self.max_acceleration * actions[..., 0])
        driving_speed = speeds[..., :-1]
        # h_k = h_0 + sum_{j < k} v_j sin(beta_j) / (length / 2) dt
        initial_heading = th.atan2(initial[:, 5], initial[:, 4]).expand(start_shape)
        turns = driving_speed * th.sin(beta) * (self.dt / (self.length / 2))
        heading = th.cat((initial_heading, turns), dim=-1).cumsum(dim=-1)
        # x_k = x_0 + sum_{j < k} v_j cos(h_j + beta_j) dt, likewise y
        course = heading[..., :-1] + beta
        x_steps = driving_speed * th.cos(course) * self.dt
        y_steps = driving_speed * th.sin(course) * self.dt
        x = th.cat(((initial[:, 0] * self.position_scale).expand(start_shape), x_steps), dim=-1).cumsum(dim=-1)
        y = th.cat(((initial[:, 1] * self.position_scale).expand(start_shape), y_steps), dim=-1).cumsum(dim=-1)

        def at_env_steps(values: th.Tensor) -> th.Tensor:  # the values after each env step, time-major
            return values[..., self.substeps :: self.substeps].permute(2, 0, 1)

        cos_heading, sin_heading = th.cos(at_env_steps(heading)), th.sin(at_env_steps(heading))
        speed = at_env_steps(speeds)
        columns[0, 1:] = at_env_steps(x) / self.position_scale
        columns[1, 1:] = at_env_steps(y) / self.position_scale
        columns[2, 1:] = speed * cos_heading / self.velocity_scale
        columns[3, 1:] = speed * sin_heading / self.velocity_scale
        columns[4, 1:] = cos_heading
        columns[5, 1:] = sin_heading
        return states


class PointMassDynamics(nn.Module):
    """
    gymnasium-robotics' PointMaze ball on ``sb3_mpail/PointMaze-v0``'s observation ``[x, y, vx, vy, goal_x,
    goal_y]``; the goal is held. The ball is MuJoCo's: a sphere of mass ``mass`` on two slide joints with viscous
    damping, pushed by ``gear * a`` (actions clipped to ``[-1, 1]``), no gravity. Each of the ``substeps`` MuJoCo
    steps (the action is held) first clips the velocity to ``+-max_speed`` as PointMaze does, then integrates with
    MuJoCo's Euler scheme, implicit in the damping: ``v' = (v + dt gear a / mass) / (1 + dt damping / mass)``,
    ``p' = p + dt v'``. The walls are not modelled: off the walls its one-step error is below 1e-7 (in float64;
    ``python -m benchmarks.maze_model_error``), on them up to the whole step.

    :param mass: the ball's mass in kg (a sphere of radius 0.1 m and density 1000 kg/m^3)
    :param damping: joint damping in N s/m
    :param gear: force in N for an action of 1
    :param dt: MuJoCo time step in seconds
    :param substeps: MuJoCo steps per action
    :param max_speed: speed limit per axis in m/s, applied before each MuJoCo step
    """

    held_state_dims = (4, 5)  # the goal
    state_dim = 6
    action_dim = 2

    def __init__(
        self,
        mass: float = 4000 * math.pi / 3 * 0.1**3,
        damping: float = 1.0,
        gear: float = 100.0,
        dt: float = 0.01,
        substeps: int = 5,
        max_speed: float = 5.0,
    ):
        super().__init__()
        self.mass = mass
        self.damping = damping
        self.gear = gear
        self.dt = dt
        self.substeps = substeps
        self.max_speed = max_speed

    def forward(self, states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        velocity_kick = actions.clamp(-1.0, 1.0) * (self.dt * self.gear / self.mass)
        damping_factor = 1.0 / (1.0 + self.dt * self.damping / self.mass)
        positions, velocities = states[:, :2], states[:, 2:4]
        for _ in range(self.substeps):
            velocities = (velocities.clamp(-self.max_speed, self.max_speed) + velocity_kick) * damping_factor
            positions = positions + self.dt * velocities
        return th.cat((positions, velocities, states[:, 4:]), dim=1)


def check_next_states(model: str, states: th.Tensor, actions: th.Tensor, next_states: Any) -> None:
    """
    Refuses next states that are not a tensor of the states' shape (a type and shape check: no host sync).

    :param model: the dynamics model, as the message names it
    :param states: the states it was given
    :param actions: the actions it was given
    :param next_states: what it returned
    :raises TypeError: it returned something other than a torch tensor
    :raises ValueError: it returned a tensor of another shape
    """
    if not isinstance(next_states, th.Tensor):
        raise TypeError(
            f"{model} must return next states as a torch tensor; for states {tuple(states.shape)} and actions "
            f"{tuple(actions.shape)} it returned a {type(next_states).__module__}.{type(next_states).__name__}."
        )
    if next_states.shape != states.shape:
        raise ValueError(
            f"{model} maps states of shape {tuple(states.shape)} (with actions {tuple(actions.shape)}) to "
            f"{tuple(next_states.shape)}; it must return next states of the states' shape {tuple(states.shape)}."
        )


class CallableDynamics(nn.Module):
    """
    Wraps a user's plain function ``f(states, actions) -> next_states`` (torch tensors in, tensor out), refusing on
    every call what is not a tensor of the states' shape: a function may be right for one batch size only.

    :param function: the dynamics function; it must be picklable (cloudpickle) for ``save``/``load``
    """

    def __init__(self, function: DynamicsFunction):
        super().__init__()
        self.function = function

    @cached_property  # built once, not on every call of the planner's hot path
    def name(self) -> str:
        """The function as error messages name it."""
        return f"The dynamics function {getattr(self.function, '__qualname__', repr(self.function))}"

    def forward(self, states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        next_states = self.function(states, actions)
        check_next_states(self.name, states, actions, next_states)
        return next_states


class TransitionReplayBuffer:
    """
    Fixed-capacity store of ``(s, a, s')`` from several episodes for fitting a dynamics model. Once full, new
    transitions replace old ones at random positions (paper App. "Predictive Model Learning"), so the buffer keeps
    a mix of recent and older behaviour instead of only the newest window.

    :param capacity: maximum number of transitions kept
    :param state_dim: size of a state
    :param action_dim: size of an action
    :param seed: seed of the replacement positions
    """

    def __init__(self, capacity: int, state_dim: int, action_dim: int, seed: int | None = None):
        self.capacity = capacity
        self.states = np.zeros((capacity, state_dim), dtype=np.float32)
        self.actions = np.zeros((capacity, action_dim), dtype=np.float32)
        self.next_states = np.zeros((capacity, state_dim), dtype=np.float32)
        self.size = 0
        self.rng = np.random.default_rng(seed)

    def add(self, states: np.ndarray, actions: np.ndarray, next_states: np.ndarray) -> None:
        n_old = self.size
        n_appended = min(len(states), self.capacity - self.size)
        self._write(
            np.arange(self.size, self.size + n_appended), states[:n_appended], actions[:n_appended], next_states[:n_appended]
        )
        self.size += n_appended
        # only transitions stored before this call are candidates, so the newest batch is kept whole
        n_replacing = min(len(states) - n_appended, n_old)
        if n_replacing > 0:
            positions = self.rng.choice(n_old, size=n_replacing, replace=False)
            self._write(positions, states[-n_replacing:], actions[-n_replacing:], next_states[-n_replacing:])

    def _write(self, positions: np.ndarray, states: np.ndarray, actions: np.ndarray, next_states: np.ndarray) -> None:
        self.states[positions] = states
        self.actions[positions] = actions
        self.next_states[positions] = next_states


class LearnedDynamics(nn.Module):
    """
    Deterministic MLP model ``f_psi(s, a) -> s'`` learned online from the agent's own transitions (MPAIL-OM):
    it predicts the normalised state change, trained with MSE and Adam, with a step learning-rate decay
    (``lr * lr_decay ** (epochs // lr_decay_every)``, floored at ``min_learning_rate``) and a replay buffer.

    :param state_dim: size of a state
    :param action_dim: size of an action
    :param hidden_sizes: hidden layer widths (paper: 3 x 64 for cartpole, 3 x 256 for Ant)
    :param learning_rate: initial Adam learning rate, ``> 0``
    :param lr_decay: multiplicative decay of the learning rate, in ``(0, 1]``
    :param lr_decay_every: number of epochs between decays
    :param min_learning_rate: learning-rate floor
    :param buffer_size: replay buffer capacity in transitions
    :param batch_size: minibatch size
    :param n_epochs: passes over the buffer per call of :meth:`fit`
    :param seed: seed of the buffer's replacement and minibatch order
    :raises ValueError: a setting is out of its range (each is named)
    """

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        hidden_sizes: Sequence[int] = (64, 64, 64),
        learning_rate: float = 1e-3,
        lr_decay: float = 0.9,
        lr_decay_every: int = 15,
        min_learning_rate: float = 1e-6,
        buffer_size: int = 100_000,
        batch_size: int = 256,
        n_epochs: int = 5,
        seed: int | None = None,
    ):
        super().__init__()
        check_arguments(
            hidden_sizes=(hidden_sizes, HIDDEN_SIZES),
            buffer_size=(buffer_size, POSITIVE_INTEGER),
            batch_size=(batch_size, POSITIVE_INTEGER),
            n_epochs=(n_epochs, POSITIVE_INTEGER),
            lr_decay_every=(lr_decay_every, POSITIVE_INTEGER),
            learning_rate=(learning_rate, POSITIVE_NUMBER),
            lr_decay=(lr_decay, DECAY_FACTOR),
            min_learning_rate=(min_learning_rate, NON_NEGATIVE_NUMBER),
        )
        self.state_dim = state_dim
        self.action_dim = action_dim
        self.net = nn.Sequential(*create_mlp(state_dim + action_dim, state_dim, list(hidden_sizes), nn.ReLU))
        self.register_buffer("input_mean", th.zeros(state_dim + action_dim))
        self.register_buffer("input_std", th.ones(state_dim + action_dim))
        self.register_buffer("delta_mean", th.zeros(state_dim))
        self.register_buffer("delta_std", th.ones(state_dim))
        self.register_buffer("epochs_trained", th.zeros((), dtype=th.long))
        self.learning_rate = learning_rate
        self.lr_decay = lr_decay
        self.lr_decay_every = lr_decay_every
        self.min_learning_rate = min_learning_rate
        self.batch_size = batch_size
        self.n_epochs = n_epochs
        self.optimizer = th.optim.Adam(self.net.parameters(), lr=learning_rate)
        self.replay_buffer = TransitionReplayBuffer(buffer_size, state_dim, action_dim, seed)
        self.rng = np.random.default_rng(seed)

    def forward(self, states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        inputs = (th.cat((states, actions), dim=1) - self.input_mean) / self.input_std
        return states + self.net(inputs) * self.delta_std + self.delta_mean

    def rollout(self, initial_states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """
        :meth:`forward` over whole sequences (the planner's path without gradients): the input and output
        normalisations are folded into the first and last layers, the first layer is split into its state and action
        parts, and the action part of every step is one matrix product before the roll-out; each step then adds the
        state part in place, and writes the new states into preallocated storage (plain products, which
        ``torch.compile`` traces as one graph).

        :param initial_states: ``(n_envs, state_dim)``
        :param actions: time-major sequences, ``(horizon, n_envs, n_samples, action_dim)``
        :return: states ``s_0 .. s_H``, ``(horizon + 1, n_envs, n_samples, state_dim)``
        """
        horizon, n_envs, n_samples, action_dim = actions.shape
        layers = [(layer.weight, layer.bias) for layer in self.net if isinstance(layer, nn.Linear)]
        weight, bias = layers[0]
        weight = weight / self.input_std
        layers[0] = (weight, bias - weight @ self.input_mean)
        weight, bias = layers[-1]
        layers[-1] = (weight * self.delta_std.unsqueeze(1), bias * self.delta_std + self.delta_mean)
        (first_weight, first_bias), later = layers[0], layers[1:]
        state_weight, action_weight = first_weight[:, : self.state_dim].t(), first_weight[:, self.state_dim :].t()
        first_layers = th.addmm(first_bias, actions.reshape(-1, action_dim), action_weight)  # every step's action part
        first_layers = first_layers.view(horizon, n_envs * n_samples, -1)
        states = actions.new_empty(horizon + 1, n_envs, n_samples, self.state_dim)
        states[0] = initial_states.unsqueeze(1)
        current = states[0].view(n_envs * n_samples, self.state_dim)
        for step in range(horizon):
            hidden = first_layers[step].addmm_(current, state_weight)
            for weight, bias in later:
                hidden = th.addmm(bias, hidden.relu_(), weight.t())
            following = states[step + 1].view(n_envs * n_samples, self.state_dim)
            th.add(current, hidden, out=following)
            current = following
        return states

    def seed(self, seed: int | None) -> None:
        """Re-seeds the replay buffer's replacement positions and the minibatch order."""
        self.replay_buffer.rng = np.random.default_rng(seed)
        self.rng = np.random.default_rng(seed)

    def current_learning_rate(self) -> float:
        decays = int(self.epochs_trained) // self.lr_decay_every
        return max(self.learning_rate * self.lr_decay**decays, self.min_learning_rate)

    def fit(self, states: np.ndarray, actions: np.ndarray, next_states: np.ndarray) -> float:
        """
        Adds transitions to the replay buffer and trains ``n_epochs`` passes over it.

        :return: mean MSE (in normalised units) of the last epoch
        """
        self.replay_buffer.add(states, actions, next_states)
        size = self.replay_buffer.size
        device = self.input_mean.device
        buffer = self.replay_buffer
        inputs = th.as_tensor(np.concatenate((buffer.states[:size], buffer.actions[:size]), axis=1), device=device)
        deltas = th.as_tensor(buffer.next_states[:size] - buffer.states[:size], device=device)
        # normalisation follows the data the model has seen; a tiny floor keeps constant dimensions finite
        self.input_mean.copy_(inputs.mean(0))
        self.input_std.copy_(inputs.std(0, unbiased=False).clamp_min(1e-6))
        self.delta_mean.copy_(deltas.mean(0))
        self.delta_std.copy_(deltas.std(0, unbiased=False).clamp_min(1e-6))
        normalized_inputs = (inputs - self.input_mean) / self.input_std
        normalized_deltas = (deltas - self.delta_mean) / self.delta_std
        epoch_losses = []
        for _ in range(self.n_epochs):
            for group in self.optimizer.param_groups:
                group["lr"] = self.current_learning_rate()
            order = th.as_tensor(self.rng.permutation(size), device=device)
            epoch_losses = []
            for start in range(0, size, self.batch_size):
                batch = order[start : start + self.batch_size]
                loss = nn.functional.mse_loss(self.net(normalized_inputs[batch]), normalized_deltas[batch])
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
                epoch_losses.append(loss.item())
            self.epochs_trained += 1
        return float(np.mean(epoch_losses))


DYNAMICS_MODELS: Dict[str, type] = {
    "bicycle": KinematicBicycle,
    "pendulum": PendulumDynamics,
    "parking": ParkingKinematics,
    "point_mass": PointMassDynamics,
    "learned": LearnedDynamics,
}

# Environments whose planning model is known, so users need not name one.
DEFAULT_DYNAMICS: Dict[str, str] = {
    "Pendulum-v1": "pendulum",
    "sb3_mpail/Navigation-v0": "bicycle",
    "sb3_mpail/Parking-v0": "parking",
    "sb3_mpail/PointMaze-v0": "point_mass",
    "sb3_mpail/PointMazeMedium-v0": "point_mass",
}
#: per model chosen automatically (:data:`DEFAULT_DYNAMICS`), its keyword arguments read from the env's attributes
#: (keyword: attribute), so that the model plans with the env's own physics (``Pendulum-v1``'s ``g``)
ENV_DYNAMICS_KWARGS: Dict[str, Dict[str, str]] = {"pendulum": {"gravity": "g"}}


def how_to_give_dynamics() -> str:
    """How to give a dynamics model, as the errors for an environment without one say (naming the models known now)."""
    return (
        f"pass policy_kwargs=dict(dynamics=...) with one of {sorted(DYNAMICS_MODELS)}, an nn.Module or a callable "
        "f(states, actions) -> next_states."
    )


DynamicsSpec = Union[str, nn.Module, DynamicsFunction]


def make_dynamics(
    dynamics: DynamicsSpec | None,
    observation_space: spaces.Box,
    action_space: spaces.Box,
    dynamics_kwargs: Dict[str, Any] | None = None,
) -> nn.Module:
    """
    Builds the planner's dynamics model and checks it on a probe batch: sizes it declares must be the environment's,
    and it must map states to new states of the observation's shape, leaving its inputs unchanged.

    :param dynamics: a name from :data:`DYNAMICS_MODELS`, an ``nn.Module`` or a plain callable
        ``f(states, actions) -> next_states``
    :param observation_space: the environment's observation space (the planner's state)
    :param action_space: the environment's action space
    :param dynamics_kwargs: keyword arguments for a named model
    :raises ValueError: no, an unknown or an unfitting model, or one that modifies its inputs in place
    :raises TypeError: ``dynamics`` is of no kind above, cannot be called with ``(states, actions)``, or the model
        returns something other than a tensor
    """
    dynamics_kwargs = dynamics_kwargs or {}
    if dynamics is None:
        raise ValueError(
            f"MPAIL plans through a dynamics model and none was given for this environment: {how_to_give_dynamics()}"
        )
    if isinstance(dynamics, str):
        if dynamics not in DYNAMICS_MODELS:
            raise ValueError(f"Unknown dynamics model {dynamics!r}: choose one of {sorted(DYNAMICS_MODELS)}.")
        if dynamics == "learned":
            dynamics_kwargs = {"state_dim": observation_space.shape[0], "action_dim": action_space.shape[0], **dynamics_kwargs}
        model = DYNAMICS_MODELS[dynamics](**dynamics_kwargs)
    elif callable(dynamics):
        check_signature(dynamics, "dynamics", "f(states, actions) -> next_states", 2)
        model = dynamics if isinstance(dynamics, nn.Module) else CallableDynamics(dynamics)
    else:
        raise TypeError(f"dynamics must be a model name, an nn.Module or a callable, got {type(dynamics).__name__}.")
    name = model.name if isinstance(model, CallableDynamics) else f"The dynamics model {type(model).__name__}"
    if isinstance(dynamics, str):
        name = f"{name} ({dynamics!r})"
    sizes = (getattr(model, "state_dim", None), getattr(model, "action_dim", None))
    env_sizes = (observation_space.shape[0], action_space.shape[0])
    if None not in sizes and sizes != env_sizes:
        raise ValueError(
            f"{name} is written for {sizes[0]}-D states and {sizes[1]}-D actions, but the environment's observations are "
            f"{env_sizes[0]}-D and its actions {env_sizes[1]}-D: choose a model for this environment."
        )
    # random probes, not zeros: a model that adds into or clamps its inputs in place may leave zeros as they were
    generator = th.Generator().manual_seed(0)
    probe_states = th.randn((2, *observation_space.shape), generator=generator)
    probe_actions = th.randn((2, *action_space.shape), generator=generator)
    given_states, given_actions = probe_states.clone(), probe_actions.clone()
    with th.no_grad():
        predicted = model(probe_states, probe_actions)
    check_next_states(name, probe_states, probe_actions, predicted)
    given = {"states": (probe_states, given_states), "actions": (probe_actions, given_actions)}
    changed = [what for what, (probe, copy) in given.items() if not th.equal(probe, copy)]
    if changed:
        raise ValueError(
            f"{name} modified the {' and '.join(changed)} it was given in place; it must leave its inputs unchanged "
            "(the planner reuses them) and return new next states, e.g. starting from states.clone()."
        )
    return model
