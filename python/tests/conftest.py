"""Shared fixtures: the repository, the ``brightpix`` command line, small configurations."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import brightpix

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def cli() -> Path:
    """The ``brightpix`` executable: $BRIGHTPIX_CLI, else built with cargo (dev profile)."""
    given = os.environ.get("BRIGHTPIX_CLI")
    if given:
        return Path(given)
    if shutil.which("cargo") is None:
        pytest.skip("cargo is not installed: cannot build the brightpix command line")
    out = subprocess.run(
        ["cargo", "build", "-q", "-p", "brightpix", "--bin", "brightpix", "--message-format=json"],
        cwd=REPO,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    for line in out.splitlines():
        message = json.loads(line)
        if message.get("reason") == "compiler-artifact" and message.get("executable"):
            if message["target"]["name"] == "brightpix":
                return Path(message["executable"])
    raise RuntimeError("cargo built no brightpix executable")


def run_cli(cli: Path, *args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(cli), *map(str, args)], capture_output=True, text=True)


@pytest.fixture(scope="session")
def canary_frames() -> np.ndarray:
    """20 simulated CANARY frames (7x7 NGS spots of 16x16 on 112x112, 50-count background)."""
    return brightpix.simulate("ngs", frames=20, seed=3, grid=(7, 7)).frames


@pytest.fixture(scope="session")
def canary(repo: Path) -> brightpix.Config:
    return brightpix.Config.load(repo / "examples" / "canary.toml")
