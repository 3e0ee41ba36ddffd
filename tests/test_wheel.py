"""
The package as a user gets it: the wheel built from this checkout, installed on its own (no dependencies, no
checkout on the path) and used from an empty folder.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: every module of the package, found in the checkout so that a new one is covered without a test change
MODULES = sorted(
    ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
    for path in (ROOT / "sb3_mpail").rglob("*.py")
)
#: the optional packages of each extra, hidden in the second import pass (not the ``plot`` extra's matplotlib:
#: stable-baselines3 requires it; tests/test_train_navigation.py checks the plotting's ImportError)
EXTRAS = {
    "zoo": ("rl_zoo3", "sb3_contrib", "seaborn"),
    "scenarios": ("highway_env", "gymnasium_robotics", "mujoco"),
}
#: the navigation command on a tiny budget (tests/test_train_navigation.py's)
TINY_NAVIGATION = [
    "--timesteps", "200", "--n-envs", "2", "--n-steps", "50", "--n-samples", "8", "--horizon", "3", "--n-iterations",
    "1", "--n-eval-episodes", "2", "--n-plot-episodes", "2", "--no-progress-bar",
]  # fmt: skip

#: what a user does first: train on a shipped demo set, save, load and plan, and score it
USER_SCRIPT = """
import json

import numpy as np
from stable_baselines3.common.env_util import make_vec_env

import sb3_mpail
from sb3_mpail import MPAIL
from sb3_mpail.demos import list_shipped_demos, shipped_demo_info, shipped_demos
from sb3_mpail.evaluation import evaluate_episodes, normalised_score

demos = shipped_demos("pendulum", 4)
model = MPAIL("MlpMPPI", make_vec_env("Pendulum-v1", n_envs=2, seed=0), demos, n_steps=16, seed=0,
              policy_kwargs=dict(n_samples=16, horizon=3, n_iterations=1))
model.learn(32)
model.save("pendulum.zip")
loaded = MPAIL.load("pendulum.zip")
action, plan = loaded.predict(np.zeros((1, 3), np.float32), deterministic=True)
episodes = evaluate_episodes(loaded, "Pendulum-v1", 1, seed=0)
print(json.dumps(dict(
    package=sb3_mpail.__file__, shipped=list_shipped_demos(), steps=loaded.num_timesteps, action=action.tolist(),
    score=normalised_score(episodes.mean_return, shipped_demo_info("pendulum")),
)))
"""

#: imports every module with the named extras' packages hidden, and calls what needs each hidden extra
IMPORT_SCRIPT = """
import importlib, json, sys

# gymnasium imports the plugins of installed packages (highway-env's, gymnasium-robotics') as it loads; uninstalled
# ones have none, so it is loaded before the packages are hidden
import gymnasium as gym

hidden = json.loads(sys.argv[1])
for packages in hidden.values():
    for package in packages:
        sys.modules[package] = None  # import now fails as if it were not installed
outcome = {}
for name in sys.argv[2:]:
    try:
        importlib.import_module(name)
        outcome[name] = None
    except ImportError as error:
        outcome[name] = str(error)


def error_of(call):
    try:
        call()
    except ImportError as error:
        return str(error)
    return None


from sb3_mpail import zoo

needs = dict(zoo=zoo.main, scenarios=lambda: gym.make("sb3_mpail/Parking-v0"))
print(json.dumps(dict(
    modules=outcome,
    calls={extra: error_of(needs[extra]) for extra in hidden},
    files=sorted(module.__file__ for module in list(sys.modules.values()) if getattr(module, "__file__", None)),
)))
"""


def run(command, cwd: Path, site: Path, timeout: int = 300) -> subprocess.CompletedProcess:
    # only the installed wheel on the path: the checkout is neither the folder nor on PYTHONPATH
    environment = {**os.environ, "PYTHONPATH": str(site), "MPLBACKEND": "Agg"}
    finished = subprocess.run(command, cwd=cwd, env=environment, capture_output=True, text=True, timeout=timeout)
    assert finished.returncode == 0, finished.stdout[-2000:] + finished.stderr[-4000:]
    return finished


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """``(site, workdir)``: the wheel installed into its own folder, and an empty folder to use it from."""
    base = tmp_path_factory.mktemp("wheel")
    source = base / "source"  # what the build reads, copied so the build leaves nothing in the checkout
    shutil.copytree(ROOT / "sb3_mpail", source / "sb3_mpail", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input", "--quiet"]
    built = subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "--wheel-dir", str(base / "dist"),
                            str(source)], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = (base / "dist").glob("sb3_mpail-*.whl")
    site = base / "site"
    subprocess.run([*pip, "install", "--no-deps", "--target", str(site), str(wheel)], check=True, timeout=300)
    workdir = base / "user"
    workdir.mkdir()
    return site, workdir


def test_the_installed_wheel_trains_on_shipped_demos_saves_loads_and_scores(installed):
    site, workdir = installed
    report = json.loads(run([sys.executable, "-c", USER_SCRIPT], workdir, site).stdout.strip().splitlines()[-1])
    assert Path(report["package"]).resolve().is_relative_to(site.resolve())
    assert {"pendulum_4", "navigation_4", "navigation_circling_4"} <= set(report["shipped"])
    assert report["steps"] == 32 and len(report["action"][0]) == 1
    assert isinstance(report["score"], float)


@pytest.mark.parametrize("hidden", [(), tuple(EXTRAS)], ids=["with-extras", "without-extras"])
def test_every_module_imports_or_names_its_extra_and_reads_nothing_from_the_checkout(installed, hidden):
    site, workdir = installed
    command = [sys.executable, "-c", IMPORT_SCRIPT, json.dumps({extra: EXTRAS[extra] for extra in hidden}), *MODULES]
    report = json.loads(run(command, workdir, site).stdout.strip().splitlines()[-1])
    for name, error in report["modules"].items():
        assert error is None or any(f"sb3-mpail[{extra}]" in error for extra in hidden), (name, error)
    if not hidden:
        assert report["modules"] == {name: None for name in MODULES}
    for extra, error in report["calls"].items():
        assert error is not None and f"sb3-mpail[{extra}]" in error, (extra, error)
    # the package, not the checkout's copy, and none of the experiments (benchmarks/, demos/)
    checkout = [ROOT / folder for folder in ("sb3_mpail", "benchmarks", "demos", "tests")]
    assert not [file for file in report["files"] if any(Path(file).resolve().is_relative_to(folder) for folder in checkout)]
    assert any(Path(file).resolve().is_relative_to(site.resolve()) for file in report["files"])


def test_the_console_scripts_run_the_main_command_and_the_zoo_with_their_defaults(installed):
    site, workdir = installed
    scripts = site / "bin"
    run([str(scripts / "sb3-mpail-train-navigation"), *TINY_NAVIGATION, "--out-dir", "navigation"], workdir, site)
    results = json.loads((workdir / "navigation" / "results.json").read_text())
    assert results["demos"] == "navigation_circling_4" and results["timesteps"] == 200
    assert (workdir / "navigation" / "model.zip").is_file() and (workdir / "navigation" / "navigation.png").is_file()
    # no -conf: the shipped hyperparameters and their shipped demos
    trained = run([str(scripts / "sb3-mpail-zoo"), "train", "--algo", "mpail", "--env", "Pendulum-v1", "-n", "64", "-f",
                   "logs", "--seed", "0"], workdir, site)  # fmt: skip
    assert str(site) in trained.stdout  # "Loading hyperparameters from: <site>/sb3_mpail/hyperparams/mpail.yml"
    assert (workdir / "logs" / "mpail" / "Pendulum-v1_1" / "Pendulum-v1.zip").is_file()
    helped = run([str(scripts / "sb3-mpail-inspect"), "--help"], workdir, site)
    assert "saved MPAIL model" in helped.stdout
