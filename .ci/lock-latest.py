"""
Writes constraints-latest.txt, the newest stack's exact versions, from a fresh resolution of sb3-mpail's ``test``
install on :data:`NEWEST`, without imitation's own requirements (imitation 1.0.1 pins stable-baselines3~=2.2.1 and
gymnasium~=0.29, which forbid the newest stack, though its code runs there): imitation is installed without them,
with what its modules that sb3-mpail uses import (:data:`IMITATION_NEEDS`).

    python3 .ci/lock-latest.py        # with the Python of the stack (3.11 here); needs network access to the index

The file is then installed whole, without dependency resolution: pip install --no-deps -r constraints-latest.txt -e .
"""

import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parent.parent
#: the newest stack's leading packages (torch: the CPU build on this machine's disk)
NEWEST = [
    "torch==2.13.0",
    "stable-baselines3==2.9.2",
    "sb3-contrib==2.9.2",
    "rl_zoo3==2.9.2",
    "gymnasium==1.4.0",
    "numpy>=2",
    "highway-env==1.12.1",
    "gymnasium-robotics==1.4.2",
    "mujoco==4.0.0",
]
IMITATION = "imitation==1.0.1"
#: what imitation's data (serialize), rewards, bc and adversarial modules import beside torch, numpy, gymnasium and SB3
IMITATION_NEEDS = ["tqdm", "rich", "datasets", "jsonpickle", "tensorboard"]


def requirements(extra: str, project: dict) -> list:
    """sb3-mpail's requirements with ``extra`` (extras of extras expanded), imitation left out."""
    found, pending = list(project["dependencies"]), [extra]
    while pending:
        for requirement in project["optional-dependencies"][pending.pop()]:
            nested = re.fullmatch(r"sb3-mpail\[(.+)\]", requirement)
            pending.extend(nested.group(1).split(",")) if nested else found.append(requirement)
    return [requirement for requirement in found if not requirement.startswith("imitation")]


def main() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = [*NEWEST, *IMITATION_NEEDS, *requirements("test", project)]
    with tempfile.TemporaryDirectory() as folder:
        report = Path(folder) / "report.json"
        subprocess.run(
            [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--quiet", "--report", str(report),
             *wanted],
            check=True,
        )
        resolved = json.loads(report.read_text())["install"]
    pins = sorted((f"{item['metadata']['name']}=={item['metadata']['version']}" for item in resolved), key=str.lower)
    pins = [re.sub(r"^torch==([^+]+)\+.*$", r"torch==\1", pin) for pin in pins]  # the local CPU build: torch==2.13.0
    header = [
        "# The newest stack (Python 3.11, CPU), exact versions, written by .ci/lock-latest.py. Install it whole, without",
        "# dependency resolution, because imitation 1.0.1's own pins (stable-baselines3~=2.2.1, gymnasium~=0.29) forbid it:",
        '#   python3 -m venv .venv-latest && .venv-latest/bin/pip install --no-deps -r constraints-latest.txt -e .',
        "# `pip check` then names only imitation's requirements.",
    ]
    (ROOT / "constraints-latest.txt").write_text("\n".join([*header, *pins, IMITATION]) + "\n")
    print(f"wrote constraints-latest.txt: {len(pins) + 1} packages")


if __name__ == "__main__":
    main()
