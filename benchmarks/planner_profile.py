"""
Where a planning step's time goes: the torch profiler's table of operators for the planner of
:mod:`benchmarks.planner_speed` (paper settings, bicycle model, float32), self CPU time first.

Usage::

    python -m benchmarks.planner_profile                      # 64 envs, 1 thread
    python -m benchmarks.planner_profile --envs 1 --threads 2 --implementation blas
"""

import argparse
from typing import List, Optional

import torch as th
from torch.profiler import ProfilerActivity, profile

from benchmarks.planner_speed import IMPLEMENTATIONS, planning_step_sb3_mpail
from sb3_mpail.mppi.native import NativeMlp


def name_the_kernel_in_profiles() -> None:
    """The compiled kernel is not a torch operator: a record_function around its calls gives it a row of its own."""
    marked_up_sums = NativeMlp.marked_up_sums

    def recorded(*args, **kwargs):
        with th.profiler.record_function("sb3_mpail::mlp_costs (compiled kernel)"):
            return marked_up_sums(*args, **kwargs)

    NativeMlp.marked_up_sums = recorded


def main(argv: Optional[List[str]] = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.planner_profile", description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--steps", type=int, default=5, help="planning steps profiled, after 3 warm-up steps")
    parser.add_argument("--implementation", choices=("sb3-mpail", "torch", "blas", "reference"), default="sb3-mpail")
    parser.add_argument("--rows", type=int, default=25, help="operators shown")
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)
    name_the_kernel_in_profiles()
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
