"""
Where a planning step's time goes: the torch profiler's table of operators for the planner of
:mod:`benchmarks.planner_speed` (paper settings, bicycle model, float32), self CPU time first.

Usage::

    python -m benchmarks.planner_profile                      # 64 envs, 1 thread
    python -m benchmarks.planner_profile --envs 1 --threads 2 --implementation blas
"""

import argparse
from typing import Callable, List, Optional

import torch as th
from torch.profiler import ProfilerActivity, profile

from benchmarks.planner_speed import IMPLEMENTATIONS, planning_step_sb3_mpail
from sb3_mpail.mppi.native import NativeMlp


def name_the_kernels_in_profiles() -> None:
    """The compiled kernels are not torch operators: a record_function around their calls gives each a row of its own."""
    from sb3_mpail.mppi import sampling

    def recorded(function: Callable, name: str) -> Callable:
        def call(*args, **kwargs):
            with th.profiler.record_function(name):
                return function(*args, **kwargs)

        return call

    NativeMlp.marked_up_sums = recorded(NativeMlp.marked_up_sums, "sb3_mpail::mlp_costs (compiled kernel)")
    sampling.standard_normal = recorded(sampling.standard_normal, "sb3_mpail::standard_normal (noise kernel or randn)")


def main(argv: Optional[List[str]] = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.planner_profile", description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--steps", type=int, default=5, help="planning steps profiled, after 3 warm-up steps")
    parser.add_argument("--implementation", choices=("sb3-mpail", "torch", "blas", "reference"), default="sb3-mpail")
    parser.add_argument("--rows", type=int, default=25, help="operators shown")
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)
    name_the_kernels_in_profiles()
    step = planning_step_sb3_mpail(args.envs, "cpu", args.implementation)
    for _ in range(3):
        step()
    with profile(activities=[ProfilerActivity.CPU]) as profiler:
        for _ in range(args.steps):
            step()
    print(f"{IMPLEMENTATIONS[args.implementation]}, {args.envs} envs, {args.threads} thread(s), {args.steps} planning steps")
    print(profiler.key_averages().table(sort_by="self_cpu_time_total", row_limit=args.rows))


if __name__ == "__main__":
    main()
