//! The wire protocol between a brightpix device and its host (`PROTOCOL.md`
//! beside this crate is the normative description; this module implements it).
//!
//! - [`HostMessage`] (host to device) and [`DeviceMessage`] (device to host)
//!   are postcard-encoded; each is sent as one *frame*:
//!   `COBS(postcard bytes ++ CRC-32/ISO-HDLC little-endian) ++ 0x00`
//!   ([`frame`]).
//! - Both sides exchange [`PROTOCOL_VERSION`] and [`SCHEMA_HASH`] in
//!   [`Hello`] / [`HelloReply`] and refuse each other when either differs.
//! - A configuration travels as a [`ConfigHeader`] (its scalars) and tables
//!   of little-endian elements in chunks ([`tables`]), then a commit that the
//!   device applies atomically.
//!
//! Everything here is `no_std` and allocation-free: decoded messages borrow
//! their byte payloads from the frame buffer.
//!
//! The host's side of a link, over any byte stream:
//!
//! ```
//! use brightpix_protocol::wire::*;
//!
//! // To the device: one frame per message.
//! let mut out = [0u8; MAX_FRAME_LEN];
//! let frame = encode(&HostMessage::hello(7), &mut out).unwrap();
//! # let mut device_bytes = [0u8; 64];
//! # let n = encode(&DeviceMessage::FrameDone { frame: 1, count: 2 }, &mut device_bytes).unwrap().len();
//! # let device_bytes = &device_bytes[..n];
//! // From the device: receive into `space()`, then take whole frames.
//! let mut reader = FrameReader::new(vec![0u8; MAX_FRAME_LEN]);
//! let space = reader.space();
//! space[..device_bytes.len()].copy_from_slice(device_bytes); // e.g. port.read(space)
//! reader.advance(device_bytes.len());
//! while let Some(received) = reader.next_frame() {
//!     match received {
//!         Received::Frame(bytes) => match decode::<DeviceMessage>(bytes) {
//!             Ok(DeviceMessage::FrameDone { frame, count }) => assert_eq!((frame, count), (1, 2)),
//!             Ok(other) => println!("{other:?}"),
//!             Err(e) => println!("damaged frame from the device: {e}"),
//!         },
//!         Received::TooLong => println!("frame too long"),
//!     }
//! }
//! ```
//!
//! A configuration goes up with [`UploadPlan`] (send each message, wait for
//! its reply), a frame's pixels with [`PixelRowsPlan`]. A `HelloReply` that
//! does not decode comes from another protocol version: read its frozen
//! prefix with [`hello_prefix`] and report [`VersionMismatch`].

pub mod bench;
pub mod capture;
pub mod frame;
pub mod health;
pub mod tables;

use core::fmt;

use heapless::Vec;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::config::{Camera, ConfigError, Crop, LevelFilter, MapKind, MemoryKind, SelectionRule};

pub use bench::{
    BenchFault, BenchFigures, BenchLimit, BenchReport, BenchResult, CountUnit, FloorCheck, Spread,
    ALL_WORKLOADS, MAX_WORKLOAD_NAME_LEN,
};
pub use capture::{edge_row_checksum, edge_row_update, CaptureStart, SyncFault, EDGE_ROW_SEED};
pub use frame::{
    decode, decode_body, encode, hello_in_body, hello_prefix, unstuff, Crc32Digest, FrameReader,
    Received, WireError, CRC32, CRC_LEN,
};
pub use health::{
    crs_sync_source_name, crs_sync_source_usb2, CameraInterface, Clocks, ErratumFix, Fault,
    FaultKind, FaultLog, Health, Silicon, StackUsage, UsbClockSync, STM32H7_REV_Y,
};
pub use tables::{PixelRowsPlan, UploadPlan};

/// Bumped by hand whenever the meaning of a message changes without its
/// types changing (the [`SCHEMA_HASH`] catches type changes by itself).
/// Version 2: sessions (`Hello.session`, echoed in `HelloReply`; a
/// matching `Hello` resets the session state), the reset reason and the
/// watchdog in `Status`. Version 3: the configuration's digest (the
/// commit CRC covers the header too, and `Status` reports it), a constant
/// background as a scalar, N = 0 for every sub-aperture as its own fault.
/// Version 4: the crop rectangle of a board that captures part of a
/// sensor (`ConfigHeader.crop`, `DeviceError::Crop`). Version 5: the
/// engine's counters in `Status` (`Status.engine`), and the bench request
/// (`HostMessage::Bench`, `DeviceMessage::BenchReport`, `Ack::BenchDone`,
/// `DeviceError::Bench`). Version 6: a capture's start (`Capture.start`:
/// at once, or on a rig's sync line, followed or driven), `CaptureStarted`
/// sent once the capture is armed, `DeviceMessage::CaptureBegan` (how the
/// first frame began: on the sync edge or not, its camera frame if the
/// camera numbers them), `DeviceError::Sync`. Version 7: the alignment
/// self-check without wiring (`Capture.edge_rows`,
/// `DeviceMessage::EdgeRows`: checksums of a frame's first and last rows).
/// PROTOCOL.md §12 lists every version.
pub const PROTOCOL_VERSION: u16 = 7;

/// Largest postcard encoding of a message that every frame buffer holds.
pub const MAX_MESSAGE_LEN: usize = 1024;

/// Largest frame on the link: COBS of a [`MAX_MESSAGE_LEN`] message and its
/// CRC, plus the 0x00 delimiter. A receiver discards longer frames.
pub const MAX_FRAME_LEN: usize = cobs::max_encoding_length(MAX_MESSAGE_LEN + CRC_LEN) + 1;

/// Largest `bytes` of a [`HostMessage::ConfigChunk`] (a multiple of every
/// table's element size).
pub const MAX_CHUNK_BYTES: usize = 960;

/// Largest `pixels` of a [`HostMessage::PixelRows`], in bytes (480 pixels).
pub const MAX_PIXEL_BYTES: usize = 960;

/// Most results in one [`DeviceMessage::Slopes`].
pub const SLOPES_PER_MESSAGE: usize = 32;

/// Longest board name in [`Capabilities`], in bytes.
pub const MAX_BOARD_NAME_LEN: usize = 32;

/// What the schema hash covers besides the message types: the conventions
/// that the types cannot express. Edit it together with PROTOCOL.md.
pub const WIRE_CONVENTIONS: &str =
    "brightpix wire 1: frame = COBS(postcard ++ crc32/iso-hdlc LE) ++ 00; \
tables little-endian: windows = x,y,width,height u16; pixel_counts u16; background i32; gain u16; \
reference_slopes = x,y i32; table order windows, pixel_counts, background, gain, reference_slopes; \
commit crc32/iso-hdlc over the header's postcard encoding then all table bytes in that order \
(the configuration's digest); a constant background fills the device's background map; \
pixels u16 LE raster order of the configured camera, which a crop places on its sensor";

/// A hash of the protocol's schema: the postcard-schema of
/// `(HostMessage, DeviceMessage)` (every type, field and variant, by name and
/// data-model type, recursively, as derived from the Rust types themselves),
/// [`WIRE_CONVENTIONS`] and the size limits above. A message type cannot
/// change without this changing, so a host and a device built from
/// different message definitions refuse each other at [`Hello`].
pub const SCHEMA_HASH: u64 = schema_hash();

const fn schema_hash() -> u64 {
    let base = u64::from_le_bytes(postcard_schema::key::hash::fnv1a64::hash_ty_path::<(
        HostMessage<'static>,
        DeviceMessage<'static>,
    )>(WIRE_CONVENTIONS));
    let limits = [
        PROTOCOL_VERSION as u64,
        MAX_MESSAGE_LEN as u64,
        MAX_FRAME_LEN as u64,
        MAX_CHUNK_BYTES as u64,
        MAX_PIXEL_BYTES as u64,
        SLOPES_PER_MESSAGE as u64,
        MAX_BOARD_NAME_LEN as u64,
    ];
    let mut state = base;
    let mut i = 0;
    while i < limits.len() {
        state = fnv1a64(state, &limits[i].to_le_bytes());
        i += 1;
    }
    state
}

/// FNV-1a (64 bit) of `bytes`, continuing from `state`.
pub const fn fnv1a64(mut state: u64, bytes: &[u8]) -> u64 {
    let mut i = 0;
    while i < bytes.len() {
        state ^= bytes[i] as u64;
        state = state.wrapping_mul(0x0000_0100_0000_01b3);
        i += 1;
    }
    state
}

// ---------------------------------------------------------------------------
// Host to device
// ---------------------------------------------------------------------------

/// Host to device. Variant 0 ([`HostMessage::Hello`]) and the two fields of
/// [`Hello`] are frozen across all protocol versions, so that any two
/// versions can tell each other apart.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum HostMessage<'a> {
    /// Starts a session (PROTOCOL.md §6): `protocol` is frozen, `session`
    /// is an id the host chose, echoed in the reply. A `Hello` whose
    /// `protocol` matches the device's ends the previous session (its frame
    /// in progress, upload, capture and level filters); one that does not
    /// match changes nothing. Reply: [`DeviceMessage::HelloReply`].
    Hello { protocol: Hello, session: u32 },
    /// Starts a configuration upload (discarding any upload in progress).
    /// Reply: `Ack(UploadStarted)` or `Error`.
    ConfigBegin {
        upload_id: u32,
        header: ConfigHeader,
    },
    /// Bytes `offset ..` of one table of the upload. Tables go in
    /// [`Table`] order, each from offset 0 without gaps, in whole elements.
    /// Reply: `Ack(ChunkStored)` or `Error`.
    ConfigChunk {
        upload_id: u32,
        table: Table,
        offset: u32,
        bytes: &'a [u8],
    },
    /// Ends the upload: `crc32` is CRC-32/ISO-HDLC of all table bytes in
    /// [`Table`] order. The device validates the staged configuration
    /// completely and only then makes it active.
    /// Reply: `Ack(ConfigApplied)` or `Error`; on error the previous
    /// configuration stays active and the upload is discarded.
    ConfigCommit { upload_id: u32, crc32: u32 },
    /// Discards the upload in progress, if any. Reply: `Ack(UploadAborted)`.
    ConfigAbort,
    /// Reply: [`DeviceMessage::Status`].
    StatusRequest,
    /// Forgets the temporally filtered levels (SPEC.md §4).
    /// Reply: `Ack(LevelFiltersReset)` or `Error(NotConfigured)`.
    ResetLevelFilters,
    /// Raw pixels `first_pixel ..` (raster index) of frame `frame`, u16
    /// little-endian, for a device whose camera the host emulates. No reply
    /// on success: the device streams `Slopes` and `FrameDone`.
    PixelRows {
        frame: u32,
        first_pixel: u32,
        pixels: &'a [u8],
    },
    /// Starts the device's own camera for `frames` frames (0: until
    /// `StopCapture`), its first frame as `start` says (PROTOCOL.md §9).
    /// Reply: `Ack(CaptureStarted)` once the capture is armed, or `Error`;
    /// then [`DeviceMessage::CaptureBegan`] before the first results. With
    /// `edge_rows`, every frame's [`DeviceMessage::EdgeRows`] precedes its
    /// `FrameDone`.
    Capture {
        frames: u32,
        start: CaptureStart,
        edge_rows: bool,
    },
    /// Stops the camera. Reply: `Ack(CaptureStopped)`.
    StopCapture,
    /// Measures the engine on the board's own workloads (`workload`: one
    /// name, or [`ALL_WORKLOADS`]), `frames` frames each (0: each
    /// workload's own count). Replies: one `BenchReport` per workload, then
    /// `Ack(BenchDone)`; or `Error(Bench(..))` and nothing measured.
    Bench { workload: &'a str, frames: u32 },
}

/// Protocol identity: the frozen prefix of `Hello` and `HelloReply`. These
/// two fields, in this order, forever.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Hello {
    pub version: u16,
    pub schema: u64,
}

impl HostMessage<'_> {
    /// `Hello` with this build's protocol and the host's `session` id.
    pub const fn hello(session: u32) -> HostMessage<'static> {
        HostMessage::Hello {
            protocol: Hello::CURRENT,
            session,
        }
    }
}

impl Hello {
    /// This build's identity.
    pub const CURRENT: Hello = Hello {
        version: PROTOCOL_VERSION,
        schema: SCHEMA_HASH,
    };

    /// Whether the peer speaks exactly this build's protocol.
    pub fn matches_current(&self) -> bool {
        *self == Self::CURRENT
    }
}

/// The scalar part of a configuration; the tables follow in chunks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct ConfigHeader {
    pub camera: Camera,
    /// Number of sub-aperture windows (entries of the `Windows` table).
    pub windows: u32,
    pub rule: SelectionRule,
    pub pixel_count: PixelCountMode,
    pub level_filter: Option<LevelFilter>,
    /// Calibration threshold, 1/16 count.
    pub threshold: Option<i32>,
    /// Validity threshold on the flux, 1/16 count.
    pub min_flux: i64,
    /// The background: none, a `Background` table, or one value for every
    /// pixel (no table).
    pub background: Background,
    /// Which optional tables follow.
    pub gain: bool,
    pub reference_slopes: bool,
    /// Where `camera` lies on a larger sensor: the rectangle a board of a
    /// rig captures (its camera interface crops it; pixels, windows and
    /// maps are the rectangle's). `None`: the camera is the whole sensor.
    pub crop: Option<Crop>,
}

/// The background of a [`ConfigHeader`]. `None` and `Map` encode as the
/// `false` and `true` of protocol 2's `bool`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum Background {
    /// No background subtracted.
    None,
    /// A `Background` table follows (one value per camera pixel).
    Map,
    /// The same value (1/16 count) for every pixel; no table. The device
    /// fills its background map with it.
    Constant(i32),
}

impl Background {
    /// Whether the device needs a background map for it.
    pub const fn needs_map(&self) -> bool {
        !matches!(self, Background::None)
    }
}

/// N: one value, or a `PixelCounts` table with one per sub-aperture.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum PixelCountMode {
    All(u16),
    PerSubaperture,
}

/// The tables of an upload, in the order they are sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum Table {
    /// 8 bytes per window: x, y, width, height as u16 LE.
    Windows,
    /// 2 bytes per window: N as u16 LE (only with `PixelCountMode::PerSubaperture`).
    PixelCounts,
    /// 4 bytes per camera pixel, row-major: i32 LE, 1/16 count.
    Background,
    /// 2 bytes per camera pixel, row-major: u16 LE, 1/4096.
    Gain,
    /// 8 bytes per window: x, y as i32 LE, 2^-16 pixel.
    ReferenceSlopes,
}

// ---------------------------------------------------------------------------
// Device to host
// ---------------------------------------------------------------------------

/// Device to host. Variant 0 ([`DeviceMessage::HelloReply`]) and the first
/// two fields of [`HelloReply`] are frozen across all protocol versions.
// `Slopes` is large (no heap to box it in); messages live briefly on the stack.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum DeviceMessage<'a> {
    HelloReply(#[serde(borrow)] HelloReply<'a>),
    Ack(Ack),
    Error(DeviceError),
    Status(Status),
    /// Results of frame `frame`, in the order the engine finished them
    /// (SPEC.md §6); sent at the end of every camera row that finished a
    /// sub-aperture, or earlier whenever [`SLOPES_PER_MESSAGE`] are pending.
    Slopes {
        frame: u32,
        results: SlopeList,
    },
    /// Frame `frame` is complete; `count` results were sent for it.
    FrameDone {
        frame: u32,
        count: u32,
    },
    /// One workload of a `Bench` request.
    BenchReport(#[serde(borrow)] BenchReport<'a>),
    /// A capture's frame 0 has begun; sent before its first results.
    /// `synced`: it is the first frame start after a sync edge the device
    /// saw (`OnSync`, `DriveSync`), i.e. the same camera frame as every
    /// other board of that edge; `false` for `Immediate`. `camera_frame`:
    /// the camera's own number of that frame, when the device can know it
    /// (a simulated camera; a camera that embeds a frame counter), else
    /// `None`.
    CaptureBegan {
        synced: bool,
        camera_frame: Option<u32>,
    },
    /// Checksums of frame `frame`'s first and last camera rows (of the
    /// configured camera: a board's rectangle), [`edge_row_checksum`] of
    /// their pixels; sent before its `FrameDone` when the capture asked
    /// (`Capture.edge_rows`). Two boards whose rectangles share a camera
    /// row see the same pixels there only on the same camera frame.
    EdgeRows {
        frame: u32,
        first: u32,
        last: u32,
    },
}

/// The device's identity and limits. The first two fields are frozen.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct HelloReply<'a> {
    pub version: u16,
    pub schema: u64,
    /// The `session` of the `Hello` this answers (0 when the `Hello` did not
    /// decode past its frozen prefix).
    pub session: u32,
    #[serde(borrow)]
    pub capabilities: Capabilities<'a>,
}

/// What a device can hold; a host sizes its uploads and frames by it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Capabilities<'a> {
    /// Sub-aperture windows per configuration.
    pub max_subapertures: u32,
    /// Camera pixels of the background and gain maps (0: no maps).
    pub max_camera_pixels: u32,
    /// Windows open at once (crossing one camera row).
    pub max_open_windows: u32,
    /// Selection pool entries (SPEC-independent engine budget).
    pub pool_entries: u32,
    /// Camera pixels the engine's row history holds: the tallest selecting
    /// window times the camera width must fit (a window is rescanned from
    /// it when its seed left out a pixel it needed).
    pub history_pixels: u32,
    /// Scratch entries: the pixels of the largest selecting window must fit.
    pub scratch_entries: u32,
    /// Sub-apertures that may end in one camera row.
    pub max_results_per_row: u32,
    /// Longest frame the device accepts, delimiter included.
    pub max_frame_bytes: u32,
    pub pixel_source: PixelSourceKind,
    /// At most [`MAX_BOARD_NAME_LEN`] bytes.
    pub board: &'a str,
}

/// Where the device's pixels come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum PixelSourceKind {
    /// Only `PixelRows` messages (camera emulated over the link).
    Link,
    /// A separate stream the host writes (e.g. a file), and `PixelRows`.
    Stream,
    /// The device's own camera: `Capture` / `StopCapture`.
    Camera,
}

/// A request succeeded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum Ack {
    UploadStarted {
        upload_id: u32,
    },
    /// `end`: bytes of `table` received so far.
    ChunkStored {
        upload_id: u32,
        table: Table,
        end: u32,
    },
    /// The upload is now the active configuration (`config_id` = its
    /// upload id); level filters are reset.
    ConfigApplied {
        config_id: u32,
        open_windows: u32,
        pool_entries: u32,
    },
    UploadAborted {
        upload_id: Option<u32>,
    },
    LevelFiltersReset,
    CaptureStarted {
        frames: u32,
    },
    /// Also sent unrequested when a `Capture` of a fixed count ends.
    CaptureStopped {
        frames: u32,
    },
    /// A `Bench` request is done: `workloads` reports were sent. The
    /// active configuration is unchanged; its level filters start afresh.
    BenchDone {
        workloads: u32,
    },
}

/// Counters since the device started, and its state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Status {
    /// Upload id of the active configuration.
    pub config_id: Option<u32>,
    /// Upload in progress.
    pub upload_id: Option<u32>,
    pub capturing: bool,
    /// Frames the engine completed.
    pub frames_processed: u64,
    /// Frames abandoned part-way (gap, bad pixel, new frame, new configuration).
    pub frames_dropped: u64,
    /// Link frames whose CRC did not match.
    pub crc_errors: u32,
    /// Link frames that did not decode (COBS, postcard, too long).
    pub decode_errors: u32,
    /// Pixel data lost before the engine (discontinuous pixel stream).
    pub overruns: u32,
    /// Pixels above the camera's bit depth.
    pub pixel_errors: u32,
    /// The session of the last matching `Hello` (`None`: none since start).
    pub session: Option<u32>,
    /// Why the device last started.
    pub reset_reason: ResetReason,
    /// The independent watchdog's timeout in ms, if the board runs one.
    pub watchdog_ms: Option<u32>,
    /// The board's health ([`health`]): what only the board can read.
    pub health: Health,
    /// The active configuration's digest: the CRC of its commit (CRC-32 of
    /// the header's encoding and every table byte, PROTOCOL.md §7).
    pub config_digest: Option<u32>,
    /// The engine's work since the device started ([`EngineCounters`]).
    pub engine: EngineCounters,
}

/// What the device's streaming engine did since the device started, summed
/// over every configuration (the firmware's `EngineStats`): how often it
/// took its slow paths, and whether its row kernel ran. Speed only: no
/// result depends on them. Counted like the fault counters (from device
/// start, saturating).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct EngineCounters {
    /// Windows finished with selection.
    pub windows: u64,
    /// Candidates those windows held at their end.
    pub candidates: u64,
    /// Candidate buffers that filled and were compacted.
    pub compactions: u64,
    /// Windows computed again from the row history.
    pub rescans: u64,
    /// Times the row kernel stopped at a window for the engine's attention.
    pub attentions: u64,
    /// Frames (whole or abandoned) in which the row kernel ran at least
    /// once; 0 while every pixel takes the engine's general path (rows not
    /// word-aligned, windows at odd columns or of odd width, no selection,
    /// below 16 bits pixels outside every window: firmware/README.md).
    pub kernel_frames: u64,
}

/// Why the device last started, as its board's reset controller says.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum ResetReason {
    /// The board does not tell (QEMU, the in-process device).
    #[default]
    Unknown,
    PowerOn,
    /// The reset pin (NRST), e.g. a debugger or the reset button.
    Pin,
    /// Brown-out: the supply dropped below its threshold.
    Brownout,
    /// A software reset (`SYSRESETREQ`), e.g. after a panic or a flash.
    Software,
    /// The independent watchdog expired: the device loop stopped running.
    Watchdog,
    /// The window watchdog, a lockup or a low-power reset.
    Other,
}

/// The results of one [`DeviceMessage::Slopes`].
pub type SlopeList = Vec<SlopeEntry, SLOPES_PER_MESSAGE>;

/// One sub-aperture's result (SPEC.md §6).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct SlopeEntry {
    pub index: u16,
    /// 2^-16 pixel.
    pub slope_x: i32,
    pub slope_y: i32,
    /// 1/16 count.
    pub flux: i64,
    pub valid: bool,
}

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
        }
    }
}

/// The result of comparing a peer's [`Hello`] / [`HelloReply`] with this build.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VersionMismatch {
    pub ours: Hello,
    pub theirs: Hello,
}

impl VersionMismatch {
    /// `Ok` if `theirs` is this build's protocol.
    pub fn check(theirs: Hello) -> Result<(), VersionMismatch> {
        if theirs.matches_current() {
            Ok(())
        } else {
            Err(VersionMismatch {
                ours: Hello::CURRENT,
                theirs,
            })
        }
    }
}

impl fmt::Display for VersionMismatch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "protocol mismatch: the peer speaks brightpix protocol {} (schema {:#018x}), \
             this build speaks {} (schema {:#018x}); build the host tool and the firmware \
             from the same brightpix version",
            self.theirs.version, self.theirs.schema, self.ours.version, self.ours.schema
        )
    }
}

impl core::error::Error for VersionMismatch {}
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

impl fmt::Display for ResetReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ResetReason::Unknown => "unknown (the board does not tell)",
            ResetReason::PowerOn => "power-on",
            ResetReason::Pin => "reset pin",
            ResetReason::Brownout => "brown-out",
            ResetReason::Software => "software reset",
            ResetReason::Watchdog => "watchdog expired",
            ResetReason::Other => "other (window watchdog, lockup or low-power)",
        })
    }
}

impl fmt::Display for Table {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Table::Windows => "windows",
            Table::PixelCounts => "pixel counts",
            Table::Background => "background",
            Table::Gain => "gain",
            Table::ReferenceSlopes => "reference slopes",
        })
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
        }
    }
}

#[cfg(test)]
mod tests;
