"""The live view (`brightpix view`) in a real browser.

Debian's chromium (installed by scripts/setup), driven by Playwright for
Python through its executable path: Playwright's own browser downloads are
never used. The page exposes what it drew as data attributes of #counts,
which the tests read.

Run by scripts/test with BRIGHTPIX_CLI pointing at the built command line.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import Page, sync_playwright

REPO = Path(__file__).resolve().parents[2]
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
# A debug build makes the simulated frames slowly on a loaded machine.
STARTUP_MS = 180_000


def cli() -> Path:
    given = os.environ.get("BRIGHTPIX_CLI")
    path = Path(given) if given else REPO / "target" / "debug" / "brightpix"
    if not path.exists():
        pytest.fail(f"{path} does not exist: cargo build -p brightpix, or set BRIGHTPIX_CLI")
    return path


def canary_12bit(tmp_path: Path) -> Path:
    """The CANARY model on a 12-bit camera, so that the device can be made to drop frames."""
    text = (REPO / "examples" / "canary.toml").read_text()
    text = text.replace("bit_depth = 16", "bit_depth = 12", 1)
    assert "bit_depth = 12" in text
    path = tmp_path / "canary12.toml"
    path.write_text(text)
    return path


def start(*args: object) -> tuple[subprocess.Popen[str], str]:
    """Starts a command that prints one line first (a URL or a port); returns it and that line."""
    process = subprocess.Popen(
        [str(cli()), *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stdout is not None
    line = process.stdout.readline().strip()
    if not line:
        process.kill()
        _, err = process.communicate()
        pytest.fail(f"{args[0]} printed nothing: {err}")
    return process, line


def stop(process: subprocess.Popen[str]) -> str:
    process.send_signal(signal.SIGINT)
    try:
        _, err = process.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        process.kill()
        _, err = process.communicate()
    return err


@pytest.fixture
def browser_page(tmp_path: Path) -> Iterator[Page]:
    if not Path(CHROMIUM).exists():
        pytest.fail("chromium is not installed: scripts/setup installs it (Debian: chromium)")
    with sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            str(tmp_path / "profile"),  # a fresh user-data-dir
            executable_path=CHROMIUM,
            args=CHROMIUM_ARGS,
            headless=True,
            viewport={"width": 1400, "height": 1100},
        )
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        yield page
        context.close()
        assert not errors, f"the page raised: {errors}"


def counts(page: Page) -> dict[str, str]:
    return page.eval_on_selector("#counts", "e => ({...e.dataset})")


def wait_for(page: Page, condition: str, timeout: float = 60_000) -> dict[str, str]:
    """Waits until `condition` (JavaScript over `c`, the counts) holds; returns the counts."""
    page.wait_for_function(
        f"() => {{ const c = document.getElementById('counts').dataset; return {condition}; }}",
        timeout=timeout,
    )
    return counts(page)


def test_live_view_of_a_simulated_device(tmp_path: Path, browser_page: Page) -> None:
    page = browser_page
    config = canary_12bit(tmp_path)
    view, url = start(
        "view",
        "--simulate",
        "--config",
        config,
        "--drop-every",
        20,
        "--rate",
        100,
        "--http-port",
        0,
    )
    try:
        assert url.startswith("http://127.0.0.1:"), url
        page.goto(url)
        first = wait_for(page, "Number(c.updates) >= 3 && c.deviceProcessed !== ''", STARTUP_MS)
        assert first["subapertures"] == "49"
        # One arrow per valid sub-aperture, a mark per invalid one.
        assert int(first["valid"]) > 0
        assert first["arrows"] == first["valid"], first
        assert int(first["valid"]) + int(first["invalid"]) <= 49
        # Counters advance: the host's frames, the page's updates, the device's count.
        later = wait_for(
            page,
            f"Number(c.frames) > {first['frames']} && Number(c.updates) > {first['updates']}"
            f" && Number(c.deviceProcessed) > {first['deviceProcessed']}",
        )
        assert later["arrows"] == later["valid"], later
        # Every 20th frame carries a pixel above 12 bits: the device drops it,
        # the host counts it, and the page shows both counts (in red).
        dropped = wait_for(page, "Number(c.dropped) > 0 && Number(c.deviceDropped) > 0")
        assert int(dropped["dropped"]) <= int(dropped["frames"]) // 20 + 1, dropped
        warned = page.locator("#health tr.warn", has_text="device: frames dropped")
        assert warned.count() == 1
        # The camera frame with each window's selected pixels.
        pixels = wait_for(page, "Number(c.pixelUpdates) > 0 && Number(c.selectedPixels) > 0")
        # At most N = 20 a window are selected.
        assert int(pixels["selectedPixels"]) <= 49 * 20, pixels
        # Click the centre sub-aperture (index 24 of the 7x7 grid) to follow it.
        box = page.locator("#pupil").bounding_box()
        assert box is not None
        page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        assert wait_for(page, "c.chosen !== ''")["chosen"] == "24"
        # How often the page redraws (reported, not asserted: the machine may be loaded).
        before, t0 = int(counts(page)["updates"]), time.monotonic()
        page.wait_for_timeout(2000)
        rate = (int(counts(page)["updates"]) - before) / (time.monotonic() - t0)
        print(f"page updates: {rate:.1f} per second")
        page.screenshot(path=str(REPO / "docs" / "view.png"), full_page=True)
    finally:
        err = stop(view)
    assert "live view at http://127.0.0.1:" in err


def test_the_view_says_when_the_device_disappears_and_reconnects(
    tmp_path: Path, browser_page: Page
) -> None:
    page = browser_page
    sock = tmp_path / "uart.sock"
    device_args = ("simulate-device", "--camera", "sim:2", "--link", "unix", "--socket", sock)
    device, port = start(*device_args)
    view = None
    try:
        assert port == f"unix:{sock}"
        view, url = start(
            "view", "--port", port, "--config", REPO / "examples" / "canary.toml", "--http-port", 0
        )
        page.goto(url)
        first = wait_for(page, "Number(c.updates) >= 2", STARTUP_MS)
        assert first["arrows"] == first["valid"], first
        stop(device)
        gone = wait_for(page, "c.message.includes('is gone')")
        assert str(sock) in gone["message"]
        assert page.locator("#banner").is_visible()
        device, _ = start(*device_args)
        back = wait_for(page, "c.message === ''", STARTUP_MS)
        wait_for(page, f"Number(c.frames) > {back['frames']}", STARTUP_MS)
        assert not page.locator("#banner").is_visible()
    finally:
        err = stop(view) if view else ""
        stop(device)
    assert "is gone or not answering" in err and "is back" in err, err


def run(*args: object) -> subprocess.CompletedProcess[str]:
    command = [str(cli()), *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


def test_bad_addresses_and_recordings_are_refused(tmp_path: Path) -> None:
    remote = run("view", "--simulate", "--listen", "0.0.0.0:0")
    assert remote.returncode != 0
    assert "not a loopback address" in remote.stderr and "--allow-remote" in remote.stderr

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        busy = run("view", "--simulate", "--http-port", port)
    assert busy.returncode != 0
    assert f"port {port} on 127.0.0.1 is in use" in busy.stderr, busy.stderr

    # A recording of the 12-bit model replayed against the 16-bit one.
    config = canary_12bit(tmp_path)
    frames = tmp_path / "frames.npy"
    np.save(frames, np.full((2, 112, 112), 60, dtype=np.uint16))
    made = run("process", "--config", config, "--frames", frames, "--out", tmp_path / "x.npy")
    assert made.returncode == 0, made.stderr
    other = run(
        "view", "--replay", tmp_path / "x.npy", "--config", REPO / "examples" / "canary.toml"
    )
    assert other.returncode != 0
    assert "recording of another configuration" in other.stderr, other.stderr


def test_a_replay_shows_valid_and_invalid_sub_apertures(tmp_path: Path, browser_page: Page) -> None:
    """Recorded results played back: an arrow for each valid sub-aperture, a cross for each
    invalid one, and the recorded frames with their selected pixels."""
    page = browser_page
    config = REPO / "examples" / "canary.toml"
    # A spot in every window whose column + row is even (25 of 49); the others are flat,
    # so nothing is selected there, their flux is 0 and they are invalid.
    frames = np.full((4, 112, 112), 60, dtype=np.uint16)
    for row in range(7):
        for col in range(7):
            if (row + col) % 2 == 0:
                y, x = 16 * row + 6, 16 * col + 5
                frames[:, y : y + 3, x : x + 3] = 900
    np.save(tmp_path / "frames.npy", frames)
    frames_path, recording = tmp_path / "frames.npy", tmp_path / "r.npy"
    made = run("process", "--config", config, "--frames", frames_path, "--out", recording)
    assert made.returncode == 0, made.stderr
    view, url = start(
        "view", "--replay", recording, "--config", config,
        "--frames", frames_path, "--rate", 50, "--http-port", 0,
    )  # fmt: skip
    try:
        page.goto(url)
        shown = wait_for(page, "Number(c.updates) >= 2 && Number(c.selectedPixels) > 0")
        assert (shown["valid"], shown["invalid"], shown["arrows"]) == ("25", "24", "25"), shown
        # The 3x3 spots: 9 pixels above the background in each of the 25 windows.
        assert shown["selectedPixels"] == str(25 * 9), shown
    finally:
        stop(view)
