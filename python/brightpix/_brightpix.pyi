# Types of the native module brightpix._brightpix; the documentation is in its
# docstrings (help(brightpix.process), ...), written once, in python/src/*.rs.

from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np
import numpy.typing as npt
from typing_extensions import Self, TypeAlias

__version__: str

Rule: TypeAlias = Literal["subtract-next", "threshold", "subtract-next-distinct", "subtract-mean"]
ArrayLike: TypeAlias = npt.ArrayLike
StrPath: TypeAlias = str | PathLike[str]

class DeviceError(RuntimeError): ...

class MismatchError(RuntimeError):
    result: Result
    mismatches: list[str]

class Config:
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
    def load(path: StrPath) -> Config: ...
    @staticmethod
    def from_toml(text: str, base_dir: StrPath | None = None) -> Config: ...
    def to_toml(self, name: str = "config") -> str: ...
    def save(self, directory: StrPath, name: str = "config") -> Path: ...
    def keywords(self) -> dict[str, Any]: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def bit_depth(self) -> int: ...
    @property
    def n_subapertures(self) -> int: ...
    @property
    def windows(self) -> npt.NDArray[np.int32]: ...
    @property
    def rule(self) -> Rule: ...
    @property
    def mean_count(self) -> int | None: ...
    @property
    def n(self) -> int | npt.NDArray[np.uint16]: ...
    @property
    def level_filter(self) -> int | None: ...
    @property
    def background(self) -> npt.NDArray[np.float64] | None: ...
    @property
    def gain(self) -> npt.NDArray[np.float64] | None: ...
    @property
    def threshold(self) -> float | None: ...
    @property
    def min_flux(self) -> float: ...
    @property
    def reference_slopes(self) -> npt.NDArray[np.float64] | None: ...
    def __eq__(self, other: object) -> bool: ...

class Result:
    slopes: npt.NDArray[np.float64]
    slopes_q16: npt.NDArray[np.int32]
    flux: npt.NDArray[np.int64]
    valid: npt.NDArray[np.bool_]
    received: npt.NDArray[np.bool_]
    source: Literal["engine", "reference", "device", "rig"]
    config: Config
    version: str
    @property
    def n_frames(self) -> int: ...
    @property
    def n_subapertures(self) -> int: ...
    def __len__(self) -> int: ...
    def save(
        self, path: StrPath, *, layout: Literal["pairs", "vector"] = "pairs"
    ) -> list[Path]: ...

def process(
    frames: npt.NDArray[Any],
    config: Config,
    *,
    reference: bool = False,
    threads: int | None = None,
) -> Result: ...
def read_frames(
    path: StrPath, *, sensor: str | None = None, hdu: str | None = None
) -> npt.NDArray[np.uint16]: ...
def centroid(
    image: npt.NDArray[Any],
    n: int,
    rule: Rule = "subtract-next",
    *,
    mean_count: int | None = None,
    background: float = 0.0,
    threshold: float | None = None,
) -> npt.NDArray[np.float64]: ...

class Device:
    def __init__(
        self, port: str, *, timeout: float = 1.5, pixels_fifo: StrPath | None = None
    ) -> None: ...
    @property
    def port(self) -> str: ...
    @property
    def info(self) -> dict[str, Any]: ...
    @property
    def config(self) -> Config | None: ...
    @property
    def last_stream(self) -> dict[str, Any] | None: ...
    def status(self) -> dict[str, Any]: ...
    def configure(self, config: Config) -> dict[str, Any]: ...
    def stream(
        self, frames: npt.NDArray[Any], verify: bool = True, *, config: Config | None = None
    ) -> Result: ...
    def capture(self, count: int) -> Result: ...
    def close(self) -> None: ...
    def __enter__(self) -> Self: ...
    def __exit__(self, *args: object) -> bool: ...

class Rig:
    @staticmethod
    def plan(
        config: Config,
        boards: int,
        *,
        board: Literal["stm32h743", "qemu-m4", "qemu-m7"] = "stm32h743",
        camera_rate: float | None = None,
        link_rate: float | None = None,
    ) -> Rig: ...
    @staticmethod
    def load(path: StrPath) -> Rig: ...
    @property
    def config(self) -> Config: ...
    @property
    def boards(self) -> list[dict[str, Any]]: ...
    def stream(
        self,
        frames: npt.NDArray[Any],
        *,
        ports: list[str] | None = None,
        verify: bool = False,
        configure: bool = True,
        pixels_fifos: list[StrPath | None] | None = None,
    ) -> Result: ...
    def to_toml(self, config_path: StrPath) -> str: ...

class SimulatedDevice:
    def __init__(self, *, qemu: bool = False, elf: StrPath | None = None) -> None: ...
    @property
    def port(self) -> str: ...
    @property
    def pixels_fifo(self) -> Path | None: ...
    def stop(self) -> None: ...

class Simulation:
    frames: npt.NDArray[np.uint16]
    true_slopes: npt.NDArray[np.float64]
    phase_slopes: npt.NDArray[np.float64]
    conditions: dict[str, Any]
    subaperture_size: int
    grid: tuple[int, int]
    background: float
    bit_depth: int
    def config(self, **keywords: Any) -> Config: ...

def simulate(
    conditions: str | Mapping[str, Any] | None = None,
    frames: int = 100,
    seed: int = 1,
    *,
    grid: tuple[int, int] = (1, 1),
) -> Simulation: ...

class TuneResult:
    @property
    def config(self) -> Config: ...
    @property
    def rule(self) -> str: ...
    @property
    def score(self) -> str: ...
    @property
    def assumptions(self) -> list[str]: ...
    @property
    def dark(self) -> list[int]: ...
    @property
    def truncated(self) -> list[int]: ...
    @property
    def classes(self) -> list[dict[str, Any]]: ...
    @property
    def scores(self) -> dict[str, Any]: ...
    def save(self, directory: StrPath, name: str = "tuned") -> list[Path]: ...

class WfeTuneResult:
    @property
    def config(self) -> Config: ...
    @property
    def rule(self) -> str: ...
    @property
    def n(self) -> int: ...
    @property
    def wfe_nm(self) -> float: ...
    @property
    def wfe_se_nm(self) -> float: ...
    @property
    def strehl(self) -> float: ...
    @property
    def science_wavelength_m(self) -> float: ...
    @property
    def wfe_all_pixels_nm(self) -> float | None: ...
    @property
    def not_resolved(self) -> list[int]: ...
    @property
    def dark(self) -> list[int]: ...
    @property
    def assumptions(self) -> list[str]: ...
    @property
    def scores(self) -> dict[str, Any]: ...
    def save(self, directory: StrPath, name: str = "tuned") -> list[Path]: ...

Recorded: TypeAlias = npt.NDArray[np.uint16] | npt.NDArray[np.uint8]
Star: TypeAlias = Sequence[float]  # (radius_arcsec, angle_deg)
LayerSpec: TypeAlias = Sequence[float]  # (altitude_m, fraction, wind_m_s, direction_deg)

@overload
def tune(
    config: Config,
    conditions: Mapping[str, Any] | None = None,
    *,
    criterion: Literal["r"] = "r",
    frames: int | None = None,  # 4000
    seed: int = 1,
    recorded: Recorded | None = None,
    lgs: str | None = None,
    launch: tuple[float, float] | None = None,  # (0, 0)
    lgs_spot: float | None = None,  # 0.28
    obscuration: float = 0.0,
    illumination_threshold: float = 0.5,
    keep_dark: bool | None = None,  # False
    score: Literal["along", "pooled"] | None = None,
    level_filter: int | None = None,
    classes: int | None = None,  # 4
    angle_classes: int | None = None,  # 2
    max_truncation: float | None = None,  # 0.05
) -> TuneResult: ...
@overload
def tune(
    config: Config,
    conditions: Mapping[str, Any] | None = None,
    *,
    criterion: Literal["wfe"],
    seed: int = 1,
    recorded: Recorded | None = None,
    obscuration: float = 0.0,
    illumination_threshold: float = 0.5,
    level_filter: int | None = None,
    asterism: Sequence[Star] | None = None,  # the paper's
    science: Star | None = None,  # (0, 0)
    layers: Sequence[LayerSpec] | None = None,  # the paper's three
    wind_scale: float | None = None,  # 1
    frame_rate: float | None = None,  # 250 Hz
    delay: float | None = None,  # 2 frames
    science_wavelength: float | None = None,  # 1.65e-6 m
    dm_actuators: int | None = None,  # sub-apertures across + 1
    dm_coupling: float | None = None,  # 0.2
    fixed_noise: float | None = None,  # 0.2 px
    episodes: int | None = None,  # 40
    episode_frames: int | None = None,  # 100
    calibration_episodes: int | None = None,  # 1
) -> WfeTuneResult: ...
def _config_from_keywords(keywords: Mapping[str, Any]) -> Config: ...
