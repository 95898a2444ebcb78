"""brightpix.dask on a dask.distributed LocalCluster with 2 workers: 2,000 frames in 8 chunks
give exactly the results of one brightpix.process call."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import brightpix
import brightpix.dask

da = pytest.importorskip("dask.array")
distributed = pytest.importorskip("dask.distributed")


def config() -> brightpix.Config:
    return brightpix.Config(
        width=48,
        height=32,
        bit_depth=12,
        grid=dict(x=0, y=0, columns=3, rows=2, width=16, height=16),
        background=20.0,
        n=[5, 10, 20, 40, 80, 256],
        min_flux=30.0,
    )


def frames(count: int) -> np.ndarray:
    rng = np.random.default_rng(4)
    out = rng.poisson(25.0, (count, 32, 48))
    spots = rng.integers(0, 16, (count, 6, 2))
    for k, (x, y) in enumerate([(0, 0), (16, 0), (32, 0), (0, 16), (16, 16), (32, 16)]):
        f = np.arange(count)
        out[f, y + spots[:, k, 1], x + spots[:, k, 0]] += rng.integers(0, 3000, count)
    return np.minimum(out, 4095).astype(np.uint16)


def test_config_pickles() -> None:
    c = config()
    assert pickle.loads(pickle.dumps(c)) == c
    assert brightpix.Config(**c.keywords()) == c


def test_local_cluster_identical_to_one_process_call() -> None:
    data = frames(2000)
    c = config()
    expected = brightpix.process(data, c)
    array = da.from_array(data, chunks=(250, 32, 48))
    assert array.numblocks == (8, 1, 1)
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        assert len(client.scheduler_info()["workers"]) == 2
        lazy = brightpix.dask.process(array, c)
        assert lazy.slopes.shape == (2000, 6, 2) and lazy.slopes.chunks[0] == (250,) * 8
        result = lazy.compute()
    assert np.array_equal(result.slopes, expected.slopes)
    assert np.array_equal(result.slopes_q16, expected.slopes_q16)
    assert np.array_equal(result.flux, expected.flux)
    assert np.array_equal(result.valid, expected.valid)
    assert 0 < expected.valid.sum() < expected.valid.size


def test_refusals() -> None:
    c = config()
    array = da.from_array(frames(20), chunks=(10, 32, 48))
    filtered = brightpix.Config(**{**c.keywords(), "level_filter": 4})
    with pytest.raises(ValueError, match="level filter"):
        brightpix.dask.process(array, filtered)
    with pytest.raises(ValueError, match="frame axis only"):
        brightpix.dask.process(array.rechunk((10, 16, 48)), c)
    with pytest.raises(TypeError, match="uint8 or uint16"):
        brightpix.dask.process(array.astype(np.float32), c)
    with pytest.raises(ValueError, match="camera is 32x48"):
        brightpix.dask.process(array[:, :16], c)
    with pytest.raises(TypeError, match="dask.array.Array"):
        brightpix.dask.process(frames(2), c)
