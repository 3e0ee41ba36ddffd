"""
Checks of the planner on a GPU, to run before timing it there: each prints PASS or FAIL with what it
measured, and the exit status is 1 if any failed.

- the optimised planner gives the reference implementation's plans (float32, paper settings, same noise);
- a planning step makes no host sync (``torch.cuda.set_sync_debug_mode("error")``; CUDA only);
- with ``compile_planner`` (``True`` and ``"reduce-overhead"``, CUDA graphs), the plans are the eager ones, and plans
  returned by earlier planning steps can still be read after later ones (CUDA graph trees reuse their outputs' memory
  on the next replay).

Usage::

    python -m benchmarks.gpu_check                          # on cuda
    python -m benchmarks.gpu_check --device cpu --no-compile  # the same checks' CPU part (a smoke test)
"""

import argparse
import sys
from typing import Any, Callable, List, Optional, Tuple

import torch as th

from benchmarks.planner_speed import make_policy, random_states

#: float32 plans of different code paths agree to this (the CPU tests' tolerance at the paper settings, times 10)
TOLERANCE = 1e-4


def planned(policy, plan_once: Callable, states: th.Tensor, steps: int, seed: int = 0) -> List[th.Tensor]:
    """The plans of ``steps`` warm-started planning steps, as returned (not copied)."""
    generator = th.Generator(device=states.device).manual_seed(seed)
    plan = policy.planner.initial_plan(states.shape[0])
    plans = []
    with th.no_grad():
        for _ in range(steps):
            plan = plan_once(states, plan, policy.temperature, generator).plan
            plans.append(plan)
    return plans


def largest_difference(plans: List[th.Tensor], expected: List[th.Tensor]) -> float:
    return max(float((plan - other).abs().max()) for plan, other in zip(plans, expected))


def check_reference(device: str, n_envs: int) -> Tuple[bool, str]:
    policy = make_policy(device)
    policy.temperature.fill_(1.0)  # as the CPU test: lower temperatures amplify float32 rounding
    states = random_states(n_envs, device)
    optimised = [plan.clone() for plan in planned(policy, policy.planner.forward, states, 3)]
    reference = planned(policy, policy.planner.reference_forward, states, 3)
    difference = largest_difference(optimised, reference)
    return difference <= TOLERANCE, f"largest plan difference {difference:.2e} (tolerance {TOLERANCE:.0e})"


def check_host_syncs(device: str, n_envs: int) -> Tuple[bool, str]:
    policy = make_policy(device)
    states = random_states(n_envs, device)
    planned(policy, policy.planner.forward, states, 2)  # warm-up: first-use work may sync
    previous_mode = th.cuda.get_sync_debug_mode()
    th.cuda.set_sync_debug_mode("error")
    try:
        planned(policy, policy.planner.forward, states, 2)
    except RuntimeError as error:
        return False, f"a planning step synced with the host: {error}"
    finally:
        th.cuda.set_sync_debug_mode(previous_mode)
    return True, "two planning steps ran under set_sync_debug_mode('error')"


def check_compiled(device: str, n_envs: int, mode: Any) -> Tuple[bool, str]:
    eager_policy, compiled_policy = make_policy(device), make_policy(device, compile_planner=mode)
    states = random_states(n_envs, device)
    eager = planned(eager_policy, eager_policy.planner.forward, states, 4)
    try:
        compiled = planned(compiled_policy, compiled_policy.planner.forward, states, 4)
        difference = largest_difference(compiled, eager)  # reads every step's plan after the last step
    except RuntimeError as error:
        return False, f"{type(error).__name__}: {error}"
    return difference <= TOLERANCE, f"largest difference from the eager plans {difference:.2e}, every step's plan readable"


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.gpu_check", description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--no-compile", action="store_true", help="skip the compiled planners (minutes of compiling)")
    args = parser.parse_args(argv)
    if args.device == "cuda" and not th.cuda.is_available():
        raise SystemExit("torch sees no CUDA device")
    name = th.cuda.get_device_name() if args.device == "cuda" else "cpu"
    print(f"torch {th.__version__}, {name}, {args.envs} envs, paper settings")
    checks: List[Tuple[str, Callable[..., Tuple[bool, str]], tuple]] = [("optimised planner = reference", check_reference, ())]
    if args.device == "cuda":
        checks.append(("no host sync in a planning step", check_host_syncs, ()))
    if not args.no_compile:
        modes = [True, "reduce-overhead"] if args.device == "cuda" else [True]
        checks += [(f"compile_planner={mode!r}", check_compiled, (mode,)) for mode in modes]
    failed = 0
    for title, check, extra_args in checks:
        passed, detail = check(args.device, args.envs, *extra_args)
        failed += not passed
        print(f"{'PASS' if passed else 'FAIL'}  {title}: {detail}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
