"""sb3-mpail: Model Predictive Adversarial Imitation Learning (MPAIL) for Stable-Baselines3."""

# first, before anything imports gymnasium (which imports its plugins): see sb3_mpail/_quiet.py
import sb3_mpail._quiet  # noqa: F401  # isort: skip
import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Navigation-v0 with gymnasium)
from sb3_mpail.demos import ExpertTransitions, load_demos
from sb3_mpail.mpail import MPAIL
from sb3_mpail.policies import MlpMPPI, MPPIPolicy

__version__ = "0.1.0"

__all__ = ["MPAIL", "ExpertTransitions", "MPPIPolicy", "MlpMPPI", "load_demos", "__version__"]
