"""The README's Python example runs as written (from the repository root)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path


def readme_example(repo: Path) -> str:
    text = (repo / "README.md").read_text()
    section = text.split("\n## Python\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert blocks, "README.md's Python section has no python block"
    return blocks[0]


def test_readme_example_runs(repo: Path, tmp_path: Path) -> None:
    (tmp_path / "examples").mkdir()
    shutil.copy(repo / "examples" / "canary.toml", tmp_path / "examples")
    script = tmp_path / "example.py"
    script.write_text(readme_example(repo))
    done = subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("(200, 49, 2) ")
    assert 0.9 < float(done.stdout.split()[-1]) <= 1.0
    assert (tmp_path / "slopes.png").stat().st_size > 10_000
