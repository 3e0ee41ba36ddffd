"""
A planning step never reads a tensor's value back to the host, so on a GPU nothing in it waits for the device, and
compiled it is one graph (what CUDA graphs capture whole).

Checked on the CPU by recording the operators a planning step dispatches: every host read-back (``.item()``,
``bool(tensor)``, data-dependent output sizes) goes through one of ``SYNCING_OPERATORS``. The highway-env models
(parking, highway, racetrack) check their speed limit on the host in eager mode and not when compiled.
"""

from typing import List

import numpy as np
import pytest
import torch as th
import torch._dynamo
from gymnasium import spaces
from torch.utils._python_dispatch import TorchDispatchMode

import sb3_mpail.mppi.highway_dynamics  # noqa: F401 (registers the highway-env models)
from sb3_mpail.envs.navigation import NavigationEnv
from sb3_mpail.policies import MPPIPolicy

SYNCING_OPERATORS = {"_local_scalar_dense", "is_nonzero", "equal", "nonzero", "masked_select", "_unique2"}


class HostReadRecorder(TorchDispatchMode):
    """Records the operators dispatched while active that read tensor values back to the host."""

    def __init__(self) -> None:
        super().__init__()
        self.host_reads: List[str] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func.overloadpacket.__name__ in SYNCING_OPERATORS:
            self.host_reads.append(str(func))
        return func(*args, **(kwargs or {}))


def box(size: int, bound: float = 1.0) -> spaces.Box:
    return spaces.Box(-bound, bound, (size,), dtype=np.float32)


PROBLEMS = {
    "bicycle": (NavigationEnv().observation_space, box(2)),
    "pendulum": (spaces.Box(-8.0, 8.0, (3,), dtype=np.float32), box(1, 2.0)),
    "point_mass": (box(6, 10.0), box(2)),
    "learned": (box(4, 10.0), box(1)),
    "parking": (box(12), box(2)),
    "highway": (box(6), box(2)),
    "racetrack": (box(6), box(1)),
}
#: models that check on the host, in eager mode only, whether their speed limit binds
CHECK_THE_SPEED_LIMIT_ON_THE_HOST = {"parking", "highway", "racetrack"}


def planning_inputs(dynamics: str, **policy_kwargs):
    """A policy of 64 samples in eval mode for ``dynamics``, observations of 3 envs and their fresh plans."""
    observation_space, action_space = PROBLEMS[dynamics]
    th.manual_seed(0)
    policy = MPPIPolicy(observation_space, action_space, dynamics=dynamics, n_samples=64, **policy_kwargs)
    policy.set_training_mode(False)
    observations = th.as_tensor(np.stack([observation_space.sample() for _ in range(3)]))
    return policy, observations, policy.initial_plan(3)


def test_the_recorder_sees_a_host_read():
    with HostReadRecorder() as recorder:
        bool(th.ones(3).sum() > 0)
    assert recorder.host_reads == ["aten._local_scalar_dense.default"]


@pytest.mark.parametrize("dynamics", sorted(set(PROBLEMS) - CHECK_THE_SPEED_LIMIT_ON_THE_HOST))
@pytest.mark.parametrize("deterministic", [False, True], ids=["training", "deterministic"])
def test_planning_steps_never_read_tensors_back_to_the_host(dynamics, deterministic):
    policy, observations, plan = planning_inputs(dynamics)
    with th.no_grad():
        policy.act(observations, plan, deterministic)  # first call: the noise generator is created and seeded
        with HostReadRecorder() as recorder:
            actions, plan = policy.act(observations, plan, deterministic)
    assert recorder.host_reads == []
    assert actions.shape == (3, PROBLEMS[dynamics][1].shape[0]) and th.isfinite(plan).all()


@pytest.mark.parametrize("dynamics", sorted(PROBLEMS))
def test_compiled_planning_iteration_is_one_graph(dynamics):
    policy, observations, plan = planning_inputs(dynamics, compile_planner=True)
    planner = policy.planner
    with th.no_grad():
        trajectory_cost = planner.trajectory_cost(observations, planner.horizon)
        actions = planner.sampler(plan, planner.n_samples, th.Generator().manual_seed(0))
        # what torch.compile traces of the roll-out/cost/weight update, without compiling it
        traced = torch._dynamo.explain(planner._update)(observations, actions, policy.temperature, trajectory_cost)
    assert (traced.graph_count, traced.graph_break_count) == (1, 0), traced.break_reasons
