"""The benchmark grid on a real Ray cluster: a local head started here, the same per-run results as the serial and
process-pool paths, and a rerun that redoes only the missing result."""

import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, List

import pytest
from test_baselines import tiny_configs

from benchmarks.runner import main

pytest.importorskip("ray", reason="Ray is not installed (the `ray` extra: pip install -c constraints.txt -e '.[ray]')")

ROOT = Path(__file__).resolve().parent.parent
#: the fields of a result that measure the machine, not the run
WALL_CLOCK_FIELDS = ("train_seconds",)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def ray_cluster():
    """
    A one-node Ray cluster on 127.0.0.1 (2 CPUs, no dashboard) started by ``ray start --head --block``, and ended by
    signalling that process, which stops the processes it started (or, if it does not within two minutes, by killing
    its process group).

    :return: its address, and the environment its drivers need: its token (token authentication, the token kept in
        the environment so that nothing is written to ``~/.ray``) and the loopback address as the node's
    """
    temp_dir = Path(tempfile.mkdtemp(prefix="ray"))  # short: Ray's socket paths inside it must fit in 107 characters
    environment = dict(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32), RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0")
    port, log = free_port(), temp_dir / "ray_start.log"
    command = [sys.executable, "-m", "ray.scripts.scripts", "start", "--head", "--block", f"--port={port}",
               "--node-ip-address=127.0.0.1", "--num-cpus=2", "--include-dashboard=false", "--disable-usage-stats",
               f"--temp-dir={temp_dir}"]  # fmt: skip
    # started outside the repository and without PYTHONPATH, so its workers find `benchmarks` only if the runner
    # ships it to them, as to the nodes of a real cluster
    head_environment = {name: value for name, value in os.environ.items() if name != "PYTHONPATH"}
    with log.open("w") as output:
        head = subprocess.Popen(command, cwd=temp_dir, stdout=output, stderr=subprocess.STDOUT,
                                env={**head_environment, **environment}, start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while "Ray runtime started" not in log.read_text():
            if head.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"the Ray head did not start:\n{log.read_text()}")
            time.sleep(0.5)
        yield f"127.0.0.1:{port}", environment
    finally:
        head.send_signal(signal.SIGTERM)
        try:
            head.wait(timeout=120)
        except subprocess.TimeoutExpired:  # the head's processes are a session of their own: end them all
            os.killpg(head.pid, signal.SIGKILL)
            head.wait()
        shutil.rmtree(temp_dir, ignore_errors=True)


def grid_arguments(folder: Path, name: str) -> List[str]:
    """The runner's arguments for a grid of two cells (pendulum, MPAIL on a 64-step budget, seeds 0 and 1)."""
    return ["--envs", "pendulum", "--algos", "mpail", "--demos", "4", "--seeds", "2", "--timesteps", "64",
            "--eval-episodes", "2", "--ood-episodes", "0", "--config-dir", str(tiny_configs(folder / "configs")),
            "--results-dir", str(folder / name), "--report-file", str(folder / f"{name}.md"),
            "--figures-dir", str(folder / f"{name}_figures")]  # fmt: skip


def run_on_ray(arguments: List[str], address: str, environment: Dict[str, str], folder: Path) -> str:
    """
    Runs the runner's command line on the cluster, in a driver process of its own as users run it (Ray reads its
    settings, the authentication mode among them, when it is first imported). The driver runs in ``folder``, not in
    the repository: Ray puts a driver's folder on its workers' import path, which would hide a runner that does not
    ship ``benchmarks`` to them.

    :return: what the driver printed
    """
    command = [sys.executable, "-m", "benchmarks.runner", *arguments, "--ray-address", address]
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    done = subprocess.run(command, cwd=folder, env={**os.environ, **environment, "PYTHONPATH": path}, capture_output=True,
                          text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, f"the runner failed on Ray:\n{done.stdout}\n{done.stderr}"
    return done.stdout


def results_of(results_dir: Path) -> dict:
    """Every result file under ``results_dir`` by its relative path, without the wall-clock fields."""
    return {
        path.relative_to(results_dir).as_posix(): {
            key: value for key, value in json.loads(path.read_text()).items() if key not in WALL_CLOCK_FIELDS
        }
        for path in sorted(results_dir.rglob("*.json"))
    }


def test_ray_runs_give_the_serial_and_process_pool_results_and_a_rerun_redoes_only_the_missing_one(ray_cluster, tmp_path):
    address, environment = ray_cluster
    main(grid_arguments(tmp_path, "serial"))
    main([*grid_arguments(tmp_path, "pool"), "--workers", "2"])
    run_on_ray(grid_arguments(tmp_path, "ray"), address, environment, tmp_path)
    serial = results_of(tmp_path / "serial")
    assert sorted(serial) == ["pendulum_64steps/mpail_4demos_seed0.json", "pendulum_64steps/mpail_4demos_seed1.json"]
    assert serial["pendulum_64steps/mpail_4demos_seed0.json"] != serial["pendulum_64steps/mpail_4demos_seed1.json"]
    assert results_of(tmp_path / "pool") == serial
    assert results_of(tmp_path / "ray") == serial

    kept, redone = (tmp_path / "ray" / "pendulum_64steps" / f"mpail_4demos_seed{seed}.json" for seed in (0, 1))
    kept_mtime = kept.stat().st_mtime_ns
    redone.unlink()
    output = run_on_ray(grid_arguments(tmp_path, "ray"), address, environment, tmp_path)
    assert "1 runs to do" in output and f"wrote {redone}" in output and str(kept) not in output
    assert kept.stat().st_mtime_ns == kept_mtime
    assert results_of(tmp_path / "ray") == serial
