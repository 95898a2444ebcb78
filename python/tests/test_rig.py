"""brightpix.Rig: one camera over three simulated boards, merged and verified bit for bit
against brightpix.process on the whole camera; the plan's refusals."""

from __future__ import annotations

import contextlib
import re

import numpy as np
import pytest

import brightpix


def test_three_boards_equal_the_whole_camera(repo) -> None:
    sim = brightpix.simulate("ngs", frames=12, seed=3, grid=(7, 7))
    config = brightpix.Config.load(repo / "examples/canary.toml")
    rig = brightpix.Rig.plan(config, 3)
    boards = rig.boards
    assert len(boards) == 3
    assert sorted(k for b in boards for k in b["subapertures"]) == list(range(49))
    assert boards[0]["rectangle"] == (0, 0, 112, 32)
    assert boards[0]["config"].width == 112 and boards[0]["config"].height == 32
    with contextlib.ExitStack() as stack:
        ports = [stack.enter_context(brightpix.simulated_device()) for _ in boards]
        merged = rig.stream(sim.frames, ports=list(ports), verify=True)
    expected = brightpix.process(sim.frames, config)
    assert merged.source == "rig" and merged.received.all()
    assert np.array_equal(merged.slopes_q16, expected.slopes_q16)
    assert np.array_equal(merged.flux, expected.flux)
    assert np.array_equal(merged.valid, expected.valid)


def test_plan_refusals(repo) -> None:
    config = brightpix.Config.load(repo / "examples/canary.toml")
    # The refusal names how many boards keep up (the count follows the
    # board's cost model, which the bench refits): that many do, one fewer
    # does not.
    with pytest.raises(ValueError, match=r"cannot keep up.*; (\d+) boards keep up") as refused:
        brightpix.Rig.plan(config, 1, camera_rate=5000.0)
    enough = int(re.search(r"; (\d+) boards keep up", str(refused.value)).group(1))
    assert enough >= 2
    assert len(brightpix.Rig.plan(config, enough, camera_rate=5000.0).boards) == enough
    with pytest.raises(ValueError, match="cannot keep up"):
        brightpix.Rig.plan(config, enough - 1, camera_rate=5000.0)
    # Beyond what seven boards (one a row of windows, the most there are)
    # serve, however the rows are dealt.
    with pytest.raises(ValueError, match="no split of these windows keeps up"):
        brightpix.Rig.plan(config, 1, camera_rate=200000.0)
    with pytest.raises(ValueError, match="cannot give 8 boards"):
        brightpix.Rig.plan(config, 8)
    with pytest.raises(ValueError, match="unknown board"):
        brightpix.Rig.plan(config, 2, board="stm32f4")
    rig = brightpix.Rig.plan(config, 2)
    with pytest.raises(ValueError, match="ports: 1 given for 2 boards"):
        rig.stream(np.zeros((1, 112, 112), np.uint16), ports=["/dev/null"])


def test_plan_counts_a_measured_link(repo) -> None:
    config = brightpix.Config.load(repo / "examples/canary.toml")
    # One STM32H743 carries CANARY at 1 kHz on its USB link (about 1 MB/s);
    # on a link measured at 0.2 MB/s its results need more boards.
    assert len(brightpix.Rig.plan(config, 1, camera_rate=1000.0).boards) == 1
    with pytest.raises(
        ValueError, match=r"of its measured link.*; (\d+) boards keep up"
    ) as refused:
        brightpix.Rig.plan(config, 1, camera_rate=1000.0, link_rate=0.2)
    enough = int(re.search(r"; (\d+) boards keep up", str(refused.value)).group(1))
    assert enough >= 2
    rig = brightpix.Rig.plan(config, enough, camera_rate=1000.0, link_rate=0.2)
    assert len(rig.boards) == enough
    with pytest.raises(ValueError, match="link_rate 0: must be a positive number of MB/s"):
        brightpix.Rig.plan(config, 1, link_rate=0.0)
