"""
Train MPAIL on ``sb3_mpail/Navigation-v0`` from observation-only demos, evaluate the planner, save it and plot it.

Usage::

    python -m sb3_mpail.train_navigation                      # CPU defaults (a few minutes on 2 cores)
    sb3-mpail-train-navigation                                # the same, as the installed console script
    python -m sb3_mpail.train_navigation --device cuda        # the paper's N512/H10/J5, 64 envs, 1M steps
    python -m sb3_mpail.train_navigation --n-samples 64 --timesteps 20000 --out-dir runs/quick

Writes ``<out-dir>/model.zip`` (loadable with ``MPAIL.load``, no demos or env needed), ``<out-dir>/navigation.png``
(planner paths over the demos; the learned cost map) and ``<out-dir>/results.json`` (returns, normalised score,
settings, wall-clock and, with ``--eval-freq``, the learning curve).
"""

import argparse
import inspect
import json
import sys
import time
from pathlib import Path
from typing import Any, Dict, List, Sequence, Tuple

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

import sb3_mpail.envs  # noqa: F401  (registers sb3_mpail/Navigation-v0)
from sb3_mpail.console import HelpFormatter, program_name
from sb3_mpail.demos import DemoSource, load_demo_episodes, shipped_demo_info, shipped_family
from sb3_mpail.evaluation import evaluate_episodes, normalised_score, reference_returns
from sb3_mpail.mpail import MPAIL
from sb3_mpail.policies import MPPIPolicy

ENV_ID = "sb3_mpail/Navigation-v0"
#: the shipped demo set trained on by default: 4 demos of an expert that circles on the goal, as the paper's does (1 and
#: 16 are shipped too, and ``navigation_<n>``, an expert that stops on the goal)
DEFAULT_DEMOS = "navigation_circling_4"
#: the shipped demo family whose expert and random returns the normalised score is measured against when the demos
#: are not a shipped set (a set is measured against its own expert)
REFERENCE = "navigation"
#: evaluation envs are seeded from ``seed + EVAL_SEED_OFFSET`` so they never replay the training starts
EVAL_SEED_OFFSET = 10_000

#: CPU defaults, chosen on 2 CPU cores by the ablations of BENCHMARKS.md ("navigation-ablations"): 200 iterations of 8
#: envs x 100 steps; delta sampling (the authors' sampler: increments of std [1.0, 0.5], each step at most 0.5 of the
#: half-range) lets the plan hold full speed, which Gaussian samples clamped at the bound do not; the discriminator
#: sees the heading as its cosine and sine (``{"angles": [5]}``), not as the wrapped yaw it would extrapolate from; five
#: discriminators, the step cost their mean logit less their standard deviation: out of distribution, where each one
#: extrapolates its own slope, they took the planner from 0.23 to 0.41 of the starts within 2 m of the goal (5 seeds;
#: the same score in distribution), at 2.2-2.4 times a single discriminator's training time
DEFAULT_TIMESTEPS = 160_000
DEFAULT_N_ENVS = 8
DEFAULT_POLICY_KWARGS: Dict[str, Any] = dict(
    n_samples=256, horizon=10, n_iterations=3, sampler="delta", noise_std=[1.0, 0.5], sampler_kwargs=dict(max_delta=0.5),
    discriminator_features=dict(angles=[5]), discriminator_ensemble_size=5, discriminator_disagreement=1.0,
)  # fmt: skip
DEFAULT_ALGORITHM_KWARGS: Dict[str, Any] = dict(n_steps=100, discriminator_update_interval=1)

#: the paper's table (N 512, H 10, J 5, Gaussian samples of std 0.3) with 64 envs and 200 steps per env per iteration,
#: for a GPU run
PAPER_TIMESTEPS = 1_000_000
PAPER_N_ENVS = 64
PAPER_POLICY_KWARGS: Dict[str, Any] = dict(n_samples=512, horizon=10, n_iterations=5, sampler="gaussian", noise_std=0.3,
                                            sampler_kwargs=None, discriminator_features=None,
                                            discriminator_ensemble_size=1)  # fmt: skip
PAPER_ALGORITHM_KWARGS: Dict[str, Any] = dict(n_steps=200, discriminator_update_interval=3)

# command-line planner and algorithm overrides: option name -> (keyword, type, where it goes)
POLICY_OPTIONS = {
    "n_samples": int,
    "horizon": int,
    "n_iterations": int,
    "noise_std": float,
    "markup": float,
    "sampler": str,
    # 1: the paper's single discriminator, trained in under half the time, generalising less (BENCHMARKS.md)
    "discriminator_ensemble_size": int,
    "discriminator_disagreement": float,
}
ALGORITHM_OPTIONS = {
    "n_steps": int,
    "discriminator_update_interval": int,
    "discriminator_learning_rate": float,
    "value_learning_rate": float,
    "initial_temperature": float,
    "temperature_decay": float,
    "n_epochs": int,
    "n_minibatches": int,
}


def reference_family(demos: DemoSource) -> str:
    """
    The shipped demo family the normalised score of a run on ``demos`` is measured against: a shipped set's own
    (``navigation_circling_4`` -> ``navigation_circling``), else :data:`REFERENCE`.

    :param demos: the demos trained on
    """
    return shipped_family(demos) or REFERENCE


def reference_of(demos: DemoSource) -> Dict[str, Any]:
    """:func:`reference_family`'s information file (its expert's and random policy's returns)."""
    return shipped_demo_info(reference_family(demos))


def make_model(
    demos: DemoSource = DEFAULT_DEMOS,
    n_envs: int = DEFAULT_N_ENVS,
    seed: int = 0,
    device: str = "cpu",
    policy_kwargs: Dict[str, Any] | None = None,
    verbose: int = 0,
    env_kwargs: Dict[str, Any] | None = None,
    **algorithm_kwargs: Any,
) -> MPAIL:
    """
    An untrained MPAIL model on ``n_envs`` navigation envs with this module's defaults, overridden by the arguments.

    :param demos: observation-only demos: a shipped demo set's name, an ``.npz`` or any source
        :func:`~sb3_mpail.demos.load_demos` reads
    :param n_envs: parallel training envs
    :param seed: seed of the envs, networks and planner noise
    :param device: ``"cpu"``, ``"cuda"`` or ``"auto"``
    :param policy_kwargs: planner settings replacing :data:`DEFAULT_POLICY_KWARGS` key by key
    :param verbose: MPAIL's verbosity
    :param env_kwargs: keyword arguments of the training envs (e.g. a wider ``start_region``)
    :param algorithm_kwargs: MPAIL constructor arguments replacing :data:`DEFAULT_ALGORITHM_KWARGS` key by key
    """
    env = make_vec_env(ENV_ID, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs)
    return MPAIL(
        "MlpMPPI",
        env,
        demos,
        policy_kwargs={**DEFAULT_POLICY_KWARGS, **(policy_kwargs or {})},
        seed=seed,
        device=device,
        verbose=verbose,
        **{**DEFAULT_ALGORITHM_KWARGS, **algorithm_kwargs},
    )


def run_episodes(
    model: MPAIL, n_episodes: int, seed: int, start_region: str | float = "default", deterministic: bool = True
) -> Tuple[np.ndarray, np.ndarray, List[np.ndarray]]:
    """
    Drives ``n_episodes`` full episodes at once (one env each) with ``predict``, carrying each env's plan as state.

    :param model: a trained (or loaded) MPAIL model
    :param n_episodes: episodes, one env each
    :param seed: seed of the envs' start draws
    :param start_region: the env's ``start_region``: ``"default"``, ``"ood"`` or a half-width in metres
    :param deterministic: execute the plans' first actions instead of sampling around them
    :return: episode returns ``(n,)``, final distances to the goal ``(n,)`` and each episode's observations
        ``(T + 1, 12)``
    """
    episodes = evaluate_episodes(model, ENV_ID, n_episodes, seed, env_kwargs=dict(start_region=start_region),
                                 deterministic=deterministic, record_observations=True)  # fmt: skip
    final_distance = np.array([info["distance_to_goal"] for info in episodes.final_infos])
    return episodes.returns, final_distance, episodes.observations


def evaluate(model: MPAIL, n_episodes: int = 10, seed: int = EVAL_SEED_OFFSET) -> Tuple[float, float]:
    """
    Mean and std of the deterministic planner's return over ``n_episodes``, on up to 10 envs at once.

    :param model: the model to evaluate
    :param n_episodes: evaluation episodes
    :param seed: seed of the evaluation envs' start draws
    """
    episodes = evaluate_episodes(model, ENV_ID, n_episodes, seed, n_envs=min(n_episodes, 10))
    return episodes.mean_return, episodes.std_return


class LearningCurveCallback(BaseCallback):
    """
    Every ``eval_freq`` env steps (checked at the end of each rollout), the deterministic planner's mean return over
    ``n_eval_episodes`` and its normalised score; ``curve`` holds ``(env steps, mean return, normalised score)``.
    Evaluation time is kept apart in ``eval_seconds`` so the training wall-clock can be reported without it.

    :param eval_freq: env steps between evaluations
    :param n_eval_episodes: episodes per evaluation
    :param seed: seed of the evaluation envs' start draws
    :param reference: the information file the score is measured against (:func:`reference_of`)
    :param verbose: print each evaluation when positive
    """

    def __init__(
        self,
        eval_freq: int,
        n_eval_episodes: int = 10,
        seed: int = EVAL_SEED_OFFSET,
        reference: Dict[str, Any] | None = None,
        verbose: int = 0,
    ):
        super().__init__(verbose)
        self.eval_freq = eval_freq
        self.n_eval_episodes = n_eval_episodes
        self.eval_seed = seed
        self.curve: List[Tuple[int, float, float]] = []
        self.eval_seconds = 0.0
        self.reference = reference if reference is not None else shipped_demo_info(REFERENCE)
        self._next = eval_freq

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.num_timesteps >= self._next:
            self._next += self.eval_freq
            self.record()

    def record(self) -> None:
        """Evaluates the model now and appends the point to ``curve``."""
        started = time.perf_counter()
        mean_return, _ = evaluate(self.model, self.n_eval_episodes, self.eval_seed)
        self.eval_seconds += time.perf_counter() - started
        score = normalised_score(mean_return, self.reference)
        self.curve.append((int(self.num_timesteps), mean_return, score))
        if self.verbose:
            print(f"[eval] {self.num_timesteps} steps: return {mean_return:.1f}, score {score:.3f}")


def _has_progress_bar_dependencies() -> bool:
    try:
        import rich  # noqa: F401
        import tqdm  # noqa: F401
    except ImportError:
        return False
    return True


def override_help(name: str, cpu: Dict[str, Any], paper: Dict[str, Any], constructor: Any) -> str:
    """
    What a setting is without its flag: the main command's CPU default and the paper's, each the constructor's own
    default where the settings leave it.

    :param name: the constructor argument
    :param cpu: the CPU settings
    :param paper: the paper's settings
    :param constructor: ``MPPIPolicy`` or ``MPAIL``
    """
    own = inspect.signature(constructor.__init__).parameters[name].default
    return f"default {cpu.get(name, own)}; paper {paper.get(name, own)}"


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """
    The command line.

    :param argv: arguments (``None``: ``sys.argv``)
    """
    parser = argparse.ArgumentParser(
        prog=program_name("sb3_mpail.train_navigation", "sb3-mpail-train-navigation"),
        description="Train MPAIL on sb3_mpail/Navigation-v0 from observation-only demos, evaluate, save and plot.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "--demos", default=DEFAULT_DEMOS, help="observation-only demos: a shipped demo set's name or a demo file (.npz)"
    )
    parser.add_argument(
        "--timesteps", type=int, default=None, help=f"env steps (default {DEFAULT_TIMESTEPS}; paper {PAPER_TIMESTEPS})"
    )
    parser.add_argument(
        "--n-envs", type=int, default=None, help=f"parallel envs (default {DEFAULT_N_ENVS}; paper {PAPER_N_ENVS})"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the envs, networks and planner noise")
    parser.add_argument(
        "--device", choices=("cpu", "cuda", "auto"), default="cpu", help="cuda also switches to --paper-settings"
    )
    parser.add_argument("--out-dir", default="runs/navigation", help="where the model, results.json and figure go")
    parser.add_argument(
        "--paper-settings",
        action="store_true",
        help="the paper's N512/H10/J5, 64 envs, 200 steps per env per iteration, discriminator every 3rd iteration "
        "(implied by --device cuda)",
    )
    planner = parser.add_argument_group("planner overrides (policy_kwargs)")
    for name, kind in POLICY_OPTIONS.items():
        help = override_help(name, DEFAULT_POLICY_KWARGS, PAPER_POLICY_KWARGS, MPPIPolicy)
        planner.add_argument("--" + name.replace("_", "-"), type=kind, default=None, help=help)
    algorithm = parser.add_argument_group("algorithm overrides (MPAIL constructor)")
    for name, kind in ALGORITHM_OPTIONS.items():
        help = override_help(name, DEFAULT_ALGORITHM_KWARGS, PAPER_ALGORITHM_KWARGS, MPAIL)
        algorithm.add_argument("--" + name.replace("_", "-"), type=kind, default=None, help=help)
    parser.add_argument("--n-eval-episodes", type=int, default=10, help="deterministic evaluation episodes")
    parser.add_argument("--n-plot-episodes", type=int, default=5, help="planner episodes drawn in the figure")
    parser.add_argument("--eval-freq", type=int, default=0, help="record a learning curve every this many env steps (0: off)")
    parser.add_argument("--no-plot", action="store_true", help="skip the figure (no matplotlib needed)")
    parser.add_argument("--no-progress-bar", action="store_true", help="no progress bar while training")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    return parser.parse_args(argv)


def settings_from_args(args: argparse.Namespace) -> Dict[str, Any]:
    """
    The run's full settings: the CPU defaults (the paper's with ``--paper-settings`` or ``--device cuda``), then the
    command-line overrides.

    :param args: the parsed command line (:func:`parse_args`)
    """
    if args.paper_settings or args.device == "cuda":
        timesteps, n_envs = PAPER_TIMESTEPS, PAPER_N_ENVS
        policy_kwargs, algorithm_kwargs = dict(PAPER_POLICY_KWARGS), dict(PAPER_ALGORITHM_KWARGS)
    else:
        timesteps, n_envs = DEFAULT_TIMESTEPS, DEFAULT_N_ENVS
        policy_kwargs, algorithm_kwargs = dict(DEFAULT_POLICY_KWARGS), dict(DEFAULT_ALGORITHM_KWARGS)
    policy_kwargs.update({name: getattr(args, name) for name in POLICY_OPTIONS if getattr(args, name) is not None})
    algorithm_kwargs.update({name: getattr(args, name) for name in ALGORITHM_OPTIONS if getattr(args, name) is not None})
    return dict(
        timesteps=args.timesteps if args.timesteps is not None else timesteps,
        n_envs=args.n_envs if args.n_envs is not None else n_envs,
        policy_kwargs=policy_kwargs,
        algorithm_kwargs=algorithm_kwargs,
    )


def main(argv: Sequence[str] | None = None) -> Dict[str, Any]:
    """
    Runs the command.

    :param argv: command-line arguments (``None``: ``sys.argv``)
    :return: what it wrote to ``results.json``
    """
    args = parse_args(argv)
    if args.threads is not None:
        th.set_num_threads(args.threads)
    if args.device == "cuda" and not th.cuda.is_available():
        raise SystemExit("--device cuda was asked for but torch sees no CUDA device; use --device cpu or auto.")
    settings = settings_from_args(args)
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    demos = args.demos
    progress_bar = not args.no_progress_bar and _has_progress_bar_dependencies()
    if not args.no_progress_bar and not progress_bar:
        print("(no progress bar: it needs tqdm and rich, e.g. pip install tqdm rich)")

    model = make_model(
        demos,
        n_envs=settings["n_envs"],
        seed=args.seed,
        device=args.device,
        policy_kwargs=settings["policy_kwargs"],
        **settings["algorithm_kwargs"],
    )
    print(
        f"MPAIL on {ENV_ID}: {settings['timesteps']} env steps, {settings['n_envs']} envs, demos {demos}, "
        f"device {model.device}, planner {settings['policy_kwargs']}, algorithm {settings['algorithm_kwargs']}"
    )
    callback = None
    if args.eval_freq > 0:
        callback = LearningCurveCallback(
            args.eval_freq, args.n_eval_episodes, seed=args.seed + EVAL_SEED_OFFSET, reference=reference_of(demos), verbose=1
        )
    started = time.perf_counter()
    model.learn(settings["timesteps"], callback=callback, progress_bar=progress_bar)
    train_seconds = time.perf_counter() - started
    if callback is not None:
        train_seconds -= callback.eval_seconds
    model_path = out_dir / "model.zip"
    model.save(model_path)

    mean_return, std_return = evaluate(model, args.n_eval_episodes, seed=args.seed + EVAL_SEED_OFFSET)
    reference = reference_of(demos)
    score = normalised_score(mean_return, reference)
    if callback is not None:
        # the curve ends with this evaluation of the final model (one taken before the last update is replaced)
        if callback.curve and callback.curve[-1][0] == model.num_timesteps:
            callback.curve.pop()
        callback.curve.append((int(model.num_timesteps), mean_return, score))
    random_return, expert_return = reference_returns(reference)
    print(
        f"deterministic planner over {args.n_eval_episodes} episodes: return {mean_return:.1f} +- {std_return:.1f} "
        f"(expert {expert_return:.1f}, random {random_return:.1f}), normalised score {score:.3f}"
    )
    results: Dict[str, Any] = dict(
        command="python -m sb3_mpail.train_navigation " + " ".join(sys.argv[1:] if argv is None else argv),
        demos=str(args.demos),
        seed=args.seed,
        device=str(model.device),
        **settings,
        train_seconds=round(train_seconds, 1),
        mean_return=mean_return,
        std_return=std_return,
        normalised_score=score,
        n_eval_episodes=args.n_eval_episodes,
        model=str(model_path),
    )
    if callback is not None:
        results["learning_curve"] = [dict(steps=s, mean_return=r, normalised_score=n) for s, r, n in callback.curve]
    if not args.no_plot and args.n_plot_episodes > 0:
        from sb3_mpail.plotting import plot_navigation

        demo_observations = np.stack(load_demo_episodes(demos))
        _, distances, trajectories = run_episodes(model, args.n_plot_episodes, seed=args.seed + EVAL_SEED_OFFSET)
        figure = plot_navigation(
            model,
            demo_observations,
            trajectories,
            out_dir / "navigation.png",
            title=f"MPAIL on Navigation-v0 ({Path(demos).name}, {settings['timesteps']} steps, seed {args.seed}): "
            f"return {mean_return:.0f}, normalised score {score:.2f}",
        )
        results["figure"] = str(figure)
        print(f"figure: {figure} (final distance to goal of the drawn episodes: {np.round(distances, 2).tolist()} m)")
    (out_dir / "results.json").write_text(json.dumps(results, indent=2))
    print(f"model: {model_path}")
    return results


if __name__ == "__main__":
    main()
