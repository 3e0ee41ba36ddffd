"""The API reference (docs/api) builds from the docstrings with Sphinx, warnings as errors, as CI builds it."""

import subprocess
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent.parent / "docs" / "api"


def test_api_reference_builds_without_warnings(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(DOCS), str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, f"the API reference does not build cleanly:\n{result.stdout}\n{result.stderr}"
    algorithm = (tmp_path / "mpail.html").read_text()
    # MPAIL's own methods and the ones it inherits from Stable-Baselines3, with their docstrings
    assert 'id="sb3_mpail.MPAIL.learn"' in algorithm
    assert "Trains for" in algorithm
    assert 'id="sb3_mpail.MPAIL.predict"' in algorithm
    # every page of the public API is there, e.g. the planner and the policy
    assert 'id="sb3_mpail.mppi.planner.MPPIPlanner"' in (tmp_path / "mppi.html").read_text()
    assert 'id="sb3_mpail.policies.MPPIPolicy.predict"' in (tmp_path / "policies.html").read_text()
