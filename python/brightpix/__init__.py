"""brightpix for Python: brightest-pixel Shack-Hartmann centroiding, bit-exact
with the brightpix firmware and its reference.

Everything here calls the Rust library that the ``brightpix`` command line
uses (the configuration loader, the streaming engine, the reference, the
serial client, the simulated devices, the simulator); nothing is computed
twice. Units: slopes in pixels (``slopes``) or 2^-16 pixel (``slopes_q16``),
``[x, y]`` with x along columns; flux in 1/16 count; configuration values in
camera counts and pixels, as in docs/CONFIG.md.

>>> import numpy as np, brightpix
>>> config = brightpix.Config(width=32, height=16, bit_depth=12,
...     grid=dict(x=0, y=0, columns=2, rows=1, width=16, height=16), n=10)
>>> frames = np.zeros((5, 16, 32), np.uint16); frames[:, 4, 9] = 100
>>> result = brightpix.process(frames, config)
>>> result.slopes.shape, result.slopes[0, 0].tolist(), result.valid[0].tolist()
((5, 2, 2), [1.5, -3.5], [True, False])
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from ._brightpix import (
    Config,
    Device,
    DeviceError,
    MismatchError,
    Result,
    Rig,
    SimulatedDevice,
    Simulation,
    TuneResult,
    WfeTuneResult,
    __version__,
    centroid,
    process,
    read_frames,
    simulate,
    tune,
)

if TYPE_CHECKING:
    from typing_extensions import Self

__all__ = [
    "Config",
    "Device",
    "DeviceError",
    "MismatchError",
    "Result",
    "Rig",
    "SimulatedDevice",
    "SimulatedPort",
    "Simulation",
    "TuneResult",
    "WfeTuneResult",
    "__version__",
    "centroid",
    "process",
    "read_frames",
    "simulate",
    "simulated_device",
    "tune",
]


class SimulatedPort(str):
    """The port of a simulated device (a ``str``: ``/dev/pts/N``).

    ``pixels_fifo`` is the FIFO the QEMU firmware reads pixels from (None for
    the in-process device, whose pixels go over the port); ``Device(port)``
    uses it.
    """

    pixels_fifo: str | None

    def __new__(cls, port: str, pixels_fifo: str | None = None) -> Self:
        self = super().__new__(cls, port)
        self.pixels_fifo = pixels_fifo
        return self


@contextlib.contextmanager
def simulated_device(
    qemu: bool = False, *, elf: str | Path | None = None
) -> Iterator[SimulatedPort]:
    """Start a simulated brightpix device; yield its port; stop it on exit.

    ``qemu=False``: the firmware's device loop on a thread of this process,
    on a pseudo-terminal. ``qemu=True``: the firmware ELF (``elf``, or the
    QEMU board's release build, built if missing) in ``qemu-system-arm``,
    pixels through a FIFO. Either speaks the serial protocol of a real
    board: ``Device(port)`` or any other client can use it.

    >>> with brightpix.simulated_device() as port:          # doctest: +SKIP
    ...     with brightpix.Device(port) as device:
    ...         device.configure(config)
    ...         result = device.stream(frames, verify=True)
    """
    device = SimulatedDevice(qemu=qemu, elf=None if elf is None else Path(elf))
    try:
        fifo = device.pixels_fifo
        yield SimulatedPort(device.port, None if fifo is None else str(fifo))
    finally:
        device.stop()
