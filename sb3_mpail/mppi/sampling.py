"""Action-sequence samplers for MPPI: perturb the warm-started plan into ``N`` candidate sequences."""

import math
from typing import Optional, Tuple, Union

import numpy as np
import torch as th
from torch import nn

from sb3_mpail.mppi.native import standard_normal


class GaussianSampler(nn.Module):
    """
    Samples action sequences ``a_k ~ N(plan, Sigma)`` independently per env, sample, step and action dimension,
    then clamps them to the action bounds (paper Alg. 2, line "sample action").

    ``noise_std`` is given relative to the action half-range, so ``0.3`` means 30% of ``(high - low) / 2`` in
    every dimension: the paper's ``Sigma = diag(0.3, ...)`` for actions normalised to ``[-1, 1]``.

    :param action_low: lower action bounds, shape ``(action_dim,)``
    :param action_high: upper action bounds, shape ``(action_dim,)``
    :param noise_std: sampling standard deviation relative to the action half-range (scalar or per dimension)
    """

    def __init__(self, action_low: np.ndarray, action_high: np.ndarray, noise_std: Union[float, np.ndarray] = 0.3):
        super().__init__()
        low = th.as_tensor(np.asarray(action_low, dtype=np.float32))
        high = th.as_tensor(np.asarray(action_high, dtype=np.float32))
        self.register_buffer("action_low", low)
        self.register_buffer("action_high", high)
        self.register_buffer("noise_std", th.as_tensor(noise_std, dtype=th.float32) * (high - low) / 2)
        # plain numbers when every action dimension shares them: scalar operands are the fastest
        self._uniform_std = _common_value(self.noise_std)
        self._uniform_bounds = (_common_value(low), _common_value(high))

    def forward(self, plan: th.Tensor, n_samples: int, generator: th.Generator) -> th.Tensor:
        """
        :param plan: sampling mean per env, shape ``(n_envs, horizon, action_dim)``
        :param n_samples: number of sequences ``N`` per env
        :param generator: source of the noise, so a seed fixes the samples
        :return: clamped action sequences, time-major, shape ``(horizon, n_envs, n_samples, action_dim)``
        """
        n_envs, horizon, action_dim = plan.shape
        # one draw for all envs x samples x steps, independent per env: torch.randn's numbers, drawn faster on the CPU
        noise = standard_normal((horizon, n_envs, n_samples, action_dim), generator, plan.device, plan.dtype)
        # in place on the fresh noise tensor: the samples stay contiguous and no second buffer is allocated
        rows, tile = _sample_rows(noise)
        rows.mul_(self.noise_std.repeat(tile) if self._uniform_std is None else self._uniform_std)
        rows.add_(plan.transpose(0, 1).unsqueeze(2).repeat(1, 1, 1, tile))
        low, high = self._uniform_bounds
        if low is None or high is None:
            rows.clamp_(self.action_low.repeat(tile), self.action_high.repeat(tile))
        else:
            rows.clamp_(low, high)
        return noise


def _sample_rows(samples: th.Tensor) -> Tuple[th.Tensor, int]:
    """
    ``samples`` ``(..., N, action_dim)`` viewed as rows of ``tile`` consecutive samples, ``(..., N / tile, tile *
    action_dim)``, with ``tile`` a divisor of ``N`` up to 32: an operand per action dimension, repeated ``tile`` times,
    then broadcasts over long rows. Broadcast over ``(..., N, action_dim)`` directly, torch's CPU loops run
    ``action_dim`` elements at a time: adding the plan that way took 3 to 6 times longer at 64 envs.

    :return: the view and ``tile``
    """
    *leading, n_samples, action_dim = samples.shape
    tile = math.gcd(n_samples, 32)
    return samples.view(*leading, n_samples // tile, tile * action_dim), tile


def _common_value(values: th.Tensor) -> Optional[float]:
    """The value every element of ``values`` shares, or ``None`` if they differ."""
    return float(values[0]) if bool((values == values[0]).all()) else None
