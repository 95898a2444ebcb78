//! The bench request (protocol 5): a board measures the engine on its own
//! generated workloads and reports, per workload, the counts per frame and
//! after the frame's last row, next to the honest floor's on the same
//! frames in the same run (PROTOCOL.md §14).

use core::fmt;

use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Longest workload name in a [`HostMessage::Bench`](super::HostMessage)
/// request or a [`BenchReport`], in bytes.
pub const MAX_WORKLOAD_NAME_LEN: usize = 48;

/// The workload name that asks for every workload the board has.
pub const ALL_WORKLOADS: &str = "all";

/// What a count counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum CountUnit {
    /// Core clock cycles (the Cortex-M DWT cycle counter, CYCCNT): caches,
    /// wait states, dual issue and branch costs included.
    Cycles,
    /// Instructions executed (QEMU under `-icount`: its timer's ticks
    /// converted exactly). Not cycles.
    Instructions,
    /// Neither: a timer that follows host time (QEMU without `-icount`).
    /// Only the presence of figures means anything.
    Uncounted,
}

/// Minimum, median and maximum of one count over the measured frames (the
/// median of an even number of frames is the lower middle one).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Spread {
    pub min: u64,
    pub median: u64,
    pub max: u64,
}

/// Whether the floor's slopes were compared with the engine's.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum FloorCheck {
    /// The same arithmetic (subtract-next, or no selection, without level
    /// filter): every window's slopes, flux and validity were equal bit for
    /// bit on every measured frame.
    Equal,
    /// Another rule or a level filter: the floor is the subtract-next work,
    /// its slopes are not the engine's.
    NotComparable,
}

/// A measured workload's counts, in the report's unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct BenchFigures {
    /// The engine over all measured frames.
    pub engine_total: u64,
    /// The engine per frame.
    pub engine_frame: Spread,
    /// The engine from the arrival of a frame's last camera row to its last
    /// result (the pushes that carry the last row).
    pub engine_last_row: Spread,
    /// The floor over the same frames.
    pub floor_total: u64,
    pub floor_frame: Spread,
    pub floor_last_row: Spread,
    pub floor_check: FloorCheck,
}

/// Why a workload was not measured on this board.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum BenchLimit {
    /// Its frame or background map is larger than the memory the board
    /// lends the bench.
    Pixels,
    /// More windows than the bench's per-window buffers.
    Windows,
    /// The engine's memory refused the configuration.
    EngineMemory,
}

/// One workload's outcome.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum BenchResult {
    Measured(BenchFigures),
    /// Not measured: it does not fit.
    DoesNotFit {
        limit: BenchLimit,
    },
    /// The engine's slopes differed from the floor's (or the engine refused
    /// a generated pixel) where they must agree: a fault to report.
    SlopesDiffer {
        window: u32,
    },
}

/// One workload's report (`DeviceMessage::BenchReport`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct BenchReport<'a> {
    /// At most [`MAX_WORKLOAD_NAME_LEN`] bytes.
    pub workload: &'a str,
    pub unit: CountUnit,
    /// The core clock the cycles are of, Hz (as the board reads it).
    pub clock_hz: Option<u32>,
    /// Camera pixels per frame.
    pub pixels: u32,
    /// Frames measured (after the workload's warm-up frames).
    pub frames: u32,
    pub result: BenchResult,
}

/// Why a bench request was refused (`DeviceError::Bench`). Nothing was
/// measured and nothing changed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum BenchFault {
    /// The board has no bench mode.
    NotSupported,
    /// A frame is in progress or a capture runs: the bench would stall it.
    Streaming,
    /// A configuration upload is in progress (the bench borrows the
    /// staging slot's memory).
    UploadInProgress,
    /// No workload of this name on the board.
    UnknownWorkload,
    /// More frames than the board records per workload.
    TooManyFrames { max: u32 },
}

impl fmt::Display for BenchFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            BenchFault::NotSupported => write!(f, "the board has no bench mode"),
            BenchFault::Streaming => write!(
                f,
                "the device is streaming (a frame in progress or a capture): stop it before a bench"
            ),
            BenchFault::UploadInProgress => write!(
                f,
                "a configuration upload is in progress: commit or abort it before a bench"
            ),
            BenchFault::UnknownWorkload => write!(f, "the board has no workload of that name"),
            BenchFault::TooManyFrames { max } => {
                write!(f, "the board measures at most {max} frames per workload")
            }
        }
    }
}

impl fmt::Display for CountUnit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CountUnit::Cycles => "cycles",
            CountUnit::Instructions => "instructions",
            CountUnit::Uncounted => "uncounted",
        })
    }
}

impl fmt::Display for BenchLimit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            BenchLimit::Pixels => "its frame does not fit the memory the board lends the bench",
            BenchLimit::Windows => "more windows than the bench's buffers",
            BenchLimit::EngineMemory => "the engine's memory refused its configuration",
        })
    }
}

impl Spread {
    /// Minimum, median (the lower middle one) and maximum of `values`,
    /// which it sorts; all 0 when empty.
    pub fn of(values: &mut [u64]) -> Spread {
        if values.is_empty() {
            return Spread::default();
        }
        values.sort_unstable();
        Spread {
            min: values[0],
            median: values[(values.len() - 1) / 2],
            max: values[values.len() - 1],
        }
    }
}
