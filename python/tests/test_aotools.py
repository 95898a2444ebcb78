"""brightpix.centroid against aotools' brightest_pixel on simulated NGS and LGS frames:
N = round(t * npix) - 1 with subtract-next, origin moved to the window centre."""

from __future__ import annotations

import numpy as np
import pytest
from aotools.image_processing.centroiders import brightest_pixel

import brightpix

TOLERANCE = 2.0**-16


@pytest.mark.parametrize("conditions", ["ngs", "rayleigh:1000", "sodium:10000"])
@pytest.mark.parametrize("fraction", [0.02, 0.08, 0.25])
def test_centroid_matches_aotools_brightest_pixel(conditions: str, fraction: float) -> None:
    sim = brightpix.simulate(conditions, frames=60, seed=5)
    images = sim.frames  # (60, 16, 16) uint16: one sub-aperture per frame
    k, h, w = images.shape
    n = round(fraction * h * w) - 1
    ours = brightpix.centroid(images, n)
    theirs = brightest_pixel(images.astype(np.float64), fraction)  # (2, k), origin at [0, 0]
    theirs = theirs.T - [(w - 1) / 2, (h - 1) / 2]
    assert ours.shape == (k, 2)
    assert np.all(np.isfinite(ours))
    assert np.max(np.abs(ours - theirs)) <= TOLERANCE
    # the spots move: the comparison covers more than one position
    assert np.ptp(ours[:, 0]) > 0.1
    # one image at a time gives the same
    assert np.array_equal(brightpix.centroid(images[3], n), ours[3])


def test_centroid_is_process_on_one_window() -> None:
    sim = brightpix.simulate("ngs", frames=10, seed=2)
    config = brightpix.Config(width=16, height=16, windows=[[0, 0, 16, 16]], n=7)
    result = brightpix.process(sim.frames, config)
    assert np.array_equal(brightpix.centroid(sim.frames, 7), result.slopes[:, 0])


def test_centroid_of_an_empty_image_is_nan() -> None:
    out = brightpix.centroid(np.zeros((2, 8, 8), np.uint16), 5)
    assert np.isnan(out).all()
