"""From Python: configure, stream and verify against the simulated devices (the firmware's
device loop in-process, and the firmware ELF in QEMU when qemu-system-arm is present)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import brightpix

REPO = Path(__file__).resolve().parents[2]
ELF_PATH = "thumbv7em-none-eabihf/release/brightpix-qemu"


def qemu_elf() -> Path | None:
    """The newest QEMU firmware build: where `cargo build --release` in firmware/ puts it."""
    dirs = [REPO / "firmware" / "target"]
    if os.environ.get("CARGO_TARGET_DIR"):
        dirs.insert(0, Path(os.environ["CARGO_TARGET_DIR"]))
    built = [d / ELF_PATH for d in dirs if (d / ELF_PATH).exists()]
    return max(built, key=lambda p: p.stat().st_mtime, default=None)


def test_configure_stream_verify_in_process(
    canary: brightpix.Config, canary_frames: np.ndarray
) -> None:
    with brightpix.simulated_device() as port, brightpix.Device(port) as device:
        assert port.startswith("/dev/") and port.pixels_fifo is None
        assert device.info["protocol_version"] >= 1
        applied = device.configure(canary)
        assert device.status()["config_id"] == applied["config_id"]
        result = device.stream(canary_frames, verify=True)
        assert result.source == "device" and result.received.all()
        expected = brightpix.process(canary_frames, canary)
        for name in ("slopes_q16", "slopes", "flux", "valid"):
            assert np.array_equal(getattr(result, name), getattr(expected, name)), name
        report = device.last_stream
        assert report["frames_done"] == 20 and report["mismatches"] == 0
        assert report["slopes_compared"] == 20 * 49
        status = device.status()
        assert status["frames_processed"] == 20
        # The engine's counters (protocol 5): 49 selecting windows a frame,
        # and the row kernel ran.
        assert status["engine"]["windows"] == 20 * 49
        assert status["engine"]["kernel_frames"] > 0


def test_level_filter_is_followed_across_stream_calls(canary_frames: np.ndarray) -> None:
    config = brightpix.Config(
        width=112,
        height=112,
        grid=dict(x=0, y=0, columns=7, rows=7, width=16, height=16),
        background=50.0,
        n=12,
        level_filter=2,
    )
    expected = brightpix.process(canary_frames, config)
    with brightpix.simulated_device() as port, brightpix.Device(port) as device:
        device.configure(config)
        first = device.stream(canary_frames[:8])
        second = device.stream(canary_frames[8:])  # verified against the continuing reference
        device.stream(canary_frames[:2], verify=False)
        with pytest.raises(ValueError, match="cannot verify"):
            device.stream(canary_frames[:2])
        device.configure(config)
        assert np.array_equal(device.stream(canary_frames[:8]).slopes_q16, expected.slopes_q16[:8])
    both = np.concatenate([first.slopes_q16, second.slopes_q16])
    assert np.array_equal(both, expected.slopes_q16)
    # and the filter matters here: restarting it changes the results
    restarted = brightpix.process(canary_frames[8:], config)
    assert not np.array_equal(restarted.slopes_q16, second.slopes_q16)


def test_a_wrong_configuration_is_a_mismatch(
    canary: brightpix.Config, canary_frames: np.ndarray
) -> None:
    other = brightpix.Config(**{**canary.keywords(), "n": 5})
    with brightpix.simulated_device() as port, brightpix.Device(port) as device:
        device.configure(canary)
        with pytest.raises(brightpix.MismatchError, match="differ from the reference") as e:
            device.stream(canary_frames[:3], config=other)  # the device still runs canary
    assert e.value.result.slopes.shape == (3, 49, 2)
    assert len(e.value.mismatches) > 0


def test_device_errors_are_python_exceptions(
    canary: brightpix.Config, canary_frames: np.ndarray
) -> None:
    with pytest.raises(FileNotFoundError, match="cannot open /dev/brightpix-none"):
        brightpix.Device("/dev/brightpix-none")
    with brightpix.simulated_device() as port, brightpix.Device(port) as device:
        with pytest.raises(ValueError, match="call configure"):
            device.stream(canary_frames)
        too_big = brightpix.Config(
            width=4096, height=4096, grid=dict(x=0, y=0, columns=90, rows=90, width=8, height=8)
        )
        with pytest.raises(brightpix.DeviceError, match="refused"):
            device.configure(too_big)
        device.configure(canary)  # the device still works
        with pytest.raises(TypeError, match="uint8 or uint16"):
            device.stream(canary_frames.astype(np.float64))
        try:
            captured = device.capture(2)
        except brightpix.DeviceError as e:  # no camera on this device
            assert "NoCamera" in str(e)
        else:
            assert captured.slopes.shape == (2, 49, 2)
        device.close()
        with pytest.raises(ValueError, match="closed"):
            device.status()


@pytest.mark.skipif(shutil.which("qemu-system-arm") is None, reason="qemu-system-arm not installed")
@pytest.mark.skipif(
    qemu_elf() is None, reason="QEMU firmware not built (cd firmware && cargo build --release)"
)
def test_configure_stream_verify_in_qemu(
    canary: brightpix.Config, canary_frames: np.ndarray
) -> None:
    with brightpix.simulated_device(qemu=True, elf=qemu_elf()) as port:
        assert port.pixels_fifo is not None
        with brightpix.Device(port, timeout=5.0) as device:
            assert "qemu" in device.info["board"].lower() or device.info["board"]
            device.configure(canary)
            result = device.stream(canary_frames[:4], verify=True)
            expected = brightpix.process(canary_frames[:4], canary)
            assert np.array_equal(result.slopes_q16, expected.slopes_q16)
            assert device.last_stream["mismatches"] == 0
