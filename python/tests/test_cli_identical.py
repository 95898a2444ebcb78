"""brightpix.process gives the command line's numbers, bit for bit: every rule, calibration
maps (background, flat, pixel weight), threshold, minimum flux, reference slopes,
per-sub-aperture N, with and without the level filter; npy and FITS input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits

import brightpix
from conftest import run_cli

COLUMNS, ROWS, SIZE = 4, 3, 16
HEIGHT, WIDTH = ROWS * SIZE, COLUMNS * SIZE
S = COLUMNS * ROWS

RULES = [
    ("subtract-next", None),
    ("threshold", None),
    ("subtract-next-distinct", None),
    ("subtract-mean", 4),
]


@pytest.fixture(scope="module")
def case(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Frames and calibration data on disk, and the same as arrays."""
    d = tmp_path_factory.mktemp("cli")
    rng = np.random.default_rng(7)
    sim = brightpix.simulate("ngs", frames=24, seed=11, grid=(COLUMNS, ROWS))
    frames = sim.frames
    arrays = {
        "background": rng.uniform(45.0, 55.0, (HEIGHT, WIDTH)),
        "flat": rng.uniform(0.8, 1.2, (HEIGHT, WIDTH)),
        "pixel_weight": rng.uniform(0.9, 1.1, (HEIGHT, WIDTH)),
        "reference_slopes": rng.uniform(-0.5, 0.5, (S, 2)),
    }
    for name, a in arrays.items():
        np.save(d / f"{name}.npy", a)
    np.save(d / "frames.npy", frames)
    fits.writeto(d / "frames.fits", frames)
    n = rng.integers(3, 60, S)
    return {"dir": d, "frames": frames, "arrays": arrays, "n": n}


def write_config(case: dict, rule: str, mean_count: int | None, gain_shift: int | None) -> Path:
    n = ", ".join(str(v) for v in case["n"])
    text = f"""
[camera]
width = {WIDTH}
height = {HEIGHT}
bit_depth = 16

[subapertures.grid]
x = 0
y = 0
columns = {COLUMNS}
rows = {ROWS}
width = {SIZE}
height = {SIZE}

[calibration]
background = "background.npy"
flat = "flat.npy"
pixel_weight = "pixel_weight.npy"
threshold_counts = 1.5

[selection]
rule = "{rule}"
pixels = [{n}]
"""
    if mean_count is not None:
        text += f"mean_count = {mean_count}\n"
    if gain_shift is not None:
        text += f"\n[selection.level_filter]\ngain_shift = {gain_shift}\n"
    text += '\n[centroid]\nreference_slopes = "reference_slopes.npy"\nmin_flux_counts = 40.0\n'
    name = f"{rule}-{gain_shift}.toml"
    path = case["dir"] / name
    path.write_text(text)
    return path


CASES = [(rule, m, g) for rule, m in RULES for g in (None, 3) if not (rule == "threshold" and g)]


@pytest.mark.parametrize(("rule", "mean_count", "gain_shift"), CASES)
def test_identical_to_the_command_line(
    cli: Path, case: dict, rule: str, mean_count: int | None, gain_shift: int | None
) -> None:
    path = write_config(case, rule, mean_count, gain_shift)
    config = brightpix.Config.load(path)
    # the same configuration from keywords and arrays
    keywords = brightpix.Config(
        width=WIDTH,
        height=HEIGHT,
        bit_depth=16,
        grid=dict(x=0, y=0, columns=COLUMNS, rows=ROWS, width=SIZE, height=SIZE),
        rule=rule,
        n=case["n"],
        mean_count=mean_count,
        threshold=1.5,
        min_flux=40.0,
        level_filter=gain_shift,
        **case["arrays"],
    )
    assert keywords == config
    out = case["dir"] / f"{rule}-{gain_shift}"
    done = run_cli(
        cli,
        "process",
        "--config",
        path,
        "--frames",
        case["dir"] / "frames.npy",
        "--out",
        f"{out}-slopes.npy",
        "--valid-out",
        f"{out}-valid.npy",
    )
    assert done.returncode == 0, done.stderr
    cli_slopes = np.load(f"{out}-slopes.npy")
    cli_valid = np.load(f"{out}-valid.npy").astype(bool)

    result = brightpix.process(case["frames"], config)
    assert result.slopes.shape == (24, S, 2)
    assert np.array_equal(result.slopes, cli_slopes)
    assert np.array_equal(result.valid, cli_valid)
    assert np.array_equal(result.slopes, result.slopes_q16 / 65536.0)
    # a case that proves something: some selection happened, some were refused
    assert 0 < result.valid.sum() < result.valid.size or rule == "threshold"
    assert result.flux.dtype == np.int64 and (result.flux > 0).any()

    # all cores or one: the same numbers
    one_thread = brightpix.process(case["frames"], config, threads=1)
    assert np.array_equal(one_thread.slopes_q16, result.slopes_q16)
    assert np.array_equal(one_thread.flux, result.flux)

    reference = brightpix.process(case["frames"], config, reference=True)
    assert reference.source == "reference"
    for name in ("slopes_q16", "flux", "valid"):
        assert np.array_equal(getattr(reference, name), getattr(result, name)), name


def test_fits_input_any_byte_and_memory_order(cli: Path, case: dict) -> None:
    path = write_config(case, "subtract-next", None, None)
    config = brightpix.Config.load(path)
    done = run_cli(
        cli,
        "process",
        "--config",
        path,
        "--frames",
        case["dir"] / "frames.fits",
        "--out",
        case["dir"] / "fits-slopes.npy",
    )
    assert done.returncode == 0, done.stderr
    expected = np.load(case["dir"] / "fits-slopes.npy")
    data = fits.getdata(case["dir"] / "frames.fits")  # BITPIX 16 + BZERO, as astropy reads it
    big_endian = case["frames"].astype(">u2")
    strided = np.zeros((24, HEIGHT, 2 * WIDTH), np.uint16)[:, :, ::2]
    strided[...] = case["frames"]
    for frames in (data, big_endian, np.asfortranarray(case["frames"]), strided):
        assert np.array_equal(brightpix.process(frames, config).slopes, expected)
    # uint8 frames: the same numbers as the same values in uint16
    small = (case["frames"] // 256).astype(np.uint8)
    assert np.array_equal(
        brightpix.process(small, config).slopes_q16,
        brightpix.process(small.astype(np.uint16), config).slopes_q16,
    )
    # one (H, W) frame: the frame axis is dropped
    one = brightpix.process(case["frames"][5], config)
    assert one.slopes.shape == (S, 2) and np.array_equal(one.slopes, expected[5])
