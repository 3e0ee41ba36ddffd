"""rl_zoo3's own train and enjoy scripts run MPAIL from a zoo-style YAML file and write the zoo's log layout."""

import subprocess
import sys

from sb3_mpail.demos import SHIPPED_DEMO_DIR
from sb3_mpail.zoo import HYPERPARAMS, QUIET_LOG_INTERVAL, with_default_hyperparams

CONFIG = """
Pendulum-v1:
  n_timesteps: 64
  n_envs: 2
  policy: 'MlpMPPI'
  demos: {demos}
  n_steps: 16
  policy_kwargs: "dict(n_samples=16, horizon=3, n_iterations=2)"
"""


def zoo(*arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sb3_mpail.zoo", *arguments], capture_output=True, text=True, timeout=300)


def test_zoo_train_then_enjoy_on_a_tiny_budget(tmp_path):
    config = tmp_path / "mpail.yml"
    config.write_text(CONFIG.format(demos=SHIPPED_DEMO_DIR / "pendulum_4.npz"))
    logs = tmp_path / "logs"
    trained = zoo("train", "--algo", "mpail", "--env", "Pendulum-v1", "-conf", str(config), "-f", str(logs), "--seed", "0")
    assert trained.returncode == 0, trained.stderr[-3000:]
    run = logs / "mpail" / "Pendulum-v1_1"
    assert (run / "Pendulum-v1.zip").exists()
    assert (run / "0.monitor.csv").exists() and (run / "Pendulum-v1" / "config.yml").exists()
    enjoyed = zoo("enjoy", "--algo", "mpail", "--env", "Pendulum-v1", "-f", str(logs), "--exp-id", "1", "--no-render",
                  "-n", "210", "--deterministic")
    assert enjoyed.returncode == 0, enjoyed.stderr[-3000:]
    assert "Episode Reward" in enjoyed.stdout


def test_zoo_train_with_normalize_true_is_refused_saying_why(tmp_path):
    config = tmp_path / "mpail.yml"
    config.write_text(CONFIG.format(demos="pendulum_4") + "  normalize: true\n")
    trained = zoo("train", "--algo", "mpail", "--env", "Pendulum-v1", "-conf", str(config), "-f", str(tmp_path / "logs"))
    assert trained.returncode == 1
    refusal = "ValueError: MPAIL needs the environment's raw observations, but this one is wrapped in VecNormalize"
    assert refusal in trained.stderr, trained.stderr[-3000:]
    assert "(rl_zoo3: normalize: false)" in trained.stderr


def test_train_reads_the_shipped_hyperparameters_unless_a_file_is_named():
    assert HYPERPARAMS.is_file()
    defaulted = with_default_hyperparams(["train", "--algo", "mpail", "--env", "Pendulum-v1"])
    quiet = ["--log-interval", str(QUIET_LOG_INTERVAL)]
    assert defaulted == ["train", "--algo", "mpail", "--env", "Pendulum-v1", "--conf-file", str(HYPERPARAMS), *quiet]
    named = ["train", "--algo", "mpail", "--env", "Pendulum-v1", "-conf", "mine.yml", "--log-interval", "1"]
    assert with_default_hyperparams(named) == named
    scored = with_default_hyperparams([*named, "--score-episodes", "3"])  # sb3-mpail's option, not passed to rl_zoo3
    assert scored == named
    for other in (["train", "--algo", "ppo", "--env", "Pendulum-v1"], ["enjoy", "--algo", "mpail", "--env", "Pendulum-v1"]):
        assert with_default_hyperparams(other) == other


def test_zoo_help_lists_its_scripts_and_an_unknown_script_is_named():
    helped = zoo("--help")
    assert helped.returncode == 0 and "{train,enjoy,record_video," in helped.stdout
    wrong = zoo("trian", "--algo", "mpail")
    assert wrong.returncode != 0 and "unknown script 'trian'" in wrong.stderr and "Traceback" not in wrong.stderr


def test_zoo_train_is_quiet_and_ends_with_the_score_against_the_shipped_expert(tmp_path):
    config = tmp_path / "mpail.yml"
    config.write_text(CONFIG.format(demos="pendulum_4").replace("n_timesteps: 64", "n_timesteps: 640"))  # 20 iterations
    trained = zoo("train", "--algo", "mpail", "--env", "Pendulum-v1", "-conf", str(config), "-f", str(tmp_path / "logs"),
                  "--seed", "0", "--score-episodes", "2")  # fmt: skip
    assert trained.returncode == 0, trained.stderr[-3000:]
    lines = trained.stdout.strip().splitlines()
    assert not [line for line in lines if "time/" in line]  # no per-iteration tables below the quiet interval
    assert lines[-1].startswith("Pendulum-v1: deterministic planner over 2 episodes: return ")
    assert "(expert -148.2, random -1243.2), normalised score " in lines[-1]  # pendulum.json's returns
    loud = zoo("train", "--algo", "mpail", "--env", "Pendulum-v1", "-conf", str(config), "-f", str(tmp_path / "logs"),
               "--seed", "0", "--score-episodes", "0", "--log-interval", "10", "-n", "320")  # fmt: skip
    assert loud.returncode == 0, loud.stderr[-3000:]
    assert sum("time/" in line for line in loud.stdout.splitlines()) == 1 and "normalised score" not in loud.stdout
