"""
How fast the planner plans through a learned model: per hidden size, the ms per planning step and the model's forward
FLOPs per second as a share of this machine's dense matmul throughput (a large ``torch.mm`` timed in the same run),
through the model's batched ``rollout`` and step by step (its ``forward`` per horizon step).

The planner is MPAIL2's size (N 512 / H 7 / J 5) on a Hopper-sized problem (11-D state, 3-D action), 8 envs, the
discriminator and value the defaults; the model's FLOPs are ``2 x sum(in x out)`` per row and step.

Usage::

    python -m benchmarks.learned_model_speed            # 1 torch thread; writes BENCHMARKS.md's learned-model-speed
    python -m benchmarks.learned_model_speed --threads 2 --no-write
"""

import argparse
import time
from typing import Any, Callable, Dict, List, Optional

import numpy as np
import torch as th
from gymnasium import spaces

from benchmarks.report import machine_description, write_section
from sb3_mpail.mppi import planner as planner_module
from sb3_mpail.policies import MPPIPolicy

STATE_DIM, ACTION_DIM, N_ENVS = 11, 3, 8
SETTINGS = dict(n_samples=512, horizon=7, n_iterations=5)
HIDDEN_SIZES = ((64, 64, 64), (128, 128, 128), (256, 256, 256))


def best_seconds(step: Callable[[], Any], min_seconds: float, rounds: int) -> float:
    """The fastest mean time of ``step`` over ``rounds`` rounds of at least ``min_seconds`` each."""
    step()
    best = float("inf")
    for _ in range(rounds):
        calls, started = 0, time.perf_counter()
        while time.perf_counter() - started < min_seconds:
            step()
            calls += 1
        best = min(best, (time.perf_counter() - started) / calls)
    return best


def matmul_flops_per_second(min_seconds: float, rounds: int, size: int = 2048) -> float:
    a, b = th.randn(size, size), th.randn(size, size)
    return 2 * size**3 / best_seconds(lambda: th.mm(a, b), min_seconds, rounds)


def measure(hidden_sizes: tuple, batched: bool, min_seconds: float, rounds: int) -> Dict[str, float]:
    """One case: ms per planning step and the model's forward FLOPs per second."""
    th.manual_seed(0)
    observation_space = spaces.Box(-np.inf, np.inf, (STATE_DIM,), np.float32)
    action_space = spaces.Box(-1, 1, (ACTION_DIM,), np.float32)
    policy = MPPIPolicy(observation_space, action_space, dynamics="learned",
                        dynamics_kwargs=dict(hidden_sizes=hidden_sizes), **SETTINGS)  # fmt: skip
    policy.set_training_mode(False)
    states, plan = th.randn(N_ENVS, STATE_DIM), policy.initial_plan(N_ENVS)
    generator = th.Generator().manual_seed(0)
    rollout = planner_module.rollout
    if not batched:  # the planner falls back to one forward call per step for models without a batched roll-out
        planner_module.rollout = planner_module.rollout_step_by_step
    try:
        with th.no_grad():
            seconds = best_seconds(lambda: policy.planner.optimise(states, plan, policy.temperature, generator),
                                   min_seconds, rounds)  # fmt: skip
    finally:
        planner_module.rollout = rollout
    widths = [STATE_DIM + ACTION_DIM, *hidden_sizes, STATE_DIM]
    flops_per_row = 2 * sum(a * b for a, b in zip(widths[:-1], widths[1:]))
    rows = N_ENVS * SETTINGS["n_samples"] * SETTINGS["horizon"] * SETTINGS["n_iterations"]
    return {"ms": 1000 * seconds, "model_flops_per_second": flops_per_row * rows / seconds}


def table(results: List[Dict[str, Any]], matmul: float, threads: int) -> str:
    lines = [
        "## Planning through a learned model",
        "",
        f"N {SETTINGS['n_samples']} / H {SETTINGS['horizon']} / J {SETTINGS['n_iterations']}, {N_ENVS} envs, "
        f"{STATE_DIM}-D state, {ACTION_DIM}-D action, {threads} torch thread(s); share = the model's forward FLOP/s "
        f"over a 2048 x 2048 `torch.mm`'s in the same run ({matmul / 1e9:.1f} GFLOP/s). Fastest of the rounds.",
        "",
        "| model | roll-out | ms per planning step | model GFLOP/s | share of matmul throughput |",
        "|---|---|---|---|---|",
    ]
    for row in results:
        model, flops = " x ".join(map(str, row["hidden_sizes"])), row["model_flops_per_second"]
        lines.append(f"| {model} | {row['rollout']} | {row['ms']:.1f} | {flops / 1e9:.1f} | {flops / matmul:.2f} |")
    lines += ["", f"Command: `python -m benchmarks.learned_model_speed --threads {threads}` on {machine_description()}."]
    return "\n".join(lines)


def main(argv: Optional[List[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--min-seconds", type=float, default=2.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--no-write", action="store_true", help="print only; leave BENCHMARKS.md alone")
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)
    matmul = matmul_flops_per_second(args.min_seconds, args.rounds)
    results = []
    for hidden_sizes in HIDDEN_SIZES:
        for batched in (True, False):
            figures = measure(hidden_sizes, batched, args.min_seconds, args.rounds)
            results.append({"hidden_sizes": hidden_sizes, "rollout": "batched" if batched else "step by step", **figures})
            print(results[-1], flush=True)
    markdown = table(results, matmul, args.threads)
    print(markdown)
    if not args.no_write:
        write_section("learned-model-speed", markdown)


if __name__ == "__main__":
    main()
