"""brightpix.tune(..., criterion="wfe") chooses the rule and N of least end-to-end residual
wavefront error as ``brightpix tune --criterion wfe`` does: the same files, byte for byte but
the summary's wall-clock line; a result whose fields agree with its scores and its TOML; every
bad value, and every keyword of the other criterion, refused before any simulation."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import brightpix
from conftest import run_cli

# A 4x4 grid of 8x8 windows: an end-to-end run of a few frames takes seconds with the
# command line's debug build (the 7x7 CANARY grid takes a minute).
SMALL = """\
[camera]
width = 32
height = 32
bit_depth = 12

[subapertures.grid]
x = 0
y = 0
columns = 4
rows = 4
width = 8
height = 8

[calibration]
background_counts = 10.0

[selection]
rule = "subtract-next"
pixels = 10
"""

# The same run as keywords of brightpix.tune and as options of brightpix tune.
CASES = {
    "defaults": (
        dict(episodes=2, episode_frames=4),
        ["--episodes", 2, "--episode-frames", 4],
    ),
    "every-condition": (
        dict(
            episodes=2,
            episode_frames=3,
            asterism=[(30.0, 0.0), (30.0, 120.0), [30.0, 240.0]],
            science=(10.0, 45.0),
            layers=[(0.0, 0.7, 5.0, 10.0), (2000.0, 0.3, 12.0, 100.0)],
            wind_scale=1.5,
            frame_rate=500.0,
            delay=1.5,
            science_wavelength=2.2e-6,
            dm_actuators=6,
            dm_coupling=0.3,
            fixed_noise=0.3,
            calibration_episodes=2,
            level_filter=3,
            seed=7,
            obscuration=0.8,
        ),
        [
            "--episodes", 2, "--episode-frames", 3, "--asterism", "30,0;30,120;30,240",
            "--science", "10,45", "--layers", "0:0.7:5:10,2000:0.3:12:100", "--wind-scale", 1.5,
            "--frame-rate", 500, "--delay", 1.5, "--science-wavelength", 2.2e-6,
            "--dm-actuators", 6, "--dm-coupling", 0.3, "--fixed-noise", 0.3,
            "--calibration-episodes", 2, "--level-filter", 3, "--seed", 7, "--obscuration", 0.8,
        ],
    ),
}  # fmt: skip

CONDITIONS = {"pixel_scale_arcsec": 0.4}

# The summary's run line: the seed and episodes, then wall-clock seconds (differ run to run).
RUN_LINE = re.compile(r"^seed \d+, \d+ episodes of \d+ frames \+ \d+ calibration; \d+ s: ")


@pytest.fixture(scope="module")
def small_toml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("config") / "small.toml"
    path.write_text(SMALL)
    return path


@pytest.fixture(scope="module")
def small(small_toml: Path) -> brightpix.Config:
    return brightpix.Config.load(small_toml)


@pytest.fixture(scope="module")
def result(small: brightpix.Config) -> brightpix.WfeTuneResult:
    return brightpix.tune(small, CONDITIONS, criterion="wfe", **CASES["defaults"][0])


def without_run_line(path: Path) -> list[str]:
    lines = path.read_text().splitlines()
    timed = [k for k, line in enumerate(lines) if RUN_LINE.match(line)]
    assert len(timed) == 1, lines[:5]
    return lines[: timed[0]] + lines[timed[0] + 1 :]


@pytest.mark.parametrize("case", CASES)
def test_writes_what_the_command_line_writes(
    case: str, small: brightpix.Config, small_toml: Path, cli: Path, tmp_path: Path
) -> None:
    keywords, options = CASES[case]
    ours = brightpix.tune(small, CONDITIONS, criterion="wfe", **keywords)
    paths = ours.save(tmp_path / "py", name="w")
    names = [p.name for p in paths]
    assert names == [
        "w.toml",
        "w-endtoend.csv",
        "w-endtoend.md",
        "w-endtoend.svg",
        "w-endtoend.png",
        "w-endtoend-strehl.svg",
        "w-endtoend-strehl.png",
        "w-endtoend-budget.svg",
        "w-endtoend-budget.png",
    ]
    done = run_cli(
        cli,
        "tune",
        "--config",
        small_toml,
        "--criterion",
        "wfe",
        "--pixel-scale",
        0.4,
        "--out",
        tmp_path / "cli",
        "--name",
        "w",
        *options,
    )
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in (tmp_path / "cli").iterdir()) == sorted(names)
    for name in names:
        theirs, mine = tmp_path / "cli" / name, tmp_path / "py" / name
        if name.endswith(".md"):
            # The one line of wall-clock times is left out; everything else is identical.
            assert without_run_line(mine) == without_run_line(theirs), name
        else:
            assert mine.read_bytes() == theirs.read_bytes(), name
    # The command line prints the assumptions the result holds.
    for line in ours.assumptions:
        assert f"brightpix: tune: {line}" in done.stderr or (
            f"brightpix: endtoend: {line}" in done.stderr
        ), line
    assert f"{ours.rule} N = {ours.n}: {ours.wfe_nm:.1f} ± {ours.wfe_se_nm:.1f} nm" in done.stdout


def test_recorded_frames_set_the_conditions_as_the_command_lines_frames(
    small: brightpix.Config, small_toml: Path, cli: Path, tmp_path: Path
) -> None:
    # 4x4 spots of 8x8 at 0.4"/pixel with 3 e- read noise on the small camera, over a 50-count
    # background where the configuration subtracts 10: the read noise and the residual
    # background are measured, and the spot size is not (so r0 is not fitted: the fit simulates
    # 2,400 frames, half a minute in the command line's debug build; test_tune.py covers it).
    simulated = {"pixels_per_subaperture": 8, "pixel_scale_arcsec": 0.4, "read_noise_e": 3.0}
    recorded = brightpix.simulate(
        {**simulated, "bit_depth": 12, "background": 50.0}, frames=30, seed=2, grid=(4, 4)
    ).frames
    np.save(tmp_path / "recorded.npy", recorded)
    ours = brightpix.tune(
        small, CONDITIONS, recorded=recorded, criterion="wfe", episodes=2, episode_frames=3
    )
    text = "\n".join(ours.assumptions)
    assert "measured from the recorded frames (30 frames): read noise 3.0" in text, text
    assert "residual background 40." in text, text
    # The measured read noise and photons are the end-to-end sensors' (not the 2 e- and 200).
    sensors = next(a for a in ours.assumptions if a.startswith("wavefront sensors:"))
    assert "read noise 2 e-" not in sensors and " 200 photons" not in sensors, sensors
    names = [p.name for p in ours.save(tmp_path / "py")]
    done = run_cli(
        cli,
        "tune",
        "--config",
        small_toml,
        "--criterion",
        "wfe",
        "--pixel-scale",
        0.4,
        "--frames",
        tmp_path / "recorded.npy",
        "--episodes",
        2,
        "--episode-frames",
        3,
        "--out",
        tmp_path / "cli",
    )
    assert done.returncode == 0, done.stderr
    for name in names:
        theirs, mine = tmp_path / "cli" / name, tmp_path / "py" / name
        if name.endswith(".md"):
            assert without_run_line(mine) == without_run_line(theirs), name
        elif name.endswith(".toml"):
            # The one difference: the command line names the file the frames came from.
            source = str(tmp_path / "recorded.npy")
            assert mine.read_text() == theirs.read_text().replace(source, "the recorded frames")
        else:
            assert mine.read_bytes() == theirs.read_bytes(), name


def test_result_agrees_with_its_scores_and_its_toml(
    result: brightpix.WfeTuneResult, tmp_path: Path
) -> None:
    scores = result.scores
    rows = len(scores["rule"])
    assert set(scores) == {"rule", "n", "all_pixels", "wfe_nm", "wfe_se_nm", "strehl", "strehl_se"}
    assert all(len(v) == rows for v in scores.values())
    assert all(isinstance(v, np.ndarray) for k, v in scores.items() if k != "rule")
    rules = np.array(scores["rule"])
    # 5 candidate rules, each at every N below the 64 pixels of a window and with all of them.
    assert len(set(rules)) == 5 and rows == 5 * 19
    assert scores["n"][scores["all_pixels"]].tolist() == [64] * 5
    # The chosen rule and N have the least residual of all, and are the row they report.
    best = int(np.argmin(scores["wfe_nm"]))
    assert (rules[best], int(scores["n"][best])) == (result.rule, result.n)
    assert scores["wfe_nm"][best] == result.wfe_nm
    assert scores["wfe_se_nm"][best] == result.wfe_se_nm > 0
    assert scores["strehl"][best] == result.strehl
    assert 0 < result.strehl < 1 and result.science_wavelength_m == 1.65e-6
    first_all = int(np.flatnonzero(scores["all_pixels"])[0])
    assert result.wfe_all_pixels_nm == scores["wfe_nm"][first_all] >= result.wfe_nm
    # N not resolved from the best: N of the chosen rule, the best among them, in order.
    mine = rules == result.rule
    assert result.n in result.not_resolved
    assert set(result.not_resolved) <= set(scores["n"][mine].tolist())
    assert result.not_resolved == sorted(result.not_resolved)
    # The 4.2 m pupil lights the corners of the 4x4 grid below half their area.
    assert result.dark == [0, 3, 12, 15]
    tuned = result.config
    assert tuned.n_subapertures == 16 - len(result.dark)
    keywords = tuned.keywords()
    assert keywords["n"] == result.n
    assert result.rule.startswith(keywords["rule"])
    frames = np.full((2, 32, 32), 10, np.uint16)
    assert brightpix.process(frames, tuned).slopes.shape == (2, 12, 2)
    # The assumptions: the sensor's, then the end-to-end run's.
    assert result.assumptions[0].startswith("telescope 4.2 m")
    assert any(a.startswith("loop: open-loop MOAO at 250 Hz") for a in result.assumptions)
    # What was scored is the residual WFE, not R per class of sub-apertures.
    scoring = next(a for a in result.assumptions if a.startswith("scoring:"))
    assert "residual wavefront error" in scoring and "frames per class" not in scoring, scoring
    assert not any("representative sub-aperture" in a for a in result.assumptions)
    assert "WfeTuneResult" in repr(result) and result.rule in repr(result)
    # The saved TOML's [tuned] table holds the same.
    tomllib = pytest.importorskip("tomllib")
    path = result.save(tmp_path)[0]
    table = tomllib.loads(path.read_text())["tuned"]
    assert (table["criterion"], table["rule"], table["N"]) == ("wfe", result.rule, result.n)
    assert (table["wfe_nm"], table["wfe_se_nm"]) == (result.wfe_nm, result.wfe_se_nm)
    assert table["strehl"] == result.strehl
    assert table["wfe_all_pixels_nm"] == result.wfe_all_pixels_nm
    assert table["N_not_resolved_from_best"] == result.not_resolved
    assert table["dark_windows"] == result.dark
    assert (table["episodes"], table["episode_frames"], table["seed"]) == (2, 4, 1)
    assert brightpix.Config.load(path).to_toml() == tuned.to_toml()


def test_save_refuses_a_bad_name_and_an_unwritable_directory(
    result: brightpix.WfeTuneResult, tmp_path: Path
) -> None:
    with pytest.raises(ValueError, match="plain file name"):
        result.save(tmp_path, name="../elsewhere")
    taken = tmp_path / "taken"
    taken.write_text("keep")
    with pytest.raises(OSError, match="cannot create"):
        result.save(taken / "tuned")
    assert taken.read_text() == "keep"
    assert list(tmp_path.iterdir()) == [taken]


WFE = dict(criterion="wfe")


@pytest.mark.parametrize(
    ("keywords", "error", "message"),
    [
        (dict(criterion="strehl"), ValueError, "one of r, wfe"),
        (dict(WFE, lgs="rayleigh:1000"), ValueError, "natural guide stars"),
        (dict(WFE, frames=100), ValueError, "criterion wfe has no use for frames"),
        (dict(WFE, score="pooled"), ValueError, "no use for score"),
        (dict(WFE, classes=2), ValueError, "no use for classes"),
        (dict(WFE, angle_classes=1), ValueError, "no use for angle_classes"),
        (dict(WFE, keep_dark=True), ValueError, "no use for keep_dark"),
        (dict(WFE, max_truncation=0.1), ValueError, "no use for max_truncation"),
        (dict(WFE, launch=(1.0, 0.0)), ValueError, "no use for launch"),
        (dict(WFE, lgs_spot=0.5), ValueError, "no use for lgs_spot"),
        (dict(episodes=4), ValueError, "episodes is an end-to-end condition"),
        (dict(asterism=[(30.0, 0.0)]), ValueError, "criterion wfe only"),
        (dict(WFE, episodes=1), ValueError, "episodes 1: at least 2"),
        (dict(WFE, episode_frames=0), ValueError, "episode frames"),
        (dict(WFE, calibration_episodes=0), ValueError, "calibration episodes"),
        (dict(WFE, asterism=[]), ValueError, "at least one guide star"),
        (dict(WFE, asterism=[(30.0,)]), ValueError, r"asterism: star 0: expected \(radius"),
        (dict(WFE, asterism=[(30.0, 0.0), (-1.0, 0.0)]), ValueError, "asterism: guide star 1"),
        (dict(WFE, asterism="30,0"), TypeError, "asterism"),
        (dict(WFE, science=(0.0, float("nan"))), ValueError, "science target"),
        (dict(WFE, science=(1.0, 2.0, 3.0)), ValueError, "science: expected"),
        (dict(WFE, layers=[(0.0, -1.0, 5.0, 0.0)]), ValueError, "layers: every layer's fraction"),
        (dict(WFE, layers=[(0.0, 1.0, 5.0)]), ValueError, "layers: layer 0: expected"),
        (dict(WFE, layers=[(0.0, 1.0, -5.0, 0.0)]), ValueError, "wind speed"),
        (dict(WFE, wind_scale=-1.0), ValueError, "wind scale"),
        (dict(WFE, frame_rate=0.0), ValueError, "frame rate"),
        (dict(WFE, delay=-1.0), ValueError, "delay"),
        (dict(WFE, science_wavelength=0.0), ValueError, "science wavelength"),
        (dict(WFE, dm_actuators=1), ValueError, "DM actuators"),
        (dict(WFE, dm_coupling=1.5), ValueError, "DM coupling"),
        (dict(WFE, fixed_noise=0.0), ValueError, "fixed reconstructor noise"),
        (dict(WFE, illumination_threshold=0.0), ValueError, "illumination threshold"),
        (dict(WFE, level_filter=20), ValueError, "1..=16"),
        (dict(WFE, conditions={"source": {"kind": "ngs"}}), ValueError, "set by tune itself"),
        (dict(WFE, recorded=np.zeros((2, 8, 8), np.uint16)), ValueError, "recorded"),
        # Checked when the scenario is built, still before any frame is simulated.
        (dict(WFE, episode_frames=100_000), ValueError, "shorter episodes"),
    ],
)
def test_bad_values_are_refused_before_any_work(
    canary: brightpix.Config, keywords: dict, error: type, message: str
) -> None:
    with pytest.raises(error, match=message):
        brightpix.tune(canary, **keywords)
