"""Action-sequence samplers for MPPI: perturb the warm-started plan into ``N`` candidate sequences."""

from typing import Optional, Union

import numpy as np
import torch as th
from torch import nn


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
        # Plain numbers when every action dimension shares them: scalar operands take the vectorised kernels, while
        # broadcasting a per-dimension tensor over the short last dimension does not.
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
        # one draw for all envs x samples x steps: a single kernel, independent noise per env
        noise = th.randn(horizon, n_envs, n_samples, action_dim, generator=generator, device=plan.device, dtype=plan.dtype)
        # in place on the fresh noise tensor: the samples stay contiguous and no second buffer is allocated
        actions = noise.mul_(self.noise_std if self._uniform_std is None else self._uniform_std)
        actions.add_(plan.transpose(0, 1).unsqueeze(2))
        low, high = self._uniform_bounds
        if low is None or high is None:
            return th.clamp_(actions, self.action_low, self.action_high)
        return th.clamp_(actions, low, high)


def _common_value(values: th.Tensor) -> Optional[float]:
    """The value every element of ``values`` shares, or ``None`` if they differ."""
    return float(values[0]) if bool((values == values[0]).all()) else None
