"""
Planner speed at the paper's settings (N=512, H=10, J=5, kinematic bicycle, 2x32 discriminator and value MLPs on the
12-D navigation state): ms per planning step and env-steps per second for several env counts, side by side with the
plain reference implementation (:mod:`sb3_mpail.mppi.reference`) and with ``pytorch_mppi`` solving the same problem.

Every measurement runs in its own subprocess, so thread settings, caches and peak memory do not leak between cases.
One planning step plans every env once (``J`` iterations); env-steps/s = envs / seconds per planning step.

The ``callable`` cases plan through the bicycle given as a user's plain function, as a user without a built-in model
gives dynamics: the planner then calls it once per horizon step, as the reference does, and its "vs reference" figure
compares it with the reference planning through the same function.

``pytorch_mppi`` (``pip install -e ".[bench]"``) plans one env at a time, so the batched case loops over the envs. It
gets exactly the same problem: its state is ``[s, s_prev]`` (24-D) so its running cost is the same ``c(s, s') =
-d(s, s')`` with markup ``eta^t``, its terminal cost is ``-eta^H V(s_H)``, the same noise covariance, bounds, N, H,
temperature, and ``J`` calls of ``command`` per planning step (the nominal plan shifted once, refined ``J`` times).

Usage::

    python -m benchmarks.planner_speed                      # CPU: 1, 64, 1024 envs; writes BENCHMARKS.md
    python -m benchmarks.planner_speed --devices cpu cuda   # and on a GPU, with CUDA graphs
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from typing import Any, Callable, Dict, List, Optional

import numpy as np
import torch as th

from benchmarks.report import machine_description, write_section

PAPER_SETTINGS = dict(n_samples=512, horizon=10, n_iterations=5)
TEMPERATURE = 0.1
IMPLEMENTATIONS = {
    "sb3-mpail": "sb3-mpail (batched, fused, CPU kernel)",
    "torch": "sb3-mpail, torch path (CPU kernel off)",
    "blas": "sb3-mpail, torch path, BLAS hidden layers (oneDNN off)",
    "compiled": "sb3-mpail + torch.compile",
    "cuda-graphs": "sb3-mpail + torch.compile(reduce-overhead) (CUDA graphs)",
    "predict": "sb3-mpail through predict(deterministic=True): checks, lock, fresh noise seed, plan carried",
    "reference": "plain reference implementation",
    "callable": "sb3-mpail, the bicycle as a user's plain function",
    "callable-reference": "plain reference implementation, the same plain function",
    "pytorch_mppi": "pytorch_mppi 0.9.1, loop over envs",
}
#: the plain implementation each case's "vs reference" compares with (the same dynamics)
REFERENCE_OF = {"callable": "callable-reference"}
BASELINES = ("reference", "callable-reference", "pytorch_mppi")


def user_bicycle() -> Callable[[th.Tensor, th.Tensor], th.Tensor]:
    """The bicycle's step as a user brings dynamics: a plain function of torch tensors, opaque to the planner."""
    # imported here: the "torch" case switches the compiled kernels off before sb3_mpail is imported
    from sb3_mpail.mppi.dynamics import KinematicBicycle

    bicycle = KinematicBicycle()

    def step(states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        return bicycle(states, actions)

    return step


def make_policy(device: str, compile_planner: Any = False, dynamics: Any = "bicycle"):
    """A navigation ``MlpMPPI`` policy at the paper's settings, in eval mode, on ``device``."""
    from sb3_mpail.envs.navigation import NavigationEnv
    from sb3_mpail.policies import MPPIPolicy

    env = NavigationEnv()
    th.manual_seed(0)
    policy = MPPIPolicy(
        env.observation_space, env.action_space, dynamics=dynamics, compile_planner=compile_planner, **PAPER_SETTINGS
    ).to(device)
    policy.set_training_mode(False)
    policy.temperature.fill_(TEMPERATURE)
    return policy


def random_states(n_envs: int, device: str) -> th.Tensor:
    """Car states spread around the navigation start region (positions within 10 m, any heading, moving)."""
    generator = th.Generator().manual_seed(1)
    scale = th.tensor([5, 5, 0.02, 0.05, 0.05, 3, 1, 0.1, 0.05, 0.1, 0.1, 1])
    return (th.randn(n_envs, 12, generator=generator) * scale).to(device)


def planning_step_sb3_mpail(n_envs: int, device: str, implementation: str) -> Callable[[], None]:
    compile_planner = {"compiled": True, "cuda-graphs": "reduce-overhead"}.get(implementation, False)
    # each case runs in its own process: switching fast paths off here is local
    if implementation in ("torch", "blas"):
        os.environ["SB3_MPAIL_NATIVE"] = "0"
    if implementation == "blas":
        from sb3_mpail.mppi import fused

        fused.ONEDNN_LINEAR = None
    policy = make_policy(device, compile_planner, user_bicycle() if implementation.startswith("callable") else "bicycle")
    planner = policy.planner
    plan_once = planner.reference_forward if implementation.endswith("reference") else planner.forward
    states = random_states(n_envs, device)
    generator = th.Generator(device=device).manual_seed(0)
    plan = planner.initial_plan(n_envs)
    if implementation == "predict":  # the deployed path, from numpy to numpy, as a robot or a server calls it
        observations, plans = states.cpu().numpy(), plan.cpu().numpy()
        starts = np.zeros(n_envs, dtype=bool)

        def predict_step() -> None:
            nonlocal plans
            _, plans = policy.predict(observations, state=plans, episode_start=starts, deterministic=True)

        return predict_step

    def step() -> None:
        nonlocal plan
        with th.no_grad():
            plan = plan_once(states, plan, policy.temperature, generator).plan

    return step


def planning_step_pytorch_mppi(n_envs: int, device: str) -> Callable[[], None]:
    from pytorch_mppi import MPPI

    policy = make_policy(device)
    planner = policy.planner
    state_dim = 12
    markup, horizon = planner.markup, planner.horizon

    def augmented_dynamics(states: th.Tensor, actions: th.Tensor, step: int) -> th.Tensor:
        current = states[:, :state_dim]
        return th.cat((planner.dynamics(current, actions), current), dim=1)

    def running_cost(states: th.Tensor, actions: th.Tensor, step: int) -> th.Tensor:
        return markup**step * planner.step_cost(states[:, state_dim:], states[:, :state_dim])

    def terminal_cost(states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        return -(markup**horizon) * planner.terminal_value(states[..., -1, :state_dim])

    noise_std = planner.sampler.noise_std
    controllers = [
        MPPI(
            augmented_dynamics,
            running_cost,
            2 * state_dim,
            th.diag(noise_std**2),
            num_samples=planner.n_samples,
            horizon=horizon,
            device=device,
            terminal_state_cost=terminal_cost,
            lambda_=TEMPERATURE,
            u_min=policy.action_low,
            u_max=policy.action_high,
            step_dependent_dynamics=True,
        )
        for _ in range(n_envs)
    ]
    states = th.cat((random_states(n_envs, device),) * 2, dim=1)

    def step() -> None:
        with th.no_grad():
            for controller, state in zip(controllers, states):
                controller.command(state, shift_nominal_trajectory=True)
                for _ in range(planner.n_iterations - 1):
                    controller.command(state, shift_nominal_trajectory=False)

    return step


def resident_bytes() -> int:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def measure(implementation: str, n_envs: int, device: str, threads: int, min_seconds: float) -> Dict[str, Any]:
    """
    Times one case in this process: warm-up steps (allocator, workspace, compilation, CUDA graph capture; one for
    pytorch_mppi, which has none of these), then steps until ``min_seconds`` have passed (at least 3).
    """
    th.set_num_threads(threads)
    if implementation == "pytorch_mppi":
        step = planning_step_pytorch_mppi(n_envs, device)
    else:
        step = planning_step_sb3_mpail(n_envs, device, implementation)
    synchronize = th.cuda.synchronize if device == "cuda" else (lambda: None)
    baseline = resident_bytes()
    for _ in range(1 if implementation == "pytorch_mppi" else 3):
        step()
    synchronize()
    if device == "cuda":
        th.cuda.reset_peak_memory_stats()
    durations: List[float] = []
    started = time.perf_counter()
    while len(durations) < 3 or time.perf_counter() - started < min_seconds:
        step_started = time.perf_counter()
        step()
        synchronize()
        durations.append(time.perf_counter() - step_started)
    seconds = float(np.median(durations))
    if device == "cuda":
        peak_bytes = th.cuda.max_memory_allocated()
    else:  # ru_maxrss is in KiB on Linux: the most memory this process ever held, beyond what it held before planning
        peak_bytes = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - baseline, 0)
    return dict(
        implementation=implementation,
        n_envs=n_envs,
        device=device,
        threads=threads,
        ms_per_step=1e3 * seconds,
        env_steps_per_second=n_envs / seconds,
        peak_mib=peak_bytes / 2**20,
        repeats=len(durations),
    )


def run_case(implementation: str, n_envs: int, device: str, threads: int, min_seconds: float) -> Optional[Dict[str, Any]]:
    command = [
        sys.executable, "-m", "benchmarks.planner_speed", "--case", implementation, str(n_envs), device,
        "--threads", str(threads), "--min-seconds", str(min_seconds),
    ]  # fmt: skip
    finished = subprocess.run(command, capture_output=True, text=True)
    if finished.returncode != 0:
        print(f"{implementation} {n_envs} envs {device}: failed\n{finished.stderr[-2000:]}", file=sys.stderr)
        return None
    result = json.loads(finished.stdout.strip().splitlines()[-1])
    print(
        f"{device:4s} {threads} threads {n_envs:5d} envs  {IMPLEMENTATIONS[implementation]:55s} "
        f"{result['ms_per_step']:10.2f} ms/step {result['env_steps_per_second']:12.1f} env-steps/s  "
        f"peak {result['peak_mib']:8.1f} MiB",
        flush=True,
    )
    return result


def cases(args: argparse.Namespace) -> List[tuple]:
    """(implementation, n_envs, device, threads) in the order they run; the slow baselines only up to a size."""
    planned = []
    for device in args.devices:
        implementations = ["sb3-mpail", "reference"] + (["pytorch_mppi"] if not args.no_pytorch_mppi else [])
        implementations += ["predict", "callable", "callable-reference"]
        implementations += ["torch"] if device == "cpu" else []
        implementations += ["blas"] if device == "cpu" and th.backends.mkldnn.is_available() else []
        implementations += ["compiled"] if args.compile else []
        implementations += ["cuda-graphs"] if device == "cuda" else []
        implementations = [name for name in implementations if args.implementations is None or name in args.implementations]
        for threads in args.threads if device == "cpu" else args.threads[:1]:
            for n_envs in args.envs:
                for implementation in implementations:
                    if implementation in BASELINES and n_envs > args.max_baseline_envs:
                        continue
                    planned.append((implementation, n_envs, device, threads))
    return planned


def training_seconds(planner: str, timesteps: int) -> float:
    """Wall-clock of ``model.learn(timesteps)`` with ``sb3_mpail.train_navigation``'s defaults, in this process."""
    from sb3_mpail.mppi.planner import MPPIPlanner
    from sb3_mpail.train_navigation import make_model

    if planner == "reference":  # the plain implementation in place of the optimised one: same plans, slower
        MPPIPlanner.forward = MPPIPlanner.reference_forward
    model = make_model(seed=0)
    started = time.perf_counter()
    model.learn(timesteps)
    return time.perf_counter() - started


def run_training(planner: str, timesteps: int, threads: int) -> float:
    command = [sys.executable, "-W", "ignore", "-m", "benchmarks.planner_speed", "--training-case", planner, str(timesteps),
               "--threads", str(threads)]  # fmt: skip
    finished = subprocess.run(command, capture_output=True, text=True, check=True)
    seconds = float(finished.stdout.strip().splitlines()[-1])
    print(f"navigation training, {timesteps} env steps, {planner} planner: {seconds:.1f} s", flush=True)
    return seconds


def table(results: List[Dict[str, Any]]) -> str:
    by_case = {(r["implementation"], r["n_envs"], r["device"], r["threads"]): r for r in results}
    lines = [
        "| device | threads | envs | implementation | ms per planning step | env-steps/s | vs reference | vs pytorch_mppi "
        "| peak memory |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for result in results:
        key = (result["n_envs"], result["device"], result["threads"])
        ratios = []
        for other in (REFERENCE_OF.get(result["implementation"], "reference"), "pytorch_mppi"):
            baseline = by_case.get((other, *key))
            if baseline is None or other == result["implementation"]:
                ratios.append("")
            else:
                ratios.append(f"{result['env_steps_per_second'] / baseline['env_steps_per_second']:.1f}x")
        lines.append(
            f"| {result['device']} | {result['threads']} | {result['n_envs']} | {IMPLEMENTATIONS[result['implementation']]} "
            f"| {result['ms_per_step']:.2f} | {result['env_steps_per_second']:,.0f} | {ratios[0]} | {ratios[1]} "
            f"| {result['peak_mib']:.0f} MiB |"
        )
    return "\n".join(lines)


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.planner_speed", description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 64, 1024])
    parser.add_argument("--devices", nargs="+", choices=("cpu", "cuda"), default=["cpu"])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch CPU thread counts to time")
    parser.add_argument("--min-seconds", type=float, default=2.0, help="time each case for at least this long")
    parser.add_argument("--rounds", type=int, default=2, help="time every case this many times; the fastest is reported")
    parser.add_argument("--compile", action="store_true", help="also time compile_planner=True")
    parser.add_argument(
        "--implementations", nargs="+", choices=tuple(IMPLEMENTATIONS), help="time only these (default: all that apply)"
    )
    parser.add_argument("--no-pytorch-mppi", action="store_true")
    parser.add_argument(
        "--max-baseline-envs", type=int, default=64, help="time the plain implementations only up to this many envs"
    )
    parser.add_argument(
        "--training-steps", type=int, default=4000,
        help="also time navigation training (train_navigation's defaults) with the plain and the optimised planner "
        "for this many env steps (0: skip)",
    )  # fmt: skip
    parser.add_argument("--no-write", action="store_true", help="print only; leave BENCHMARKS.md alone")
    parser.add_argument("--case", nargs=3, metavar=("IMPLEMENTATION", "N_ENVS", "DEVICE"), help=argparse.SUPPRESS)
    parser.add_argument("--training-case", nargs=2, metavar=("PLANNER", "TIMESTEPS"), help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def main(argv: Optional[List[str]] = None) -> None:
    args = parse_args(argv)
    if args.case:
        implementation, n_envs, device = args.case
        print(json.dumps(measure(implementation, int(n_envs), device, args.threads[0], args.min_seconds)))
        return
    if args.training_case:
        th.set_num_threads(args.threads[0])
        print(training_seconds(args.training_case[0], int(args.training_case[1])))
        return
    if "cuda" in args.devices and not th.cuda.is_available():
        raise SystemExit("--devices cuda was asked for but torch sees no CUDA device")
    if not args.no_pytorch_mppi:
        try:
            import pytorch_mppi  # noqa: F401
        except ImportError as error:
            raise SystemExit('pytorch_mppi is not installed: pip install -e ".[bench]" (or pass --no-pytorch-mppi)') from error
    load = os.getloadavg()[0]
    print(f"paper settings {PAPER_SETTINGS}, bicycle model, {machine_description()}, load average {load:.1f}")
    # Every case once per round, the rounds one after the other: a burst of load on the machine then slows one round
    # of a case, not all of them, and the best round is kept.
    best: Dict[tuple, Dict[str, Any]] = {}
    for _ in range(args.rounds):
        for case in cases(args):
            result = run_case(*case, args.min_seconds)
            if result is not None and (case not in best or result["ms_per_step"] < best[case]["ms_per_step"]):
                best[case] = result
    results = list(best.values())
    training = ""
    if args.training_steps > 0:
        threads = args.threads[0]
        plain, optimised = (run_training(planner, args.training_steps, threads) for planner in ("reference", "sb3-mpail"))
        from sb3_mpail.train_navigation import DEFAULT_N_ENVS, DEFAULT_POLICY_KWARGS, DEFAULT_TIMESTEPS

        whole_run = " (a whole training run of `benchmarks/navigation.py`, evaluations off)"
        training = (
            f"Training wall-clock, `sb3_mpail.train_navigation`'s defaults ({DEFAULT_N_ENVS} envs, {DEFAULT_POLICY_KWARGS}), "
            f"{args.training_steps} env steps{whole_run if args.training_steps == DEFAULT_TIMESTEPS else ''}, seed 0, "
            f"{threads} thread(s): plain planner {plain:.1f} s, optimised {optimised:.1f} s ({plain / optimised:.1f}x).\n\n"
        )
    command = "python -m benchmarks.planner_speed " + " ".join(argv if argv is not None else sys.argv[1:])
    markdown = (
        f"## Planner speed\n\n"
        f"One planning step = every env planned once at the paper's settings (N=512, H=10, J=5), kinematic bicycle, "
        f"2x32 discriminator cost on (s, s') and 2x32 value, float32; median over repeats after warm-up, "
        f"each case in its own process, the fastest of {args.rounds} rounds over all cases. Peak memory: on CPU the "
        f"most resident memory beyond what the process held before planning; on CUDA `max_memory_allocated`. "
        f"pytorch_mppi plans one env at a time (a loop over envs) "
        f"on the same problem (see the module docstring).\n\n"
        f"{table(results)}\n\n{training}"
        f"Command: `{command.strip()}` on {machine_description().split(',')[0]}; 1-minute load average {load:.1f} "
        f"when it started (other jobs on the machine inflate the absolute times; ratios are from the same run).\n"
    )
    print(markdown)
    if not args.no_write:
        write_section("planner_speed_cuda" if "cuda" in args.devices else "planner_speed", markdown)


if __name__ == "__main__":
    main()
