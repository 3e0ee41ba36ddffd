"""
Discriminator ensembles: several logits ``d_k(s, s')`` whose disagreement marks the transitions none of them was
trained near, so that a planner can treat them as less expert-like than any single network's extrapolation says.
"""

from typing import Sequence

import torch as th
from torch import nn


class DiscriminatorEnsemble(nn.Module):
    """
    ``K`` discriminators on ``(s, s')``, trained on the same batches from different initialisations. The logit it
    gives (the reward, and the planner's negated step cost) is their mean less ``disagreement`` times their standard
    deviation: near the data they agree, far from it each extrapolates its own way, and the spread lowers the reward
    there (a pessimistic cost for out-of-distribution transitions).

    :param members: the discriminators, each called as imitation's reward nets are, ``(state, action, next_state,
        done)`` to ``(batch,)`` logits
    :param disagreement: weight of the members' standard deviation, ``>= 0`` (``0``: their mean)
    """

    def __init__(self, members: Sequence[nn.Module], disagreement: float = 1.0):
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"An ensemble needs at least 2 discriminators; got {len(members)}.")
        self.members = nn.ModuleList(members)
        self.disagreement = float(disagreement)

    def member_logits(self, state: th.Tensor, next_state: th.Tensor) -> th.Tensor:
        """Each member's logits ``(K, batch)`` on ``(batch, n_features)`` states and next states."""
        return th.stack([member(state, None, next_state, None) for member in self.members])

    def forward(self, state: th.Tensor, action: None, next_state: th.Tensor, done: None) -> th.Tensor:
        logits = self.member_logits(state, next_state)
        return logits.mean(dim=0) - self.disagreement * logits.std(dim=0, unbiased=False)


def member_logits(discriminator: nn.Module, state: th.Tensor, next_state: th.Tensor) -> th.Tensor:
    """
    The logits each discriminator of ``discriminator`` is trained on, ``(K, batch)``: an ensemble's members', or a
    single network's as ``(1, batch)``.
    """
    if isinstance(discriminator, DiscriminatorEnsemble):
        return discriminator.member_logits(state, next_state)
    return discriminator(state, None, next_state, None).unsqueeze(0)
