"""rl_zoo3's own train and enjoy scripts run MPAIL from a zoo-style YAML file and write the zoo's log layout."""

import subprocess
import sys

from sb3_mpail.demos import SHIPPED_DEMO_DIR
from sb3_mpail.zoo import HYPERPARAMS, with_default_hyperparams

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
    assert defaulted == ["train", "--algo", "mpail", "--env", "Pendulum-v1", "--conf-file", str(HYPERPARAMS)]
    named = ["train", "--algo", "mpail", "--env", "Pendulum-v1", "-conf", "mine.yml"]
    assert with_default_hyperparams(named) == named
    for other in (["train", "--algo", "ppo", "--env", "Pendulum-v1"], ["enjoy", "--algo", "mpail", "--env", "Pendulum-v1"]):
        assert with_default_hyperparams(other) == other


def test_zoo_help_lists_its_scripts_and_an_unknown_script_is_named():
    helped = zoo("--help")
    assert helped.returncode == 0 and "{train,enjoy,record_video," in helped.stdout
    wrong = zoo("trian", "--algo", "mpail")
    assert wrong.returncode != 0 and "unknown script 'trian'" in wrong.stderr and "Traceback" not in wrong.stderr
