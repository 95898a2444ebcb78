"""brightpix.tune chooses the rule and N as ``brightpix tune`` does: the same files, byte for
byte; recorded frames measured; bad values refused before any simulation; truncated spots warn."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import brightpix
from conftest import run_cli

LGS = dict(lgs="rayleigh:1500", classes=2, frames=40)


@pytest.fixture(scope="module")
def lgs_result(canary: brightpix.Config) -> brightpix.TuneResult:
    return brightpix.tune(canary, **LGS)


def test_writes_what_the_command_line_writes(
    lgs_result: brightpix.TuneResult, repo: Path, cli: Path, tmp_path: Path
) -> None:
    ours = lgs_result.save(tmp_path / "py", name="lgs")
    assert [p.name for p in ours] == ["lgs.toml", "lgs-tune.csv", "lgs-tune.svg", "lgs-tune.png"]
    done = run_cli(
        cli,
        "tune",
        "--config",
        repo / "examples" / "canary.toml",
        "--out",
        tmp_path / "cli",
        "--name",
        "lgs",
        "--lgs",
        "rayleigh:1500",
        "--launch",
        "0,0",
        "--classes",
        2,
        "--count",
        40,
    )
    assert done.returncode == 0, done.stderr
    for name in ["lgs.toml", "lgs-tune.csv", "lgs-tune.svg"]:
        theirs = (tmp_path / "cli" / name).read_bytes()
        assert (tmp_path / "py" / name).read_bytes() == theirs, name
    # The command line prints the assumptions the result holds.
    for line in lgs_result.assumptions:
        assert f"brightpix: tune: {line}" in done.stderr


def test_save_refuses_a_bad_name_and_an_unwritable_directory(
    lgs_result: brightpix.TuneResult, tmp_path: Path
) -> None:
    with pytest.raises(ValueError, match="plain file name"):
        lgs_result.save(tmp_path, name="../elsewhere")
    taken = tmp_path / "taken"
    taken.write_text("keep")
    with pytest.raises(OSError, match="cannot create"):
        lgs_result.save(taken / "tuned")
    assert taken.read_text() == "keep"
    assert list(tmp_path.iterdir()) == [taken]


def test_result_describes_the_classes(
    lgs_result: brightpix.TuneResult, canary: brightpix.Config
) -> None:
    # The 4 corner windows are outside the 4.2 m pupil and 8 more are lit below half their area.
    assert len(lgs_result.dark) == 12
    tuned = lgs_result.config
    assert tuned.n_subapertures == 37
    assert lgs_result.score == "along the elongation"
    classes = lgs_result.classes
    members = sorted(i for c in classes for i in c["windows"])
    assert members == sorted(set(range(49)) - set(lgs_result.dark))
    for c in classes:
        assert 1 <= c["n"] <= 256
        assert c["r"] > 0 and c["r_se"] > 0
        assert c["r"] <= c["r_all_pixels"] + 4 * c["r_se"]
    scores = lgs_result.scores
    rows = len(scores["rule"])
    assert all(len(v) == rows for v in scores.values())
    for k, n in [(k, c["n"]) for k, c in enumerate(classes)]:
        mine = (scores["class"] == k) & (scores["n"] == n)
        rules = {r for r, m in zip(scores["rule"], mine) if m}
        assert lgs_result.rule in rules
    # The tuned configuration processes frames of the camera.
    frames = brightpix.simulate("ngs", frames=3, seed=5, grid=(7, 7)).frames
    assert brightpix.process(frames, tuned).slopes.shape == (3, 37, 2)


# The spot size fitted to 30 noisy frames may come out wide enough to warn of truncation.
@pytest.mark.filterwarnings("ignore:spots are truncated")
def test_recorded_frames_set_the_conditions(canary: brightpix.Config) -> None:
    recorded = brightpix.simulate({"read_noise_e": 4.0}, frames=30, seed=2, grid=(7, 7)).frames
    result = brightpix.tune(canary, recorded=recorded, frames=20)
    text = "\n".join(result.assumptions)
    assert text.count("measured from the recorded frames (30 frames)") == 1, text
    assert "r0 0.1250" not in text and "(fitted: shift-and-add spot FWHM" in text
    # The read noise is measured (4 e- simulated), not the default 2 e-.
    noise = float(re.search(r"detector: .* read noise ([0-9.]+) e-", text).group(1))
    assert 3.6 < noise < 4.4, text


@pytest.mark.parametrize(
    ("keywords", "error", "message"),
    [
        (dict(frames=10), ValueError, "at least 20"),
        (dict(classes=0), ValueError, "distance class"),
        (dict(score="sideways"), ValueError, "one of along, pooled"),
        (dict(lgs="helium:3"), ValueError, "rayleigh:DEPTH"),
        (dict(illumination_threshold=0.0), ValueError, "illumination threshold"),
        (dict(level_filter=20), ValueError, "1..=16"),
        (dict(conditions={"source": {"kind": "ngs"}}), ValueError, "set by tune itself"),
        (dict(conditions={"r0": 0.1}), ValueError, "unknown field"),
        (dict(conditions={"r0_m": -1.0}), ValueError, "r0"),
        (dict(conditions="ngs"), TypeError, "lgs="),
        (dict(recorded=np.zeros((2, 8, 8), np.uint16)), ValueError, "recorded"),
    ],
)
def test_bad_values_are_refused_before_any_work(
    canary: brightpix.Config, keywords: dict, error: type, message: str
) -> None:
    with pytest.raises(error, match=message):
        brightpix.tune(canary, **keywords)


def test_truncated_spots_warn(canary: brightpix.Config) -> None:
    # The paper's sodium LGS at 0.22"/pixel: the spots do not fit their 16x16 windows.
    with pytest.warns(UserWarning, match="truncated"):
        result = brightpix.tune(canary, lgs="sodium:8000", launch=(21.0, 0.0), frames=20, classes=1)
    assert result.truncated
