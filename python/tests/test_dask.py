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


def _misaligned(data: bytes) -> memoryview:
    """``data`` in a read-only buffer that starts one byte past an aligned address."""
    block = bytearray(len(data) + 1)
    block[1:] = data
    return memoryview(bytes(block))[1:]


def _toml_config(directory) -> brightpix.Config:
    """A configuration loaded from TOML, as a user writes it, with background and flat maps."""
    rng = np.random.default_rng(9)
    np.save(directory / "background.npy", rng.uniform(18.0, 22.0, (32, 48)))
    np.save(directory / "flat.npy", rng.uniform(0.8, 1.2, (32, 48)))
    (directory / "wfs.toml").write_text(
        """
[camera]
width = 48
height = 32
bit_depth = 12

[subapertures.grid]
x = 0
y = 0
columns = 3
rows = 2
width = 16
height = 16

[calibration]
background = "background.npy"
flat = "flat.npy"

[selection]
rule = "subtract-next"
pixels = 20

[centroid]
min_flux_counts = 30.0
"""
    )
    return brightpix.Config.load(str(directory / "wfs.toml"))


def test_objects_unpickle_from_any_buffer(tmp_path) -> None:
    """Protocol 5 hands arrays over out of band; dask.distributed gives them back at any
    alignment. Configurations, results and frames must work from such buffers."""
    import pickle

    c = _toml_config(tmp_path)
    data = frames(40)
    expected = brightpix.process(data, c)
    for obj in (c, expected):
        buffers: list = []
        payload = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
        assert buffers, "nothing went out of band: this test would not test alignment"
        misaligned = [_misaligned(bytes(b.raw())) for b in buffers]
        back = pickle.loads(payload, buffers=misaligned)
        if obj is c:
            assert back == c
            assert (
                brightpix.process(data, back).slopes_q16.tobytes() == expected.slopes_q16.tobytes()
            )
        else:
            for name in ("slopes", "slopes_q16", "flux", "valid", "received"):
                assert np.array_equal(getattr(back, name), getattr(obj, name)), name
            assert back.source == "engine" and back.config == c
    # Frames: misaligned and read-only, and not contiguous.
    odd = np.frombuffer(_misaligned(data.tobytes()), dtype=np.uint16).reshape(data.shape)
    assert not odd.flags.aligned and not odd.flags.writeable
    assert np.array_equal(brightpix.process(odd, c).slopes_q16, expected.slopes_q16)
    strided = np.repeat(data, 2, axis=2)[:, :, ::2]
    assert not strided.flags.c_contiguous
    assert np.array_equal(brightpix.process(strided, c).slopes_q16, expected.slopes_q16)


def test_local_cluster_with_toml_configuration(tmp_path) -> None:
    """As the issue's user ran it: Config.load, worker processes, maps in the configuration;
    and a failure inside a worker reaches the caller as an exception, not a restart loop."""
    c = _toml_config(tmp_path)
    data = frames(600)
    expected = brightpix.process(data, c)
    bad = data.copy()
    bad[450, 3, 4] = 4096  # above the 12-bit range, in the fourth chunk
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        lazy = brightpix.dask.process(da.from_array(data, chunks=(150, 32, 48)), c)
        result = [f.result(timeout=300) for f in client.compute(list(lazy))]
        for got, want in zip(
            result, (expected.slopes, expected.slopes_q16, expected.flux, expected.valid)
        ):
            assert np.array_equal(got, want)
        # Results and configurations also cross the boundary whole.
        shipped = client.submit(brightpix.process, data[:100], c).result(timeout=300)
        assert np.array_equal(shipped.slopes_q16, expected.slopes_q16[:100])
        failing = brightpix.dask.process(da.from_array(bad, chunks=(150, 32, 48)), c)
        with pytest.raises(ValueError, match="4096"):
            client.compute(failing.slopes).result(timeout=300)
