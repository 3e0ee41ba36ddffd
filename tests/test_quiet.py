"""Importing the package and running its main command print no third-party notice that does not concern the user."""

import subprocess
import sys

import pytest

TINY = [
    "--timesteps", "100", "--n-envs", "2", "--n-steps", "50", "--n-samples", "8", "--horizon", "3",
    "--n-iterations", "1", "--n-eval-episodes", "1", "--no-plot",
]  # fmt: skip


def run_python(*arguments: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *arguments], capture_output=True, text=True, timeout=300, cwd=cwd)


def test_import_prints_nothing():
    # the package, then what users import beside it; under gymnasium 0.29 importing gymnasium imports every plugin,
    # gymnasium-robotics included, which printed its AdroitHand notice twice
    imported = run_python("-c", "import sb3_mpail, gymnasium, stable_baselines3, sb3_mpail.envs.maze")
    assert imported.returncode == 0, imported.stderr
    assert (imported.stdout, imported.stderr) == ("", "")


def test_point_maze_is_made_without_gymnasium_robotics_notice():
    pytest.importorskip("mujoco", reason="PointMaze needs mujoco (the scenarios extra)")
    pytest.importorskip("gymnasium_robotics", reason="PointMaze needs gymnasium-robotics (the scenarios extra)")
    made = run_python("-c", "import sb3_mpail, gymnasium as gym; gym.make('sb3_mpail/PointMaze-v0').reset(seed=0)")
    assert made.returncode == 0, made.stderr
    assert made.stderr == ""


def test_main_command_prints_no_warning(tmp_path):
    trained = run_python("-m", "sb3_mpail.train_navigation", *TINY, "--out-dir", str(tmp_path), cwd=tmp_path)
    assert trained.returncode == 0, trained.stderr[-3000:]
    assert "warn" not in (trained.stdout + trained.stderr).lower()
    assert "AdroitHand" not in trained.stderr and "render_mode" not in trained.stderr
    assert (tmp_path / "model.zip").is_file()
