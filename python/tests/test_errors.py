"""Bad input is a specific Python exception with the Rust error's message, before any work;
never a crash or a panic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import brightpix
from conftest import run_cli

GRID = dict(x=0, y=0, columns=2, rows=1, width=16, height=16)


@pytest.fixture
def config() -> brightpix.Config:
    return brightpix.Config(width=32, height=16, bit_depth=12, grid=GRID)


def test_frames_of_the_wrong_type(config: brightpix.Config) -> None:
    good = np.zeros((3, 16, 32), np.uint16)
    with pytest.raises(
        TypeError, match=r"uint8 or uint16 camera counts; got dtype float64.*astype"
    ):
        brightpix.process(good.astype(np.float64), config)
    with pytest.raises(TypeError, match="got dtype int32"):
        brightpix.process(good.astype(np.int32), config)
    with pytest.raises(TypeError, match="must be a numpy array .* not list"):
        brightpix.process(good.tolist(), config)
    with pytest.raises(TypeError):
        brightpix.process(good, "canary.toml")
    with pytest.raises(ValueError, match="thread count of 0"):
        brightpix.process(good, config, threads=0)


def test_frames_of_the_wrong_shape(config: brightpix.Config) -> None:
    with pytest.raises(
        ValueError,
        match=r"frames are 16x31 pixels \(height x width\); the "
        r"configuration's camera is 16x32",
    ):
        brightpix.process(np.zeros((3, 16, 31), np.uint16), config)
    with pytest.raises(
        ValueError,
        match=r"shape \(height, width\) or \(frames, height, width\); "
        r"got \(2, 3, 16, 32\)",
    ):
        brightpix.process(np.zeros((2, 3, 16, 32), np.uint16), config)


def test_pixels_above_the_bit_depth(config: brightpix.Config) -> None:
    frames = np.zeros((3, 16, 32), np.uint16)
    frames[2, 5, 7] = 4096
    with pytest.raises(ValueError, match="frame 2: pixel at row 5, column 7 is 4096"):
        brightpix.process(frames, config)
    with pytest.raises(ValueError, match="frame 2: raw pixel at row 5, column 7 is 4096"):
        brightpix.process(frames, config, reference=True)


def test_bad_maps_and_values() -> None:
    bg = np.full((16, 32), 50.0)
    bg[3, 4] = np.nan
    with pytest.raises(ValueError, match=r"^background: pixel \(row 3, column 4\) is NaN counts"):
        brightpix.Config(width=32, height=16, grid=GRID, background=bg)
    flat = np.ones((16, 32))
    flat[1, 2] = -0.5
    with pytest.raises(ValueError, match=r"^flat: pixel \(row 1, column 2\) has gain -0.5"):
        brightpix.Config(width=32, height=16, grid=GRID, flat=flat)
    with pytest.raises(ValueError, match=r"^flat: shape \(32, 16\); expected \(16, 32\)"):
        brightpix.Config(width=32, height=16, grid=GRID, flat=np.ones((32, 16)))
    with pytest.raises(ValueError, match="^n: .*2 entries, expected one per sub-aperture|^n:"):
        brightpix.Config(width=32, height=16, grid=GRID, n=[1, 2, 3])
    with pytest.raises(ValueError, match=r"^n: entry 1 is 2.5; expected an integer"):
        brightpix.Config(width=32, height=16, grid=GRID, n=[1, 2.5])
    with pytest.raises(ValueError, match="^n: N, the number of pixels to select, is 0"):
        brightpix.Config(width=32, height=16, grid=GRID, n=0)
    with pytest.raises(ValueError, match='^mean_count: rule = "subtract-mean" needs mean_count'):
        brightpix.Config(width=32, height=16, grid=GRID, rule="subtract-mean")
    with pytest.raises(ValueError, match='^rule: "median" is not a rule'):
        brightpix.Config(width=32, height=16, grid=GRID, rule="median")
    with pytest.raises(ValueError, match="^grid: unknown field `colour`"):
        brightpix.Config(width=32, height=16, grid={**GRID, "colour": 1})
    with pytest.raises(ValueError, match="give exactly one of grid"):
        brightpix.Config(width=32, height=16)
    with pytest.raises(ValueError, match="^width: -1 is out of range"):
        brightpix.Config(width=-1, height=16, grid=GRID)
    with pytest.raises(ValueError, match=r"^windows: sub-aperture 1 \(row 1: x = 30"):
        brightpix.Config(width=32, height=16, windows=[[0, 0, 8, 8], [30, 0, 8, 8]])
    with pytest.raises(TypeError, match="^threshold must be a number"):
        brightpix.Config(width=32, height=16, grid=GRID, threshold="high")


def test_config_file_errors_are_the_command_lines(cli: Path, tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(
        "[camera]\nwidth = 32\nheight = 16\nbit_depth = 12\n"
        "[subapertures.grid]\nx = 0\ny = 0\ncolumns = 3\nrows = 1\n"
        "width = 16\nheight = 16\n[selection]\npixel = 20\n"
    )
    with pytest.raises(ValueError) as python:
        brightpix.Config.load(path)
    frames = tmp_path / "f.npy"
    np.save(frames, np.zeros((1, 16, 32), np.uint16))
    done = run_cli(
        cli, "process", "--config", path, "--frames", frames, "--out", tmp_path / "o.npy"
    )
    assert done.returncode != 0
    assert str(python.value) in done.stderr
    assert "unknown field `pixel`" in str(python.value)
    path.write_text(path.read_text().replace("pixel = 20", "pixels = 20"))
    with pytest.raises(ValueError, match=r"bad.toml: subapertures.grid: sub-aperture 2 .* extends"):
        brightpix.Config.load(path)
    path.write_text(
        path.read_text().replace("[selection]", '[calibration]\nflat = "no.npy"\n[selection]')
    )
    with pytest.raises(OSError, match="calibration.flat"):
        brightpix.Config.load(path)
    with pytest.raises(FileNotFoundError, match="cannot read the configuration"):
        brightpix.Config.load(tmp_path / "missing.toml")


def test_missing_port() -> None:
    with pytest.raises(FileNotFoundError, match="cannot open /dev/brightpix-missing"):
        brightpix.Device("/dev/brightpix-missing")
    with pytest.raises(ValueError, match="timeout must be a positive"):
        brightpix.Device("/dev/brightpix-missing", timeout=0)


def test_bad_simulation_and_centroid_arguments() -> None:
    with pytest.raises(ValueError, match='conditions "lgs": expected "ngs"'):
        brightpix.simulate("lgs", frames=1)
    with pytest.raises(ValueError, match="conditions: unknown field `r0`"):
        brightpix.simulate({"r0": 0.1}, frames=1)
    with pytest.raises(ValueError, match="invalid simulation parameter"):
        brightpix.simulate({"photons": -1.0}, frames=1)
    with pytest.raises(TypeError, match="conditions must be a name"):
        brightpix.simulate(3, frames=1)
    with pytest.raises(ValueError, match="at most 64x64"):
        brightpix.centroid(np.zeros((65, 8), np.uint16), 4)
    with pytest.raises(TypeError, match="uint8 or uint16"):
        brightpix.centroid(np.zeros((8, 8)), 4)
    with pytest.raises(ValueError, match="the value is -1; expected an integer"):
        brightpix.centroid(np.zeros((8, 8), np.uint16), -1)
