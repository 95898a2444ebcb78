"""AOT (Adaptive Optics Telemetry) both ways, checked with the standard's reference package,
aotpy: files brightpix writes (Result.save, ``process --out x.aot.fits``) are read by aotpy with
the same numbers; files aotpy writes from simulated frames are read by brightpix
(``read_frames``, ``process --frames``) and give the slopes the same frames give as .npy."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits

import brightpix
from conftest import run_cli

aotpy = pytest.importorskip("aotpy")


def read_aot(path: Path) -> aotpy.AOSystem:
    # aotpy warns of what brightpix's files have beyond or short of a whole AO system: the
    # BP_VALID / BP_WINDOWS tables, and no corrector or loop. Anything worse raises.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return aotpy.AOSystem.read_from_file(path)


@pytest.fixture(scope="module")
def result(canary: brightpix.Config, canary_frames: np.ndarray) -> brightpix.Result:
    return brightpix.process(canary_frames[:6], canary)


def check_sensor(system: aotpy.AOSystem, result: brightpix.Result) -> aotpy.ShackHartmann:
    assert system.ao_mode == "SCAO"
    (wfs,) = system.wavefront_sensors
    assert isinstance(wfs, aotpy.ShackHartmann)
    assert wfs.dimensions == 2
    assert wfs.n_valid_subapertures == result.n_subapertures == 49
    # examples/canary.toml: a 7x7 grid of 16-pixel windows from (0, 0), in row order.
    assert wfs.subaperture_size == 16
    np.testing.assert_array_equal(wfs.subaperture_mask.data, np.arange(49).reshape(7, 7))
    assert [(c.x, c.y) for c in wfs.mask_offsets] == [(0, 0)]
    # Measurements: (frames, 2, sub-apertures) pixels, x then y.
    assert wfs.measurements.unit == "pix"
    np.testing.assert_array_equal(wfs.measurements.data, np.moveaxis(result.slopes, 2, 1))
    assert wfs.measurements.time.frame_numbers == list(range(result.n_frames))
    np.testing.assert_array_equal(wfs.subaperture_intensities.data, result.flux / 16.0)
    assert "subtract-next" in wfs.centroiding_algorithm
    assert "N = 20" in wfs.centroiding_algorithm
    meta = {m.key: m.value for m in system.metadata}
    assert meta["BPRULE"] == "subtract-next"
    assert meta["BPNPIX"] == 20
    assert meta["BPVERS"] == result.version
    assert meta["BPCALIB"] == "background map"
    assert meta["BPCFGDIG"].startswith("0x")
    return wfs


def test_result_save_is_read_by_aotpy(result: brightpix.Result, tmp_path: Path) -> None:
    path = tmp_path / "r.aot.fits"
    assert result.save(path) == [path]
    wfs = check_sensor(read_aot(path), result)
    assert wfs.ref_measurements is None  # canary.toml has no reference slopes
    assert wfs.detector.pixel_intensities is None  # frames only on request
    with fits.open(path) as hdus:
        np.testing.assert_array_equal(hdus["BP_VALID"].data["VALID"], result.valid)
        assert hdus[0].header["AOT-VERS"] == "2.0.0"


def test_cli_writes_aot_with_pixels(
    cli: Path, repo: Path, canary_frames: np.ndarray, result: brightpix.Result, tmp_path: Path
) -> None:
    frames = tmp_path / "f.npy"
    np.save(frames, canary_frames[:6])
    out = tmp_path / "cli.aot.fits"
    config = repo / "examples" / "canary.toml"
    done = run_cli(
        cli, "process", "--config", config, "--frames", frames, "--out", out, "--aot-pixels"
    )
    assert done.returncode == 0, done.stderr
    wfs = check_sensor(read_aot(out), result)
    np.testing.assert_array_equal(wfs.detector.pixel_intensities.data, canary_frames[:6])
    # --aot-pixels needs an AOT output.
    done = run_cli(
        cli, "process", "--config", config, "--frames", frames, "--out", tmp_path / "x.fits",
        "--aot-pixels",
    )  # fmt: skip
    assert done.returncode != 0 and "not an AOT file" in done.stderr


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    """An AOT file written by aotpy: two Shack-Hartmann sensors, one with simulated CANARY frames
    as its detector's pixel intensities, one whose detector has none."""
    frames = brightpix.simulate("ngs", frames=8, seed=11, grid=(7, 7)).frames
    star = aotpy.NaturalGuideStar("NGS")
    time = aotpy.Time("WFS TIME", frame_numbers=list(range(100, 108)))
    camera = aotpy.Detector("OCAM", pixel_intensities=aotpy.Image("NGS PIXELS", frames, time=time))
    mask = np.arange(49).reshape(7, 7)
    ngs = aotpy.ShackHartmann(
        "NGS WFS",
        source=star,
        n_valid_subapertures=49,
        detector=camera,
        subaperture_mask=aotpy.Image("NGS MASK", mask),
        mask_offsets=[aotpy.Coordinates(0, 0)],
        subaperture_size=16,
    )
    lgs = aotpy.ShackHartmann(
        "LGS WFS", source=star, n_valid_subapertures=49, detector=aotpy.Detector("LGS CAMERA")
    )
    system = aotpy.AOSystem(
        ao_mode="SCAO",
        main_telescope=aotpy.MainTelescope("TELESCOPE"),
        sources=[star],
        wavefront_sensors=[ngs, lgs],
    )
    path = tmp_path_factory.mktemp("aot") / "recorded.aot.fits"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no corrector, no loop: a sensor's telemetry only
        system.write_to_file(path)
    return path, frames


def test_aotpy_file_read_by_brightpix(
    recorded: tuple[Path, np.ndarray], canary: brightpix.Config
) -> None:
    path, frames = recorded
    read = brightpix.read_frames(path, sensor="NGS WFS")
    assert read.dtype == np.uint16
    np.testing.assert_array_equal(read, frames)
    from_aot = brightpix.process(read, canary)
    from_array = brightpix.process(frames, canary)
    np.testing.assert_array_equal(from_aot.slopes_q16, from_array.slopes_q16)
    np.testing.assert_array_equal(from_aot.valid, from_array.valid)


def test_aot_and_npy_give_the_same_slopes_on_the_command_line(
    cli: Path, repo: Path, recorded: tuple[Path, np.ndarray], tmp_path: Path
) -> None:
    path, frames = recorded
    npy = tmp_path / "frames.npy"
    np.save(npy, frames)
    config = repo / "examples" / "canary.toml"
    for frames_in, out, extra in [
        (path, tmp_path / "from_aot.npy", ["--sensor", "NGS WFS"]),
        (npy, tmp_path / "from_npy.npy", []),
    ]:
        done = run_cli(
            cli, "process", "--config", config, "--frames", frames_in, "--out", out, *extra
        )
        assert done.returncode == 0, done.stderr
    np.testing.assert_array_equal(
        np.load(tmp_path / "from_aot.npy"), np.load(tmp_path / "from_npy.npy")
    )
    np.testing.assert_array_equal(
        np.load(tmp_path / "from_aot.valid.npy"), np.load(tmp_path / "from_npy.valid.npy")
    )


def test_bad_sensor_choices_are_specific_errors(
    cli: Path, repo: Path, recorded: tuple[Path, np.ndarray], tmp_path: Path
) -> None:
    path, _ = recorded
    with pytest.raises(ValueError, match=r"2 wavefront sensors: 'NGS WFS' \(Shack-Hartmann\)"):
        brightpix.read_frames(path)
    with pytest.raises(ValueError, match=r"no wavefront sensor 'TTS'.*'LGS WFS'"):
        brightpix.read_frames(path, sensor="TTS")
    with pytest.raises(ValueError, match="'LGS CAMERA' without PIXEL_INTENSITIES"):
        brightpix.read_frames(path, sensor="LGS WFS")
    plain = tmp_path / "plain.npy"
    np.save(plain, np.zeros((1, 4, 4), np.uint16))
    with pytest.raises(ValueError, match="not AOT"):
        brightpix.read_frames(plain, sensor="NGS WFS")
    # The command line says the same, naming the file, before any work.
    done = run_cli(
        cli, "process", "--config", repo / "examples" / "canary.toml", "--frames", path,
        "--out", tmp_path / "x.npy", "--sensor", "TTS",
    )  # fmt: skip
    assert done.returncode != 0
    assert str(path) in done.stderr and "no wavefront sensor 'TTS'" in done.stderr
    assert not (tmp_path / "x.npy").exists()
    done = run_cli(
        cli, "tune", "--config", repo / "examples" / "canary.toml", "--frames", path,
        "--sensor", "LGS WFS", "--out", tmp_path / "tuned",
    )  # fmt: skip
    assert done.returncode != 0 and "without PIXEL_INTENSITIES" in done.stderr
