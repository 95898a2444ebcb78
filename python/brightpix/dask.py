"""brightpix on Dask: frames that do not fit one machine.

``process(array, config)`` maps :func:`brightpix.process` over the chunks of a
dask array of frames (chunked along the frame axis only) with
``map_blocks``; on any scheduler, a ``dask.distributed`` cluster included, the
result is identical to ``brightpix.process`` on the whole array, because
frames are independent: each chunk's results depend only on its frames.

With the level filter (SPEC.md §4) a frame's result depends on every earlier
frame, so chunks are not independent; ``process`` refuses such a
configuration (``ValueError``) rather than give results that differ from one
``brightpix.process`` call. Process such data in order instead, e.g.
``for block in array.blocks: ...`` through one ``brightpix.Device``, or in
one ``brightpix.process`` call per machine-sized piece with the filter off.
"""

from __future__ import annotations

import pickle
from typing import NamedTuple

import numpy as np

from . import Config
from . import process as _process

__all__ = ["DaskResult", "process"]


class DaskResult(NamedTuple):
    """Lazy results: dask arrays with the shapes and units of :class:`brightpix.Result`."""

    slopes: object
    """``(F, S, 2)`` float64, pixels."""
    slopes_q16: object
    """``(F, S, 2)`` int32, 2^-16 pixel."""
    flux: object
    """``(F, S)`` int64, 1/16 count."""
    valid: object
    """``(F, S)`` bool."""

    def compute(self, **kwargs: object) -> DaskResult:
        """All four computed together (one pass over the frames) as numpy arrays."""
        import dask

        return DaskResult(*dask.compute(*self, **kwargs))


def _block(frames: np.ndarray, config_bytes: bytes) -> np.ndarray:
    """One chunk of frames -> a structured (F, S) array of every output.

    The configuration arrives as pickled bytes and is rebuilt here, inside
    the task: a failure to rebuild it is then the task's exception, which
    the scheduler hands to the caller, rather than a failure to deserialize
    the task, which kills the worker (and dask.distributed restarts it and
    retries, without end). Bytes also travel in-band: no out-of-band buffer
    (which may arrive at any alignment) is involved."""
    config = pickle.loads(config_bytes)
    result = _process(frames, config)
    out = np.empty(result.flux.shape, dtype=_RECORD)
    for axis, name in enumerate("xy"):
        out["slope_" + name] = result.slopes[..., axis]
        out["q16_" + name] = result.slopes_q16[..., axis]
    out["flux"] = result.flux
    out["valid"] = result.valid
    return out


_RECORD = np.dtype(
    [
        ("slope_x", "<f8"),
        ("slope_y", "<f8"),
        ("q16_x", "<i4"),
        ("q16_y", "<i4"),
        ("flux", "<i8"),
        ("valid", "?"),
    ]
)


def process(array: object, config: Config) -> DaskResult:
    """Process a dask array of frames chunk by chunk, lazily.

    Parameters
    ----------
    array
        A ``dask.array.Array`` of uint8 or uint16 camera counts, shape
        ``(F, H, W)``, chunked along the frame axis only (each chunk holds
        whole frames; ``array.rechunk({1: -1, 2: -1})`` makes it so).
    config
        The processing configuration. The level filter must be off: see the
        module documentation.

    Returns
    -------
    DaskResult
        Dask arrays ``slopes`` ``(F, S, 2)`` float64 px, ``slopes_q16`` int32,
        ``flux`` ``(F, S)`` int64 in 1/16 count, ``valid`` ``(F, S)`` bool,
        chunked like ``array`` along frames; identical to
        ``brightpix.process(array.compute(), config)``.
    """
    import dask.array as da

    if not isinstance(array, da.Array):
        raise TypeError(f"array must be a dask.array.Array, not {type(array).__name__}")
    if not isinstance(config, Config):
        raise TypeError(f"config must be a brightpix.Config, not {type(config).__name__}")
    if config.level_filter is not None:
        raise ValueError(
            "the level filter makes each frame depend on all earlier frames, so chunks "
            "cannot be processed independently; process these frames in order with "
            "brightpix.process (or without the level filter)"
        )
    if array.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"frames must be uint8 or uint16 camera counts; got dtype {array.dtype}")
    if array.ndim != 3:
        raise ValueError(f"frames must have shape (frames, height, width); got {array.shape}")
    if array.shape[1:] != (config.height, config.width):
        raise ValueError(
            f"frames are {array.shape[1]}x{array.shape[2]} pixels (height x width); "
            f"the configuration's camera is {config.height}x{config.width}"
        )
    if len(array.chunks[1]) != 1 or len(array.chunks[2]) != 1:
        raise ValueError(
            "chunk the frames along the frame axis only (each chunk whole frames): "
            "array.rechunk({1: -1, 2: -1})"
        )
    s = config.n_subapertures
    # Protocol 4: every buffer in-band, in the one bytes object.
    config_bytes = pickle.dumps(config, protocol=4)
    records = array.map_blocks(
        _block,
        config_bytes,
        dtype=_RECORD,
        chunks=(array.chunks[0], (s,)),
        drop_axis=2,
        meta=np.empty((0, 0), dtype=_RECORD),
    )
    return DaskResult(
        slopes=da.stack([records["slope_x"], records["slope_y"]], axis=-1),
        slopes_q16=da.stack([records["q16_x"], records["q16_y"]], axis=-1),
        flux=records["flux"],
        valid=records["valid"],
    )
