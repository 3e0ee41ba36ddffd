"""Cartpole with a continuous force action: gymnasium's ``CartPole-v1`` physics, Euler integration, tau = 0.02 s.

The cart-pole equations, constants, start distribution, termination rule and reward are those of gymnasium's
``CartPole-v1`` (Barto, Sutton and Anderson's cart-pole as written by gymnasium). Only the action differs: a force
``10 N * clip(a, -1, 1)`` for ``a`` in ``Box(-1, 1, (1,))`` instead of the discrete push of +-10 N, so an action of
+1 (-1) gives exactly ``CartPole-v1``'s action 1 (0). The physics runs in float64 Python floats as gymnasium's does
and the observation is its float32 copy, so both envs give identical observations for the same seed and pushes.

:data:`cartpole_dynamics` is the same step written on batched torch tensors, for an MPPI planner with the exact model.
"""

import math
from typing import Any, ClassVar, Dict, Optional, Tuple

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import logger, spaces

GRAVITY = 9.8
MASS_CART = 1.0
MASS_POLE = 0.1
TOTAL_MASS = MASS_CART + MASS_POLE
HALF_LENGTH = 0.5  # gymnasium's ``length``: half the pole's length
POLE_MASS_LENGTH = MASS_POLE * HALF_LENGTH
FORCE_MAG = 10.0  # N for an action of +-1
TAU = 0.02  # s per step
THETA_THRESHOLD = 12 * 2 * math.pi / 360  # rad (12 degrees)
X_THRESHOLD = 2.4  # m
MAX_EPISODE_STEPS = 200


class ContinuousCartPoleEnv(gym.Env):
    """
    Balance a pole on a cart by pushing the cart with a continuous force.

    Observation (float32): ``[x, x_dot, theta, theta_dot]`` (m, m/s, rad, rad/s), bounds as ``CartPole-v1``'s.
    Action: ``Box(-1, 1, (1,))``, the force ``10 * clip(a, -1, 1)`` N on the cart (positive pushes right).
    Reward: +1 per step, the terminating step included (0 for steps taken after it, as ``CartPole-v1``).
    Termination: ``|x| > 2.4`` or ``|theta| > 12`` degrees.
    Start: every state variable uniform in ``[-0.05, 0.05]``. The environment itself has no time limit;
    ``sb3_mpail/ContinuousCartPole-v0`` truncates after :data:`MAX_EPISODE_STEPS` (200) steps.

    :param render_mode: ``None`` or ``"rgb_array"`` (a plain numpy drawing of the cart and pole, 400 x 600 pixels)
    """

    metadata: ClassVar[Dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, render_mode: Optional[str] = None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"Unsupported render_mode {render_mode!r}; choose one of {self.metadata['render_modes']}.")
        self.render_mode = render_mode
        high = np.array(
            [X_THRESHOLD * 2, np.finfo(np.float32).max, THETA_THRESHOLD * 2, np.finfo(np.float32).max], dtype=np.float32
        )
        self.observation_space = spaces.Box(-high, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.state: Optional[Tuple[float, float, float, float]] = None
        self._steps_beyond_terminated: Optional[int] = None

    def reset(self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None):
        super().reset(seed=seed)
        self.state = tuple(float(value) for value in self.np_random.uniform(low=-0.05, high=0.05, size=(4,)))
        self._steps_beyond_terminated = None
        return np.array(self.state, dtype=np.float32), {}

    def step(self, action):
        if self.state is None:
            raise RuntimeError("Call reset() before step().")
        force = FORCE_MAG * min(max(float(np.asarray(action, dtype=np.float64).reshape(-1)[0]), -1.0), 1.0)
        x, x_dot, theta, theta_dot = self.state
        cos_theta, sin_theta = math.cos(theta), math.sin(theta)
        temp = (force + POLE_MASS_LENGTH * theta_dot**2 * sin_theta) / TOTAL_MASS
        theta_acc = (GRAVITY * sin_theta - cos_theta * temp) / (
            HALF_LENGTH * (4.0 / 3.0 - MASS_POLE * cos_theta**2 / TOTAL_MASS)
        )
        x_acc = temp - POLE_MASS_LENGTH * theta_acc * cos_theta / TOTAL_MASS
        x = x + TAU * x_dot
        x_dot = x_dot + TAU * x_acc
        theta = theta + TAU * theta_dot
        theta_dot = theta_dot + TAU * theta_acc
        self.state = (x, x_dot, theta, theta_dot)
        terminated = bool(x < -X_THRESHOLD or x > X_THRESHOLD or theta < -THETA_THRESHOLD or theta > THETA_THRESHOLD)
        reward = 1.0
        if terminated:
            # as CartPole-v1: the terminating step earns 1, steps taken after it earn 0 (with a warning)
            if self._steps_beyond_terminated is None:
                self._steps_beyond_terminated = 0
            else:
                if self._steps_beyond_terminated == 0:
                    logger.warn("Stepping a terminated ContinuousCartPoleEnv; call reset() first. Rewards are 0 now.")
                self._steps_beyond_terminated += 1
                reward = 0.0
        return np.array(self.state, dtype=np.float32), reward, terminated, False, {}

    def render(self) -> Optional[np.ndarray]:
        """An ``(400, 600, 3)`` uint8 picture of the cart (black), the pole (brown) and the track, or ``None``."""
        if self.render_mode != "rgb_array":
            return None
        height, width = 400, 600
        image = np.full((height, width, 3), 255, dtype=np.uint8)
        scale = width / (2 * X_THRESHOLD)
        track_y = 300
        image[track_y, :] = 0
        if self.state is None:
            return image
        x, _, theta, _ = self.state
        cart_x = int(round(width / 2 + x * scale))
        image[track_y - 15 : track_y + 15, max(cart_x - 25, 0) : max(min(cart_x + 25, width), 0)] = 0
        pole_length = 2 * HALF_LENGTH * scale
        for fraction in np.linspace(0.0, 1.0, 200):
            column = int(round(cart_x + fraction * pole_length * math.sin(theta)))
            row = int(round(track_y - 10 - fraction * pole_length * math.cos(theta)))
            image[max(row - 4, 0) : max(row + 5, 0), max(column - 4, 0) : max(column + 5, 0)] = (202, 152, 101)
        return image


def cartpole_dynamics(states: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """
    The env's step on batches (no termination): ``(batch, 4)`` states and ``(batch, 1)`` actions in ``[-1, 1]``.
    A plain function, so it can be given to MPAIL as ``policy_kwargs=dict(dynamics=cartpole_dynamics)``.
    """
    x, x_dot, theta, theta_dot = states.unbind(-1)
    force = FORCE_MAG * th.clamp(actions[..., 0], -1.0, 1.0)
    cos_theta, sin_theta = th.cos(theta), th.sin(theta)
    temp = (force + POLE_MASS_LENGTH * theta_dot.square() * sin_theta) / TOTAL_MASS
    theta_acc = (GRAVITY * sin_theta - cos_theta * temp) / (
        HALF_LENGTH * (4.0 / 3.0 - MASS_POLE * cos_theta.square() / TOTAL_MASS)
    )
    x_acc = temp - POLE_MASS_LENGTH * theta_acc * cos_theta / TOTAL_MASS
    return th.stack((x + TAU * x_dot, x_dot + TAU * x_acc, theta + TAU * theta_dot, theta_dot + TAU * theta_acc), dim=-1)
