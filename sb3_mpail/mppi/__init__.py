"""Batched infinite-horizon MPPI: sampling, dynamics, costs and the planner that combines them."""

from sb3_mpail.mppi.costs import (
    AngleFeatures,
    ConcaveValue,
    FeatureChain,
    GoalFrameFeatures,
    LaneFrameFeatures,
    MazeFrameFeatures,
    TerminalValue,
    TransitionCost,
    highway_env_lane_centrelines,
    make_transition_discriminator,
    make_value_network,
)
from sb3_mpail.mppi.dynamics import (
    DEFAULT_DYNAMICS,
    DYNAMICS_MODELS,
    CallableDynamics,
    KinematicBicycle,
    LearnedDynamics,
    ParkingKinematics,
    PendulumDynamics,
    PointMassDynamics,
    TransitionReplayBuffer,
    make_dynamics,
)
from sb3_mpail.mppi.ensemble import DiscriminatorEnsemble, ValueEnsemble
from sb3_mpail.mppi.highway_dynamics import (  # also registers them by name
    HighwayKinematics,
    HighwayTrafficKinematics,
    RacetrackKinematics,
)
from sb3_mpail.mppi.planner import MPPIPlanner, PlanResult
from sb3_mpail.mppi.sampling import ActionSampler, DeltaSampler, GaussianSampler

__all__ = [
    "AngleFeatures",
    "FeatureChain",
    "GoalFrameFeatures",
    "LaneFrameFeatures",
    "MazeFrameFeatures",
    "DEFAULT_DYNAMICS",
    "DYNAMICS_MODELS",
    "CallableDynamics",
    "ConcaveValue",
    "ActionSampler",
    "DeltaSampler",
    "DiscriminatorEnsemble",
    "GaussianSampler",
    "HighwayKinematics",
    "HighwayTrafficKinematics",
    "KinematicBicycle",
    "LearnedDynamics",
    "MPPIPlanner",
    "ParkingKinematics",
    "PendulumDynamics",
    "PlanResult",
    "PointMassDynamics",
    "RacetrackKinematics",
    "TerminalValue",
    "TransitionCost",
    "TransitionReplayBuffer",
    "ValueEnsemble",
    "highway_env_lane_centrelines",
    "make_dynamics",
    "make_transition_discriminator",
    "make_value_network",
]
