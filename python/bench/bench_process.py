"""brightpix.process against the command line and against numpy (a benchmark, not a test).

On one 240x240 x 1000-frame uint16 cube (15x15 sub-apertures of 16x16 pixels,
simulated CANARY NGS spots; subtract-next N = 20, 50-count background):

- ``brightpix.process`` (all cores, and one thread), best of ``--repeat`` runs;
- ``brightpix process`` (the command line, release build): the processing time
  it prints (reading the .npy included, writing excluded), best of ``--repeat``;
- the numpy peer: the same algorithm vectorised over every sub-aperture of a
  block of frames in float32 (``np.partition`` for the (N+1)-th brightest value,
  clip, centre of gravity by matrix products), the way a Python user would
  write it; best of ``--repeat``. Its slopes are checked against brightpix's.

Ratios are of times measured in the same run. Run from the repository root:

    .venv/bin/python python/bench/bench_process.py
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import brightpix

REPO = Path(__file__).resolve().parents[2]
SIDE, SUB, N, BACKGROUND = 240, 16, 20, 50.0
GRID = SIDE // SUB


def best_of(repeat: int, run) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def numpy_slopes(frames: np.ndarray, n: int, background: float, block: int = 32) -> np.ndarray:
    """Subtract-next brightest-pixel centre of gravity in numpy, (F, S, 2) pixels."""
    count = frames.shape[0]
    npix = SUB * SUB
    kth = npix - (n + 1)  # index of v(N+1) in ascending order
    coords = np.indices((SUB, SUB), dtype=np.float32).reshape(2, npix)[::-1]  # x, y
    coords = (coords - (SUB - 1) / 2).T  # (npix, 2)
    out = np.empty((count, GRID * GRID, 2))
    for first in range(0, count, block):
        f = frames[first : first + block].astype(np.float32) - np.float32(background)
        b = f.shape[0]
        sub = f.reshape(b, GRID, SUB, GRID, SUB).transpose(0, 1, 3, 2, 4).reshape(b, -1, npix)
        level = np.partition(sub, kth, axis=-1)[..., kth : kth + 1]
        weights = np.maximum(sub - level, 0)
        flux = weights.sum(axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[first : first + b] = (weights @ coords) / flux
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--cli", type=Path, default=None, help="brightpix executable (release)")
    args = parser.parse_args()

    cli = args.cli
    if cli is None:
        target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
        cli = target / "release" / "brightpix"
        if not cli.exists():
            print("building the command line (cargo build --release -p brightpix)...")
            subprocess.run(["cargo", "build", "--release", "-p", "brightpix"], cwd=REPO, check=True)

    work = Path(tempfile.mkdtemp(prefix="brightpix-bench-"))
    print(f"simulating {args.frames} frames of {GRID}x{GRID} spots ({SIDE}x{SIDE})...")
    sim = brightpix.simulate("ngs", frames=args.frames, seed=1, grid=(GRID, GRID))
    frames = sim.frames
    config = sim.config(rule="subtract-next", n=N)
    assert config.background is not None and (config.background == BACKGROUND).all()
    np.save(work / "frames.npy", frames)
    toml = config.save(work, "bench")

    result = brightpix.process(frames, config)
    t_py = best_of(args.repeat, lambda: brightpix.process(frames, config))
    t_py1 = best_of(args.repeat, lambda: brightpix.process(frames, config, threads=1))

    cli_times = []
    for _ in range(args.repeat):
        done = subprocess.run(
            [
                str(cli),
                "process",
                "--config",
                str(toml),
                "--frames",
                str(work / "frames.npy"),
                "--out",
                str(work / "cli.npy"),
            ],
            capture_output=True,
            text=True,
            check=True,
        )
        cli_times.append(float(re.search(r" in ([0-9.]+) s", done.stderr).group(1)))
    t_cli = min(cli_times)
    assert np.array_equal(np.load(work / "cli.npy"), result.slopes), "CLI and Python differ"

    theirs = numpy_slopes(frames, N, BACKGROUND)
    t_np = best_of(args.repeat, lambda: numpy_slopes(frames, N, BACKGROUND))
    ok = result.valid
    worst = np.abs(theirs[ok] - result.slopes[ok]).max()

    mpx = args.frames * SIDE * SIDE / 1e6
    print(
        f"cube: {args.frames} x {SIDE}x{SIDE} uint16, {GRID * GRID} sub-apertures, "
        f"subtract-next N = {N}; {os.cpu_count()} cores; best of {args.repeat}"
    )
    for name, t in [
        ("brightpix.process (all cores)", t_py),
        ("brightpix.process (threads=1)", t_py1),
        ("brightpix process, CLI (all cores, reading included)", t_cli),
        ("numpy np.partition (one core)", t_np),
    ]:
        print(f"  {name:55s} {t * 1e3:8.1f} ms  {mpx / t:7.1f} Mpx/s")
    print(f"python / CLI time:                 {t_py / t_cli:.3f}  (issue: within 1.05)")
    print(f"numpy / python time:               {t_np / t_py:.2f}x (issue: >= 4x)")
    print(f"numpy / python time, one thread:   {t_np / t_py1:.2f}x")
    print(f"numpy peer vs brightpix slopes:    max |diff| {worst:.2e} px over valid results")


if __name__ == "__main__":
    main()
