"""The README's Python examples run as written, the training budget alone shrunk."""

import re
from pathlib import Path

from sb3_mpail.train_navigation import make_model

README = Path(__file__).resolve().parent.parent / "README.md"
#: the quickstart's budget, replaced by a tiny one (the only change made to an example)
QUICKSTART_BUDGET = "model.learn(50_000, progress_bar=True)"


def readme_examples() -> list:
    """The README's ```python blocks, in order."""
    return re.findall(r"^```python\n(.*?)^```", README.read_text(), flags=re.S | re.M)


def test_the_readme_has_the_quickstart_and_the_deployment_example():
    examples = readme_examples()
    assert len(examples) == 2 and QUICKSTART_BUDGET in examples[0] and "MPAIL.load(\"runs/navigation" in examples[1]


def test_the_quickstart_trains_saves_reloads_and_scores(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    exec(readme_examples()[0].replace(QUICKSTART_BUDGET, "model.learn(400)"), {})
    printed = capsys.readouterr().out.splitlines()
    assert "pendulum_4" in printed[0] and (tmp_path / "pendulum.zip").is_file()
    float(printed[-1])  # the normalised score


def test_the_deployment_example_drives_a_saved_navigation_model_from_both_start_regions(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    tiny = make_model(n_envs=2, policy_kwargs=dict(n_samples=8, horizon=3, n_iterations=1), n_steps=50)
    tiny.learn(100)
    tiny.save(tmp_path / "runs" / "navigation" / "model.zip")  # where the main command saves it
    exec(readme_examples()[1], {})
    printed = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in printed] == ["default", "ood"]
    assert all(re.fullmatch(r"\w+: [\d.]+ m from the goal, then [\d.]+ m after 100 steps", line) for line in printed)
