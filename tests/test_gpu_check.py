"""benchmarks/gpu_check.py, the checks to run on a GPU before timing the planner there, runs and passes on the CPU."""

import subprocess
import sys
from pathlib import Path


def test_the_gpu_checks_cpu_part_runs_and_passes():
    command = [sys.executable, "-m", "benchmarks.gpu_check", "--device", "cpu", "--envs", "4", "--no-compile"]
    finished = subprocess.run(command, cwd=Path(__file__).parents[1], capture_output=True, text=True, timeout=300)
    assert finished.returncode == 0, finished.stdout + finished.stderr[-2000:]
    assert "PASS  optimised planner = reference" in finished.stdout
