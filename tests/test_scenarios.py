"""Smoke tests of issue 5's scenarios: each trains from its shipped demos with its zoo_configs/mpail.yml entry."""

import subprocess
import sys
from pathlib import Path

from sb3_mpail import MPAIL
from sb3_mpail.mppi.costs import FeatureSelection
from sb3_mpail.mppi.dynamics import LearnedDynamics

ROOT = Path(__file__).resolve().parent.parent


def zoo_train(env_id: str, timesteps: int, logs: Path) -> MPAIL:
    trained = subprocess.run(
        [sys.executable, "-m", "sb3_mpail.zoo", "train", "--algo", "mpail", "--env", env_id,
         "-conf", str(ROOT / "zoo_configs" / "mpail.yml"), "-f", str(logs), "--seed", "0", "-n", str(timesteps)],
        capture_output=True, text=True, timeout=300, cwd=ROOT,
    )
    assert trained.returncode == 0, trained.stderr[-3000:]
    name = env_id.replace("/", "-")
    model = MPAIL.load(logs / "mpail" / f"{name}_1" / f"{name}.zip")
    assert model.num_timesteps == timesteps
    return model


def test_cartpole_mpail_om_trains_with_the_shipped_zoo_entry(tmp_path):
    model = zoo_train("sb3_mpail/ContinuousCartPole-v0", 800, tmp_path)
    # MPAIL-OM: no prior model, the planner's dynamics were fitted online to the agent's own transitions
    assert isinstance(model.policy.dynamics, LearnedDynamics)
    assert int(model.policy.dynamics.epochs_trained) > 0


def test_lap_from_one_noisy_partial_demo_trains_with_the_shipped_zoo_entry(tmp_path):
    model = zoo_train("sb3_mpail/NavigationLap-v0", 960, tmp_path)
    assert model.demos_are_features
    # the discriminator sees x, y, vx, vy; the value sees the whole 12-D state
    assert isinstance(model.policy.discriminator_features, FeatureSelection)
    assert model.policy.discriminator_features.indices.tolist() == [0, 1, 6, 7]
    assert model.policy.feature_space.shape == (4,) and model.policy.value_net[0].in_features == 12
