"""
The benchmark grid: MPAIL against GAIL, AIRL (obs-only), BC (uses expert actions) and IRL-MPC, on the same demos and
env-step budget (``zoo_configs/<algo>.yml``, MPAIL's ``sb3_mpail/hyperparams/mpail.yml``), over envs x demo
counts x seeds.

    python -m benchmarks.runner --envs navigation pendulum --algos mpail gail airl bc irl_mpc --demos 1 4 16 --seeds 5
    python -m benchmarks.runner --envs cartpole --algos mpail gail airl --demos 4 --seeds 3
    python -m benchmarks.runner --envs lap --algos gail --demos 1 --seeds 3

Each finished run writes ``<results-dir>/<env>/<algo>_<n>demos_seed<s>.json`` (its learning curve, final score and,
on navigation, its out-of-distribution episodes); a rerun skips the runs whose file exists, so an interrupted grid
resumes where it stopped. GAIL and IRL-MPC of the same env, demo count and seed come from one GAIL training run (IRL-MPC
deploys that run's reward and critic). Runs go to ``--workers`` local processes, or to a Ray cluster with
``--ray-address`` (the ``ray`` extra, ``pip install -e '.[ray]'``), whose results come back to be written here. At the
end, the tables of every result found go into BENCHMARKS.md (normalised score mean and 95% CI, env steps to reach 0.9)
and the figures into ``benchmarks/figures/``.

The lap (``sb3_mpail/NavigationLap-v0``, one noisy demo of position and body-frame velocity) has no expert return:
its runs are measured as ``benchmarks/scenarios.py`` measures MPAIL's, by the cross-track error to the demo's path
(mean and max over 5 laps) and the mean speed, and its table sets them beside MPAIL's scenario figures.
"""

import argparse
import json
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch as th

from benchmarks.baselines import ALGO_LABELS, ALGOS, ENV_NAMES, env_id_of, env_name_of, load_config, train_baseline
from benchmarks.report import (
    BENCHMARKS_FILE,
    DETERMINISTIC_NOISE,
    commands_of,
    format_ci,
    machine_description,
    machines_of,
    mean_ci,
    write_section,
)
from benchmarks.scenarios import RESULTS as SCENARIO_RESULTS
from benchmarks.scenarios import SCENARIOS, Scenario, lap_figures, zoo_hyperparameters
from sb3_mpail.demos import list_shipped_demos, shipped_demo_info, shipped_demos
from sb3_mpail.envs.navigation import DT, MAX_SPEED, REWARD_OFFSET
from sb3_mpail.evaluation import Episodes, evaluate_episodes, normalised_score
from sb3_mpail.train_navigation import DEFAULT_POLICY_KWARGS, make_model

RESULTS_DIR = Path(__file__).resolve().parent / "results"
FIGURES_DIR = Path(__file__).resolve().parent / "figures"
TARGET = 0.9
#: learning-curve episodes start from ``reset(seed=EVAL_SEED + i)``, the OOD ones from ``OOD_SEED + i``; both
#: ranges are disjoint from the demos' start seeds
EVAL_SEED, OOD_SEED = 10_000, 50_000
#: an OOD episode "reaches the goal" when it ends within this distance of it (metres)
GOAL_RADIUS = 2.0
GOAL = np.array([10.0, 10.0])
#: an OOD episode "ends circling" when its mean absolute yaw rate over its last half exceeds this (rad/s)
CIRCLING_YAW_RATE = 2.0
#: ... and "circles away from the goal" when it also ends farther than this from it (metres; the expert circles the
#: goal at about 0.6 m)
CIRCLING_AWAY = 5.0
#: the farthest a car drives in a 100-step episode at its 3 m/s top speed (metres)
MAX_TRAVEL = MAX_SPEED * DT * 100
NAVIGATION = "sb3_mpail/Navigation-v0"
#: the true-reward planner's terminal value per metre to the goal: ten steps' worth, the planner's horizon
TRUE_VALUE_SLOPE = 10.0
TRUE_REWARD_LABEL = "the same planner on the true reward (the ceiling)"
TRUE_REWARD_NOTE = (
    "The ceiling: the main command's planner, untrained, planning on the true reward (step cost = the next state's "
    f"distance to the goal, terminal value = -{TRUE_VALUE_SLOPE:g} x its distance) instead of a learned cost and "
    "value, from the same starts (one deterministic run)."
)
LAP = "sb3_mpail/NavigationLap-v0"
#: the lap's figures, in the order of its curve points after the env-step count
LAP_FIGURES = ("cte_mean", "cte_max", "speed")


def grid_of(env: str) -> Tuple[str, str]:
    """
    The demo sets and env of a grid: an env (id or short name) trains on its own shipped sets, ``<env>_<n>``; the
    name of other shipped sets of an env (e.g. ``navigation_circling``) trains on those, in the env their information
    file names.

    :param env: an env id, an env's short name or a shipped demo-set prefix
    :return: the demo-set prefix and the gymnasium id
    """
    if any(name.rsplit("_", 1)[0] == env for name in list_shipped_demos()) and env not in ENV_NAMES.values():
        return env, shipped_demo_info(env)["env_id"]
    env_id = env_id_of(env)
    return env_name_of(env_id), env_id


def grid_name(demo_set: str, timesteps: Optional[int] = None) -> str:
    """
    The name of a grid (its results folder, report sections and figures): its demo sets' prefix, e.g. ``navigation``,
    or ``navigation_200000steps`` when ``--timesteps`` overrides every budget.

    :param demo_set: the shipped demo sets' prefix (:func:`grid_of`)
    :param timesteps: the override, or ``None`` for the configs' budgets
    """
    return demo_set + ("" if timesteps is None else f"_{timesteps}steps")


def result_path(
    results_dir: Path, demo_set: str, algo: str, n_demos: int, seed: int, timesteps: Optional[int] = None
) -> Path:
    """
    Where a run's result goes.

    :param results_dir: the grid's folder
    :param demo_set: the shipped demo sets' prefix (:func:`grid_of`)
    :param algo: one of :data:`~benchmarks.baselines.ALGOS`
    :param n_demos: demo count
    :param seed: training seed
    :param timesteps: the budget override, or ``None``
    """
    return Path(results_dir) / grid_name(demo_set, timesteps) / f"{algo}_{n_demos}demos_seed{seed}.json"


def make_jobs(envs: Sequence[str], algos: Sequence[str], demos: Sequence[int], seeds: Sequence[int]) -> List[Dict[str, Any]]:
    """
    The grid's training runs, seed by seed; GAIL and IRL-MPC share one run (``algos`` lists what a job reports).

    :param envs: env ids, short names or shipped demo-set prefixes (:func:`grid_of`)
    :param algos: algorithms
    :param demos: demo counts
    :param seeds: training seeds
    """
    shared = tuple(algo for algo in ("gail", "irl_mpc") if algo in algos)
    groups = [(algo,) for algo in ALGOS if algo in algos and algo not in shared] + ([shared] if shared else [])
    return [
        dict(env_id=grid_of(env)[1], demo_set=grid_of(env)[0], algos=group, n_demos=n_demos, seed=seed)
        for env in envs
        for n_demos in demos
        for seed in seeds
        for group in groups
    ]


def job_paths(job: Dict[str, Any], options: Dict[str, Any]) -> Dict[str, Path]:
    """
    The result files a job writes, by algorithm.

    :param job: an entry of :func:`make_jobs`
    :param options: :func:`train_job`'s options
    """
    return {
        algo: result_path(options["results_dir"], job["demo_set"], algo, job["n_demos"], job["seed"], options.get("timesteps"))
        for algo in job["algos"]
    }


def curve_point(predictor: Any, env_id: str, steps: int, n_episodes: int, stats: Dict[str, Any]) -> Tuple[float, ...]:
    """
    One learning-curve point: ``(env steps, normalised score, mean return)`` over ``n_episodes`` deterministic
    episodes, or on the lap ``(env steps, cte_mean, cte_max, speed)`` over the laps MPAIL's scenario is measured on.

    :param predictor: anything SB3's ``predict`` works on
    :param env_id: gymnasium id
    :param steps: env steps trained so far
    :param n_episodes: evaluation episodes, env ``i`` reset with ``EVAL_SEED + i`` (not the lap's: its lap count is
        the scenario's)
    :param stats: the demo sets' information (:func:`~sb3_mpail.demos.shipped_demo_info`)
    """
    if env_id == LAP:
        figures = lap_figures(predictor, stats, SCENARIOS["lap"].n_eval_episodes)
        return (steps, *(figures[key] for key in LAP_FIGURES))
    # exactly one episode per seed (one env each), so the envs whose first episode ends early (cartpole's falls) add
    # no second ones weighting the mean towards failures
    mean_return = evaluate_episodes(predictor, env_id, n_episodes, EVAL_SEED).mean_return
    return steps, normalised_score(mean_return, stats), mean_return


def train_job(job: Dict[str, Any], options: Dict[str, Any]) -> Dict[Path, Dict[str, Any]]:
    """
    Trains one job and measures it; writes nothing, so that it can run on another machine than the one keeping the
    results (a Ray node).

    :param job: an entry of :func:`make_jobs`
    :param options: ``results_dir``, ``config_dir`` (``None``: the default files), ``eval_episodes``,
        ``ood_episodes``, ``eval_every`` (0: a tenth of the budget), ``timesteps`` (``None``: the configs'), ``threads``,
        and ``command``, the command line recorded with the results (optional)
    :return: each of its algorithms' result, by the file it goes to (:func:`job_paths`)
    """
    env_id, algos, n_demos, seed = job["env_id"], job["algos"], job["n_demos"], job["seed"]
    paths = job_paths(job, options)
    results: Dict[Path, Dict[str, Any]] = {}
    th.set_num_threads(options["threads"])
    algo = "irl_mpc" if "irl_mpc" in algos else algos[0]
    hyperparams = load_config(algo, env_id, options["config_dir"])
    budget = hyperparams["n_timesteps"] if options["timesteps"] is None else options["timesteps"]
    eval_every = options["eval_every"] or max(1, budget // 10)
    stats = shipped_demo_info(job["demo_set"])
    curves: Dict[str, List[Tuple[float, ...]]] = {name: [] for name in algos}
    finals: Dict[str, Any] = {}

    def on_eval(steps: int, predictors: Dict[str, Any]) -> None:
        for name, predictor in predictors.items():
            if name in curves:
                curves[name].append(curve_point(predictor, env_id, steps, options["eval_episodes"], stats))
                finals[name] = predictor

    start = time.perf_counter()
    train_baseline(algo, env_id, f"{job['demo_set']}_{n_demos}", seed, hyperparams, eval_every, on_eval, budget)
    seconds = time.perf_counter() - start
    for name, path in paths.items():
        result: Dict[str, Any] = dict(
            env_id=env_id, algo=name, n_demos=n_demos, seed=seed, n_timesteps=budget, curve=curves[name],
            train_seconds=round(seconds, 1), shared_run=list(algos), hyperparams=hyperparams, machine=machine_description(),
            command=options.get("command"),
        )  # fmt: skip
        if env_id == LAP:
            result["lap"] = dict(zip(LAP_FIGURES, curves[name][-1][1:]))
        else:
            result.update(final_score=curves[name][-1][1], final_return=curves[name][-1][2],
                          steps_to_target=next((point[0] for point in curves[name] if point[1] >= TARGET), None))  # fmt: skip
        if env_id == NAVIGATION and options["ood_episodes"] > 0:
            result["ood"] = ood_record(ood_episodes(finals[name], options["ood_episodes"]))
        scenario = scenario_of(env_id)
        if scenario is not None and env_id != LAP:  # the lap's curve points are its figures already
            result["scenario_figures"] = scenario[1].figures(finals[name], stats, scenario[1].n_eval_episodes)
        results[path] = result
    return results


def write_results(results: Dict[Path, Dict[str, Any]]) -> List[str]:
    """
    Writes each result to its file, whole or not at all (beside it first, then renamed over it).

    :param results: :func:`train_job`'s
    :return: the result files written
    """
    for path, result in results.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(path.name + ".partial")
        partial.write_text(json.dumps(result, default=str))
        partial.replace(path)
    return [str(path) for path in results]


def run_job(job: Dict[str, Any], options: Dict[str, Any]) -> List[str]:
    """
    Trains one job and writes each of its algorithms' result file.

    :param job: an entry of :func:`make_jobs`
    :param options: :func:`train_job`'s
    :return: the result files written
    """
    return write_results(train_job(job, options))


def run_grid(jobs: List[Dict[str, Any]], options: Dict[str, Any], workers: int = 1, ray_address: Optional[str] = None) -> None:
    """
    Runs the jobs one after another, in ``workers`` local processes, or as Ray tasks on the cluster at ``ray_address``.

    :param jobs: :func:`make_jobs`'s entries
    :param options: :func:`train_job`'s options
    :param workers: local processes
    :param ray_address: a Ray cluster's address (``auto`` for the local one)
    """
    jobs = [job for job in jobs if not all(path.exists() for path in job_paths(job, options).values())]
    print(f"{len(jobs)} runs to do", flush=True)
    if not jobs:
        return
    if ray_address is not None:
        run_on_ray(jobs, options, ray_address)
    elif workers > 1:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            for paths in pool.map(run_job, jobs, [options] * len(jobs)):
                print("wrote", *paths, flush=True)
    else:
        for job in jobs:
            print("wrote", *run_job(job, options), flush=True)


def run_on_ray(jobs: List[Dict[str, Any]], options: Dict[str, Any], address: str) -> None:
    """
    Runs the jobs as Ray tasks of ``options["threads"]`` CPUs each on the cluster at ``address``, and writes each
    result here as its task finishes: the nodes need sb3-mpail installed, and get this ``benchmarks`` package (with its
    configs and BC's action demos) from the driver; a ``config_dir`` must be readable at the same path on every node.

    :param jobs: :func:`make_jobs`'s entries
    :param options: :func:`train_job`'s options
    :param address: the cluster's address (``auto`` for the one running on this machine)
    """
    try:
        import ray
    except ImportError as error:
        raise SystemExit("--ray-address needs Ray, which is not installed: pip install -e '.[ray]'.") from error
    if options["config_dir"] is not None:  # tasks run in folders of Ray's own
        options = dict(options, config_dir=Path(options["config_dir"]).resolve())
    # the tasks are this module's functions, which Ray's workers import by name: the package travels with them
    ray.init(address=address, runtime_env=dict(py_modules=[str(Path(__file__).resolve().parent)]))
    try:
        remote = ray.remote(num_cpus=options["threads"])(train_job)
        pending = [remote.remote(job, options) for job in jobs]
        while pending:
            finished, pending = ray.wait(pending)
            print("wrote", *write_results(ray.get(finished[0])), flush=True)
    finally:
        ray.shutdown()


# --------------------------------------------------------------------------------------------------------------------
# tables and figures


def load_results(results_dir: Path, name: str) -> List[Dict[str, Any]]:
    """
    Every result of one grid.

    :param results_dir: the grid's folder
    :param name: :func:`grid_name`
    """
    return [json.loads(path.read_text()) for path in sorted((Path(results_dir) / name).glob("*.json"))]


#: marks the rows with runs trained under other hyperparameters than their algorithm's file holds now
EARLIER_SETTINGS_NOTE = (
    "‡: runs trained with an earlier entry of their algorithm's hyperparameter file than it holds now (their stored "
    "`hyperparams` differ); the runner skips finished runs, so delete their result files to train them again."
)


def comparable_settings(hyperparams: Dict[str, Any]) -> Dict[str, Any]:
    """Hyperparameters as a result file stores them, less the demo set, which each run names for itself."""
    settings = json.loads(json.dumps(hyperparams, default=str))
    for entry in (settings, settings.get("gail")):
        if isinstance(entry, dict):
            entry.pop("demos", None)
    return settings


def trained_with_earlier_settings(run: Dict[str, Any], config_dir: Optional[Path] = None) -> bool:
    """
    Whether a stored run's hyperparameters differ from its algorithm's entry now (or the entry is gone). A GAIL run
    that IRL-MPC shared stores IRL-MPC's entry, GAIL's inside it.

    :param run: a result (:func:`load_results`)
    :param config_dir: the folder of the hyperparameter files (``None``: the shipped ones)
    """
    stored = run["hyperparams"]
    if run["algo"] == "gail":
        stored = stored.get("gail", stored)
    try:
        entry = load_config(run["algo"], run["env_id"], config_dir)
    except ValueError:
        return True
    return comparable_settings(stored) != comparable_settings(entry)


def seeds_cell(runs: Sequence[Dict[str, Any]], n_seeds: Optional[int], config_dir: Optional[Path] = None) -> str:
    """
    A table's seeds cell: the runs done (of those asked for, marked incomplete when fewer), and how many of them were
    trained with earlier settings (:data:`EARLIER_SETTINGS_NOTE`).

    :param runs: the row's results
    :param n_seeds: seeds asked for (``None``: only the count)
    :param config_dir: the folder of the hyperparameter files (``None``: the shipped ones)
    """
    done = f"{len(runs)}"
    if n_seeds is not None:
        done += f"/{n_seeds}" + ("" if len(runs) >= n_seeds else " **incomplete**")
    earlier = sum(trained_with_earlier_settings(run, config_dir) for run in runs)
    return done + (f" ({earlier} ‡)" if earlier else "")


def steps_summary(runs: Sequence[Dict[str, Any]]) -> str:
    """
    Env steps to reach a normalised score of 0.9: the median over the seeds that reached it, and how many did.

    :param runs: results of one algorithm, env and demo count
    """
    reached = [run["steps_to_target"] for run in runs if run["steps_to_target"] is not None]
    if not reached:
        return f"not reached (0/{len(runs)})"
    return f"{int(np.median(reached))} ({len(reached)}/{len(runs)})"


def grid_table(
    results: List[Dict[str, Any]], env_id: str, algos: Sequence[str], demos: Sequence[int], n_seeds: int,
    config_dir: Optional[Path] = None,
) -> str:  # fmt: skip
    """
    The markdown table of one env: per algorithm and demo count, seeds done, final normalised score mean and 95% CI,
    env steps to 0.9.

    :param results: :func:`load_results`
    :param env_id: gymnasium id
    :param algos: rows
    :param demos: demo counts
    :param n_seeds: seeds asked for (cells with fewer are marked incomplete)
    :param config_dir: the folder of the hyperparameter files the runs are checked against (``None``: the shipped ones)
    """
    lines = ["| algorithm | demos | seeds | normalised score (mean ± 95% CI) | env steps to 0.9: median (seeds reached) |",
             "|---|---|---|---|---|"]  # fmt: skip
    for algo in algos:
        for n_demos in demos:
            runs = [r for r in results if r["env_id"] == env_id and r["algo"] == algo and r["n_demos"] == n_demos]
            done = seeds_cell(runs, n_seeds, config_dir)
            if not runs:
                lines.append(f"| {ALGO_LABELS[algo]} | {n_demos} | {done} | not run | not run |")
                continue
            score = format_ci(*mean_ci([run["final_score"] for run in runs]))
            lines.append(f"| {ALGO_LABELS[algo]} | {n_demos} | {done} | {score} | {steps_summary(runs)} |")
    return "\n".join(lines)


def expert_pose_gaussian(demo_set: str, n_demos: int) -> Tuple[np.ndarray, np.ndarray]:
    """
    The Gaussian fitted to the expert's poses ``(x, y, cos yaw, sin yaw)`` in the demos, for the paper's OOD energy
    ``log p_E(s)`` (its appendix, after Liu et al. 2020). The pose rather than the whole state: the car starts at rest,
    and the expert's height and body rates are constant or nearly so, which leaves their covariance singular.

    :param demo_set: the shipped demo sets' prefix
    :param n_demos: demo count
    :return: the mean ``(4,)`` and covariance ``(4, 4)``
    """
    states = np.concatenate([trajectory.obs for trajectory in shipped_demos(demo_set, n_demos)])
    poses = np.stack([states[:, 0], states[:, 1], np.cos(states[:, 5]), np.sin(states[:, 5])], axis=1)
    return poses.mean(axis=0), np.cov(poses, rowvar=False) + 1e-6 * np.eye(4)


def ood_energy(start_poses: np.ndarray, gaussian: Tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """
    ``log p_E`` of each start pose ``(x, y, yaw)`` under :func:`expert_pose_gaussian`: near 0 or above in
    distribution, very negative far out of it.
    """
    mean, covariance = gaussian
    poses = np.stack([start_poses[:, 0], start_poses[:, 1], np.cos(start_poses[:, 2]), np.sin(start_poses[:, 2])], axis=1)
    offsets = poses - mean
    mahalanobis = np.einsum("ni,ij,nj->n", offsets, np.linalg.inv(covariance), offsets)
    return -0.5 * (mahalanobis + np.log(np.linalg.det(2 * np.pi * covariance)))


def ood_episodes(predictor: Any, n_episodes: int, seed: int = OOD_SEED) -> Episodes:
    """
    The paper's OOD test of a navigation agent: ``n_episodes`` deterministic 100-step episodes from starts uniform in
    the 40 x 40 m box with uniform heading (env ``i`` reset with ``seed + i``, the same starts for every agent), with
    their observations.

    :param predictor: anything SB3's ``predict`` works on
    :param n_episodes: episodes
    :param seed: seed of the first start
    """
    return evaluate_episodes(predictor, NAVIGATION, n_episodes, seed, env_kwargs=dict(start_region="ood"),
                             record_observations=True)  # fmt: skip


def ood_record(episodes: Episodes) -> Dict[str, Any]:
    """
    What a result keeps of :func:`ood_episodes`: per episode the start pose ``(x, y, yaw)``, the final position, the
    final reward and whether it ends circling, and the share of episodes ending within :data:`GOAL_RADIUS` and
    their mean final reward.
    """
    record = dict(
        start_poses=[[float(obs[0][0]), float(obs[0][1]), float(obs[0][5])] for obs in episodes.observations],
        final_positions=[[float(obs[-1][0]), float(obs[-1][1])] for obs in episodes.observations],
        final_rewards=[REWARD_OFFSET - info["distance_to_goal"] for info in episodes.final_infos],
        circling=[bool(np.abs(obs[len(obs) // 2 :, 11]).mean() > CIRCLING_YAW_RATE) for obs in episodes.observations],
    )
    measures = ood_measures(record)  # one definition of reaching the goal
    return dict(record, reached=measures["reached"], mean_final_reward=measures["final_reward"])


class GoalDistance(th.nn.Module):
    """The navigation reward as a step cost: the next position's distance to the goal (minus the reward, plus a constant)."""

    def forward(self, states: th.Tensor, next_states: th.Tensor) -> th.Tensor:
        return th.linalg.vector_norm(next_states[..., :2] - next_states.new_tensor(GOAL), dim=-1)


class GoalValue(th.nn.Module):
    """A terminal value for the true reward: ``-TRUE_VALUE_SLOPE`` times the distance to the goal."""

    def forward(self, states: th.Tensor) -> th.Tensor:
        return -TRUE_VALUE_SLOPE * th.linalg.vector_norm(states[..., :2] - states.new_tensor(GOAL), dim=-1)


def true_reward_record(n_episodes: int, results_dir: Path = RESULTS_DIR) -> Dict[str, Any]:
    """
    The ceiling of every navigation OOD table: the main command's planner (its ``policy_kwargs``, untrained) planning
    on the true reward (:class:`GoalDistance` step costs, :class:`GoalValue` terminal value) instead of a learned one,
    on the same :func:`ood_episodes` starts. Kept in ``<results-dir>/navigation_true_reward/<n>starts.json``, computed
    again when the main command's planner settings or the starts' seed have changed since.

    :param n_episodes: OOD episodes, as many as the table's runs drove
    :param results_dir: where the record is kept
    """
    path = Path(results_dir) / "navigation_true_reward" / f"{n_episodes}starts.json"
    settings = dict(planner=repr(sorted(DEFAULT_POLICY_KWARGS.items())), ood_seed=OOD_SEED, value_slope=TRUE_VALUE_SLOPE,
                    deterministic_noise=DETERMINISTIC_NOISE)  # fmt: skip
    stored = json.loads(path.read_text()) if path.exists() else {}
    if stored.get("settings") == settings:
        return stored
    planner = make_model(n_envs=1, policy_kwargs=dict(step_cost=GoalDistance(), terminal_value=GoalValue()))
    record = dict(ood_record(ood_episodes(planner, n_episodes)), settings=settings)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record))
    return record


def ood_measures(record: Dict[str, Any]) -> Dict[str, float]:
    """
    One run's OOD figures: the fraction of episodes ending within :data:`GOAL_RADIUS` of the goal (all, and among the
    starts any policy can reach: within ``MAX_TRAVEL + GOAL_RADIUS``), the mean final reward and the mean progress
    ``(start distance - final distance) / start distance``, and the shares of episodes ending in a circle, anywhere
    and farther than :data:`CIRCLING_AWAY` from the goal. Records without start poses give only the first and the
    third.

    :param record: a result's ``ood`` entry
    """
    final_rewards = np.asarray(record["final_rewards"])
    final_distances = REWARD_OFFSET - final_rewards
    measures = dict(reached=float(np.mean(final_distances < GOAL_RADIUS)), final_reward=float(final_rewards.mean()))
    if "start_poses" in record:
        start_distances = np.linalg.norm(np.asarray(record["start_poses"])[:, :2] - GOAL, axis=1)
        reachable = start_distances <= MAX_TRAVEL + GOAL_RADIUS
        measures["reached_reachable"] = float(np.mean(final_distances[reachable] < GOAL_RADIUS))
        measures["progress"] = float(np.mean((start_distances - final_distances) / start_distances))
    if "circling" in record:
        circling = np.asarray(record["circling"], dtype=bool)
        measures["circling"] = float(circling.mean())
        measures["circling_away"] = float(np.mean(circling & (final_distances > CIRCLING_AWAY)))
    return measures


def ood_table(
    results: List[Dict[str, Any]], algos: Sequence[str], n_demos: int, ceiling: Optional[Dict[str, Any]] = None,
    config_dir: Optional[Path] = None,
) -> str:  # fmt: skip
    """
    The navigation OOD table: per algorithm, :func:`ood_measures`' means over seeds with their 95% CIs.

    :param results: :func:`load_results`
    :param algos: rows
    :param n_demos: demo count
    :param ceiling: :func:`true_reward_record` on the same starts, the last row
    :param config_dir: the folder of the hyperparameter files the runs are checked against (``None``: the shipped ones)
    """
    columns = ("reached_reachable", "reached", "final_reward", "progress", "circling_away")
    lines = [
        f"| algorithm | seeds | ends within {GOAL_RADIUS:g} m of goal, reachable starts | ... all starts | mean final reward "
        f"| mean progress | ends circling farther than {CIRCLING_AWAY:g} m from the goal |",
        "|---|---|---|---|---|---|---|",
    ]
    for algo in algos:
        runs = [
            r for r in results if r["env_id"] == NAVIGATION and r["algo"] == algo and r["n_demos"] == n_demos and "ood" in r
        ]
        if not runs:
            lines.append(f"| {ALGO_LABELS[algo]} | 0 |" + " not run |" * len(columns))
            continue
        measures = [ood_measures(run["ood"]) for run in runs]
        cells = [format_ci(*mean_ci([m[c] for m in measures])) if all(c in m for m in measures) else "–" for c in columns]
        lines.append(f"| {ALGO_LABELS[algo]} | {seeds_cell(runs, None, config_dir)} | " + " | ".join(cells) + " |")
    if ceiling is not None:
        measures = ood_measures(ceiling)
        lines.append(f"| {TRUE_REWARD_LABEL} | – | " + " | ".join(f"{measures[c]:.2f}" for c in columns) + " |")
    return "\n".join(lines)


def scenario_of(env_id: str) -> Optional[Tuple[str, Scenario]]:
    """The name and :class:`~benchmarks.scenarios.Scenario` of ``benchmarks/scenarios.py`` that trains on ``env_id``."""
    return next(((name, scenario) for name, scenario in SCENARIOS.items() if scenario.env_id == env_id), None)


def stored_scenario_runs(name: str) -> Optional[Dict[str, Any]]:
    """MPAIL's runs of a scenario from ``benchmarks/scenarios.py`` (its ``scenarios.json`` entry), or ``None``."""
    return json.loads(SCENARIO_RESULTS.read_text()).get(name) if SCENARIO_RESULTS.exists() else None


def scenario_table(results: List[Dict[str, Any]], name: str, scenario: Scenario, algos: Sequence[str],
                   demos: Sequence[int], n_seeds: int, scenario_mpail: bool = True) -> str:  # fmt: skip
    """
    A scenario's own figures (success and crashes, share of steps on the road, ...) per algorithm and demo count, as
    ``benchmarks/scenarios.py`` measures MPAIL's, mean ± 95% CI over seeds.

    :param results: :func:`load_results` of the grid
    :param name: the scenario's key in :data:`~benchmarks.scenarios.SCENARIOS`
    :param scenario: the scenario
    :param algos: rows
    :param demos: demo counts
    :param n_seeds: seeds asked for (rows with fewer are marked incomplete)
    :param scenario_mpail: when the grid has no MPAIL runs, add MPAIL's from ``benchmarks/scenarios.py`` (the zoo
        entry's budget); so not for grids with ``--timesteps``
    """
    titles = " | ".join(title for _, title in scenario.columns)
    lines = [f"| algorithm | demos | seeds | {titles} | source |", "|---|---|---|" + "---|" * len(scenario.columns) + "---|"]
    rows = []
    for algo in algos:
        for n_demos in demos:
            runs = [r["scenario_figures"] for r in results if r["algo"] == algo and r["n_demos"] == n_demos
                    and "scenario_figures" in r]  # fmt: skip
            done = f"{len(runs)}/{n_seeds}" + ("" if len(runs) >= n_seeds else " **incomplete**")
            rows.append((ALGO_LABELS[algo], n_demos, done, runs, "this grid"))
    stored = stored_scenario_runs(name) if scenario_mpail and not any(r["algo"] == "mpail" for r in results) else None
    if stored is not None:
        n_demos = int(zoo_hyperparameters(scenario.env_id)["demos"].rsplit("_", 1)[1])
        rows.insert(0, (ALGO_LABELS["mpail"], n_demos, str(len(stored["runs"])), stored["runs"], f"`{stored['command']}`"))
    for label, n_demos, done, runs, source in rows:
        cells = [format_ci(*mean_ci([run[key] for run in runs]), digits=3) if runs else "not run"
                 for key, _ in scenario.columns]  # fmt: skip
        lines.append(f"| {label} | {n_demos} | {done} | {' | '.join(cells)} | {source} |")
    return "\n".join(lines)


def lap_table(
    results: List[Dict[str, Any]], algos: Sequence[str], demos: Sequence[int], n_seeds: int, scenario_mpail: bool = True
) -> str:
    """
    The lap's markdown table: per algorithm and demo count, the cross-track error to the demo's path (mean and max
    over the laps) and the mean speed, per seed and as mean ± std over seeds.

    :param results: :func:`load_results` of the lap grid
    :param algos: rows
    :param demos: demo counts
    :param n_seeds: seeds asked for (cells with fewer are marked incomplete)
    :param scenario_mpail: when the grid has no MPAIL runs, add MPAIL's from ``benchmarks/scenarios.py``'s lap run
        (same laps, same measure, ``sb3_mpail/hyperparams/mpail.yml``'s budget); so not for grids with ``--timesteps``
    """
    lines = ["| algorithm | demos | seeds | mean cross-track error (m) | max cross-track error (m) | speed (m/s) | source |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    rows: List[Tuple[str, int, str, List[Dict[str, float]], str]] = []
    for algo in algos:
        for n_demos in demos:
            runs = sorted((r for r in results if r["algo"] == algo and r["n_demos"] == n_demos), key=lambda r: r["seed"])
            done = f"{len(runs)}/{n_seeds}" + ("" if len(runs) >= n_seeds else " **incomplete**")
            rows.append((ALGO_LABELS[algo], n_demos, done, [run["lap"] for run in runs], "this grid"))
    scenario = stored_scenario_runs("lap") if scenario_mpail and not any(r["algo"] == "mpail" for r in results) else None
    if scenario is not None:
        runs = sorted(scenario["runs"], key=lambda run: run["seed"])
        rows.insert(0, (ALGO_LABELS["mpail"], 1, str(len(runs)), runs, f"`{scenario['command']}`"))
    for label, n_demos, done, figures, source in rows:
        if not figures:
            lines.append(f"| {label} | {n_demos} | {done} | not run | not run | not run | {source} |")
            continue
        cells = []
        for key in LAP_FIGURES:
            values = [run[key] for run in figures]
            cells.append(f"**{np.mean(values):.3f} ± {np.std(values):.3f}** ({', '.join(f'{v:.3f}' for v in values)})")
        lines.append(f"| {label} | {n_demos} | {done} | {' | '.join(cells)} | {source} |")
    return "\n".join(lines)


def plot_curves(results: List[Dict[str, Any]], env_id: str, n_demos: int, path: Path) -> Optional[Path]:
    """
    Normalised score against env steps per algorithm: the mean over seeds and a band of ± one standard deviation
    (BC, which takes no env steps, as a dashed line at its final score).

    :param results: :func:`load_results`
    :param env_id: gymnasium id
    :param n_demos: demo count
    :param path: the PNG to write
    :return: the path, or ``None`` when there is nothing to plot
    """
    from sb3_mpail.plotting import import_pyplot, save_figure

    runs = [r for r in results if r["env_id"] == env_id and r["n_demos"] == n_demos]
    if not runs:
        return None
    plt = import_pyplot()
    figure, axis = plt.subplots(figsize=(8, 5), constrained_layout=True)
    budget = max(r["n_timesteps"] for r in runs)
    for index, algo in enumerate(ALGOS):
        curves = [np.asarray(r["curve"], dtype=float) for r in runs if r["algo"] == algo]
        if not curves:
            continue
        color, label = f"C{index}", f"{ALGO_LABELS[algo]} ({len(curves)} seeds)"
        if algo == "bc":
            axis.axhline(np.mean([c[-1, 1] for c in curves]), color=color, ls="--", label=label)
            continue
        steps = curves[0][:, 0]
        scores = np.stack([np.interp(steps, c[:, 0], c[:, 1]) for c in curves])
        mean, spread = scores.mean(0), scores.std(0)
        axis.plot(steps, mean, color=color, lw=2, label=label)
        axis.fill_between(steps, mean - spread, mean + spread, color=color, alpha=0.2)
    axis.axhline(TARGET, color="r", ls=":", lw=1, label=f"target {TARGET}")
    axis.set_xlim(0, max(budget, 1))
    axis.set_xlabel("env steps")
    axis.set_ylabel("normalised score (mean ± std over seeds)")
    axis.set_title(f"{env_id}, {n_demos} demos")
    axis.grid(alpha=0.3)
    axis.legend(loc="best", fontsize=8)
    return save_figure(figure, path)


def plot_lap_curves(results: List[Dict[str, Any]], path: Path, scenario_mpail: bool = True) -> Optional[Path]:
    """
    The lap's mean cross-track error against env steps, one line per seed of each algorithm (log scale: a run that
    leaves the track is metres off, one that follows it centimetres).

    :param results: :func:`load_results` of the lap grid
    :param path: the PNG to write
    :param scenario_mpail: when the grid has no MPAIL runs, draw the final figures of MPAIL's scenario runs (no
        curve is kept for them) as dashed lines at their budget
    :return: the path, or ``None`` when there is nothing to plot
    """
    from sb3_mpail.plotting import import_pyplot, save_figure

    if not results:
        return None
    plt = import_pyplot()
    figure, axis = plt.subplots(figsize=(8, 5), constrained_layout=True)
    for index, algo in enumerate(ALGOS):
        runs = sorted((r for r in results if r["algo"] == algo), key=lambda r: r["seed"])
        for run in runs:
            curve = np.asarray(run["curve"], dtype=float)
            label = f"{ALGO_LABELS[algo]} ({len(runs)} seeds)" if run is runs[0] else None
            axis.plot(curve[:, 0], curve[:, 1], color=f"C{index}", marker="o", ms=3, label=label)
    scenario = stored_scenario_runs("lap") if scenario_mpail and not any(r["algo"] == "mpail" for r in results) else None
    if scenario is not None:
        for run in scenario["runs"]:
            label = f"{ALGO_LABELS['mpail']} after {scenario['timesteps']} steps ({len(scenario['runs'])} seeds, scenarios.py)"
            axis.axhline(run["cte_mean"], color="C0", ls="--", lw=1, label=label if run is scenario["runs"][0] else None)
    axis.set_yscale("log")
    axis.set_xlabel("env steps")
    axis.set_ylabel(f"mean cross-track error over {SCENARIOS['lap'].n_eval_episodes} laps (m)")
    axis.set_title(f"{LAP}, one seed per line")
    axis.grid(alpha=0.3)
    axis.legend(loc="best", fontsize=8)
    return save_figure(figure, path)


def plot_ood(
    results: List[Dict[str, Any]],
    algos: Sequence[str],
    n_demos: int,
    path: Path,
    gaussian: Optional[Tuple[np.ndarray, np.ndarray]] = None,
) -> Optional[Path]:
    """
    Final positions of the navigation OOD episodes (starts uniform in the 40 x 40 m box), one panel per algorithm,
    every seed pooled, coloured by the final reward; the goal and its 2 m circle. With the expert's pose Gaussian
    and start poses recorded, a last panel draws the final reward against the start's OOD energy (the paper's OOD
    figure): per algorithm, the mean over the starts of each energy bin.

    :param results: :func:`load_results`
    :param algos: panels
    :param n_demos: demo count
    :param path: the PNG to write
    :param gaussian: :func:`expert_pose_gaussian`, or ``None`` for no energy panel
    :return: the path, or ``None`` when there is nothing to plot
    """
    from sb3_mpail.plotting import import_pyplot, save_figure

    panels = [(a, [r for r in results if r["env_id"] == NAVIGATION and r["algo"] == a and r["n_demos"] == n_demos
                   and "ood" in r]) for a in algos]  # fmt: skip
    panels = [(algo, runs) for algo, runs in panels if runs]
    if not panels:
        return None
    energy_runs = [(algo, runs) for algo, runs in panels if all("start_poses" in r["ood"] for r in runs)]
    with_energy = gaussian is not None and bool(energy_runs)
    plt = import_pyplot()
    n_axes = len(panels) + with_energy
    figure, axes = plt.subplots(1, n_axes, figsize=(4 * n_axes, 4.3), constrained_layout=True, squeeze=False)
    for axis, (algo, runs) in zip(axes[0], panels):
        positions = np.concatenate([np.asarray(r["ood"]["final_positions"]) for r in runs])
        rewards = np.concatenate([np.asarray(r["ood"]["final_rewards"]) for r in runs])
        points = axis.scatter(positions[:, 0], positions[:, 1], c=rewards, s=8, cmap="viridis", vmin=-20, vmax=REWARD_OFFSET)
        axis.add_patch(plt.Rectangle((-20, -20), 40, 40, fill=False, ls="--", color="0.5"))
        axis.add_patch(plt.Circle((10, 10), GOAL_RADIUS, fill=False, color="r"))
        axis.plot(10, 10, "r*", ms=12)
        axis.set(xlim=(-30, 30), ylim=(-30, 30), aspect="equal", title=f"{ALGO_LABELS[algo]}\n{len(runs)} seeds")
    figure.colorbar(points, ax=axes[0][: len(panels)].tolist(), label="final reward")
    if with_energy:
        axis = axes[0][-1]
        energies = {algo: np.concatenate([ood_energy(np.asarray(r["ood"]["start_poses"]), gaussian) for r in runs])
                    for algo, runs in energy_runs}  # fmt: skip
        edges = np.quantile(np.concatenate(list(energies.values())), np.linspace(0, 1, 9))
        for algo, runs in energy_runs:
            rewards = np.concatenate([np.asarray(r["ood"]["final_rewards"]) for r in runs])
            bins = np.clip(np.digitize(energies[algo], edges[1:-1]), 0, len(edges) - 2)
            centres = [energies[algo][bins == b].mean() for b in range(len(edges) - 1) if np.any(bins == b)]
            means = [rewards[bins == b].mean() for b in range(len(edges) - 1) if np.any(bins == b)]
            axis.plot(centres, means, "o-", label=ALGO_LABELS[algo].split(" (")[0])
        axis.set(xlabel="OOD energy log p_E(start pose)  (higher: closer to the demos)", ylabel="mean final reward",
                 title="final reward against OOD energy")  # fmt: skip
        axis.axhline(REWARD_OFFSET - GOAL_RADIUS, color="r", ls=":", lw=1)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    return save_figure(figure, path)


def write_report(
    results_dir: Path,
    envs: Sequence[str],
    algos: Sequence[str],
    demos: Sequence[int],
    n_seeds: int,
    command: str,
    timesteps: Optional[int] = None,
    report_file: Path = BENCHMARKS_FILE,
    figures_dir: Path = FIGURES_DIR,
    config_dir: Optional[Path] = None,
) -> None:
    """
    Writes one BENCHMARKS.md section per env grid (``baselines-<grid name>``; navigation also
    ``baselines-<grid name>-ood``) and the figures, from every result of the grid found: its rows are the algorithms
    and demo counts asked for and any others with stored results.

    :param results_dir: the grid's folder
    :param envs: env ids or short names
    :param algos: table rows (at least)
    :param demos: demo counts (at least)
    :param n_seeds: seeds asked for (at least)
    :param command: the command line to quote
    :param timesteps: the budget override, or ``None``
    :param report_file: the markdown file
    :param figures_dir: folder of the figures
    :param config_dir: the folder of the hyperparameter files the runs are checked against (``None``: the shipped ones)
    """
    for env in envs:
        demo_set, env_id = grid_of(env)
        name, stats = grid_name(demo_set, timesteps), shipped_demo_info(demo_set)
        results = load_results(results_dir, name)
        # every stored result of the grid, not only the runs asked for now: a partial rerun keeps the other rows
        grid_algos = [algo for algo in ALGOS if algo in algos or any(r["algo"] == algo for r in results)]
        grid_demos = sorted(set(demos) | {r["n_demos"] for r in results})
        grid_seeds = max([n_seeds] + [r["seed"] + 1 for r in results])
        if env_id == LAP:
            section = lap_report(results, stats, grid_algos, grid_demos, grid_seeds, command, scenario_mpail=timesteps is None)
            figure = plot_lap_curves(results, figures_dir / f"baselines_{name}.png", scenario_mpail=timesteps is None)
            if figure is not None:
                section += f"\n\n![{env_id}](benchmarks/figures/{figure.name})"
            write_section(f"baselines-{name}", section, report_file)
            continue
        budgets = {algo: sorted({r["n_timesteps"] for r in results if r["algo"] == algo}) for algo in grid_algos}
        figures = [plot_curves(results, env_id, n, figures_dir / f"baselines_{name}_{n}demos.png") for n in grid_demos]
        lines = [
            f"## Baselines on {env_id}" + ("" if demo_set == env_name_of(env_id) else f", demos {demo_set}_<n>")
            + ("" if timesteps is None else f" ({timesteps} env steps)"),
            "",
            f"Normalised score = (R - random) / (expert - random), random {stats['random_return_mean']:.1f}, expert "
            f"{stats['expert_return_mean']:.1f} ({stats['expert_algo']}); final deterministic evaluation on "
            f"episodes from fixed seeds; mean ± 95% CI (Student's t) over seeds. Env-step budgets: "
            + ", ".join(f"{ALGO_LABELS[a]} {'/'.join(map(str, budgets[a])) or '-'}" for a in grid_algos)
            + " (zoo_configs/<algo>.yml, MPAIL's sb3_mpail/hyperparams/mpail.yml, unless `--timesteps` overrides "
            "them). BC uses the expert's actions and no env "
            "steps; IRL-MPC's env steps are its GAIL run's. Learning curves are evaluated once the env-step count passes "
            "each multiple of `--eval-every` (default a tenth of the budget), after whole rollouts or rounds, so env "
            "steps to 0.9 are resolved to that grid.",
            "",
            grid_table(results, env_id, grid_algos, grid_demos, grid_seeds, config_dir),
            "",
        ]
        earlier = any(trained_with_earlier_settings(run, config_dir) for run in results if run["algo"] in grid_algos)
        lines += [EARLIER_SETTINGS_NOTE, ""] if earlier else []
        for n_demos in grid_demos:
            mpail, gail = ([r for r in results if r["env_id"] == env_id and r["algo"] == a and r["n_demos"] == n_demos]
                           for a in ("mpail", "gail"))  # fmt: skip
            if mpail and gail:
                lines.append(f"MPAIL vs GAIL, {n_demos} demos, env steps to 0.9: MPAIL {steps_summary(mpail)}, "
                             f"GAIL {steps_summary(gail)}.")  # fmt: skip
        scenario = scenario_of(env_id)
        if scenario is not None and any("scenario_figures" in r for r in results):
            table = scenario_table(results, *scenario, grid_algos, grid_demos, grid_seeds, timesteps is None)
            lines += [f"The scenario's own figures, measured as `benchmarks/scenarios.py` measures MPAIL's "
                      f"({scenario[1].n_eval_episodes} episodes per seed); mean ± 95% CI over seeds:", "", table,
                      ""]  # fmt: skip
        lines += [""] + [f"![{env_id}](benchmarks/figures/{figure.name})" for figure in figures if figure is not None]
        lines += ["", f"{command_line(results, command)} on {machines_of(results)}."]
        write_section(f"baselines-{name}", "\n".join(lines), report_file)
        if env_id == NAVIGATION and any("ood" in r for r in results):
            n_ood = 4 if 4 in grid_demos else grid_demos[0]
            gaussian = expert_pose_gaussian(demo_set, n_ood)
            n_ood_starts = max(len(r["ood"]["final_rewards"]) for r in results if "ood" in r)
            figure = plot_ood(results, grid_algos, n_ood, figures_dir / f"baselines_{name}_ood.png", gaussian)
            ood = [
                "## Navigation out of distribution" + ("" if demo_set == "navigation" else f", demos {demo_set}_<n>")
                + ("" if timesteps is None else f" ({timesteps} env steps)"),
                "",
                f"Agents trained on {n_ood} demos (starts within 1 m of the origin), run deterministically for 100 steps "
                "from starts uniform in the 40 x 40 m box centred at the origin with uniform heading (env option "
                f"`start_region='ood'`, seeds {OOD_SEED}+, the same starts for every algorithm). Goal reached = the "
                f"episode ends within {GOAL_RADIUS:.0f} m of (10, 10); reachable starts: within "
                f"{MAX_TRAVEL + GOAL_RADIUS:g} m of it (farther, no policy arrives in 100 steps at the 3 m/s top speed); "
                "final reward = sqrt(200) - final distance; progress = (start distance - final distance) / start "
                "distance. Means ± 95% CI (Student's t) over seeds. OOD energy: the log-density of the start pose "
                "(x, y, cos yaw, sin yaw) under a Gaussian fitted to the expert's poses (the paper's appendix). "
                f"{TRUE_REWARD_NOTE}",
                "",
                ood_table(results, grid_algos, n_ood, true_reward_record(n_ood_starts, results_dir), config_dir),
                "",
            ]
            ood += [EARLIER_SETTINGS_NOTE, ""] if earlier else []
            if figure is not None:
                ood.append(f"![final positions](benchmarks/figures/{figure.name})")
            ood += ["", f"{command_line([r for r in results if 'ood' in r], command)}."]
            write_section(f"baselines-{name}-ood", "\n".join(ood), report_file)


def command_line(results: List[Dict[str, Any]], command: str) -> str:
    """
    The commands that made a grid's results (:func:`~benchmarks.report.commands_of`).

    :param results: :func:`load_results`'s
    :param command: this invocation's command, quoted for results that predate the record
    :return: ``Command: `...``` or ``Commands: `...`; `...```
    """
    commands = commands_of(results, command) or [command]
    return ("Command: " if len(commands) == 1 else "Commands: ") + "; ".join(f"`{c}`" for c in commands)


def lap_report(
    results: List[Dict[str, Any]],
    stats: Dict[str, Any],
    algos: Sequence[str],
    demos: Sequence[int],
    n_seeds: int,
    command: str,
    scenario_mpail: bool = True,
) -> str:
    """
    The lap's BENCHMARKS.md section: :func:`lap_table` with the budgets, the demo's driver and the command.

    :param results: :func:`load_results` of the lap grid
    :param stats: the lap demos' information (``shipped_demo_info("lap")``)
    :param algos: table rows
    :param demos: demo counts
    :param n_seeds: seeds asked for
    :param command: the command line to quote
    :param scenario_mpail: :func:`lap_table`'s
    """
    budgets = sorted({r["n_timesteps"] for r in results})
    driver = stats["driver_on_eval_laps"]
    return "\n".join([
        f"## Baselines on {LAP}: MPAIL vs GAIL on one lap from a single noisy partial demo",
        "",
        "The demo holds only x, y and the body-frame velocity (0.05 m / 0.05 m/s sensor noise); every discriminator "
        "sees only those 4 dimensions of s and s' (GAIL: reward_net_kwargs `features=[0, 1, 6, 7]`, PPO generator on "
        "the full state). Deterministic agent after the budget ("
        + "/".join(map(str, budgets or ["-"]))
        + f" env steps), driven for {SCENARIOS['lap'].n_eval_episodes} laps (reset seeds {EVAL_SEED}+, the laps "
        "`benchmarks/scenarios.py` measures MPAIL on); cross-track error to the demo's recorded path over every step "
        "of every lap, mean planar speed. Mean ± std over seeds (per seed in brackets). The demo's driver on the same "
        f"laps: {driver['cte_mean']:.3f} m mean, {driver['cte_max']:.3f} m max, {driver['speed']:.2f} m/s.",
        "",
        lap_table(results, algos, demos, n_seeds, scenario_mpail),
        "",
        f"{command_line(results, command)} on {machines_of(results)}.",
    ])  # fmt: skip


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=["navigation", "pendulum"], help="env ids or short names")
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS)
    parser.add_argument("--demos", nargs="+", type=int, default=[4], help="demo counts (shipped demo sets <env>_<n>)")
    parser.add_argument("--seeds", type=int, default=5, help="seeds 0 .. n-1")
    parser.add_argument("--workers", type=int, default=1, help="local processes")
    parser.add_argument("--ray-address", default=None, help="run on this Ray cluster instead ('auto': the local one)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads per run")
    parser.add_argument("--eval-episodes", type=int, default=10, help="episodes per learning-curve point")
    parser.add_argument("--eval-every", type=int, default=0, help="env steps between curve points (0: a tenth of the budget)")
    parser.add_argument("--ood-episodes", type=int, default=100, help="navigation OOD episodes per run (0: none)")
    parser.add_argument("--timesteps", type=int, default=None, help="override every budget (a separate grid and report)")
    parser.add_argument(
        "--config-dir", type=Path, default=None, help="a folder of every algorithm's <algo>.yml (default: the shipped ones)"
    )
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    parser.add_argument("--report-file", type=Path, default=BENCHMARKS_FILE)
    parser.add_argument("--figures-dir", type=Path, default=FIGURES_DIR)
    parser.add_argument("--report-only", action="store_true", help="only write the tables and figures of existing results")
    return parser.parse_args(argv)


def main(argv: Optional[Sequence[str]] = None) -> None:
    """
    Runs the grid (skipping finished runs) and writes the report.

    :param argv: command-line arguments
    """
    args = parse_args(argv)
    th.set_num_threads(args.threads)  # the runs' setting, also quoted in the report
    options = dict(results_dir=args.results_dir, config_dir=args.config_dir, eval_episodes=args.eval_episodes,
                   eval_every=args.eval_every, ood_episodes=args.ood_episodes, timesteps=args.timesteps,
                   threads=args.threads)  # fmt: skip
    command = "python -m benchmarks.runner " + " ".join(
        [f"--envs {' '.join(args.envs)}", f"--algos {' '.join(args.algos)}", f"--demos {' '.join(map(str, args.demos))}",
         f"--seeds {args.seeds}"]
        + ([f"--timesteps {args.timesteps}"] if args.timesteps is not None else [])
        + ([f"--eval-every {args.eval_every}"] if args.eval_every else [])
    )  # fmt: skip
    if not args.report_only:
        jobs = make_jobs(args.envs, args.algos, args.demos, range(args.seeds))
        run_grid(jobs, options | dict(command=command), args.workers, args.ray_address)
    write_report(args.results_dir, args.envs, args.algos, args.demos, args.seeds, command, args.timesteps, args.report_file,
                 args.figures_dir, args.config_dir)  # fmt: skip


if __name__ == "__main__":
    main()
