"""Writes one benchmark's results into its own section of BENCHMARKS.md, leaving the other sections alone."""

import math
import platform
from pathlib import Path
from typing import Any, Iterable, List, Mapping, Sequence, Tuple

import numpy as np
import torch as th

BENCHMARKS_FILE = Path(__file__).resolve().parent.parent / "BENCHMARKS.md"


#: how the library's deterministic planning draws its samples, recorded beside the evaluations made with it: an earlier
#: version drew the same samples at every step (a worse planner), and locomotion results that lack this record came
#: from it
DETERMINISTIC_NOISE = "fresh at every step"
#: what evaluations of that earlier version (December 2 07:15 to December 3 14:45) record where one was marked after
#: the fact; navigation runs from before it record nothing, and were evaluated with fresh samples
SAME_NOISE = "the same at every step"


def machine_description() -> str:
    """One line naming the machine a figure was measured on."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    gpu = f", GPU {th.cuda.get_device_name()}" if th.cuda.is_available() else ""
    return f"{cpu}, {th.get_num_threads()} torch threads{gpu}; torch {th.__version__}, Python {platform.python_version()}"


def machines_of(runs: Iterable[Mapping[str, Any]]) -> str:
    """
    The machines a table's stored runs were measured on (each run's ``machine``, :func:`machine_description` when it
    ran), for the report's machine line: the machine writing the report may be another.

    :param runs: stored results
    """
    return "; ".join(sorted({run.get("machine", "machine not recorded") for run in runs}))


def commands_of(runs: Iterable[Mapping[str, Any]], unrecorded: str = "") -> List[str]:
    """
    The command lines that made a table's stored runs (each run's ``command``), sorted, for the report's command line:
    a table that several invocations filled quotes them all.

    :param runs: stored results
    :param unrecorded: what stands for the command of a run that predates the record
    """
    return sorted({run.get("command") or unrecorded for run in runs})


def write_section(name: str, markdown: str, path: Path = BENCHMARKS_FILE) -> None:
    """
    Replaces the section ``name`` (between ``<!-- name:start -->`` and ``<!-- name:end -->``) of BENCHMARKS.md,
    appending it if absent.

    :param name: section key, e.g. ``"pendulum"``
    :param markdown: the section's body
    """
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    header = "# Benchmarks\n\nEvery figure here was written by the command named beside it.\n"
    text = path.read_text() if path.exists() else header
    block = f"{start}\n{markdown.strip()}\n{end}"
    if start in text and end in text:
        before, rest = text.split(start, 1)
        text = before + block + rest.split(end, 1)[1]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    partial = path.with_name(path.name + ".partial")
    partial.write_text(text)
    partial.replace(path)


def mean_ci(values: Sequence[float]) -> Tuple[float, float]:
    """
    The mean and the half-width of its 95% confidence interval (Student's t; NaN for fewer than two values).

    :param values: one value per seed
    """
    from scipy import stats

    values = np.asarray(values, dtype=float)
    if len(values) < 2:
        return float(values.mean()), math.nan
    return float(values.mean()), float(stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / math.sqrt(len(values)))


def format_ci(mean: float, half_width: float, digits: int = 2, signed: bool = False) -> str:
    """``mean ± half_width`` (just the mean when the half-width is NaN); ``signed``: the mean's sign always shown."""
    return f"{mean:{'+' if signed else ''}.{digits}f}" + ("" if math.isnan(half_width) else f" ± {half_width:.{digits}f}")
