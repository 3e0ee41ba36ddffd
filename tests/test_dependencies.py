"""Every third-party package that the package, its tests, benchmarks and demo scripts import is declared in
pyproject.toml, as a dependency or in an extra: the newest stack installs exactly what is declared."""

import ast
import re
import sys
from importlib import metadata
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python 3.11+

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("sb3_mpail", "benchmarks", "tests", "demos")
#: distributions of the optional imports that the test install leaves out
NOT_INSTALLED = {"pytorch_mppi": "pytorch-mppi"}
#: imported where present, never needed: gymnasium's own dependency, read only to drop a notice (sb3_mpail/_quiet.py)
UNDECLARED_ON_PURPOSE = {"farama_notifications"}


def normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def declared_distributions() -> set:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = [*project["dependencies"], *(r for extra in project["optional-dependencies"].values() for r in extra)]
    return {normalise(re.match(r"[A-Za-z0-9][A-Za-z0-9._-]*", requirement).group()) for requirement in requirements}


def imported_modules() -> dict:
    """:return: top-level module imported -> the files importing it, for the modules that are not ours or stdlib"""
    files = [path for folder in FOLDERS for path in (ROOT / folder).rglob("*.py")]
    local = {*FOLDERS, *(path.stem for path in files)}
    modules: dict = {}
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in local and top not in sys.stdlib_module_names:
                    modules.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    return modules


def test_every_imported_package_is_declared():
    distributions = metadata.packages_distributions()
    declared = declared_distributions()
    undeclared = {}
    for module, files in sorted(imported_modules().items()):
        if module in UNDECLARED_ON_PURPOSE:
            continue
        installed = distributions.get(module) or [NOT_INSTALLED.get(module, module)]
        providers = {normalise(name) for name in installed}
        if not providers & declared:
            undeclared[module] = (sorted(providers), sorted(files))
    assert not undeclared, f"imported but not declared in pyproject.toml (module: distributions, files): {undeclared}"


def test_nothing_relies_on_imitation_paths_that_break_on_the_newest_stack():
    # imitation 1.0.1's bc.reconstruct_policy unpickles with torch.load, refused by torch's weights_only default
    # (torch 2.6+); its util.video_wrapper imports gymnasium.wrappers.monitoring, gone in gymnasium 1.x. SB3's own
    # save and load, and SB3's VecVideoRecorder, do those jobs here.
    this_file = Path(__file__).resolve()
    files = [path for folder in FOLDERS for path in (ROOT / folder).rglob("*.py") if path.resolve() != this_file]
    users = [str(path.relative_to(ROOT)) for path in files if re.search(r"reconstruct_policy|video_wrapper", path.read_text())]
    assert not users
