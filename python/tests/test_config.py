"""brightpix.Config: from TOML and from keywords through one converter; TOML out; properties."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import brightpix


def test_keywords_equal_the_toml_file(canary: brightpix.Config) -> None:
    keywords = brightpix.Config(
        width=112,
        height=112,
        bit_depth=16,
        grid=dict(x=0, y=0, columns=7, rows=7, width=16, height=16),
        background=50.0,
        n=20,
    )
    assert keywords == canary
    assert canary.n_subapertures == 49 and canary.rule == "subtract-next" and canary.n == 20
    assert canary.windows.shape == (49, 4) and canary.windows.dtype == np.int32
    assert canary.windows[8].tolist() == [16, 16, 16, 16]
    assert (canary.background == 50.0).all() and canary.background.shape == (112, 112)
    assert canary.gain is None and canary.level_filter is None and canary.min_flux == 0.0
    assert "49 sub-apertures" in repr(canary)


def test_to_toml_round_trip(canary: brightpix.Config, repo: Path) -> None:
    text = canary.to_toml("canary")
    assert "[subapertures.grid]" in text and "background_counts = 50.0" in text
    assert brightpix.Config.from_toml(text) == canary
    vignetted = brightpix.Config.load(repo / "examples" / "canary-vignetted.toml")
    assert vignetted.n_subapertures == 36
    assert brightpix.Config.from_toml(vignetted.to_toml()) == vignetted


def test_save_and_load_with_maps(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    config = brightpix.Config(
        width=40,
        height=24,
        bit_depth=14,
        windows=np.array([[0, 0, 8, 8], [10, 2, 12, 12], [30, 10, 10, 14]]),
        rule="subtract-mean",
        mean_count=3,
        n=np.array([4, 9, 16]),
        background=rng.uniform(0, 100, (24, 40)),
        flat=rng.uniform(0.5, 2, (24, 40)),
        threshold=2.25,
        min_flux=12.5,
        reference_slopes=rng.uniform(-1, 1, (3, 2)),
        level_filter=5,
    )
    path = config.save(tmp_path, "mine")
    assert path == tmp_path / "mine.toml"
    assert (tmp_path / "mine-background.npy").exists()
    assert brightpix.Config.load(path) == config
    assert brightpix.Config(**config.keywords()) == config
    assert config.rule == "subtract-mean" and config.mean_count == 3
    assert config.n.tolist() == [4, 9, 16] and config.level_filter == 5
    assert config.threshold == 2.25 and config.min_flux == 12.5
    # stored in fixed point: multiples of 1/16 count, 1/4096 gain, 2^-16 pixel
    assert np.all(config.background * 16 == np.round(config.background * 16))
    assert np.all(config.gain * 4096 == np.round(config.gain * 4096))
    assert np.abs(config.reference_slopes * 65536 % 1).max() == 0
    assert config != brightpix.Config(**{**config.keywords(), "n": 5})


def test_simulation_config_matches_its_frames() -> None:
    sim = brightpix.simulate("rayleigh:1000", frames=3, seed=2, grid=(3, 2))
    assert sim.frames.shape == (3, 32, 48) and sim.frames.dtype == np.uint16
    assert sim.true_slopes.shape == (3, 6, 2) and sim.phase_slopes.shape == (3, 6, 2)
    assert sim.conditions["source"]["kind"] == "rayleigh"
    config = sim.config(rule="threshold", n=30)
    assert config.n_subapertures == 6 and config.rule == "threshold"
    assert (config.background == sim.background).all()
    result = brightpix.process(sim.frames, config)
    assert result.valid.all()
    again = brightpix.simulate({**sim.conditions}, frames=3, seed=2, grid=(3, 2))
    assert np.array_equal(again.frames, sim.frames)
