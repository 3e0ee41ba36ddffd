"""Action-sequence samplers for MPPI: perturb the warm-started plan into ``N`` candidate sequences."""

import math
from typing import Any, Dict, Optional, Sequence, Tuple, Union

import numpy as np
import torch as th
from torch import nn

from sb3_mpail.checks import POSITIVE_NUMBER, check_arguments, per_action_dimension
from sb3_mpail.mppi.native import standard_normal


class ActionSampler(nn.Module):
    """
    What every sampler holds: the action bounds its samples are clamped to, and ``N`` standard normal draws per env,
    step and action dimension at once (``torch.randn``'s numbers, drawn faster on the CPU).

    :param action_low: lower action bounds, shape ``(action_dim,)``
    :param action_high: upper action bounds, shape ``(action_dim,)``
    """

    def __init__(self, action_low: np.ndarray, action_high: np.ndarray):
        super().__init__()
        low = th.as_tensor(np.asarray(action_low, dtype=np.float32))
        high = th.as_tensor(np.asarray(action_high, dtype=np.float32))
        self.register_buffer("action_low", low)
        self.register_buffer("action_high", high)

    @property
    def half_range(self) -> th.Tensor:
        return (self.action_high - self.action_low) / 2

    def standard_noise(self, plan: th.Tensor, n_samples: int, generator: th.Generator) -> th.Tensor:
        """Standard normal noise ``(horizon, n_envs, n_samples, action_dim)`` for a plan ``(n_envs, horizon, action_dim)``."""
        n_envs, horizon, action_dim = plan.shape
        return standard_normal((horizon, n_envs, n_samples, action_dim), generator, plan.device, plan.dtype)

    def forward(self, plan: th.Tensor, n_samples: int, generator: th.Generator) -> th.Tensor:
        """
        :param plan: sampling mean per env, shape ``(n_envs, horizon, action_dim)``
        :param n_samples: number of sequences ``N`` per env
        :param generator: source of the noise, so a seed fixes the samples
        :return: clamped action sequences, time-major, shape ``(horizon, n_envs, n_samples, action_dim)``
        """
        raise NotImplementedError


class GaussianSampler(ActionSampler):
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
        super().__init__(action_low, action_high)
        self.register_buffer("noise_std", th.as_tensor(noise_std, dtype=th.float32) * self.half_range)
        # plain numbers when every action dimension shares them: scalar operands are the fastest
        self._uniform_std = _common_value(self.noise_std)
        self._uniform_bounds = (_common_value(self.action_low), _common_value(self.action_high))

    def forward(self, plan: th.Tensor, n_samples: int, generator: th.Generator) -> th.Tensor:
        """See :meth:`ActionSampler.forward`: the plan plus scaled Gaussian noise, clamped."""
        noise = self.standard_noise(plan, n_samples, generator)
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


class DeltaSampler(ActionSampler):
    """
    Samples smooth action sequences by perturbing the plan's *increments* (the authors' default sampler): with ``P``
    the plan and ``D_t = P_t - P_{t-1}`` its increments (``D_0 = 0``), each sample is
    ``u_t = P_0 + sum_{i <= t} clamp(D_i + eps_i, -max_delta, max_delta)``, ``eps ~ N(0, noise_std^2)``, clamped to
    the action bounds. Every sample is a random walk whose steps are limited to ``max_delta``, so consecutive actions
    never jump, and with no noise the samples are the plan itself (where its own increments are within the limit).

    ``noise_std`` and ``max_delta`` are relative to the action half-range, like :class:`GaussianSampler`'s std; the
    authors use ``[1.0, 0.5]`` and ``[0.2, 0.2]`` for the navigation car's ``[speed, steering]``.

    :param action_low: lower action bounds, shape ``(action_dim,)``
    :param action_high: upper action bounds, shape ``(action_dim,)``
    :param noise_std: std of the increments' noise relative to the action half-range (scalar or per dimension)
    :param max_delta: largest change between consecutive actions relative to the half-range, ``> 0`` (scalar or per
        dimension)
    :raises ValueError: ``noise_std`` is negative, or ``max_delta`` is not a finite number ``> 0`` or one per action
        dimension
    """

    def __init__(
        self,
        action_low: np.ndarray,
        action_high: np.ndarray,
        noise_std: Union[float, np.ndarray] = (1.0, 0.5),
        max_delta: Union[float, np.ndarray] = 0.2,
    ):
        super().__init__(action_low, action_high)
        check_arguments(max_delta=(max_delta, per_action_dimension(POSITIVE_NUMBER, len(self.action_low))))
        std = th.as_tensor(np.asarray(noise_std, dtype=np.float32))
        delta = th.as_tensor(np.asarray(max_delta, dtype=np.float32))
        if bool((std < 0).any()):
            raise ValueError(f"DeltaSampler needs noise_std >= 0; got {noise_std}.")
        self.register_buffer("noise_std", std * self.half_range)
        self.register_buffer("max_delta", delta * self.half_range)

    def forward(self, plan: th.Tensor, n_samples: int, generator: th.Generator) -> th.Tensor:
        """See :meth:`ActionSampler.forward`: clamped random walks of perturbed increments from the plan's start."""
        noise = self.standard_noise(plan, n_samples, generator)
        increments = th.diff(plan.transpose(0, 1), dim=0, prepend=plan[:, :1].transpose(0, 1)).unsqueeze(2)
        steps = th.clamp(noise.mul_(self.noise_std).add_(increments), -self.max_delta, self.max_delta)
        samples = th.cumsum(steps, dim=0).add_(plan[:, 0].unsqueeze(1))
        return th.clamp(samples, self.action_low, self.action_high)


#: the samplers a policy can name
SAMPLERS = {"gaussian": GaussianSampler, "delta": DeltaSampler}


def make_sampler(
    sampler: Union[str, nn.Module],
    action_low: np.ndarray,
    action_high: np.ndarray,
    noise_std: Union[float, Sequence[float]],
    sampler_kwargs: Dict[str, Any] | None = None,
) -> nn.Module:
    """
    The planner's sampler: a module as given, or a named one (:data:`SAMPLERS`) built for the action bounds.

    :param sampler: ``"gaussian"``, ``"delta"`` or a module ``sampler(plan, n_samples, generator)``
    :param noise_std: the named sampler's noise std, relative to the action half-range
    :param sampler_kwargs: further keyword arguments of a named sampler
    """
    if isinstance(sampler, nn.Module):
        return sampler
    if sampler not in SAMPLERS:
        raise ValueError(f"Unknown sampler {sampler!r}: expected one of {sorted(SAMPLERS)} or an nn.Module.")
    return SAMPLERS[sampler](action_low, action_high, np.asarray(noise_std, dtype=np.float32), **(sampler_kwargs or {}))
