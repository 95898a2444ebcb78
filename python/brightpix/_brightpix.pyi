"""Type stubs and documentation of the native module ``brightpix._brightpix``.

Units everywhere: pixels are camera pixels; counts are raw camera ADU;
slopes are ``[x, y]`` (x along columns, y along rows) from the window's
centre, reference slopes subtracted; ``slopes_q16`` are the engine's
integers in 2^-16 pixel; flux is in 1/16 count (SPEC.md §5).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path
from typing import Any, Literal, Union

import numpy as np
import numpy.typing as npt

__version__: str

Rule = Literal["subtract-next", "threshold", "subtract-next-distinct", "subtract-mean"]
ArrayLike = npt.ArrayLike
StrPath = Union[str, PathLike[str]]

class DeviceError(RuntimeError):
    """The device refused a request (the message names the device's typed
    error, e.g. ``[DeviceError::NoCamera]``), dropped a frame, or speaks
    another protocol version."""

class MismatchError(RuntimeError):
    """``Device.stream(verify=True)``: the device's results differ from the
    reference's."""

    result: Result
    """What the device sent."""
    mismatches: list[str]
    """The first differences (frame, sub-aperture, device and reference values)."""

class Config:
    """A processing configuration: camera, sub-aperture windows, calibration,
    selection rule and N, centroiding (docs/CONFIG.md).

    From a TOML file with :meth:`load` (the same format, validation and
    error messages as the ``brightpix`` command line), or from keywords,
    converted and validated by the same code. Every conversion to the
    engine's fixed point rounds half away from zero; a value that does not
    fit is a ``ValueError`` naming the keyword (and, for maps, the pixel).

    Keywords (all but ``width`` and ``height`` optional; give exactly one of
    ``grid`` and ``windows``):

    - ``width``, ``height``: the camera frame, pixels (1..=4096).
    - ``bit_depth``: bits per raw pixel, 1..=16 (default 16); frames are
      checked against it.
    - ``grid``: a dict with the keys of ``[subapertures.grid]``: ``x``,
      ``y`` (first window's top-left corner), ``columns``, ``rows``,
      ``width``, ``height`` (window size), optional ``pitch_x``,
      ``pitch_y`` (default: the window size) and ``skip`` (a list of
      ``[column, row]`` positions without a window). Windows are numbered
      row by row.
    - ``windows``: an ``(S, 4)`` integer array of ``x, y, width, height``
      per window, pixels, in output order. Windows are at most 64x64.
    - ``rule``: ``"subtract-next"`` (default; the paper's N+1th
      subtracted), ``"threshold"``, ``"subtract-next-distinct"`` or
      ``"subtract-mean"`` (SPEC.md §3).
    - ``n``: N, the brightest pixels kept: an int for every sub-aperture,
      or an ``(S,)`` integer array (default 20).
    - ``mean_count``: M for ``"subtract-mean"`` (1..=16).
    - ``background``: counts, a number or an ``(H, W)`` map.
    - ``flat``, ``pixel_weight``: ``(H, W)`` gain maps (dimensionless);
      the engine applies flat x pixel_weight, within 0..=65535/4096.
    - ``threshold``: counts; calibrated values below it become 0.
    - ``min_flux``: counts; a sub-aperture is valid only if its flux
      exceeds it (default 0).
    - ``reference_slopes``: ``(S, 2)`` ``[x, y]`` pixels subtracted from
      the slopes.
    - ``level_filter``: gain shift G (1..=16) of the temporal filter of
      the subtracted level (SPEC.md §4), or None (off).
    """

    def __init__(
        self,
        *,
        width: int,
        height: int,
        bit_depth: int = 16,
        grid: Mapping[str, Any] | None = None,
        windows: ArrayLike | None = None,
        rule: Rule = "subtract-next",
        n: int | ArrayLike | None = None,
        mean_count: int | None = None,
        background: float | ArrayLike | None = None,
        flat: ArrayLike | None = None,
        pixel_weight: ArrayLike | None = None,
        threshold: float | None = None,
        min_flux: float | None = None,
        reference_slopes: ArrayLike | None = None,
        level_filter: int | None = None,
    ) -> None: ...
    @staticmethod
    def load(path: StrPath) -> Config:
        """Load a TOML configuration; relative data-file paths resolve
        against its directory. Errors: ``FileNotFoundError``/``OSError``
        (unreadable files), ``ValueError`` (everything else), with the
        command line's message (file, key, problem)."""
    @staticmethod
    def from_toml(text: str, base_dir: StrPath | None = None) -> Config:
        """Parse TOML text; relative data-file paths resolve against
        ``base_dir`` (default: the current directory)."""
    def to_toml(self, name: str = "config") -> str:
        """The configuration as TOML. Maps, reference slopes and long lists
        are referenced as ``{name}-*.npy`` files, which :meth:`save` writes."""
    def save(self, directory: StrPath, name: str = "config") -> Path:
        """Write ``directory/name.toml`` and its ``.npy`` data files (exact:
        loading them gives this configuration back); return the TOML path."""
    def keywords(self) -> dict[str, Any]:
        """The keywords that rebuild this configuration: ``Config(**c.keywords()) == c``."""
    @property
    def width(self) -> int:
        """Camera width, pixels."""
    @property
    def height(self) -> int:
        """Camera height, pixels."""
    @property
    def bit_depth(self) -> int: ...
    @property
    def n_subapertures(self) -> int:
        """S, the number of windows."""
    @property
    def windows(self) -> npt.NDArray[np.int32]:
        """``(S, 4)``: x, y, width, height of each window, pixels."""
    @property
    def rule(self) -> Rule: ...
    @property
    def mean_count(self) -> int | None: ...
    @property
    def n(self) -> int | npt.NDArray[np.uint16]:
        """N: one int, or ``(S,)`` per sub-aperture."""
    @property
    def level_filter(self) -> int | None:
        """The level filter's gain shift, or None."""
    @property
    def background(self) -> npt.NDArray[np.float64] | None:
        """``(H, W)`` counts (multiples of 1/16), or None."""
    @property
    def gain(self) -> npt.NDArray[np.float64] | None:
        """``(H, W)`` flat x pixel weight (multiples of 1/4096), or None."""
    @property
    def threshold(self) -> float | None:
        """Counts, or None."""
    @property
    def min_flux(self) -> float:
        """Counts."""
    @property
    def reference_slopes(self) -> npt.NDArray[np.float64] | None:
        """``(S, 2)`` pixels, or None."""
    def __eq__(self, other: object) -> bool: ...

class Result:
    """Slopes, flux and validity of every frame and sub-aperture, with what
    made them. For a single ``(H, W)`` frame the leading frame axis is
    absent: ``slopes`` is ``(S, 2)``, ``flux`` ``(S,)``."""

    slopes: npt.NDArray[np.float64]
    """``(F, S, 2)`` ``[x, y]`` pixels from the window centre, reference
    slopes subtracted: ``slopes_q16 / 65536``. 0.0 where not valid; NaN
    where a device sent nothing."""
    slopes_q16: npt.NDArray[np.int32]
    """``(F, S, 2)`` the engine's integers, 2^-16 pixel."""
    flux: npt.NDArray[np.int64]
    """``(F, S)`` the sum of the selected weights, 1/16 count."""
    valid: npt.NDArray[np.bool_]
    """``(F, S)`` flux above ``min_flux``."""
    received: npt.NDArray[np.bool_]
    """``(F, S)`` a result arrived (False only for a device's lost results)."""
    source: Literal["engine", "reference", "device"]
    config: Config
    """The configuration that produced it."""
    version: str
    """The brightpix version that produced it."""
    @property
    def n_frames(self) -> int: ...
    @property
    def n_subapertures(self) -> int: ...
    def __len__(self) -> int: ...

def process(frames: npt.NDArray[Any], config: Config, *, reference: bool = False) -> Result:
    """Compute the slopes of camera frames, as ``brightpix process`` does.

    ``frames``: a numpy ``uint8`` or ``uint16`` array of counts, ``(H, W)``
    or ``(F, H, W)``, in any memory order and byte order (FITS data from
    astropy, big-endian, is fine; it is copied only when not C-contiguous
    native uint16). Raw values must be below ``2**config.bit_depth``.

    ``reference=True`` uses the independent reference implementation (a
    full sort per sub-aperture) instead of the streaming engine; the
    results are identical, bit for bit.

    The GIL is released while processing. With the level filter on, frames
    are processed in order and the filter starts from its reset state.

    Raises ``TypeError`` (not uint8/uint16, not an array), ``ValueError``
    (shape, a pixel above the bit depth: the message names frame, row,
    column and value).
    """

def centroid(
    image: npt.NDArray[Any],
    n: int,
    rule: Rule = "subtract-next",
    *,
    mean_count: int | None = None,
    background: float = 0.0,
    threshold: float | None = None,
) -> npt.NDArray[np.float64]:
    """Brightest-pixel centre of gravity of sub-aperture images, the
    engine's arithmetic, for people used to aotools.

    ``image``: ``uint8``/``uint16`` counts, ``(h, w)`` or a stack
    ``(k, h, w)``, at most 64x64. Returns ``[x, y]`` pixels from the
    image's centre, ``(2,)`` or ``(k, 2)`` (note: aotools returns ``(2, k)``);
    NaN where no pixel has weight. Rounded to 2^-16 pixel.

    aotools: ``aotools.brightest_pixel(img, t)`` subtracts the
    ``round(t * h * w)``-th brightest value, clips at 0 and takes the centre
    of gravity with the origin at pixel ``[0, 0]``. That is
    ``centroid(img, n=round(t * h * w) - 1, rule="subtract-next")`` plus
    ``[(w - 1) / 2, (h - 1) / 2]``, to within 2^-16 pixel.
    """

class Device:
    """A brightpix device on a serial port (a board on USB: ``/dev/ttyACM0``;
    a simulated one: the port :func:`brightpix.simulated_device` yields).

    Connecting checks the protocol version and schema. Every failure is an
    exception carrying the client's message: ``FileNotFoundError`` /
    ``PermissionError`` / ``OSError`` (the port cannot be opened),
    ``TimeoutError`` (the device does not answer, or stops for ``timeout``
    seconds), ``ConnectionError`` (the port disappears), ``DeviceError``
    (the device refuses), ``ValueError`` (misuse). An exception raised
    part-way through ``stream`` or ``capture`` carries what had arrived as
    ``.result``. Usable as a context manager (closes the port).
    """

    def __init__(
        self, port: str, *, timeout: float = 1.5, pixels_fifo: StrPath | None = None
    ) -> None: ...
    @property
    def port(self) -> str: ...
    @property
    def info(self) -> dict[str, Any]:
        """The device's identity and limits (board, protocol version, schema, sizes)."""
    @property
    def config(self) -> Config | None:
        """The configuration applied by :meth:`configure` (or given to :meth:`stream`)."""
    @property
    def last_stream(self) -> dict[str, Any] | None:
        """Totals of the last :meth:`stream`: frames sent/done/dropped,
        elapsed seconds, frames per second, and with ``verify`` the frames
        verified, results compared and mismatches."""
    def status(self) -> dict[str, Any]:
        """The device's counters (active configuration id, frames processed
        and dropped, link errors, overruns, pixel errors)."""
    def configure(self, config: Config) -> dict[str, Any]:
        """Upload ``config`` in chunks, committed atomically (on any error
        the device keeps its previous configuration); resets the device's
        level filters. Returns the configuration id, windows open at once,
        pool entries, messages and bytes sent, and the seconds it took."""
    def stream(
        self, frames: npt.NDArray[Any], verify: bool = True, *, config: Config | None = None
    ) -> Result:
        """Send frames (``uint8``/``uint16`` ``(H, W)`` or ``(F, H, W)``, as
        for :func:`process`) and return the device's results.

        ``verify=True`` checks every integer against the reference, which
        has seen every frame streamed since :meth:`configure` (so the level
        filter is followed across calls), and raises ``MismatchError`` on
        any difference. ``config`` tells the client the configuration of a
        device configured earlier (no upload; the reference starts from a
        reset level filter).
        """
    def capture(self, count: int) -> Result:
        """Record ``count`` frames from the device's own camera (needs
        :meth:`configure` first); a device without a camera raises
        ``DeviceError`` (``NoCamera``)."""
    def close(self) -> None: ...
    def __enter__(self) -> Device: ...
    def __exit__(self, *args: object) -> bool: ...

class SimulatedDevice:
    """A simulated device (prefer :func:`brightpix.simulated_device`):
    ``qemu=False`` runs the firmware's device loop on a thread of this
    process on a pseudo-terminal; ``qemu=True`` runs the firmware ELF in
    ``qemu-system-arm``, pixels through a FIFO."""

    def __init__(self, *, qemu: bool = False, elf: StrPath | None = None) -> None: ...
    @property
    def port(self) -> str: ...
    @property
    def pixels_fifo(self) -> Path | None: ...
    def stop(self) -> None: ...

class Simulation:
    """Monte-Carlo Shack-Hartmann frames (the simulator of ``brightpix
    paper``) and the slopes that made them."""

    frames: npt.NDArray[np.uint16]
    """``(F, rows * size, columns * size)`` camera counts; each frame holds
    ``columns x rows`` independent sub-aperture images, row by row."""
    true_slopes: npt.NDArray[np.float64]
    """``(F, S, 2)`` ``[x, y]`` pixels from each sub-aperture's centre: the
    centre of gravity of the noiseless image (the paper's true slope)."""
    phase_slopes: npt.NDArray[np.float64]
    """``(F, S, 2)`` pixels: the wavefront's G-tilt as a spot shift."""
    conditions: dict[str, Any]
    """Every simulator parameter (the keys a conditions dict may give)."""
    subaperture_size: int
    """Side of a sub-aperture image, pixels."""
    grid: tuple[int, int]
    """``(columns, rows)``."""
    background: float
    """Counts added to every pixel (what calibration should subtract)."""
    bit_depth: int
    def config(self, **keywords: Any) -> Config:
        """A :class:`Config` for these frames (camera, grid, background);
        ``keywords`` as for ``Config`` (``rule``, ``n``, ...)."""

def simulate(
    conditions: str | Mapping[str, Any] | None = None,
    frames: int = 100,
    seed: int = 1,
    *,
    grid: tuple[int, int] = (1, 1),
) -> Simulation:
    """Simulate Shack-Hartmann frames with the paper's Monte-Carlo model.

    ``conditions``: None or ``"ngs"`` (the paper's CANARY NGS: 16x16
    pixels of 0.22", r0 = 12.5 cm, 200 photons, 2 e- read noise, 50-count
    background), ``"rayleigh:DEPTH[:ALTITUDE]"`` or
    ``"sodium:SEPARATION[:ALTITUDE]"`` (the paper's LGS cases, metres; the
    elongation is along x), or a dict of simulator parameters (the keys of
    :attr:`Simulation.conditions`, e.g. ``{"r0_m": 0.1, "photons": 150,
    "source": {"kind": "rayleigh", ...}}``; unknown keys are errors).
    ``grid``: ``(columns, rows)`` of sub-apertures per frame. Results
    depend only on ``seed`` (not on threads). GIL released.
    """

def _config_from_keywords(keywords: Mapping[str, Any]) -> Config: ...
