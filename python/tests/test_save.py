"""Result.save writes what ``brightpix process --out`` writes, through the same Rust writers:
the .npy set, FITS (read back with astropy) and CSV, in both slope layouts; the numbers equal
the Result's, and the files equal the command line's."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits

import brightpix
from conftest import run_cli


@pytest.fixture(scope="module")
def result(canary: brightpix.Config, canary_frames: np.ndarray) -> brightpix.Result:
    return brightpix.process(canary_frames[:6], canary)


def test_npy_set(result: brightpix.Result, tmp_path: Path) -> None:
    written = result.save(tmp_path / "r.npy")
    names = sorted(p.name for p in written)
    assert names == ["r.flux.npy", "r.json", "r.npy", "r.valid.npy"]
    np.testing.assert_array_equal(np.load(tmp_path / "r.npy"), result.slopes)
    np.testing.assert_array_equal(np.load(tmp_path / "r.flux.npy"), result.flux / 16.0)
    valid = np.load(tmp_path / "r.valid.npy")
    assert valid.dtype == np.uint8
    np.testing.assert_array_equal(valid, result.valid)
    provenance = json.loads((tmp_path / "r.json").read_text())
    assert provenance["bprule"] == "subtract-next"
    assert provenance["bpnpix"] == result.config.n
    assert provenance["bpnframe"] == 6
    assert provenance["bplayout"] == "pairs"
    assert provenance["bpvers"] == result.version
    assert provenance["bpprod"] == "brightpix Python package (engine)"
    assert provenance["units"]["slopes"] == "pixel"
    assert "bpcfgfil" not in provenance  # no configuration file to name


def test_vector_layout(result: brightpix.Result, tmp_path: Path) -> None:
    result.save(tmp_path / "v.npy", layout="vector")
    vector = np.load(tmp_path / "v.npy")
    s = result.n_subapertures
    assert vector.shape == (6, 2 * s)
    np.testing.assert_array_equal(vector[:, :s], result.slopes[:, :, 0])
    np.testing.assert_array_equal(vector[:, s:], result.slopes[:, :, 1])
    assert json.loads((tmp_path / "v.json").read_text())["bplayout"] == "vector"


def test_fits_read_by_astropy(result: brightpix.Result, tmp_path: Path) -> None:
    path = tmp_path / "r.fits"
    assert result.save(path) == [path]
    with fits.open(path) as hdus:
        header = hdus[0].header
        assert header["BPRULE"] == "subtract-next"
        assert header["BPNPIX"] == result.config.n
        assert header["BPBITS"] == result.config.bit_depth
        np.testing.assert_array_equal(hdus["SLOPES"].data, result.slopes)
        assert hdus["SLOPES"].header["BUNIT"] == "pixel"
        np.testing.assert_array_equal(hdus["FLUX"].data, result.flux / 16.0)
        np.testing.assert_array_equal(hdus["VALID"].data, result.valid)


def test_csv_rows(result: brightpix.Result, tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    result.save(path)
    lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    rows = list(csv.DictReader(lines))
    s = result.n_subapertures
    assert len(rows) == 6 * s
    for row in rows[:: s // 3 or 1]:
        f, k = int(row["frame"]), int(row["subaperture"])
        assert float(row["slope_x"]) == result.slopes[f, k, 0]
        assert float(row["slope_y"]) == result.slopes[f, k, 1]
        assert float(row["flux"]) == result.flux[f, k] / 16.0
        assert int(row["valid"]) == result.valid[f, k]


def test_files_equal_the_command_lines(
    cli: Path, repo: Path, canary: brightpix.Config, canary_frames: np.ndarray, tmp_path: Path
) -> None:
    frames = tmp_path / "frames.npy"
    np.save(frames, canary_frames[:6])
    config = repo / "examples" / "canary.toml"
    for out in ["c.fits", "c.npy"]:
        done = run_cli(
            cli, "process", "--config", config, "--frames", frames, "--out", tmp_path / out
        )
        assert done.returncode == 0, done.stderr
    brightpix.process(canary_frames[:6], canary).save(tmp_path / "p.npy")
    brightpix.process(canary_frames[:6], canary).save(tmp_path / "p.fits")
    for suffix in [".npy", ".flux.npy", ".valid.npy"]:
        assert (tmp_path / f"c{suffix}").read_bytes() == (tmp_path / f"p{suffix}").read_bytes()
    with fits.open(tmp_path / "c.fits") as c, fits.open(tmp_path / "p.fits") as p:
        for name in ["SLOPES", "FLUX", "VALID"]:
            np.testing.assert_array_equal(c[name].data, p[name].data)
        assert c[0].header["BPCFGDIG"] == p[0].header["BPCFGDIG"]


def test_bad_arguments(result: brightpix.Result, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="layout"):
        result.save(tmp_path / "r.npy", layout="columns")
    with pytest.raises(ValueError, match="unrecognised|extension|expected"):
        result.save(tmp_path / "r.txt")
    assert not list(tmp_path.iterdir())
    for name in ["r.fits", "r.npy", "r.csv"]:
        with pytest.raises(FileNotFoundError, match="does not exist"):
            result.save(tmp_path / "missing-directory" / name)
