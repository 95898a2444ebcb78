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
pub mod fault;
pub mod frame;
pub mod health;
pub mod link_test;
pub mod tables;

use core::fmt;

use heapless::Vec;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::config::{Camera, Crop, LevelFilter, SelectionRule};

pub use bench::{
    BenchFault, BenchFigures, BenchLimit, BenchReport, BenchResult, CountUnit, FloorCheck, Spread,
    ALL_WORKLOADS, MAX_WORKLOAD_NAME_LEN,
};
pub use capture::{edge_row_checksum, edge_row_update, CaptureStart, SyncFault, EDGE_ROW_SEED};
pub use fault::{
    CapacityKind, ConfigFault, CropFault, DeviceError, FrameFault, MessageKind, TablePosition,
};
pub use frame::{
    decode, decode_body, encode, hello_in_body, hello_prefix, unstuff, Crc32Digest, FrameReader,
    Received, WireError, CRC32, CRC_LEN,
};
pub use health::{
    crs_sync_source_name, crs_sync_source_usb2, CameraInterface, Clocks, ErratumFix, Fault,
    FaultKind, FaultLog, Health, Silicon, StackUsage, UsbClockSync, STM32H7_REV_Y,
};
pub use link_test::{link_fill, link_fill_byte, LinkTestFault, MAX_LINK_FILL, MAX_LINK_TEST_BYTES};
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
/// Version 8: the link test (`HostMessage::LinkTest`,
/// `DeviceMessage::LinkFill`, `Ack::LinkTestDone`, `DeviceError::LinkTest`).
/// PROTOCOL.md §12 lists every version.
pub const PROTOCOL_VERSION: u16 = 8;

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
    /// Sends `bytes` fill bytes ([`link_fill_byte`]) to the host as fast as
    /// the link takes them, `chunk` a message (the last may be shorter).
    /// Replies: the `LinkFill` messages, then `Ack(LinkTestDone)`; or
    /// `Error(LinkTest(..))` and nothing sent (PROTOCOL.md §15).
    LinkTest { bytes: u32, chunk: u16 },
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
    /// Bytes `offset ..` of a link test's fill ([`link_fill_byte`]), in
    /// order, none left out.
    LinkFill {
        offset: u32,
        fill: &'a [u8],
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
    /// A `LinkTest` is done: `bytes` fill bytes were sent in `messages`
    /// `LinkFill` messages.
    LinkTestDone {
        bytes: u32,
        messages: u32,
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

#[cfg(test)]
mod tests;
