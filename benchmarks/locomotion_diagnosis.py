"""
Where a trained locomotion model's planning fails: a saved ``locomotion_ablations`` model played three ways from the
same starts, its planner as trained (``learned-model``), its planner with the learned model replaced by MuJoCo itself
(``simulator``: the learned reward and value, but perfect predictions), and the policy prior's actor alone (``actor``:
the mean of ``pi(a | s)``, no planning). If planning through the simulator scores no better than through the learned
model, the model's errors are not what costs the score: the learned reward and value are.

Results go to ``benchmarks/results/locomotion_diagnosis/<task>_<steps>steps/<variant>_seed<N>_<player>.json`` (a
rerun skips finished ones), the table to the ``locomotion-diagnosis`` section of BENCHMARKS.md.

Usage::

    python -m benchmarks.locomotion_diagnosis --env Hopper-v4 --seeds 0 1 2 3 4 --episodes 4
    python -m benchmarks.locomotion_diagnosis --report-only
"""

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Dict, Optional, Sequence

import gymnasium as gym
import numpy as np
import torch as th
from torch import nn

from benchmarks import locomotion_ablations
from benchmarks.locomotion_ablations import EVAL_SEED, demos_reference, grid_dir, grid_runs, stored_run
from benchmarks.report import commands_of, format_ci, machine_description, machines_of, mean_ci, write_section
from sb3_mpail import MPAIL
from sb3_mpail.envs.locomotion import evaluate_locomotion
from sb3_mpail.evaluation import normalised_score

RESULTS_DIR = Path(__file__).resolve().parent / "results" / "locomotion_diagnosis"
#: how a saved model is played, and what each way asks
PLAYERS: Dict[str, str] = {
    "learned-model": "the planner as trained, through its learned model",
    "simulator": "the same planner, reward and value through MuJoCo itself: perfect predictions",
    "actor": "the policy prior's actor alone (its mean action), no planning",
}


class SimulatorDynamics(nn.Module):
    """
    ``f(s, a) -> s'`` through a MuJoCo env's own simulator, row by row: the observation's positions and velocities are
    set as the state (the positions the observation leaves out, such as the torso's x, at zero: the dynamics do not
    depend on them), the action is simulated for the env's frame skip, and the env's own observation is read back.
    Exact where the observation holds the state (velocities clipped by the env are set clipped).

    :param env_id: a gymnasium MuJoCo env whose observation is its positions (less the first few) and velocities
    """

    def __init__(self, env_id: str):
        super().__init__()
        self.env = gym.make(env_id).unwrapped
        self.n_positions, n_velocities = self.env.model.nq, self.env.model.nv
        observation_size = self.env.observation_space.shape[0]
        self.n_left_out = self.n_positions + n_velocities - observation_size
        if not 0 <= self.n_left_out <= self.n_positions:
            raise ValueError(
                f"{env_id}'s observation ({observation_size} values) is not its positions and velocities "
                f"({self.n_positions} + {n_velocities}) less some positions, so it cannot be set as the simulator's state."
            )

    def forward(self, states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        rows, controls = states.double().cpu().numpy(), actions.double().cpu().numpy()
        positions = np.zeros((len(rows), self.n_positions))
        positions[:, self.n_left_out :] = rows[:, : self.n_positions - self.n_left_out]
        velocities = rows[:, self.n_positions - self.n_left_out :]
        next_rows = np.empty_like(rows)
        for row, (position, velocity, control) in enumerate(zip(positions, velocities, controls)):
            self.env.set_state(position, velocity)
            self.env.do_simulation(control, self.env.frame_skip)
            next_rows[row] = self.env._get_obs()
        return th.as_tensor(next_rows, dtype=states.dtype, device=states.device)


class PriorActor:
    """The policy prior's actor as a deterministic player: ``tanh`` of its mean, in the env's units."""

    def __init__(self, model: MPAIL):
        if model.policy.prior is None:
            raise ValueError("The model has no policy prior (policy_kwargs=dict(policy_prior=True)), so no actor to play.")
        self.prior = model.policy.prior

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        with th.no_grad():
            mean, _, _ = self.prior.sac.actor.get_action_dist_params(th.as_tensor(observation, dtype=th.float32))
            return self.prior.to_env_actions(th.tanh(mean)).numpy(), None


def player_of(model: MPAIL, env_id: str, player: str) -> Any:
    """The saved model played the way ``player`` (a key of :data:`PLAYERS`) names."""
    if player == "simulator":
        model.policy.planner.dynamics = SimulatorDynamics(env_id)
    return PriorActor(model) if player == "actor" else model


def diagnose(
    env_id: str, variant: str, seed: int, player: str, n_episodes: int, ablations_dir: Path, out_dir: Path, command: str
) -> Path:
    """
    Plays one saved model one way and writes its figures (skipped when the result exists).

    :param ablations_dir: the ``locomotion_ablations`` grid folder holding ``<variant>_seed<N>.zip``
    :return: the result file
    """
    path = Path(out_dir) / f"{variant}_seed{seed}_{player}.json"
    if path.exists():
        return path
    th.set_num_threads(1)
    trained = stored_run(ablations_dir, variant, seed)
    model = MPAIL.load(Path(ablations_dir) / f"{variant}_seed{seed}.zip", device="cpu")
    started = time.perf_counter()
    figures = evaluate_locomotion(player_of(model, env_id, player), env_id, n_episodes, EVAL_SEED + seed, n_envs=n_episodes)
    reference = demos_reference(trained["settings"])
    result = dict(
        env_id=env_id, variant=variant, seed=seed, player=player, timesteps=trained["timesteps"], n_episodes=n_episodes,
        seconds=round(time.perf_counter() - started, 1), command=command, machine=machine_description(),
        score=normalised_score(figures["return"], reference),
        speed_ratio=figures["forward_speed"] / reference["expert_forward_speed"], **figures,
    )  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result))
    return path


def report(results_dir: Path) -> str:
    """The ``locomotion-diagnosis`` section: per task, budget and variant, each way of playing over the same seeds."""
    lines = [
        "## Locomotion diagnosis: the learned model, or the learned reward and value?",
        "",
        "Saved `locomotion_ablations` models played from the same starts: through their learned model as trained, "
        "through MuJoCo itself (the same planner, learned reward and value, perfect predictions), and by the policy "
        "prior's actor alone. Score = (R - random) / (expert - random); means ± 95% CI (Student's t) over seeds.",
    ]
    for runs in grid_runs(results_dir, "*_seed*_*.json"):
        lines += ["", f"### {runs[0]['env_id']}, models trained for {runs[0]['timesteps']} env steps", "",
                  f"{runs[0]['n_episodes']} episodes per model and player, on {machines_of(runs)}. Commands: "
                  + "; ".join(f"`{command}`" for command in commands_of(runs)), "",
                  "| variant | played | seeds | score | score per seed | forward speed / expert's | episode length |",
                  "|---|---|---|---|---|---|---|"]  # fmt: skip
        for variant in sorted({run["variant"] for run in runs}):
            for player, meaning in PLAYERS.items():
                mine = sorted((run for run in runs if run["variant"] == variant and run["player"] == player),
                              key=lambda run: run["seed"])  # fmt: skip
                if not mine:
                    continue
                per_seed = ", ".join(f"{run['score']:.2f}" for run in mine)
                cells = [format_ci(*mean_ci([run[key] for run in mine])) for key in ("score", "speed_ratio", "length")]
                lines.append(f"| `{variant}` | {meaning} | {len(mine)} | {cells[0]} | {per_seed} | {cells[1]} | {cells[2]} |")
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Hopper-v4", help="a task with a locomotion_ablations grid (default: Hopper-v4)")
    parser.add_argument("--variant", default="defaults", help="the ablation variant whose saved models are played")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--players", nargs="+", default=list(PLAYERS), choices=list(PLAYERS))
    parser.add_argument("--episodes", type=int, default=4, help="episodes per model and player (default: 4)")
    parser.add_argument("--timesteps", type=int, default=None, help="the grid's budget (default: the zoo entry's)")
    parser.add_argument("--report-only", action="store_true", help="only rewrite the section from stored results")
    args = parser.parse_args(argv)
    if not args.report_only:
        ablations_dir = grid_dir(args.env, args.timesteps, locomotion_ablations.RESULTS_DIR)
        out_dir = grid_dir(args.env, args.timesteps, RESULTS_DIR)
        command = "python -m benchmarks.locomotion_diagnosis " + " ".join(argv if argv is not None else sys.argv[1:])
        for seed, player in [(seed, player) for seed in args.seeds for player in args.players]:
            path = diagnose(args.env, args.variant, seed, player, args.episodes, ablations_dir, out_dir, command)
            print("wrote", path, json.loads(path.read_text())["score"], flush=True)
    th.set_num_threads(1)  # the runs' setting, quoted in the report
    write_section("locomotion-diagnosis", report(RESULTS_DIR))


if __name__ == "__main__":
    main()
