//! Why a request failed (PROTOCOL.md §5, `Error`): [`DeviceError`] and
//! the faults it carries, each with the `Display` text the host tool
//! shows. [`ConfigFault`] is the engine's [`ConfigError`] with `u32` for
//! `usize`, converted both ways.

use core::fmt;

use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use super::{
    BenchFault, HostMessage, LinkTestFault, SyncFault, Table, MAX_CHUNK_BYTES, MAX_FRAME_LEN,
};
use crate::config::{ConfigError, MapKind, MemoryKind};

/// A request failed; the device's state is as before it (except where noted).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum DeviceError {
    /// A link frame did not decode (bad COBS, not a message, trailing bytes).
    Decode,
    /// A link frame's CRC-32 did not match.
    Crc,
    /// A link frame longer than `max_frame_bytes`; discarded.
    FrameTooLong,
    /// No matching `Hello` since the device started: it refuses everything
    /// else (a `Hello` with another version or schema opens nothing).
    HelloRequired,
    /// The message is not valid now (e.g. `PixelRows` during `Capture`).
    Unexpected { message: MessageKind },
    /// A chunk or commit without an upload in progress.
    NoUpload,
    /// A chunk or commit for another upload than the one in progress.
    UploadMismatch { expected: u32, found: u32 },
    /// A chunk not at the next expected position (`expected: None`: all
    /// tables are complete). The upload is discarded.
    ChunkOutOfOrder {
        expected: Option<TablePosition>,
        found: TablePosition,
    },
    /// A chunk that is not a whole number of elements, or longer than
    /// [`MAX_CHUNK_BYTES`]. The upload is discarded.
    ChunkLength { table: Table, len: u32 },
    /// A chunk past the end of its table. The upload is discarded.
    ChunkPastEnd { table: Table, end: u32, len: u32 },
    /// Commit before every table was complete. The upload is discarded.
    UploadIncomplete {
        table: Table,
        received: u32,
        expected: u32,
    },
    /// The commit's CRC differs from the device's over the bytes it received.
    /// The upload is discarded.
    UploadCrc { computed: u32, claimed: u32 },
    /// The configuration does not fit the device's static buffers.
    Capacity {
        what: CapacityKind,
        needed: u32,
        available: u32,
    },
    /// The configuration is invalid or does not fit the engine's memory.
    Config(ConfigFault),
    /// Pixels or a level-filter reset with no active configuration.
    NotConfigured,
    /// Frame `frame` was dropped (or, for `PixelOutOfRange`, abandoned
    /// part-way: SPEC.md §8).
    Frame { frame: u32, fault: FrameFault },
    /// `Capture` on a device without a camera, or the camera refused.
    NoCamera,
    /// At `ConfigBegin`: the device's camera interface cannot crop the
    /// header's rectangle. The upload is not started.
    Crop(CropFault),
    /// A `Bench` request was refused; nothing was measured.
    Bench(BenchFault),
    /// A `Capture` on the sync line was refused; nothing was started.
    Sync(SyncFault),
    /// A `LinkTest` was refused; nothing was sent.
    LinkTest(LinkTestFault),
}

/// Why a device's camera interface cannot capture a crop rectangle (the
/// STM32H743's DCMI: RM0433 "DCMI crop feature"; a simulated camera: whole
/// 32-bit words of its bus).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum CropFault {
    /// The rectangle's width must be a multiple of `multiple` pixels (the
    /// DCMI counts the width in pixel clocks, one a pixel, and captures
    /// whole 32-bit words of every line).
    Width { width: u16, multiple: u16 },
    /// The rectangle's pixel count must be a multiple of `multiple`: a
    /// frame is whole words of the bus (and, on the DCMI, whole DMA bursts).
    FramePixels { pixels: u32, multiple: u16 },
    /// The interface takes sensors of at most `max` pixels a side.
    SensorSize { width: u16, height: u16, max: u16 },
}

/// [`ConfigError`] on the wire: the same variants with `u32` instead of
/// `usize` (whose width differs between device and host). Converts both
/// ways without loss for every value a valid upload can produce; the
/// exhaustive conversions make a new `ConfigError` variant a compile error
/// here, and so a schema change.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum ConfigFault {
    CameraSize {
        width: u16,
        height: u16,
    },
    BitDepth {
        bit_depth: u8,
    },
    NoSubapertures,
    TooManySubapertures {
        count: u32,
        max: u32,
    },
    EmptyWindow {
        index: u32,
    },
    WindowTooLarge {
        index: u32,
        width: u16,
        height: u16,
    },
    WindowOutsideCamera {
        index: u32,
    },
    PixelCountZero {
        index: u32,
    },
    PixelCountListLength {
        expected: u32,
        found: u32,
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
        expected: u32,
        found: u32,
    },
    BackgroundOutOfRange {
        pixel: u32,
        value: i32,
    },
    ThresholdOutOfRange {
        value: i32,
    },
    ReferenceSlopeOutOfRange {
        index: u32,
    },
    NegativeMinFlux,
    MemoryBudget {
        needed: u32,
        available: u32,
        what: MemoryKind,
    },
    PixelCountZeroAll,
    CropOutsideSensor {
        x: u16,
        y: u16,
        width: u16,
        height: u16,
        sensor_width: u16,
        sensor_height: u16,
    },
}

fn narrow(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

impl From<ConfigError> for ConfigFault {
    fn from(e: ConfigError) -> Self {
        use ConfigError as E;
        use ConfigFault as F;
        match e {
            E::CameraSize { width, height } => F::CameraSize { width, height },
            E::BitDepth { bit_depth } => F::BitDepth { bit_depth },
            E::NoSubapertures => F::NoSubapertures,
            E::TooManySubapertures { count, max } => F::TooManySubapertures {
                count: narrow(count),
                max: narrow(max),
            },
            E::EmptyWindow { index } => F::EmptyWindow {
                index: narrow(index),
            },
            E::WindowTooLarge {
                index,
                width,
                height,
            } => F::WindowTooLarge {
                index: narrow(index),
                width,
                height,
            },
            E::WindowOutsideCamera { index } => F::WindowOutsideCamera {
                index: narrow(index),
            },
            E::PixelCountZero { index } => F::PixelCountZero {
                index: narrow(index),
            },
            E::PixelCountListLength { expected, found } => F::PixelCountListLength {
                expected: narrow(expected),
                found: narrow(found),
            },
            E::MeanCount { count } => F::MeanCount { count },
            E::LevelFilterGain { gain_shift } => F::LevelFilterGain { gain_shift },
            E::LevelFilterWithoutSubtraction => F::LevelFilterWithoutSubtraction,
            E::MapSize {
                map,
                expected,
                found,
            } => F::MapSize {
                map,
                expected: narrow(expected),
                found: narrow(found),
            },
            E::BackgroundOutOfRange { pixel, value } => F::BackgroundOutOfRange {
                pixel: narrow(pixel),
                value,
            },
            E::ThresholdOutOfRange { value } => F::ThresholdOutOfRange { value },
            E::ReferenceSlopeOutOfRange { index } => F::ReferenceSlopeOutOfRange {
                index: narrow(index),
            },
            E::NegativeMinFlux => F::NegativeMinFlux,
            E::MemoryBudget {
                needed,
                available,
                what,
            } => F::MemoryBudget {
                needed: narrow(needed),
                available: narrow(available),
                what,
            },
            E::PixelCountZeroAll => F::PixelCountZeroAll,
            E::CropOutsideSensor {
                x,
                y,
                width,
                height,
                sensor_width,
                sensor_height,
            } => F::CropOutsideSensor {
                x,
                y,
                width,
                height,
                sensor_width,
                sensor_height,
            },
        }
    }
}

impl From<ConfigFault> for ConfigError {
    fn from(e: ConfigFault) -> Self {
        use ConfigError as E;
        use ConfigFault as F;
        let w = |v: u32| v as usize;
        match e {
            F::CameraSize { width, height } => E::CameraSize { width, height },
            F::BitDepth { bit_depth } => E::BitDepth { bit_depth },
            F::NoSubapertures => E::NoSubapertures,
            F::TooManySubapertures { count, max } => E::TooManySubapertures {
                count: w(count),
                max: w(max),
            },
            F::EmptyWindow { index } => E::EmptyWindow { index: w(index) },
            F::WindowTooLarge {
                index,
                width,
                height,
            } => E::WindowTooLarge {
                index: w(index),
                width,
                height,
            },
            F::WindowOutsideCamera { index } => E::WindowOutsideCamera { index: w(index) },
            F::PixelCountZero { index } => E::PixelCountZero { index: w(index) },
            F::PixelCountListLength { expected, found } => E::PixelCountListLength {
                expected: w(expected),
                found: w(found),
            },
            F::MeanCount { count } => E::MeanCount { count },
            F::LevelFilterGain { gain_shift } => E::LevelFilterGain { gain_shift },
            F::LevelFilterWithoutSubtraction => E::LevelFilterWithoutSubtraction,
            F::MapSize {
                map,
                expected,
                found,
            } => E::MapSize {
                map,
                expected: w(expected),
                found: w(found),
            },
            F::BackgroundOutOfRange { pixel, value } => E::BackgroundOutOfRange {
                pixel: w(pixel),
                value,
            },
            F::ThresholdOutOfRange { value } => E::ThresholdOutOfRange { value },
            F::ReferenceSlopeOutOfRange { index } => {
                E::ReferenceSlopeOutOfRange { index: w(index) }
            }
            F::NegativeMinFlux => E::NegativeMinFlux,
            F::MemoryBudget {
                needed,
                available,
                what,
            } => E::MemoryBudget {
                needed: w(needed),
                available: w(available),
                what,
            },
            F::PixelCountZeroAll => E::PixelCountZeroAll,
            F::CropOutsideSensor {
                x,
                y,
                width,
                height,
                sensor_width,
                sensor_height,
            } => E::CropOutsideSensor {
                x,
                y,
                width,
                height,
                sensor_width,
                sensor_height,
            },
        }
    }
}

impl fmt::Display for ConfigFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        ConfigError::from(*self).fmt(f)
    }
}

/// Why a frame was dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum FrameFault {
    /// A raw pixel above `2^bit_depth - 1` (SPEC.md §8).
    PixelOutOfRange { row: u16, column: u16, value: u16 },
    /// Pixels did not continue where the frame stood (lost data); the rest
    /// of the frame is ignored.
    Gap { expected: u32, found: u32 },
    /// A new frame started before this one was complete.
    Incomplete { received: u32 },
    /// Pixels beyond the frame's last pixel.
    PastEnd { first_pixel: u32, count: u32 },
    /// `PixelRows` with an odd number of bytes.
    OddLength,
    /// A new configuration was applied while this frame was partly received.
    Reconfigured,
    /// The capture was stopped while this frame was partly received.
    Stopped,
}

/// A position in an upload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct TablePosition {
    pub table: Table,
    pub offset: u32,
}

/// Which static buffer of the device is too small.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum CapacityKind {
    Subapertures,
    CameraPixels,
    ResultsPerRow,
}

/// The kinds of [`HostMessage`], for errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum MessageKind {
    Hello,
    ConfigBegin,
    ConfigChunk,
    ConfigCommit,
    ConfigAbort,
    StatusRequest,
    ResetLevelFilters,
    PixelRows,
    Capture,
    StopCapture,
    Bench,
    LinkTest,
}

impl HostMessage<'_> {
    pub fn kind(&self) -> MessageKind {
        match self {
            HostMessage::Hello { .. } => MessageKind::Hello,
            HostMessage::ConfigBegin { .. } => MessageKind::ConfigBegin,
            HostMessage::ConfigChunk { .. } => MessageKind::ConfigChunk,
            HostMessage::ConfigCommit { .. } => MessageKind::ConfigCommit,
            HostMessage::ConfigAbort => MessageKind::ConfigAbort,
            HostMessage::StatusRequest => MessageKind::StatusRequest,
            HostMessage::ResetLevelFilters => MessageKind::ResetLevelFilters,
            HostMessage::PixelRows { .. } => MessageKind::PixelRows,
            HostMessage::Capture { .. } => MessageKind::Capture,
            HostMessage::StopCapture => MessageKind::StopCapture,
            HostMessage::Bench { .. } => MessageKind::Bench,
            HostMessage::LinkTest { .. } => MessageKind::LinkTest,
        }
    }
}

impl core::error::Error for DeviceError {}
impl core::error::Error for ConfigFault {}
impl core::error::Error for CropFault {}

impl fmt::Display for CropFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            CropFault::Width { width, multiple } => write!(
                f,
                "its width, {width} pixels, is not a multiple of {multiple}"
            ),
            CropFault::FramePixels { pixels, multiple } => write!(
                f,
                "its {pixels} pixels are not a multiple of {multiple} (whole words of the camera bus)"
            ),
            CropFault::SensorSize { width, height, max } => write!(
                f,
                "the {width}x{height} sensor is larger than the interface takes ({max} per side)"
            ),
        }
    }
}

impl fmt::Display for FrameFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FrameFault::PixelOutOfRange { row, column, value } => write!(
                f,
                "pixel at row {row}, column {column} is {value}, above the camera's bit depth"
            ),
            FrameFault::Gap { expected, found } => write!(
                f,
                "pixels were lost: expected pixel {expected}, got pixel {found}"
            ),
            FrameFault::Incomplete { received } => write!(
                f,
                "a new frame started after only {received} pixels of this one"
            ),
            FrameFault::PastEnd { first_pixel, count } => write!(
                f,
                "{count} pixels from pixel {first_pixel} run past the end of the frame"
            ),
            FrameFault::OddLength => write!(f, "pixel data has an odd number of bytes"),
            FrameFault::Reconfigured => {
                write!(f, "a new configuration was applied in the middle of it")
            }
            FrameFault::Stopped => write!(f, "the capture was stopped in the middle of it"),
        }
    }
}

impl fmt::Display for DeviceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use DeviceError::*;
        match *self {
            Decode => write!(f, "the device could not decode a frame from the host"),
            Crc => write!(f, "a frame from the host failed its CRC check on the device"),
            FrameTooLong => write!(
                f,
                "a frame from the host was longer than the device accepts ({MAX_FRAME_LEN} bytes)"
            ),
            HelloRequired => write!(
                f,
                "the device refuses requests until a Hello with its protocol version and schema"
            ),
            Unexpected { message } => write!(f, "{message:?} is not valid in the device's state"),
            NoUpload => write!(f, "no configuration upload is in progress"),
            UploadMismatch { expected, found } => write!(
                f,
                "message for upload {found}, but upload {expected} is in progress"
            ),
            ChunkOutOfOrder {
                expected: Some(e),
                found,
            } => write!(
                f,
                "chunk at {} offset {}, expected {} offset {}; upload discarded",
                found.table, found.offset, e.table, e.offset
            ),
            ChunkOutOfOrder {
                expected: None,
                found,
            } => write!(
                f,
                "chunk at {} offset {} after all tables were complete; upload discarded",
                found.table, found.offset
            ),
            ChunkLength { table, len } => write!(
                f,
                "{table} chunk of {len} bytes is not whole elements of at most {MAX_CHUNK_BYTES} bytes; upload discarded"
            ),
            ChunkPastEnd { table, end, len } => write!(
                f,
                "{table} chunk ends at byte {end}, past the table's {len} bytes; upload discarded"
            ),
            UploadIncomplete {
                table,
                received,
                expected,
            } => write!(
                f,
                "commit with {table} incomplete ({received} of {expected} bytes); upload discarded"
            ),
            UploadCrc { computed, claimed } => write!(
                f,
                "upload CRC mismatch: device computed {computed:#010x}, host sent {claimed:#010x}; upload discarded"
            ),
            Capacity {
                what,
                needed,
                available,
            } => write!(
                f,
                "the configuration needs {needed} {what:?} but the device holds {available}"
            ),
            Config(e) => write!(f, "configuration refused: {}", ConfigError::from(e)),
            NotConfigured => write!(f, "the device has no active configuration"),
            Frame { frame, fault } => write!(f, "frame {frame} dropped: {fault}"),
            NoCamera => write!(f, "the device has no camera to capture from"),
            Crop(fault) => write!(
                f,
                "the device's camera interface cannot crop this rectangle: {fault}"
            ),
            Bench(fault) => write!(f, "bench refused: {fault}"),
            Sync(fault) => write!(f, "capture on the sync line refused: {fault}"),
            LinkTest(fault) => write!(f, "link test refused: {fault}"),
        }
    }
}
