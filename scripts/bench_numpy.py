#!/usr/bin/env python3
"""brightpix against a vectorised numpy implementation, on the same .npy cube, in one run.

The numpy baseline is the best vectorised form we know of the paper's
subtract-next (N+1-th subtracted) centroiding: the cube is viewed as
(frames, rows, columns, pixels per sub-aperture) without a copy of the frames,
calibrated into int32 (16 * raw - background, SPEC.md section 2), `np.partition`
finds v(N+1) of every sub-aperture of every frame in one call, the weights are
max(0, p - v(N+1)) in place, and one matrix product gives the flux and both moments. Its slopes
are checked against brightpix's (within 2^-16 px) before any time is reported.

Timed, in interleaved rounds (median of each):
  - numpy on the cube in memory (loading the .npy is not timed);
  - `brightpix process` on the .npy file: wall time of the whole command
    (start-up, reading, writing the slopes) and the time it reports itself
    (reading the frames included);
  - `brightpix.process` from the Python package, if it is importable (the
    cube in memory, all cores).
The ratio reported is numpy's time over `brightpix process`'s wall time, the
least favourable to brightpix.

Usage (from the repository root, after scripts/setup, which makes .venv with numpy):
  .venv/bin/python scripts/bench_numpy.py                    # 240x240 and 112x112 cubes
  .venv/bin/python scripts/bench_numpy.py --frames 400 --rounds 7 --brightpix BIN
Needs numpy; builds `target/release/brightpix` with cargo if it is missing.
"""

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

try:
    import numpy as np
except ImportError:
    sys.exit(
        "bench_numpy.py needs numpy: run scripts/setup (it makes .venv with numpy), "
        "then .venv/bin/python scripts/bench_numpy.py"
    )

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
N = 20
SIDE = 16
BACKGROUND_COUNTS = 50

CONFIG = """[camera]
width = {width}
height = {height}
bit_depth = 16

[subapertures.grid]
x = 0
y = 0
columns = {across}
rows = {across}
width = {side}
height = {side}

[calibration]
background_counts = {background}

[selection]
rule = "subtract-next"
pixels = {n}
"""


def spot_cube(frames, across, seed=1):
    """Spot frames: a Gaussian spot per sub-aperture (200 photons, sigma 1.5 px) at a
    random offset of up to +-3 px, 50 counts of background, +-3 counts of uniform
    noise (the model of brightpix's bench frames)."""
    rng = np.random.default_rng(seed)
    width = across * SIDE
    centres = 7.5 + (rng.random((frames, across, across, 2)) - 0.5) * 6.0
    j, i = np.mgrid[0:SIDE, 0:SIDE]
    out = np.empty((frames, width, width), dtype=np.uint16)
    for f in range(frames):
        cx = centres[f, :, :, 0][:, :, None, None]
        cy = centres[f, :, :, 1][:, :, None, None]
        spot = 200.0 / (2 * np.pi * 2.25) * np.exp(-((i - cx) ** 2 + (j - cy) ** 2) / 4.5)
        noise = (rng.random((across, across, SIDE, SIDE)) - 0.5) * 6.0
        tiles = BACKGROUND_COUNTS + spot + noise  # (rows, columns, j, i)
        out[f] = np.rint(tiles).transpose(0, 2, 1, 3).reshape(width, width)
    return out


def numpy_subtract_next(cube, across, n=N):
    """Slopes [x, y] in pixels from the window centre, shape (frames, sub-apertures, 2)."""
    frames = cube.shape[0]
    # (frames, row, j, column, i) -> (frames, row, column, j, i): one copy, as int32 Q4,
    # then every step in place.
    p = cube.reshape(frames, across, SIDE, across, SIDE).transpose(0, 1, 3, 2, 4)
    p = p.astype(np.int32).reshape(frames, across * across, SIDE * SIDE)
    p <<= 4
    p -= BACKGROUND_COUNTS * 16
    k = SIDE * SIDE - n - 1  # ascending index of v(N+1)
    level = np.partition(p, k, axis=-1)[..., k : k + 1]
    p -= level
    np.maximum(p, 0, out=p)
    # One matrix product gives the flux and both moments: columns 1, i, j.
    coords = np.arange(SIDE * SIDE)
    basis = np.stack([np.ones(SIDE * SIDE), coords % SIDE, coords // SIDE], axis=-1)
    sums = p.astype(np.float64) @ basis  # (frames, sub-apertures, 3)
    flux = sums[..., :1]
    with np.errstate(invalid="ignore", divide="ignore"):
        slopes = sums[..., 1:] / flux - (SIDE - 1) / 2.0
    return np.where(flux > 0, slopes, 0.0)


def ensure_brightpix(path):
    if path and os.path.exists(path):
        return path
    path = os.path.join(
        os.environ.get("CARGO_TARGET_DIR", os.path.join(REPO, "target")),
        "release",
        "brightpix",
    )
    if not os.path.exists(path):
        print(
            "building brightpix (cargo build --release -p brightpix)...",
            file=sys.stderr,
        )
        subprocess.run(["cargo", "build", "--release", "-p", "brightpix"], cwd=REPO, check=True)
    return path


def run_cli(brightpix, config, frames, out, threads):
    args = [brightpix, "process", "--config", config, "--frames", frames, "--out", out]
    if threads:
        args += ["--threads", str(threads)]
    started = time.perf_counter()
    run = subprocess.run(args, check=False, capture_output=True, text=True)
    wall = time.perf_counter() - started
    if run.returncode != 0:
        sys.exit(f"brightpix process failed:\n{run.stderr}")
    reported = re.search(r"in ([0-9.]+) s", run.stderr)
    return wall, float(reported.group(1)) if reported else wall


def bench(across, frames, rounds, brightpix, threads, scratch):
    width = across * SIDE
    cube = spot_cube(frames, across)
    config = os.path.join(scratch, f"config-{width}.toml")
    with open(config, "w") as f:
        f.write(
            CONFIG.format(
                width=width,
                height=width,
                across=across,
                side=SIDE,
                background=BACKGROUND_COUNTS,
                n=N,
            )
        )
    frames_path = os.path.join(scratch, f"cube-{width}.npy")
    np.save(frames_path, cube)
    out = os.path.join(scratch, f"slopes-{width}.npy")

    # Agreement first.
    run_cli(brightpix, config, frames_path, out, threads)
    ours = np.load(out)
    theirs = numpy_subtract_next(cube, across)
    difference = float(np.max(np.abs(ours - theirs)))
    if difference > 2.0**-16:
        sys.exit(f"{width}x{width}: numpy and brightpix disagree by {difference:.3g} px (> 2^-16)")

    package = None
    try:
        import brightpix as package

        package_config = package.Config.load(config)
        got = package.process(cube, package_config, threads=threads).slopes
        if float(np.max(np.abs(got - ours))) != 0.0:
            sys.exit(f"{width}x{width}: the Python package and brightpix process differ")
    except ImportError:
        package = None

    times = {"numpy": [], "cli wall": [], "cli reported": [], "python package": []}
    for _ in range(rounds):
        started = time.perf_counter()
        numpy_subtract_next(cube, across)
        times["numpy"].append(time.perf_counter() - started)
        wall, reported = run_cli(brightpix, config, frames_path, out, threads)
        times["cli wall"].append(wall)
        times["cli reported"].append(reported)
        if package is not None:
            started = time.perf_counter()
            package.process(cube, package_config, threads=threads)
            times["python package"].append(time.perf_counter() - started)
    pixels = cube.size
    medians = {k: statistics.median(v) for k, v in times.items() if v}
    print(
        f"{width}x{width}, {across}x{across} sub-apertures of {SIDE}x{SIDE}, subtract-next"
        f" N={N}: {frames} frames, {pixels / 1e6:.1f} Mpx,"
        f" max |slope difference| {difference:.2g} px"
    )
    for name, seconds in medians.items():
        ratio = medians["numpy"] / seconds
        print(f"  {name:<16} {pixels / seconds / 1e6:8.1f} Mpx/s   {ratio:6.2f}x numpy")
    return {
        "workload": f"numpy-{width}",
        "numpy_mpx_per_s": pixels / medians["numpy"] / 1e6,
        "brightpix_process_mpx_per_s": pixels / medians["cli wall"] / 1e6,
        "x_numpy": medians["numpy"] / medians["cli wall"],
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--frames",
        type=int,
        default=0,
        help="frames per cube (default: about 20 Mpx of frames)",
    )
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument(
        "--brightpix", help="the brightpix binary (default: target/release/brightpix)"
    )
    parser.add_argument("--threads", type=int, help="brightpix threads (default: all cores)")
    parser.add_argument(
        "--sizes",
        default="15,7",
        help="sub-apertures across, comma-separated (15: 240x240, 7: 112x112)",
    )
    args = parser.parse_args()
    brightpix = ensure_brightpix(args.brightpix)
    print(f"numpy {np.__version__}; brightpix {brightpix}; {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory(prefix="brightpix-numpy-") as scratch:
        for across in [int(a) for a in args.sizes.split(",")]:
            frames = args.frames or max(16, 20_000_000 // (across * SIDE) ** 2)
            bench(across, frames, args.rounds, brightpix, args.threads, scratch)


if __name__ == "__main__":
    main()
