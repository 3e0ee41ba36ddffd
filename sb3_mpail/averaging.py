"""A running average of the policy's weights along training, for deployment only (the planner trains on the live ones)."""

import torch as th
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from sb3_mpail.policies import MPPIPolicy


class PolicyAverage(AveragedModel):
    """
    An exponential moving average of an :class:`~sb3_mpail.policies.MPPIPolicy`'s parameters (torch's
    ``AveragedModel``): after each of training's updates, ``average += rate * (live - average)``, starting from the first
    update's weights. Its buffers (input statistics, spectral norm's singular vectors, the temperature) are copied from
    the live policy at each update: they are statistics and settings, not weights to average.

    Adversarial training moves the learned reward, and with it the value and the planner, from one rollout to the next,
    so the live weights at the end of a run are one draw from that swing; the average is what ``MPAIL.predict`` plans
    with.

    :param policy: the live policy (copied; the copy is the average)
    :param rate: the weight of each update, in (0, 1]: 1 keeps the last update's weights
    """

    def __init__(self, policy: MPPIPolicy, rate: float):
        super().__init__(policy, multi_avg_fn=get_ema_multi_avg_fn(1.0 - rate), use_buffers=False)
        self.rate = rate

    @property
    def policy(self) -> MPPIPolicy:
        """The averaged policy, which plans as the live one does."""
        return self.module

    @property
    def is_started(self) -> bool:
        """Whether an update has set the average (before that it holds the policy's weights as they were copied)."""
        return bool(self.n_averaged.item() > 0)

    @th.no_grad()
    def update(self, policy: MPPIPolicy) -> None:
        """Moves the average towards ``policy``'s parameters (the first call copies them) and copies its buffers."""
        self.update_parameters(policy)
        for mine, live in zip(self.module.buffers(), policy.buffers()):
            mine.copy_(live)
