"""
The scenarios beyond the navigation task. Each scenario trains MPAIL with the hyperparameters of its entry in the
package's ``sb3_mpail/hyperparams/mpail.yml`` (the same ones ``python -m sb3_mpail.zoo train --algo mpail --env <id>``
uses) from its shipped demos, over several seeds, and evaluates the deterministic planner. The expert's and the random
policy's figures come from the shipped demos' information file (``sb3_mpail/data/<name>.json``):

- ``cartpole``: MPAIL-OM's return as a normalised score (random = 0, expert = 1);
- ``lap``: the single noisy, partially observed demo: cross-track error to the demo's recorded path (mean and max
  over 5 laps) and mean speed, next to the scripted driver's own;
- ``parking``: highway-env ``parking-v0``'s return as a normalised score and the share of episodes ending parked;
- ``racetrack``: highway-env ``racetrack-v0`` (no other vehicles) driven by steering: its return as a normalised
  score and the share of steps on the road;
- ``highway``: highway-env ``highway-v0`` (no other vehicles) driven by acceleration and steering: its return as a
  normalised score, the share of steps on the road and the mean speed;
- ``highway_traffic``: highway-env ``highway-fast-v0`` in traffic (20 IDM/MOBIL vehicles) driven by acceleration and
  steering: the share of episodes ending in a collision, the mean speed, the return and its normalised score; and
  the crash rate and speed of the same model in ``highway-v0``'s denser traffic;
- ``ant``: MuJoCo Ant with an online-learned model (MPAIL-OM): its return as a normalised score and its forward speed,
  next to the expert's;
- ``pointmaze``: gymnasium-robotics PointMaze (U-maze, fixed start and goal cells) planned through a wall-free
  point-mass model: its return as a normalised score, the share of episodes ending at the goal and the share of
  steps touching a wall;
- ``pointmaze_medium``: the same on PointMaze's Medium maze from random start and goal cells.

Run: ``python -m benchmarks.scenarios cartpole --seeds 0 1 2``; each run's figures are kept in
``benchmarks/figures/scenarios.json`` and the ``scenarios`` section of BENCHMARKS.md is rebuilt from all of them, with
the notes of ``benchmarks/scenarios_notes.md`` (``--report-only`` rebuilds it without training).
"""

import argparse
import json
import math
import time
from functools import partial
from pathlib import Path
from typing import Callable, Dict, List, NamedTuple, Optional, Tuple

import gymnasium as gym
import numpy as np
import torch as th
import yaml
from stable_baselines3.common.env_util import make_vec_env

import sb3_mpail.envs  # noqa: F401  (registers the package's envs)
from benchmarks.report import DETERMINISTIC_NOISE, format_ci, machine_description, mean_ci, write_section
from sb3_mpail import MPAIL
from sb3_mpail.demos import shipped_demo_info, shipped_demos
from sb3_mpail.envs.ant import evaluate_ant
from sb3_mpail.envs.lap import lap_metrics
from sb3_mpail.envs.maze import point_maze_figures
from sb3_mpail.evaluation import Episodes, evaluate_episodes, normalised_score
from sb3_mpail.zoo import HYPERPARAMS

RESULTS = Path(__file__).resolve().parent / "figures" / "scenarios.json"
#: each finished seed's figures, so that an interrupted run goes on where it stopped
RUNS_DIR = Path(__file__).resolve().parent / "results" / "scenarios"
#: each seed's trained model (not committed)
MODELS_DIR = Path(__file__).resolve().parent.parent / "runs" / "benchmarks" / "scenarios"
#: how each scenario's settings were chosen, what failed and what is left: written by hand, appended to the section
NOTES = Path(__file__).resolve().parent / "scenarios_notes.md"
EVAL_SEED = 10_000


def cartpole_figures(model: MPAIL, stats: Dict, n_episodes: int) -> Dict[str, float]:
    """Mean return of the deterministic planner and its normalised score."""
    mean_return = evaluate_episodes(model, "sb3_mpail/ContinuousCartPole-v0", n_episodes, EVAL_SEED).mean_return
    return {"return": mean_return, "score": normalised_score(mean_return, stats)}


def cartpole_reference(stats: Dict) -> str:
    return f"Expert ({stats['expert_algo']}) {stats['expert_return_mean']:.1f}, random {stats['random_return_mean']:.1f}."


def lap_figures(model: MPAIL, stats: Dict, n_episodes: int) -> Dict[str, float]:
    """Cross-track error to the demo's recorded path and mean speed of the deterministic planner over the laps."""
    path = shipped_demos("lap", 1)[0].obs[:, :2]
    plan = None

    def planner(observation: np.ndarray, episode_start: bool) -> np.ndarray:
        nonlocal plan
        starts = np.array([episode_start])
        actions, plan = model.predict(observation[None], state=plan, episode_start=starts, deterministic=True)
        return actions[0]

    return lap_metrics(planner, path, n_episodes, EVAL_SEED)


def lap_reference(stats: Dict) -> str:
    driver = stats["driver_on_eval_laps"]
    return (
        f"The demo's driver ({stats['expert']}) on the same laps: cross-track error {driver['cte_mean']:.3f} m mean, "
        f"{driver['cte_max']:.3f} m max, speed {driver['speed']:.2f} m/s. Demo noise: {stats['position_noise']} m on "
        f"position, {stats['velocity_noise']} m/s on velocity. Paper (real robot): MPAIL 0.17 / 0.76 m at 0.70 m/s."
    )


def parking_figures(model: MPAIL, stats: Dict, n_episodes: int) -> Dict[str, float]:
    """
    Mean parking-v0 return of the deterministic planner, its normalised score and the shares of episodes that end
    parked and crashed. The success rate is the figure that says whether it parks: a crash costs only 5 and ends
    the episode, so crashing early returns more than driving around for the 100 s limit.
    """
    episodes = evaluate_episodes(model, "sb3_mpail/Parking-v0", n_episodes, EVAL_SEED)
    return {
        "return": episodes.mean_return,
        "score": normalised_score(episodes.mean_return, stats),
        "success": float(np.mean([info["is_success"] for info in episodes.final_infos])),
        "crashed": float(np.mean([info["crashed"] for info in episodes.final_infos])),
    }


def parking_reference(stats: Dict) -> str:
    return (
        f"Expert ({stats['expert_algo']}) {stats['expert_return_mean']:.1f}, parked in {stats['expert_success_rate']:.0%} "
        f"of {stats['n_eval_episodes']} episodes, crashed in {stats.get('expert_crash_rate', math.nan):.0%}; random "
        f"{stats['random_return_mean']:.1f}, "
        f"{stats['random_success_rate']:.0%} parked."
    )


def road_figures(env_id: str, model: MPAIL, stats: Dict, n_episodes: int) -> Dict[str, float]:
    """
    Mean return of the deterministic planner on a highway-env road scenario (racetrack: lane centring minus a steering
    penalty; highway: speed and rightmost lane; up to 1 per step, 0 off the road), its normalised score, the share of
    steps on which the car is on the road and its mean speed.
    """
    on_road: List[bool] = []
    speeds: List[float] = []

    def record_step(info: Dict, _: bool) -> None:
        on_road.append(bool(info["rewards"]["on_road_reward"]))
        speeds.append(float(info["speed"]))

    mean_return = evaluate_episodes(model, env_id, n_episodes, EVAL_SEED, on_step=record_step).mean_return
    return {
        "return": mean_return,
        "score": normalised_score(mean_return, stats),
        "on_road": float(np.mean(on_road)),
        "speed": float(np.mean(speeds)),
    }


def road_reference(stats: Dict) -> str:
    return (
        f"Expert ({stats['expert_algo']}) {stats['expert_return_mean']:.1f}, random {stats['random_return_mean']:.1f} "
        f"over {stats['n_eval_episodes']} episodes of 200 steps."
    )


ROAD_COLUMNS = (("return", "return"), ("score", "normalised score"), ("on_road", "share of steps on the road"))


def traffic_figures(model: MPAIL, stats: Dict, n_episodes: int) -> Dict[str, float]:
    """
    highway-env users' own figures of the deterministic planner in traffic: the share of episodes that end in a
    collision (``info["crashed"]``, which ends them), the mean speed over every step (``info["speed"]``, m/s), the mean
    return (speed, rightmost lane, 0 off the road, per step, less for a crash) and its normalised score, in the
    training traffic (``highway-fast-v0``'s); and the crash rate and speed of the same model, unchanged, in
    ``highway-v0``'s denser traffic (``dense_``: 4 lanes, 50 vehicles). A crash ends the episode early, so a low return
    can be a crash or a slow drive: read the crash rate and speed beside it.
    """

    def drive(env_id: str) -> Tuple[Episodes, float]:
        speeds: List[float] = []
        episodes = evaluate_episodes(model, env_id, n_episodes, EVAL_SEED,
                                     on_step=lambda info, _: speeds.append(float(info["speed"])))  # fmt: skip
        return episodes, float(np.mean(speeds))

    def crash_rate(episodes: Episodes) -> float:
        return float(np.mean([info["crashed"] for info in episodes.final_infos]))

    episodes, speed = drive("sb3_mpail/HighwayTraffic-v0")
    dense_episodes, dense_speed = drive("sb3_mpail/HighwayTrafficDense-v0")
    return {
        "crashed": crash_rate(episodes),
        "speed": speed,
        "return": episodes.mean_return,
        "score": normalised_score(episodes.mean_return, stats),
        "dense_crashed": crash_rate(dense_episodes),
        "dense_speed": dense_speed,
    }


def traffic_reference(stats: Dict) -> str:
    return (
        f"Expert ({stats['expert_algo']}) {stats['expert_return_mean']:.1f}, crashed in {stats['expert_crash_rate']:.0%} "
        f"of {stats['n_eval_episodes']} episodes at {stats['expert_speed_mean']:.1f} m/s (its demos: "
        f"{len(stats['failed_demo_seeds'])} crashed episodes dropped, {stats['demo_speed_mean']:.1f} m/s); random "
        f"{stats['random_return_mean']:.1f}, crashed in {stats['random_crash_rate']:.0%}, over 30 s episodes (151 steps). "
        f"In highway-v0's traffic (40 s episodes): the expert crashed in {stats['dense_expert_crash_rate']:.0%} at "
        f"{stats['dense_expert_speed_mean']:.1f} m/s, random in {stats['dense_random_crash_rate']:.0%}."
    )


def ant_figures(model: MPAIL, stats: Dict, n_episodes: int) -> Dict[str, float]:
    """
    Mean return of the deterministic planner, its normalised score and its forward speed (the torso's x velocity
    over every step): the paper's Ant walks, but slower than the expert. Standing still is worth about 1 per step
    (the healthy reward), so the speed says more than the score about whether it walks.
    """
    figures = evaluate_ant(model, n_episodes, EVAL_SEED, n_envs=n_episodes)
    mean_return = figures["return"]
    return {"return": mean_return, "score": normalised_score(mean_return, stats), "speed": figures["forward_speed"]}


def ant_reference(stats: Dict) -> str:
    return (
        f"Expert ({stats['expert_algo']}, {stats['expert_timesteps']} steps) {stats['expert_return_mean']:.1f} at "
        f"{stats['expert_forward_speed']:.2f} m/s, random {stats['random_return_mean']:.1f} over "
        f"{stats['n_eval_episodes']} episodes of 200 steps."
    )


def pointmaze_figures(env_id: str, model: MPAIL, stats: Dict, n_episodes: int) -> Dict[str, float]:
    """
    Mean return of the deterministic planner, its normalised score, the share of episodes ending within 0.45 m of
    the goal and the share of steps touching a wall: the planning model has no walls, which the entries give the
    planner as a known constraint cost.
    """
    figures = point_maze_figures(model, n_episodes, EVAL_SEED, env_id=env_id)
    return {**figures, "score": normalised_score(figures["return"], stats)}


def pointmaze_reference(stats: Dict) -> str:
    return (
        f"Expert ({stats['expert_algo']}) {stats['expert_return_mean']:.1f}, at the goal in "
        f"{stats['expert_success_rate']:.0%} of {stats['n_eval_episodes']} episodes, touching a wall in "
        f"{stats['expert_wall_steps']:.2%} of steps; random {stats['random_return_mean']:.1f} over "
        f"{gym.spec(stats['env_id']).max_episode_steps}-step episodes."
    )


MAZE_COLUMNS = (("return", "return"), ("score", "normalised score"), ("success", "success rate"),
                ("wall_steps", "steps on a wall"))  # fmt: skip


class Scenario(NamedTuple):
    """
    One benchmark scenario.

    :param env_id: registered env id, also the key of its ``sb3_mpail/hyperparams/mpail.yml`` entry
    :param demos: the shipped demo family, whose information file holds the expert's figures
    :param title: what the BENCHMARKS.md table calls it
    :param figures: ``figures(model, stats, n_episodes)``: the trained model's figures, keyed like ``columns``
    :param columns: ``(key, column title)`` of each figure in the table
    :param reference: ``reference(stats)``: a sentence giving the expert's figures
    :param n_eval_episodes: evaluation episodes per seed
    """

    env_id: str
    demos: str
    title: str
    figures: Callable[[MPAIL, Dict, int], Dict[str, float]]
    columns: Tuple[Tuple[str, str], ...]
    reference: Callable[[Dict], str]
    n_eval_episodes: int


SCENARIOS: Dict[str, Scenario] = {
    "cartpole": Scenario(
        "sb3_mpail/ContinuousCartPole-v0",
        "cartpole",
        "Cartpole, online-learned model (MPAIL-OM)",
        cartpole_figures,
        (("return", "return"), ("score", "normalised score")),
        cartpole_reference,
        10,
    ),
    "lap": Scenario(
        "sb3_mpail/NavigationLap-v0",
        "lap",
        "One lap from a single noisy demo of position and body-frame velocity",
        lap_figures,
        (("cte_mean", "mean cross-track error (m)"), ("cte_max", "max cross-track error (m)"), ("speed", "speed (m/s)")),
        lap_reference,
        5,
    ),
    "parking": Scenario(
        "sb3_mpail/Parking-v0",
        "parking",
        "highway-env parking-v0 (walls on) from 16 scripted-expert demos that stop in the slot and stay (observations only)",
        parking_figures,
        (("success", "success rate"), ("crashed", "crash rate"), ("return", "return"), ("score", "normalised score")),
        parking_reference,
        20,
    ),
    "racetrack": Scenario(
        "sb3_mpail/Racetrack-v0",
        "racetrack",
        "highway-env racetrack-v0 (steering only, no other vehicles) from 4 scripted lane-keeping demos (observations only)",
        partial(road_figures, "sb3_mpail/Racetrack-v0"),
        ROAD_COLUMNS,
        road_reference,
        10,
    ),
    "highway": Scenario(
        "sb3_mpail/Highway-v0",
        "highway",
        "highway-env highway-v0 (acceleration and steering, no other vehicles) from 4 scripted demos (observations only)",
        partial(road_figures, "sb3_mpail/Highway-v0"),
        (*ROAD_COLUMNS, ("speed", "speed (m/s)")),
        road_reference,
        10,
    ),
    "highway_traffic": Scenario(
        "sb3_mpail/HighwayTraffic-v0",
        "highway_traffic",
        "highway-env highway-fast-v0 in traffic (20 vehicles, acceleration and steering) from 16 IDM/MOBIL demos "
        "(observations only)",
        traffic_figures,
        (("crashed", "crash rate"), ("speed", "speed (m/s)"), ("return", "return"), ("score", "normalised score"),
         ("dense_crashed", "highway-v0: crash rate"), ("dense_speed", "highway-v0: speed (m/s)")),
        traffic_reference,
        20,
    ),
    "ant": Scenario(
        "sb3_mpail/Ant-v0",
        "ant",
        "MuJoCo Ant (27-D observation, 200 steps) with an online-learned model (MPAIL-OM) from 4 PPO demos",
        ant_figures,
        (("return", "return"), ("score", "normalised score"), ("speed", "forward speed (m/s)")),
        ant_reference,
        5,
    ),
    "pointmaze": Scenario(
        "sb3_mpail/PointMaze-v0",
        "pointmaze",
        "gymnasium-robotics PointMaze U-maze through a wall-free point-mass model, from 4 scripted demos (observations only)",
        partial(pointmaze_figures, "sb3_mpail/PointMaze-v0"),
        MAZE_COLUMNS,
        pointmaze_reference,
        20,
    ),
    "pointmaze_medium": Scenario(
        "sb3_mpail/PointMazeMedium-v0",
        "pointmaze_medium",
        "gymnasium-robotics PointMaze Medium from random start and goal cells, seen along the maze's shortest paths, "
        "from 32 scripted demos (observations only)",
        partial(pointmaze_figures, "sb3_mpail/PointMazeMedium-v0"),
        MAZE_COLUMNS,
        pointmaze_reference,
        20,
    ),
}



def zoo_hyperparameters(env_id: str) -> Dict:
    """The scenario's ``sb3_mpail/hyperparams/mpail.yml`` entry as ``MPAIL`` arguments, plus ``n_envs`` and ``n_timesteps``."""
    entry = dict(yaml.safe_load(HYPERPARAMS.read_text())[env_id])
    if isinstance(entry.get("policy_kwargs"), str):
        entry["policy_kwargs"] = eval(entry["policy_kwargs"], {"dict": dict})  # rl_zoo3's convention: a Python string
    entry.pop("policy")
    return entry


def run_seed(name: str, stats: Dict, seed: int, runs_dir: Optional[Path] = RUNS_DIR) -> Dict:
    """
    Trains and evaluates one seed of a scenario, or reads its stored figures if this seed already ran with the entry's
    current hyperparameters, evaluation episodes and deterministic planner (an interrupted run goes on from the seeds
    it finished).

    :param name: the scenario's key in :data:`SCENARIOS`
    :param stats: the shipped demos' information
    :param seed: the seed
    :param runs_dir: where each seed's figures are stored; ``None``: neither read nor stored
    """
    scenario = SCENARIOS[name]
    hyperparameters = zoo_hyperparameters(scenario.env_id)
    settings = {
        "hyperparameters": repr(hyperparameters),
        "n_eval_episodes": scenario.n_eval_episodes,
        "deterministic_noise": DETERMINISTIC_NOISE,  # an evaluation by another planner is not reused
    }
    path = None if runs_dir is None else Path(runs_dir) / f"{name}_seed{seed}.json"
    if path is not None and path.exists():
        stored = json.loads(path.read_text())
        if stored["settings"] == settings:
            return stored["run"]
    n_envs, timesteps = hyperparameters.pop("n_envs"), int(hyperparameters.pop("n_timesteps"))
    model = MPAIL("MlpMPPI", make_vec_env(scenario.env_id, n_envs=n_envs, seed=seed), seed=seed, **hyperparameters)
    start = time.time()
    model.learn(timesteps)
    seconds = time.time() - start
    MODELS_DIR.mkdir(parents=True, exist_ok=True)
    model.save(MODELS_DIR / f"{name}_seed{seed}.zip")  # for evaluations to come
    run = {"seed": seed, **scenario.figures(model, stats, scenario.n_eval_episodes), "seconds": seconds}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"settings": settings, "run": run}, indent=2) + "\n")
    return run


def mean_and_ci(runs: List[Dict], key: str) -> str:
    """A figure's mean over the seeds ± the half-width of its 95% confidence interval."""
    return format_ci(*mean_ci([run[key] for run in runs]), digits=3)


def summary_table(results: Dict[str, Dict]) -> str:
    """One row per scenario: its budget, seeds and every figure's mean ± 95% CI over the seeds."""
    rows = []
    for name, result in results.items():
        scenario, runs = SCENARIOS[name], result["runs"]
        figures = "; ".join(f"{title} {mean_and_ci(runs, key)}" for key, title in scenario.columns)
        rows.append(f"| `{name}` | `{scenario.env_id}` | {result['timesteps']} | {len(runs)} | {figures} |")
    header = "| scenario | env | env steps per seed | seeds | figures (mean ± 95% CI over seeds) |\n|---|---|---|---|---|\n"
    return header + "\n".join(rows)


def section(results: Dict[str, Dict]) -> str:
    """The ``scenarios`` section of BENCHMARKS.md from every scenario's stored results."""
    parts = [
        "## Scenarios beyond navigation\n\n"
        "MPAIL's deterministic planner after training with the scenario's `sb3_mpail/hyperparams/mpail.yml` entry, "
        "evaluated on "
        "fixed episodes (reset seeds from 10000); normalised score = (return - random) / (expert - random).",
        summary_table(results),
    ]
    for name, result in results.items():
        scenario = SCENARIOS[name]
        runs = result["runs"]
        keys = [key for key, _ in scenario.columns]
        rows = "\n".join(
            f"| {run['seed']} | " + " | ".join(f"{run[key]:.3f}" for key in keys) + f" | {run['seconds']:.0f} |"
            for run in runs
        )
        summary = " | ".join(f"**{mean_and_ci(runs, key)}**" for key in keys)
        parts.append(
            f"""### {scenario.title}: `{scenario.env_id}`

{result['timesteps']} env steps per seed, hyperparameters `{result['hyperparameters']}`; {result['n_eval_episodes']}
evaluation episodes per seed. {scenario.reference(result['stats'])} (`sb3_mpail/data/{scenario.demos}.json`)

| seed | {" | ".join(title for _, title in scenario.columns)} | train seconds |
|---|{"---|" * len(keys)}---|
{rows}
| mean ± 95% CI over {len(runs)} seeds | {summary} | |

Command: `{result['command']}` on {result['machine']}. Zoo equivalent (one seed):
`python -m sb3_mpail.zoo train --algo mpail --env {SCENARIOS[name].env_id}`."""
        )
    parts.append(NOTES.read_text().strip())
    return "\n\n".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario", nargs="?", choices=sorted(SCENARIOS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--threads", type=int, default=1, help="torch threads per run")
    parser.add_argument("--no-write", action="store_true", help="print only; leave BENCHMARKS.md and the results alone")
    parser.add_argument("--report-only", action="store_true", help="rebuild the BENCHMARKS.md section from stored results")
    args = parser.parse_args()
    if args.report_only:
        write_section("scenarios", section(json.loads(RESULTS.read_text())))
        return
    if args.scenario is None:
        parser.error("name a scenario, or pass --report-only")
    scenario = SCENARIOS[args.scenario]
    th.set_num_threads(args.threads)
    stats = shipped_demo_info(scenario.demos)
    runs: List[Dict] = []
    for seed in args.seeds:
        runs.append(run_seed(args.scenario, stats, seed, None if args.no_write else RUNS_DIR))
        print(runs[-1], flush=True)
    hyperparameters = zoo_hyperparameters(scenario.env_id)
    result = {
        "runs": runs,
        "stats": stats,
        "timesteps": hyperparameters.pop("n_timesteps"),
        "hyperparameters": {key: value for key, value in hyperparameters.items() if key != "demos"},
        "n_eval_episodes": scenario.n_eval_episodes,
        "command": f"python -m benchmarks.scenarios {args.scenario} --seeds {' '.join(map(str, args.seeds))}",
        "machine": machine_description(),
    }
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    results[args.scenario] = result
    markdown = section(results)
    print(markdown)
    if not args.no_write:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(json.dumps(results, indent=2) + "\n")
        write_section("scenarios", markdown)


if __name__ == "__main__":
    main()
