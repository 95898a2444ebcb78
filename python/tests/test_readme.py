"""The README's Python examples run as written (from the repository root)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import brightpix


def readme_example(repo: Path, heading: str = "Python", index: int = 0) -> str:
    text = (repo / "README.md").read_text()
    section = text.split(f"\n## {heading}\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) > index, f"README.md's section {heading!r} has no python block {index}"
    return blocks[index]


def run_example(
    repo: Path, tmp_path: Path, heading: str, index: int = 0
) -> subprocess.CompletedProcess[str]:
    (tmp_path / "examples").mkdir()
    shutil.copy(repo / "examples" / "canary.toml", tmp_path / "examples")
    script = tmp_path / "example.py"
    script.write_text(readme_example(repo, heading, index))
    return subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
        timeout=300,
    )


def test_readme_example_runs(repo: Path, tmp_path: Path) -> None:
    done = run_example(repo, tmp_path, "Python")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("(200, 49, 2) ")
    assert 0.9 < float(done.stdout.split()[-1]) <= 1.0
    assert (tmp_path / "slopes.png").stat().st_size > 10_000


def test_readme_tune_example_runs(repo: Path, tmp_path: Path) -> None:
    done = run_example(repo, tmp_path, "Reproducing the paper; choosing N")
    assert done.returncode == 0, done.stderr
    rule, ns = done.stdout.split(" ", 1)
    assert rule in {"subtract-next", "threshold"} or rule.startswith("subtract-mean"), done.stdout
    assert all(1 <= int(n) <= 256 for n in ns.strip()[1:-1].split(", ")), done.stdout
    # The 4.2 m pupil leaves 37 of the 49 windows lit at least half.
    assert brightpix.Config.load(tmp_path / "tuned" / "tuned.toml").n_subapertures == 37
    for name in ["tuned-tune.csv", "tuned-tune.svg", "tuned-tune.png"]:
        assert (tmp_path / "tuned" / name).stat().st_size > 0, name


def test_readme_tune_wfe_example_runs(repo: Path, tmp_path: Path) -> None:
    done = run_example(repo, tmp_path, "Reproducing the paper; choosing N", index=1)
    assert done.returncode == 0, done.stderr
    rule, n, wfe, not_resolved = done.stdout.split(" ", 3)
    assert rule in {"subtract-next", "threshold"} or rule.startswith("subtract-mean"), done.stdout
    assert 1 <= int(n) <= 256 and 0 < int(wfe) < 1000, done.stdout
    assert int(n) in [int(m) for m in not_resolved.strip()[1:-1].split(", ")], done.stdout
    # One N for the 37 windows the 4.2 m pupil lights at least half.
    tuned = brightpix.Config.load(tmp_path / "tuned" / "tuned.toml")
    assert tuned.n_subapertures == 37 and tuned.keywords()["n"] == int(n)
    for suffix in [".csv", ".md", ".svg", ".png", "-strehl.svg", "-budget.png"]:
        assert (tmp_path / "tuned" / f"tuned-endtoend{suffix}").stat().st_size > 0, suffix
