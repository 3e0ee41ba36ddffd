"""
The learned reward as a function of the discriminator's logit ``d = log D - log(1 - D)``, shared by the planner's step
costs (module, fused and compiled paths alike), the value's returns and the prior's Q targets.
"""

import math
from typing import Callable, Dict

import torch as th
from torch import nn

#: ``"logit"`` is ``d`` itself (AIRL's form, the paper's), negative wherever a transition looks more like the agent's
#: than the expert's; ``"softplus"`` is ``-log(1 - D) = softplus(d)`` (GAIL's form), positive everywhere, so staying
#: alive always pays: where falls end episodes, a mostly negative reward pays the agent to end them; ``"capped"`` is
#: ``log 2D = log 2 - softplus(-d)``: about ``d + log 2`` where a transition looks like the agent's, flat at ``log 2``
#: where it looks like the expert's, so that looking more expert-like than the expert's own transitions (a planner
#: pushing past the demos' speeds, where the logit extrapolates upwards) earns nothing more
REWARD_FORMS: Dict[str, Callable[[th.Tensor], th.Tensor]] = {
    "logit": lambda logits: logits,
    "softplus": nn.functional.softplus,
    "capped": lambda logits: math.log(2.0) - nn.functional.softplus(-logits),
}
