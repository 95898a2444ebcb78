//! The processing configuration: camera, sub-aperture windows, calibration,
//! selection and centroiding. Borrowed views only (`no_std`, no heap): the
//! host owns its maps in `Vec`s, the firmware in static buffers, and both hand
//! the engine a [`Config`] that points at them.
//!
//! Every number here has the fixed-point format that `shared/SPEC.md` gives.
//! [`Config::validate`] checks every bound that SPEC.md relies on, so a
//! configuration that passes cannot overflow the arithmetic.

use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Largest camera side, in pixels.
pub const MAX_CAMERA_SIDE: u16 = 4096;
/// Largest sub-aperture window side, in pixels (SPEC.md §5 bounds assume it).
pub const MAX_WINDOW_SIDE: u16 = 64;
/// Largest number of sub-aperture windows in one configuration.
pub const MAX_SUBAPERTURES: usize = 16384;
/// Largest `M` of [`SelectionRule::SubtractMean`].
pub const MAX_MEAN_COUNT: u16 = 16;
/// Largest |background| in 1/16 counts (SPEC.md §2).
pub const MAX_BACKGROUND_ABS: i32 = 1 << 20;
/// Largest |fixed threshold| in 1/16 counts (SPEC.md §2).
pub const MAX_THRESHOLD_ABS: i32 = 1 << 25;
/// Largest |reference slope| in 2^-16 pixel.
pub const MAX_REFERENCE_SLOPE_ABS: i32 = (MAX_WINDOW_SIDE as i32) << 16;
/// Fractional bits of calibrated values: they are in 1/16 count.
pub const CALIBRATED_FRACTION_BITS: u32 = 4;
/// Fractional bits of the gain map: 4096 is a gain of 1.0.
pub const GAIN_FRACTION_BITS: u32 = 12;
/// Fractional bits of slopes: they are in 2^-16 pixel.
pub const SLOPE_FRACTION_BITS: u32 = 16;
/// Extra fractional bits of the temporal level filter's state.
pub const LEVEL_FILTER_FRACTION_BITS: u32 = 8;

/// The camera: frame size and the bit depth of its raw pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Camera {
    pub width: u16,
    pub height: u16,
    /// Raw pixels are `0 ..= 2^bit_depth - 1`; 1..=16.
    pub bit_depth: u8,
}

impl Camera {
    pub const fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
    pub const fn max_raw(&self) -> u16 {
        if self.bit_depth >= 16 {
            u16::MAX
        } else {
            (1u16 << self.bit_depth) - 1
        }
    }
}

/// Where the configured camera lies on a larger sensor: the rectangle a
/// board of a rig captures when several boards share one camera
/// (PROTOCOL.md §4). The rectangle is columns `x .. x + camera.width` and
/// rows `y .. y + camera.height` of a `sensor_width` x `sensor_height`
/// sensor. Windows, maps and pixels stay in the rectangle's coordinates
/// (the configured camera's), so no arithmetic of SPEC.md changes: the crop
/// says only which of the sensor's pixels the board's camera interface
/// keeps. The engine never sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Schema)]
pub struct Crop {
    pub x: u16,
    pub y: u16,
    pub sensor_width: u16,
    pub sensor_height: u16,
}

impl Crop {
    /// The whole sensor, at `camera`'s bit depth.
    pub const fn sensor(&self, camera: Camera) -> Camera {
        Camera {
            width: self.sensor_width,
            height: self.sensor_height,
            bit_depth: camera.bit_depth,
        }
    }
}

/// One sub-aperture: a rectangle of camera pixels, `x`/`y` its top-left
/// corner (column, row), inclusive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Schema)]
pub struct SubapertureWindow {
    pub x: u16,
    pub y: u16,
    pub width: u16,
    pub height: u16,
}

impl SubapertureWindow {
    pub const fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
    /// Last row (inclusive).
    pub const fn last_row(&self) -> u16 {
        self.y + self.height - 1
    }
    /// One past the last column.
    pub const fn end_column(&self) -> u16 {
        self.x + self.width
    }
}

/// How a sub-aperture's pixels are weighted after ranking (SPEC.md §3).
/// `v(k)` is the k-th largest calibrated value, duplicates counted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum SelectionRule {
    /// Keep `p >= v(N)`, weight `p` (the paper's selection without subtraction).
    Threshold,
    /// Weight `max(0, p - v(N+1))` (the paper's "N+1th subtracted algorithm",
    /// literal, as COMPASS).
    SubtractNext,
    /// Keep `p >= v(N)`, subtract the largest value strictly below `v(N)`
    /// (DARC as flown).
    SubtractNextDistinct,
    /// Keep `p >= v(N)`, subtract the floor of the mean of the `count`
    /// largest values strictly below `v(N)` (DARC's useBrightThrAv).
    SubtractMean { count: u16 },
}

impl SelectionRule {
    /// Whether the rule subtracts a level (and so can be temporally filtered).
    pub const fn subtracts(&self) -> bool {
        !matches!(self, SelectionRule::Threshold)
    }
}

/// Temporal filtering of the subtracted level, per sub-aperture (SPEC.md §4):
/// `s += (level * 256 - s) >> gain_shift`, i.e. an exponential average with
/// gain `2^-gain_shift`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct LevelFilter {
    /// 1..=16.
    pub gain_shift: u8,
}

/// Number of brightest pixels to select: one for all, or one per sub-aperture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelCount<'a> {
    All(u16),
    PerSubaperture(&'a [u16]),
}

impl PixelCount<'_> {
    pub fn for_subaperture(&self, index: usize) -> u16 {
        match self {
            PixelCount::All(n) => *n,
            PixelCount::PerSubaperture(list) => list[index],
        }
    }
}

/// Selection parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Selection<'a> {
    pub rule: SelectionRule,
    /// N. `N >= pixel count` of a window means no selection there.
    pub count: PixelCount<'a>,
    pub level_filter: Option<LevelFilter>,
}

impl Default for Selection<'_> {
    /// The paper's recommendation: subtract the 21st brightest, keep 20.
    fn default() -> Self {
        Selection {
            rule: SelectionRule::SubtractNext,
            count: PixelCount::All(20),
            level_filter: None,
        }
    }
}

/// Per-pixel calibration (SPEC.md §2). Maps are full camera frames, row-major.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Calibration<'a> {
    /// Background in 1/16 count, |b| <= 2^20.
    pub background: Option<&'a [i32]>,
    /// Gain (flat field x pixel weight) in 1/4096, 0..=65535.
    pub gain: Option<&'a [u16]>,
    /// Calibrated values below this (1/16 count) become 0.
    pub threshold: Option<i32>,
}

/// Centre-of-gravity parameters (SPEC.md §5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Centroid<'a> {
    /// Reference slopes `[x, y]` in 2^-16 pixel, one per sub-aperture.
    pub reference_slopes: Option<&'a [[i32; 2]]>,
    /// A sub-aperture is valid only if its flux (1/16 count) exceeds this; >= 0.
    pub min_flux: i64,
}

/// A whole processing configuration, borrowed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Config<'a> {
    pub camera: Camera,
    /// Output order is this order.
    pub windows: &'a [SubapertureWindow],
    pub calibration: Calibration<'a>,
    pub selection: Selection<'a>,
    pub centroid: Centroid<'a>,
    /// Where `camera` lies on a larger sensor, for a board that captures a
    /// rectangle of it; `None`: the camera is the whole sensor.
    pub crop: Option<Crop>,
}

/// Why a configuration was refused. Each names the offending item.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ConfigError {
    CameraSize {
        width: u16,
        height: u16,
    },
    BitDepth {
        bit_depth: u8,
    },
    NoSubapertures,
    TooManySubapertures {
        count: usize,
        max: usize,
    },
    EmptyWindow {
        index: usize,
    },
    WindowTooLarge {
        index: usize,
        width: u16,
        height: u16,
    },
    WindowOutsideCamera {
        index: usize,
    },
    PixelCountZero {
        index: usize,
    },
    PixelCountListLength {
        expected: usize,
        found: usize,
    },
    MeanCount {
        count: u16,
    },
    LevelFilterGain {
        gain_shift: u8,
    },
    LevelFilterWithoutSubtraction,
    MapSize {
        map: MapKind,
        expected: usize,
        found: usize,
    },
    BackgroundOutOfRange {
        pixel: usize,
        value: i32,
    },
    ThresholdOutOfRange {
        value: i32,
    },
    ReferenceSlopeOutOfRange {
        index: usize,
    },
    NegativeMinFlux,
    /// The engine's static memory cannot hold this many simultaneously open
    /// windows, or their selection state.
    MemoryBudget {
        needed: usize,
        available: usize,
        what: MemoryKind,
    },
    /// N = 0 for every sub-aperture (a single N, not a per-sub-aperture list).
    PixelCountZeroAll,
    /// The crop rectangle (the camera) does not lie on its sensor, or the
    /// sensor is larger than [`MAX_CAMERA_SIDE`].
    CropOutsideSensor {
        x: u16,
        y: u16,
        width: u16,
        height: u16,
        sensor_width: u16,
        sensor_height: u16,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum MapKind {
    Background,
    Gain,
    ReferenceSlopes,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum MemoryKind {
    Subapertures,
    OpenWindows,
    SelectionEntries,
    /// Pixels of the engine's row history (the tallest selecting window's
    /// rows of the camera).
    RowHistory,
    /// Scratch entries (the largest selecting window's pixels).
    ScratchEntries,
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        use ConfigError::*;
        match *self {
            CameraSize { width, height } => write!(
                f,
                "camera size {width}x{height} is outside 1..={MAX_CAMERA_SIDE} per side"
            ),
            BitDepth { bit_depth } => write!(f, "bit depth {bit_depth} is outside 1..=16"),
            NoSubapertures => write!(f, "no sub-aperture windows are configured"),
            TooManySubapertures { count, max } => {
                write!(f, "{count} sub-apertures configured, at most {max} allowed")
            }
            EmptyWindow { index } => write!(f, "sub-aperture {index} has zero width or height"),
            WindowTooLarge {
                index,
                width,
                height,
            } => write!(
                f,
                "sub-aperture {index} is {width}x{height}, larger than {MAX_WINDOW_SIDE} per side"
            ),
            WindowOutsideCamera { index } => {
                write!(f, "sub-aperture {index} extends outside the camera frame")
            }
            PixelCountZero { index } => {
                write!(
                    f,
                    "sub-aperture {index}: number of pixels to select (N) is 0"
                )
            }
            PixelCountListLength { expected, found } => write!(
                f,
                "per-sub-aperture N has {found} entries, expected one per sub-aperture ({expected})"
            ),
            MeanCount { count } => write!(
                f,
                "subtract-mean count M = {count} is outside 1..={MAX_MEAN_COUNT}"
            ),
            LevelFilterGain { gain_shift } => {
                write!(f, "level filter gain shift {gain_shift} is outside 1..=16")
            }
            LevelFilterWithoutSubtraction => write!(
                f,
                "a level filter needs a subtracting rule; the threshold rule subtracts nothing"
            ),
            MapSize {
                map,
                expected,
                found,
            } => write!(f, "{map:?} map has {found} entries, expected {expected}"),
            BackgroundOutOfRange { pixel, value } => write!(
                f,
                "background at pixel {pixel} is {value}/16 counts, beyond +-{MAX_BACKGROUND_ABS}/16"
            ),
            ThresholdOutOfRange { value } => write!(
                f,
                "threshold {value}/16 counts is beyond +-{MAX_THRESHOLD_ABS}/16"
            ),
            ReferenceSlopeOutOfRange { index } => write!(
                f,
                "reference slope of sub-aperture {index} is beyond +-{MAX_WINDOW_SIDE} pixels"
            ),
            NegativeMinFlux => write!(f, "minimum flux is negative"),
            MemoryBudget {
                needed,
                available,
                what,
            } => write!(
                f,
                "configuration needs {needed} {what:?} but the engine's memory holds {available}"
            ),
            PixelCountZeroAll => write!(
                f,
                "the number of pixels to select (N) is 0 for every sub-aperture; it must be at least 1"
            ),
            CropOutsideSensor {
                x,
                y,
                width,
                height,
                sensor_width,
                sensor_height,
            } => write!(
                f,
                "crop rectangle {width}x{height} at ({x}, {y}) does not lie on the {sensor_width}x{sensor_height} sensor (at most {MAX_CAMERA_SIDE} per side)"
            ),
        }
    }
}

impl core::error::Error for ConfigError {}

impl Config<'_> {
    /// Checks every bound SPEC.md relies on. Memory limits are checked by the
    /// engine that is asked to hold the configuration.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let cam = self.camera;
        if cam.width == 0
            || cam.height == 0
            || cam.width > MAX_CAMERA_SIDE
            || cam.height > MAX_CAMERA_SIDE
        {
            return Err(ConfigError::CameraSize {
                width: cam.width,
                height: cam.height,
            });
        }
        if !(1..=16).contains(&cam.bit_depth) {
            return Err(ConfigError::BitDepth {
                bit_depth: cam.bit_depth,
            });
        }
        if let Some(crop) = self.crop {
            let fits = |start: u16, len: u16, side: u16| {
                (1..=MAX_CAMERA_SIDE).contains(&side) && start as u32 + len as u32 <= side as u32
            };
            if !fits(crop.x, cam.width, crop.sensor_width)
                || !fits(crop.y, cam.height, crop.sensor_height)
            {
                return Err(ConfigError::CropOutsideSensor {
                    x: crop.x,
                    y: crop.y,
                    width: cam.width,
                    height: cam.height,
                    sensor_width: crop.sensor_width,
                    sensor_height: crop.sensor_height,
                });
            }
        }
        let count = self.windows.len();
        if count == 0 {
            return Err(ConfigError::NoSubapertures);
        }
        if count > MAX_SUBAPERTURES {
            return Err(ConfigError::TooManySubapertures {
                count,
                max: MAX_SUBAPERTURES,
            });
        }
        for (index, w) in self.windows.iter().enumerate() {
            if w.width == 0 || w.height == 0 {
                return Err(ConfigError::EmptyWindow { index });
            }
            if w.width > MAX_WINDOW_SIDE || w.height > MAX_WINDOW_SIDE {
                return Err(ConfigError::WindowTooLarge {
                    index,
                    width: w.width,
                    height: w.height,
                });
            }
            if w.x as u32 + w.width as u32 > cam.width as u32
                || w.y as u32 + w.height as u32 > cam.height as u32
            {
                return Err(ConfigError::WindowOutsideCamera { index });
            }
        }
        match self.selection.count {
            PixelCount::All(0) => return Err(ConfigError::PixelCountZeroAll),
            PixelCount::All(_) => {}
            PixelCount::PerSubaperture(list) => {
                if list.len() != count {
                    return Err(ConfigError::PixelCountListLength {
                        expected: count,
                        found: list.len(),
                    });
                }
                if let Some(index) = list.iter().position(|&n| n == 0) {
                    return Err(ConfigError::PixelCountZero { index });
                }
            }
        }
        if let SelectionRule::SubtractMean { count } = self.selection.rule {
            if count == 0 || count > MAX_MEAN_COUNT {
                return Err(ConfigError::MeanCount { count });
            }
        }
        if let Some(filter) = self.selection.level_filter {
            if !(1..=16).contains(&filter.gain_shift) {
                return Err(ConfigError::LevelFilterGain {
                    gain_shift: filter.gain_shift,
                });
            }
            if !self.selection.rule.subtracts() {
                return Err(ConfigError::LevelFilterWithoutSubtraction);
            }
        }
        let pixels = cam.pixel_count();
        if let Some(map) = self.calibration.background {
            if map.len() != pixels {
                return Err(ConfigError::MapSize {
                    map: MapKind::Background,
                    expected: pixels,
                    found: map.len(),
                });
            }
            // The largest magnitude first, in a loop without an exit (it
            // vectorises; engines validate their configuration each time
            // they are built), then the first pixel over, if any.
            let largest = map.iter().fold(0, |m, b| m.max(b.unsigned_abs()));
            if largest > MAX_BACKGROUND_ABS as u32 {
                let pixel = map
                    .iter()
                    .position(|b| b.unsigned_abs() > MAX_BACKGROUND_ABS as u32)
                    .unwrap_or(0);
                return Err(ConfigError::BackgroundOutOfRange {
                    pixel,
                    value: map[pixel],
                });
            }
        }
        if let Some(map) = self.calibration.gain {
            if map.len() != pixels {
                return Err(ConfigError::MapSize {
                    map: MapKind::Gain,
                    expected: pixels,
                    found: map.len(),
                });
            }
        }
        if let Some(value) = self.calibration.threshold {
            if value.unsigned_abs() > MAX_THRESHOLD_ABS as u32 {
                return Err(ConfigError::ThresholdOutOfRange { value });
            }
        }
        if let Some(refs) = self.centroid.reference_slopes {
            if refs.len() != count {
                return Err(ConfigError::MapSize {
                    map: MapKind::ReferenceSlopes,
                    expected: count,
                    found: refs.len(),
                });
            }
            if let Some(index) = refs.iter().position(|r| {
                r.iter()
                    .any(|s| s.unsigned_abs() > MAX_REFERENCE_SLOPE_ABS as u32)
            }) {
                return Err(ConfigError::ReferenceSlopeOutOfRange { index });
            }
        }
        if self.centroid.min_flux < 0 {
            return Err(ConfigError::NegativeMinFlux);
        }
        Ok(())
    }

    /// N for sub-aperture `index`.
    pub fn pixel_count(&self, index: usize) -> u16 {
        self.selection.count.for_subaperture(index)
    }
}

/// A regular grid of equal windows: the usual Shack-Hartmann layout, expanded
/// into the list the engine uses. Sub-apertures are numbered row by row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RegularGrid {
    /// Top-left pixel of the first window.
    pub x: u16,
    pub y: u16,
    /// Windows across and down.
    pub columns: u16,
    pub rows: u16,
    /// Window size.
    pub width: u16,
    pub height: u16,
    /// Distance between window origins; defaults to the window size.
    pub pitch_x: u16,
    pub pitch_y: u16,
}

impl RegularGrid {
    /// The window at grid position (column, row).
    pub fn window(&self, column: u16, row: u16) -> SubapertureWindow {
        SubapertureWindow {
            // Saturating: an overflowing grid yields a window outside the
            // camera, which validation then names, instead of a panic.
            x: self.x.saturating_add(column.saturating_mul(self.pitch_x)),
            y: self.y.saturating_add(row.saturating_mul(self.pitch_y)),
            width: self.width,
            height: self.height,
        }
    }

    /// All windows, row by row.
    pub fn windows(&self) -> impl Iterator<Item = SubapertureWindow> + '_ {
        (0..self.rows).flat_map(move |r| (0..self.columns).map(move |c| self.window(c, r)))
    }
}
