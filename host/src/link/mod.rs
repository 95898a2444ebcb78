//! The host's side of the wire protocol (`shared/PROTOCOL.md`): a
//! synchronous client over any [`Port`] (a serial port through
//! `serialport`, a pseudo-terminal, a Unix socket).
//!
//! ```no_run
//! use brightpix::config_file::ProcessingConfig;
//! use brightpix::link::Client;
//! # fn main() -> anyhow::Result<()> {
//! let config = ProcessingConfig::load("examples/canary.toml")?;
//! let mut client = Client::open("/dev/ttyACM0")?; // Hello, version and schema checked
//! client.configure(&config.view())?;             // chunked upload, committed atomically
//! let frame = vec![0u16; 112 * 112];
//! let slopes = client.stream_frame(0, &frame)?;  // PixelRows out, Slopes + FrameDone back
//! println!("{} sub-apertures, status {:?}", slopes.slopes.len(), client.status()?);
//! # Ok(()) }
//! ```
//!
//! - Every request but `PixelRows` gets exactly one reply; the client waits
//!   for it. Errors name the device's typed [`DeviceError`].
//! - Pixels go out without waiting: [`Client::stream_frames`] keeps a few
//!   frames in flight and reads results while it writes, so throughput is
//!   not bound by round trips. They go over the link or, for a device whose
//!   pixel source is a separate stream (QEMU's semihosting FIFO), into a
//!   [`PixelSink::Fifo`].
//! - Timeouts: nothing from the device for [`ClientOptions::timeout`]
//!   (1.5 s by default) while the client waits for something, a port that
//!   closes, or a write the device does not take, ends the call with a
//!   [`LinkError`]; what was already received is kept
//!   ([`Interrupted::received`], or delivered to the callback before the
//!   error).

pub mod limits;
mod port;
mod sink;
pub mod verify;

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fmt;
use std::io::{self, ErrorKind};
use std::time::{Duration, Instant};

use brightpix_protocol::wire::{
    decode, encode, hello_prefix, Ack, Capabilities, DeviceError, DeviceMessage, FrameFault,
    FrameReader, Hello, HostMessage, MessageKind, PixelRowsPlan, PixelSourceKind, Received,
    SlopeEntry, Status, UploadPlan, VersionMismatch, MAX_CHUNK_BYTES, MAX_FRAME_LEN,
    MAX_PIXEL_BYTES,
};
use brightpix_protocol::{Camera, Config};

pub use port::{open_port, Port, UnixPort};
pub use serialport;
pub use sink::{FifoWriter, PixelSink};

/// Timeouts of a [`Client`].
#[derive(Clone, Copy, Debug)]
pub struct ClientOptions {
    /// Longest silence while waiting for the device (a reply, results), and
    /// longest a write may stall.
    pub timeout: Duration,
    /// How long [`Client::connect`] keeps sending `Hello` (QEMU's pty
    /// answers its first bytes up to ~0.7 s late, or loses them).
    pub connect_timeout: Duration,
    /// Frames sent ahead of their results in [`Client::stream_frames`].
    pub frames_in_flight: usize,
}

impl Default for ClientOptions {
    fn default() -> Self {
        ClientOptions {
            timeout: Duration::from_millis(1500),
            connect_timeout: Duration::from_secs(4),
            frames_in_flight: 4,
        }
    }
}

/// What the device said about itself in `HelloReply`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceInfo {
    pub version: u16,
    pub schema: u64,
    pub max_subapertures: u32,
    pub max_camera_pixels: u32,
    pub max_open_windows: u32,
    pub pool_entries: u32,
    pub history_pixels: u32,
    pub scratch_entries: u32,
    pub max_results_per_row: u32,
    pub max_frame_bytes: u32,
    pub pixel_source: PixelSourceKind,
    pub board: String,
    /// The session id the device echoed.
    pub session: u32,
}

impl DeviceInfo {
    fn new(version: u16, schema: u64, session: u32, c: &Capabilities<'_>) -> Self {
        DeviceInfo {
            version,
            schema,
            session,
            max_subapertures: c.max_subapertures,
            max_camera_pixels: c.max_camera_pixels,
            max_open_windows: c.max_open_windows,
            pool_entries: c.pool_entries,
            history_pixels: c.history_pixels,
            scratch_entries: c.scratch_entries,
            max_results_per_row: c.max_results_per_row,
            max_frame_bytes: c.max_frame_bytes,
            pixel_source: c.pixel_source,
            board: c.board.to_string(),
        }
    }
}

impl fmt::Display for DeviceInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "board \"{}\", protocol {} (schema {:#018x}); up to {} sub-apertures, {} map pixels, \
             {} open windows, {} pool entries, {} history pixels, {} scratch entries, {} results per \
             row, frames of {} bytes; pixels: {:?}",
            self.board,
            self.version,
            self.schema,
            self.max_subapertures,
            self.max_camera_pixels,
            self.max_open_windows,
            self.pool_entries,
            self.history_pixels,
            self.scratch_entries,
            self.max_results_per_row,
            self.max_frame_bytes,
            self.pixel_source
        )
    }
}

/// Why a call failed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// Not a `source` field: the reason is in the message, and a chained
    /// source would print it twice (`cannot open X: reason: reason`).
    #[error("cannot open {port}: {error}")]
    Open { port: String, error: io::Error },
    #[error("{0}")]
    Version(VersionMismatch),
    #[error(
        "{port} does not answer like a brightpix device: no HelloReply within {:.1} s \
         (is the device running, and is this its port?)",
        .waited.as_secs_f64()
    )]
    NoHello { port: String, waited: Duration },
    #[error("the device refused {request}: {error} [DeviceError::{error:?}]")]
    Device { request: String, error: DeviceError },
    #[error(
        "the device stopped answering: nothing from {port} for {timeout:?} while waiting for {waiting}"
    )]
    Timeout {
        port: String,
        timeout: Duration,
        waiting: String,
    },
    #[error("the device did not take data on {port} for {timeout:?} (writing {what})")]
    WriteStalled {
        port: String,
        timeout: Duration,
        what: String,
    },
    #[error("{port} closed or disappeared ({source})")]
    Disconnected { port: String, source: io::Error },
    #[error("unexpected reply to {request}: {reply}")]
    Unexpected { request: String, reply: String },
    #[error("pixel FIFO {path}: {source}")]
    Fifo { path: String, source: io::Error },
    #[error("frame {frame} was dropped by the device: {fault}")]
    FrameDropped { frame: u32, fault: FrameFault },
    #[error("{0}")]
    Usage(String),
    #[error("interrupted (SIGINT or SIGTERM)")]
    Interrupted,
}

/// A call that failed part-way, with everything it had received.
#[derive(Debug)]
pub struct Interrupted<T> {
    pub error: LinkError,
    pub received: T,
}

impl<T> fmt::Display for Interrupted<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.error.fmt(f)
    }
}

impl<T: fmt::Debug> std::error::Error for Interrupted<T> {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        Some(&self.error)
    }
}

impl<T> From<Interrupted<T>> for LinkError {
    fn from(i: Interrupted<T>) -> Self {
        i.error
    }
}

/// The results of one frame, as the device sent them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FrameSlopes {
    pub frame: u32,
    /// In the order received (SPEC.md §6: by index within a camera row is
    /// not guaranteed); see [`FrameSlopes::by_index`].
    pub slopes: Vec<SlopeEntry>,
    /// `FrameDone.count`, if the frame completed.
    pub done_count: Option<u32>,
}

impl FrameSlopes {
    /// One entry per sub-aperture `0..subapertures`: `None` where the device
    /// sent nothing (or an index twice: the later one wins).
    pub fn by_index(&self, subapertures: usize) -> Vec<Option<SlopeEntry>> {
        let mut out = vec![None; subapertures];
        for s in &self.slopes {
            if let Some(slot) = out.get_mut(s.index as usize) {
                *slot = Some(*s);
            }
        }
        out
    }
}

/// How a frame ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FrameOutcome {
    /// `FrameDone` arrived.
    Done(FrameSlopes),
    /// The device dropped the frame (`Error(Frame{..})`); results sent
    /// before that are kept.
    Dropped {
        slopes: FrameSlopes,
        fault: FrameFault,
    },
    /// The call failed before the frame ended.
    Incomplete(FrameSlopes),
}

impl FrameOutcome {
    pub fn slopes(&self) -> &FrameSlopes {
        match self {
            FrameOutcome::Done(s) | FrameOutcome::Incomplete(s) => s,
            FrameOutcome::Dropped { slopes, .. } => slopes,
        }
    }

    pub fn frame(&self) -> u32 {
        self.slopes().frame
    }
}

/// A successful configuration upload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Configured {
    /// The device's id of the configuration now active (the upload id).
    pub config_id: u32,
    pub open_windows: u32,
    pub pool_entries: u32,
    /// Messages and table bytes sent.
    pub messages: usize,
    pub table_bytes: usize,
    pub elapsed: Duration,
}

/// Totals of a [`Client::stream_frames`] call.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StreamReport {
    pub frames_sent: usize,
    pub frames_done: usize,
    pub frames_dropped: usize,
    pub pixel_bytes: usize,
    pub elapsed: Duration,
}

/// A reply to a request. [`Client::request`] returns an `Error` reply as
/// [`LinkError::Device`], so it never returns `Reply::Error`.
#[derive(Clone, Debug)]
pub enum Reply {
    Hello(DeviceInfo),
    Ack(Ack),
    Error(DeviceError),
    Status(Status),
}

/// A frame from the device, decoded and owned.
enum Incoming {
    Reply(Reply),
    /// A `HelloReply` of another protocol version (only its prefix decoded).
    ForeignHello(Hello),
    Slopes {
        frame: u32,
        results: Vec<SlopeEntry>,
    },
    FrameDone {
        frame: u32,
        count: u32,
    },
    FrameError {
        frame: u32,
        fault: FrameFault,
    },
    Damaged,
}

/// A synchronous client of one brightpix device.
pub struct Client {
    port: Box<dyn Port>,
    name: String,
    options: ClientOptions,
    io_timeout: Option<Duration>,
    rx: FrameReader<Vec<u8>>,
    read_buf: Vec<u8>,
    tx: Vec<u8>,
    info: DeviceInfo,
    sink: PixelSink,
    fifo: Option<FifoWriter>,
    replies: VecDeque<Reply>,
    /// Results of frames not finished yet.
    open_frames: BTreeMap<u32, Vec<SlopeEntry>>,
    finished: VecDeque<FrameOutcome>,
    /// Unrequested errors that are not about a frame (e.g. `Crc` after a
    /// damaged frame from the host), oldest first.
    pub notices: Vec<DeviceError>,
    /// Frames from the device that did not decode (damaged on the way).
    pub damaged_frames: u64,
    /// Frame outcomes discarded because they were not of a frame the
    /// client was waiting for (an earlier stream's or session's).
    pub stale_outcomes: u64,
    camera: Option<Camera>,
    subapertures: usize,
    upload_counter: u32,
    /// This client's session id.
    session: u32,
    /// Polled while the client waits or streams: `true` ends the call
    /// with [`LinkError::Interrupted`] (e.g. after Ctrl-C).
    interrupt: Option<fn() -> bool>,
}

/// How long the client waits for `HelloReply` before it sends `Hello` again
/// (QEMU's pty drops what the device sends before it notices the client,
/// up to ~1 s after the port opens).
pub const HELLO_RETRY: Duration = Duration::from_millis(700);

/// A fresh non-zero id from the clock, this process and `salt`.
fn fresh_id(salt: u32) -> u32 {
    use std::sync::atomic::{AtomicU32, Ordering};
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    let count = COUNTER.fetch_add(1, Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| {
            d.subsec_nanos() ^ (d.as_secs() as u32).rotate_left(16)
        });
    let mixed = (nanos ^ std::process::id().rotate_left(8) ^ salt)
        .wrapping_add(count.wrapping_mul(0x9E37_79B9))
        .wrapping_mul(0x85EB_CA6B);
    (mixed ^ (mixed >> 15)) | 1
}

impl Client {
    /// Opens `port_name` ([`open_port`]) and connects.
    pub fn open(port_name: &str) -> Result<Client, LinkError> {
        Self::open_with(port_name, ClientOptions::default())
    }

    pub fn open_with(port_name: &str, options: ClientOptions) -> Result<Client, LinkError> {
        let port = open_port(port_name).map_err(|error| LinkError::Open {
            port: port_name.to_string(),
            error,
        })?;
        Self::connect_with(port, options)
    }

    /// Handshake on `port`: `Hello` with this build's protocol version and
    /// schema hash; a device of another protocol is refused with a message
    /// naming both.
    pub fn connect(port: Box<dyn Port>) -> Result<Client, LinkError> {
        Self::connect_with(port, ClientOptions::default())
    }

    pub fn connect_with(
        mut port: Box<dyn Port>,
        options: ClientOptions,
    ) -> Result<Client, LinkError> {
        let name = port.describe();
        let _ = port.discard_input();
        let mut client = Client {
            port,
            name,
            options,
            io_timeout: None,
            rx: FrameReader::new(vec![0u8; MAX_FRAME_LEN]),
            read_buf: vec![0u8; 16 * 1024],
            tx: vec![0u8; MAX_FRAME_LEN],
            info: DeviceInfo {
                version: 0,
                schema: 0,
                max_subapertures: 0,
                max_camera_pixels: 0,
                max_open_windows: 0,
                pool_entries: 0,
                history_pixels: 0,
                scratch_entries: 0,
                max_results_per_row: 0,
                max_frame_bytes: MAX_FRAME_LEN as u32,
                pixel_source: PixelSourceKind::Link,
                board: String::new(),
                session: 0,
            },
            session: 0,
            sink: PixelSink::Link,
            fifo: None,
            replies: VecDeque::new(),
            open_frames: BTreeMap::new(),
            finished: VecDeque::new(),
            notices: Vec::new(),
            damaged_frames: 0,
            stale_outcomes: 0,
            camera: None,
            subapertures: 0,
            upload_counter: 0,
            interrupt: None,
        };
        client.handshake()?;
        Ok(client)
    }

    /// Opens a session (PROTOCOL.md §6): a 0x00 (ends whatever partial
    /// frame a previous client left in the device's receiver), then `Hello`
    /// with a fresh session id, resent until the `HelloReply` that echoes
    /// that id. Everything the device sent before that reply belongs to an
    /// earlier session and is discarded; so is every later `HelloReply`
    /// (answers to the resent `Hello`s).
    fn handshake(&mut self) -> Result<(), LinkError> {
        // Old bytes (a previous session's results) are of no interest.
        let draining = Instant::now();
        while self.pump(Duration::from_millis(20))? > 0
            && draining.elapsed() < Duration::from_millis(500)
        {}
        self.forget_everything();
        self.session = fresh_id(0x5E55_1011);
        let started = Instant::now();
        let mut frame = vec![0u8];
        frame.extend_from_slice(self.encode(&HostMessage::hello(self.session))?);
        loop {
            self.write_raw(&frame, "Hello")?;
            let attempt = Instant::now();
            while attempt.elapsed() < HELLO_RETRY {
                self.pump(Duration::from_millis(50))?;
                while let Some(reply) = self.replies.pop_front() {
                    let Reply::Hello(info) = reply else { continue };
                    let theirs = Hello {
                        version: info.version,
                        schema: info.schema,
                    };
                    // Another protocol's reply carries no session we can read.
                    VersionMismatch::check(theirs).map_err(LinkError::Version)?;
                    if info.session != self.session {
                        continue; // an answer to another client's Hello
                    }
                    self.info = info;
                    // Results, errors and frame outcomes so far are the
                    // previous session's.
                    self.forget_everything();
                    self.notices.clear();
                    self.damaged_frames = 0;
                    self.stale_outcomes = 0;
                    return Ok(());
                }
            }
            if started.elapsed() >= self.options.connect_timeout {
                return Err(LinkError::NoHello {
                    port: self.name.clone(),
                    waited: started.elapsed(),
                });
            }
        }
    }

    /// Makes waits and streams end with [`LinkError::Interrupted`] once
    /// `interrupted()` returns true (e.g. `sim_device::interrupted`).
    pub fn set_interrupt(&mut self, interrupted: Option<fn() -> bool>) {
        self.interrupt = interrupted;
    }

    fn check_interrupt(&self) -> Result<(), LinkError> {
        match self.interrupt {
            Some(f) if f() => Err(LinkError::Interrupted),
            _ => Ok(()),
        }
    }

    /// This client's session id (sent in `Hello`, echoed by the device).
    pub fn session(&self) -> u32 {
        self.session
    }

    fn forget_everything(&mut self) {
        self.replies.clear();
        self.open_frames.clear();
        self.finished.clear();
    }

    /// The device's identity and limits.
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// The port's name.
    pub fn port_name(&self) -> &str {
        &self.name
    }

    pub fn options(&self) -> &ClientOptions {
        &self.options
    }

    pub fn set_options(&mut self, options: ClientOptions) {
        self.options = options;
    }

    /// Where [`Client::send_frame`] writes pixels.
    pub fn set_pixel_sink(&mut self, sink: PixelSink) {
        self.fifo = None;
        self.sink = sink;
    }

    /// Closes the pixel FIFO if it is open (the client does so before every
    /// request and at the end of [`Client::stream_frames`]).
    pub fn close_pixel_fifo(&mut self) {
        self.fifo = None;
    }

    pub fn pixel_sink(&self) -> &PixelSink {
        &self.sink
    }

    // --- requests ----------------------------------------------------------

    /// `StatusRequest`: the device's counters.
    pub fn status(&mut self) -> Result<Status, LinkError> {
        match self.request(&HostMessage::StatusRequest)? {
            Reply::Status(s) => Ok(s),
            other => Err(unexpected("StatusRequest", &other)),
        }
    }

    /// Uploads `config` (ConfigBegin, chunks, ConfigCommit; one reply each)
    /// under a fresh upload id. On any error the device keeps its previous
    /// configuration.
    pub fn configure(&mut self, config: &Config<'_>) -> Result<Configured, LinkError> {
        let started = Instant::now();
        let upload_id = self.fresh_upload_id();
        let chunk = MAX_CHUNK_BYTES.min((self.info.max_frame_bytes as usize).saturating_sub(64));
        let mut plan = UploadPlan::new(*config, upload_id, chunk);
        let total = plan.message_count();
        let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
        let mut messages = 0;
        let mut table_bytes = 0;
        while let Some(message) = plan.next(&mut scratch) {
            messages += 1;
            let what = describe_upload_message(&message, messages, total);
            if let HostMessage::ConfigChunk { bytes, .. } = &message {
                table_bytes += bytes.len();
            }
            let reply = self.request(&message).map_err(|e| match e {
                LinkError::Device { error, .. } => LinkError::Device {
                    request: format!("the configuration upload at {what}"),
                    error,
                },
                other => other,
            })?;
            match (&message, reply) {
                (
                    HostMessage::ConfigBegin { .. },
                    Reply::Ack(Ack::UploadStarted { upload_id: id }),
                )
                | (
                    HostMessage::ConfigChunk { .. },
                    Reply::Ack(Ack::ChunkStored { upload_id: id, .. }),
                ) if id == upload_id => {}
                (
                    HostMessage::ConfigCommit { .. },
                    Reply::Ack(Ack::ConfigApplied {
                        config_id,
                        open_windows,
                        pool_entries,
                    }),
                ) if config_id == upload_id => {
                    // The device dropped any frame in progress: results of
                    // earlier frames can no longer complete.
                    self.stale_outcomes += (self.open_frames.len() + self.finished.len()) as u64;
                    self.open_frames.clear();
                    self.finished.clear();
                    self.camera = Some(config.camera);
                    self.subapertures = config.windows.len();
                    return Ok(Configured {
                        config_id,
                        open_windows,
                        pool_entries,
                        messages,
                        table_bytes,
                        elapsed: started.elapsed(),
                    });
                }
                (_, other) => return Err(unexpected(&what, &other)),
            }
        }
        Err(LinkError::Usage(
            "the upload plan ended without a commit".into(),
        ))
    }

    /// Tells the client the device's active configuration without
    /// uploading it (e.g. for streaming to a device configured earlier).
    pub fn assume_configured(&mut self, config: &Config<'_>) {
        self.camera = Some(config.camera);
        self.subapertures = config.windows.len();
    }

    fn fresh_upload_id(&mut self) -> u32 {
        self.upload_counter = self.upload_counter.wrapping_add(1);
        fresh_id(self.upload_counter)
    }

    /// `ResetLevelFilters`.
    pub fn reset_level_filters(&mut self) -> Result<(), LinkError> {
        self.expect_ack(&HostMessage::ResetLevelFilters, "ResetLevelFilters")
            .map(|_| ())
    }

    /// `ConfigAbort`: discards an upload in progress; returns its id.
    pub fn abort_upload(&mut self) -> Result<Option<u32>, LinkError> {
        match self.expect_ack(&HostMessage::ConfigAbort, "ConfigAbort")? {
            Ack::UploadAborted { upload_id } => Ok(upload_id),
            other => Err(unexpected("ConfigAbort", &Reply::Ack(other))),
        }
    }

    fn expect_ack(&mut self, message: &HostMessage<'_>, what: &str) -> Result<Ack, LinkError> {
        match self.request(message)? {
            Reply::Ack(a) => Ok(a),
            other => Err(unexpected(what, &other)),
        }
    }

    /// Sends one request and waits for its reply (results of frames that
    /// arrive meanwhile are kept for [`Client::next_outcome`]). An `Error`
    /// reply becomes [`LinkError::Device`].
    pub fn request(&mut self, message: &HostMessage<'_>) -> Result<Reply, LinkError> {
        let kind = message.kind();
        let frame = self.encode(message)?.to_vec();
        self.request_raw(&frame, kind)
    }

    /// Sends `frame` (an encoded message, perhaps deliberately damaged) and
    /// waits for the reply that a request of `kind` gets.
    pub fn request_raw(&mut self, frame: &[u8], kind: MessageKind) -> Result<Reply, LinkError> {
        // Anything still queued is unrequested.
        self.move_replies_to_notices();
        self.close_pixel_fifo();
        let what = format!("{kind:?}");
        self.write_raw(frame, &what)?;
        let reply = self.wait(&format!("the reply to {what}"), |c| {
            while let Some(reply) = c.replies.pop_front() {
                match (&reply, kind) {
                    (Reply::Hello(_), MessageKind::Hello) => return Some(reply),
                    (Reply::Hello(_), _) => {} // late answer to an earlier Hello
                    _ => return Some(reply),
                }
            }
            None
        })?;
        match reply {
            Reply::Error(error) => Err(LinkError::Device {
                request: what,
                error,
            }),
            other => Ok(other),
        }
    }

    fn move_replies_to_notices(&mut self) {
        while let Some(r) = self.replies.pop_front() {
            if let Reply::Error(e) = r {
                self.notices.push(e);
            }
        }
    }

    // --- pixels and results -----------------------------------------------

    /// Sends frame `frame`'s pixels (raster order) through the pixel sink,
    /// without waiting for results; reads what the device sends meanwhile.
    pub fn send_frame(&mut self, frame: u32, pixels: &[u16]) -> Result<usize, LinkError> {
        if let Some(camera) = self.camera {
            if pixels.len() != camera.pixel_count() {
                return Err(LinkError::Usage(format!(
                    "frame {frame} has {} pixels, the configured camera {}x{} has {}",
                    pixels.len(),
                    camera.width,
                    camera.height,
                    camera.pixel_count()
                )));
            }
        }
        let bytes = encode_pixel_rows(frame, pixels);
        self.send_pixels(&bytes)?;
        Ok(bytes.len())
    }

    /// Writes encoded `PixelRows` frames to the pixel sink, reading from the
    /// link while it writes.
    pub fn send_pixels(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        match &self.sink {
            PixelSink::Link => self.write_raw(bytes, "pixels"),
            PixelSink::Fifo(_) => self.write_fifo(bytes),
        }
    }

    fn write_fifo(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        if self.fifo.is_none() {
            let PixelSink::Fifo(path) = &self.sink else {
                unreachable!()
            };
            let writer =
                FifoWriter::open(path, self.options.timeout).map_err(|source| LinkError::Fifo {
                    path: path.display().to_string(),
                    source,
                })?;
            self.fifo = Some(writer);
        }
        let mut rest = bytes;
        let mut last_progress = Instant::now();
        while !rest.is_empty() {
            let Some(fifo) = self.fifo.as_mut() else {
                unreachable!()
            };
            match fifo.try_write(rest) {
                Ok(n) if n > 0 => {
                    rest = &rest[n..];
                    last_progress = Instant::now();
                    self.pump(Duration::ZERO)?;
                }
                Ok(_) => self.fifo_wait(&mut last_progress)?,
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    self.fifo_wait(&mut last_progress)?
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(source) => {
                    return Err(LinkError::Fifo {
                        path: fifo.path().display().to_string(),
                        source,
                    })
                }
            }
        }
        Ok(())
    }

    fn fifo_wait(&mut self, last_progress: &mut Instant) -> Result<(), LinkError> {
        if last_progress.elapsed() > self.options.timeout {
            let path = match &self.sink {
                PixelSink::Fifo(p) => p.display().to_string(),
                PixelSink::Link => String::new(),
            };
            return Err(LinkError::WriteStalled {
                port: path,
                timeout: self.options.timeout,
                what: "pixels".into(),
            });
        }
        // The device may be waiting for us to read its results.
        self.pump(Duration::from_millis(2))?;
        Ok(())
    }

    /// Waits for the next frame to end (done or dropped).
    pub fn next_outcome(&mut self) -> Result<FrameOutcome, LinkError> {
        self.check_stream_errors()?;
        self.wait("frame results", |c| c.finished.pop_front())
    }

    /// A frame that has ended, if any, without waiting.
    pub fn try_outcome(&mut self) -> Option<FrameOutcome> {
        self.finished.pop_front()
    }

    /// Errors that end a stream: the device refuses pixels altogether.
    fn check_stream_errors(&mut self) -> Result<(), LinkError> {
        let mut fatal = None;
        self.replies.retain(|r| match r {
            Reply::Error(
                e @ (DeviceError::NotConfigured
                | DeviceError::HelloRequired
                | DeviceError::Unexpected { .. }),
            ) => {
                fatal.get_or_insert(*e);
                false
            }
            _ => true,
        });
        self.move_replies_to_notices();
        match fatal {
            Some(error) => Err(LinkError::Device {
                request: "pixels (PixelRows)".into(),
                error,
            }),
            None => Ok(()),
        }
    }

    /// Results received so far of frames that have not ended (taken).
    pub fn take_incomplete(&mut self) -> Vec<FrameSlopes> {
        std::mem::take(&mut self.open_frames)
            .into_iter()
            .map(|(frame, slopes)| FrameSlopes {
                frame,
                slopes,
                done_count: None,
            })
            .collect()
    }

    /// Sends one frame and waits for its results. A dropped frame is an
    /// error ([`LinkError::FrameDropped`]) with the results sent before.
    pub fn stream_frame(
        &mut self,
        frame: u32,
        pixels: &[u16],
    ) -> Result<FrameSlopes, Interrupted<FrameSlopes>> {
        let mut outcome = None;
        let result = self.stream_frames(frame, [pixels], |o| outcome = Some(o));
        match (result, outcome) {
            (Ok(_), Some(FrameOutcome::Done(s))) => Ok(s),
            (Ok(_), Some(FrameOutcome::Dropped { slopes, fault })) => Err(Interrupted {
                error: LinkError::FrameDropped {
                    frame: slopes.frame,
                    fault,
                },
                received: slopes,
            }),
            (Ok(_), other) => Err(Interrupted {
                error: LinkError::Usage(format!("frame {frame}: no outcome")),
                received: other.map(|o| o.slopes().clone()).unwrap_or_default(),
            }),
            (Err(error), other) => Err(Interrupted {
                error,
                received: other.map(|o| o.slopes().clone()).unwrap_or_default(),
            }),
        }
    }

    /// Streams frames numbered `first_frame, first_frame + 1, ...`, keeping
    /// up to [`ClientOptions::frames_in_flight`] sent ahead of their
    /// results. Every frame's outcome goes to `on_outcome` as it arrives, in
    /// order; on an error, frames in flight go there as
    /// [`FrameOutcome::Incomplete`] with what had arrived, then the error is
    /// returned. Only outcomes of frames this call sent count: results or
    /// drops of any other frame (an earlier stream's, a previous client's)
    /// are discarded and counted in [`Client::stale_outcomes`].
    pub fn stream_frames<F: AsRef<[u16]>>(
        &mut self,
        first_frame: u32,
        frames: impl IntoIterator<Item = F>,
        mut on_outcome: impl FnMut(FrameOutcome),
    ) -> Result<StreamReport, LinkError> {
        let started = Instant::now();
        let mut report = StreamReport::default();
        let window = self.options.frames_in_flight.max(1);
        let mut in_flight: BTreeSet<u32> = BTreeSet::new();
        let mut deliver = |o: FrameOutcome, report: &mut StreamReport| {
            match &o {
                FrameOutcome::Done(_) => report.frames_done += 1,
                FrameOutcome::Dropped { .. } => report.frames_dropped += 1,
                FrameOutcome::Incomplete(_) => {}
            }
            on_outcome(o);
        };
        let result = (|| {
            for (k, pixels) in frames.into_iter().enumerate() {
                while in_flight.len() >= window {
                    let o = self.next_outcome_of(&in_flight)?;
                    in_flight.remove(&o.frame());
                    deliver(o, &mut report);
                }
                self.check_interrupt()?;
                let frame = first_frame.wrapping_add(k as u32);
                // Results a previous stream left under this number are stale.
                if self.open_frames.remove(&frame).is_some() {
                    self.stale_outcomes += 1;
                }
                in_flight.insert(frame);
                report.pixel_bytes += self.send_frame(frame, pixels.as_ref())?;
                report.frames_sent += 1;
                while let Some(o) = self.take_outcome_of(&in_flight) {
                    in_flight.remove(&o.frame());
                    deliver(o, &mut report);
                }
                self.check_stream_errors()?;
            }
            while !in_flight.is_empty() {
                let o = self.next_outcome_of(&in_flight)?;
                in_flight.remove(&o.frame());
                deliver(o, &mut report);
            }
            Ok(())
        })();
        report.elapsed = started.elapsed();
        self.close_pixel_fifo();
        match result {
            Ok(()) => Ok(report),
            Err(e) => {
                while let Some(o) = self.take_outcome_of(&in_flight) {
                    in_flight.remove(&o.frame());
                    deliver(o, &mut report);
                }
                for s in self.take_incomplete() {
                    if in_flight.remove(&s.frame) {
                        deliver(FrameOutcome::Incomplete(s), &mut report);
                    }
                }
                for frame in in_flight {
                    deliver(
                        FrameOutcome::Incomplete(FrameSlopes {
                            frame,
                            ..FrameSlopes::default()
                        }),
                        &mut report,
                    );
                }
                Err(e)
            }
        }
    }

    /// The next ended frame among `frames`, without waiting; outcomes of
    /// other frames are discarded (stale).
    fn take_outcome_of(&mut self, frames: &BTreeSet<u32>) -> Option<FrameOutcome> {
        while let Some(o) = self.finished.pop_front() {
            if frames.contains(&o.frame()) {
                return Some(o);
            }
            self.stale_outcomes += 1;
        }
        None
    }

    /// Waits for the next frame among `frames` to end.
    fn next_outcome_of(&mut self, frames: &BTreeSet<u32>) -> Result<FrameOutcome, LinkError> {
        self.check_stream_errors()?;
        self.wait("frame results", |c| c.take_outcome_of(frames))
    }

    /// `Capture { frames }` on a device with its own camera: records
    /// `frames` frames (at least 1) and waits for `Ack(CaptureStopped)`.
    pub fn capture(
        &mut self,
        frames: u32,
    ) -> Result<Vec<FrameOutcome>, Interrupted<Vec<FrameOutcome>>> {
        self.capture_with(frames, &mut |_| {})
    }

    /// [`Client::capture`], calling `on_frame` with each frame as it arrives.
    pub fn capture_with(
        &mut self,
        frames: u32,
        on_frame: &mut dyn FnMut(&FrameOutcome),
    ) -> Result<Vec<FrameOutcome>, Interrupted<Vec<FrameOutcome>>> {
        let mut received = Vec::new();
        if frames == 0 {
            return Err(Interrupted {
                error: LinkError::Usage("capture needs at least one frame".into()),
                received,
            });
        }
        let result = (|| {
            match self.request(&HostMessage::Capture { frames })? {
                Reply::Ack(Ack::CaptureStarted { .. }) => {}
                other => return Err(unexpected("Capture", &other)),
            }
            loop {
                let next = self.wait("captured frames", |c| {
                    if let Some(o) = c.finished.pop_front() {
                        return Some(Ok(o));
                    }
                    let at = c
                        .replies
                        .iter()
                        .position(|r| matches!(r, Reply::Ack(Ack::CaptureStopped { .. })))?;
                    c.replies.remove(at);
                    Some(Err(()))
                })?;
                match next {
                    Ok(o) => {
                        on_frame(&o);
                        received.push(o);
                    }
                    Err(()) => {
                        // Results of the last frame precede the stop.
                        while let Some(o) = self.finished.pop_front() {
                            on_frame(&o);
                            received.push(o);
                        }
                        return Ok(());
                    }
                }
            }
        })();
        match result {
            Ok(()) => Ok(received),
            Err(error) => {
                let stop = self
                    .encode(&HostMessage::StopCapture)
                    .map(<[u8]>::to_vec)
                    .unwrap_or_default();
                let _ = self.write_raw(&stop, "StopCapture");
                for s in self.take_incomplete() {
                    received.push(FrameOutcome::Incomplete(s));
                }
                Err(Interrupted { error, received })
            }
        }
    }

    // --- bytes ----------------------------------------------------------------

    /// Encodes `message` as one frame (into the client's buffer).
    pub fn encode(&mut self, message: &HostMessage<'_>) -> Result<&[u8], LinkError> {
        match encode(message, &mut self.tx) {
            Ok(frame) => Ok(frame),
            Err(e) => Err(LinkError::Usage(format!(
                "cannot encode {:?}: {e}",
                message.kind()
            ))),
        }
    }

    /// Writes bytes to the link as they are, reading from it whenever the
    /// write would wait.
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        self.write_raw(bytes, "raw bytes")
    }

    fn write_raw(&mut self, bytes: &[u8], what: &str) -> Result<(), LinkError> {
        const PIECE: usize = 4096;
        for piece in bytes.chunks(PIECE) {
            self.set_timeout(self.options.timeout)?;
            let mut rest = piece;
            while !rest.is_empty() {
                match self.port.write(rest) {
                    Ok(0) => {
                        return Err(LinkError::Disconnected {
                            port: self.name.clone(),
                            source: io::Error::new(ErrorKind::WriteZero, "the port took no bytes"),
                        })
                    }
                    Ok(n) => rest = &rest[n..],
                    Err(e) if e.kind() == ErrorKind::Interrupted => {}
                    Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => {
                        return Err(LinkError::WriteStalled {
                            port: self.name.clone(),
                            timeout: self.options.timeout,
                            what: what.to_string(),
                        })
                    }
                    Err(source) => {
                        return Err(LinkError::Disconnected {
                            port: self.name.clone(),
                            source,
                        })
                    }
                }
            }
            if bytes.len() > PIECE {
                self.pump(Duration::ZERO)?;
            }
        }
        let _ = self.port.flush();
        Ok(())
    }

    fn set_timeout(&mut self, t: Duration) -> Result<(), LinkError> {
        if self.io_timeout != Some(t) {
            self.port
                .set_io_timeout(t)
                .map_err(|source| LinkError::Disconnected {
                    port: self.name.clone(),
                    source,
                })?;
            self.io_timeout = Some(t);
        }
        Ok(())
    }

    /// Waits until `found` returns something; an error if the device sends
    /// nothing for the timeout.
    fn wait<T>(
        &mut self,
        waiting: &str,
        mut found: impl FnMut(&mut Self) -> Option<T>,
    ) -> Result<T, LinkError> {
        let mut last_byte = Instant::now();
        loop {
            if let Some(t) = found(self) {
                return Ok(t);
            }
            self.check_interrupt()?;
            let left = self.options.timeout.saturating_sub(last_byte.elapsed());
            if left.is_zero() {
                return Err(LinkError::Timeout {
                    port: self.name.clone(),
                    timeout: self.options.timeout,
                    waiting: waiting.to_string(),
                });
            }
            if self.pump(left.min(Duration::from_millis(200)))? > 0 {
                last_byte = Instant::now();
            }
        }
    }

    /// Reads what arrives within `wait` (one read) and decodes every whole
    /// frame; returns the bytes read.
    fn pump(&mut self, wait: Duration) -> Result<usize, LinkError> {
        self.set_timeout(wait)?;
        let n = match self.port.read(&mut self.read_buf) {
            Ok(0) => {
                return Err(LinkError::Disconnected {
                    port: self.name.clone(),
                    source: io::Error::new(ErrorKind::UnexpectedEof, "end of stream"),
                })
            }
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
                ) =>
            {
                return Ok(0)
            }
            Err(source) => {
                return Err(LinkError::Disconnected {
                    port: self.name.clone(),
                    source,
                })
            }
        };
        let mut incoming = Vec::new();
        let mut at = 0;
        while at < n {
            at += self.rx.push(&self.read_buf[at..n]);
            while let Some(received) = self.rx.next_frame() {
                incoming.push(match received {
                    Received::Frame(bytes) => decode_incoming(bytes),
                    Received::TooLong => Incoming::Damaged,
                });
            }
        }
        for i in incoming {
            self.absorb(i);
        }
        Ok(n)
    }

    fn absorb(&mut self, incoming: Incoming) {
        match incoming {
            Incoming::Reply(r) => self.replies.push_back(r),
            Incoming::ForeignHello(theirs) => {
                // Reported by the handshake as a version mismatch.
                self.replies.push_back(Reply::Hello(DeviceInfo {
                    version: theirs.version,
                    schema: theirs.schema,
                    ..self.info.clone()
                }))
            }
            Incoming::Slopes { frame, results } => {
                self.open_frames.entry(frame).or_default().extend(results)
            }
            Incoming::FrameDone { frame, count } => {
                let slopes = self.open_frames.remove(&frame).unwrap_or_default();
                self.finished.push_back(FrameOutcome::Done(FrameSlopes {
                    frame,
                    slopes,
                    done_count: Some(count),
                }));
            }
            Incoming::FrameError { frame, fault } => {
                let slopes = self.open_frames.remove(&frame).unwrap_or_default();
                self.finished.push_back(FrameOutcome::Dropped {
                    slopes: FrameSlopes {
                        frame,
                        slopes,
                        done_count: None,
                    },
                    fault,
                });
            }
            Incoming::Damaged => self.damaged_frames += 1,
        }
    }
}

fn unexpected(request: &str, reply: &Reply) -> LinkError {
    LinkError::Unexpected {
        request: request.to_string(),
        reply: format!("{reply:?}"),
    }
}

fn decode_incoming(bytes: &mut [u8]) -> Incoming {
    let copy = bytes.to_vec();
    match decode::<DeviceMessage>(bytes) {
        Ok(DeviceMessage::HelloReply(h)) => Incoming::Reply(Reply::Hello(DeviceInfo::new(
            h.version,
            h.schema,
            h.session,
            &h.capabilities,
        ))),
        Ok(DeviceMessage::Ack(a)) => Incoming::Reply(Reply::Ack(a)),
        Ok(DeviceMessage::Error(DeviceError::Frame { frame, fault })) => {
            Incoming::FrameError { frame, fault }
        }
        Ok(DeviceMessage::Error(e)) => Incoming::Reply(Reply::Error(e)),
        Ok(DeviceMessage::Status(s)) => Incoming::Reply(Reply::Status(s)),
        Ok(DeviceMessage::Slopes { frame, results }) => Incoming::Slopes {
            frame,
            results: results.to_vec(),
        },
        Ok(DeviceMessage::FrameDone { frame, count }) => Incoming::FrameDone { frame, count },
        Err(_) => {
            let mut copy = copy;
            match hello_prefix(&mut copy) {
                Some(h) => Incoming::ForeignHello(h),
                None => Incoming::Damaged,
            }
        }
    }
}

fn describe_upload_message(message: &HostMessage<'_>, k: usize, total: usize) -> String {
    match message {
        HostMessage::ConfigChunk {
            table,
            offset,
            bytes,
            ..
        } => format!(
            "ConfigChunk {k} of {total} ({table} table, bytes {offset}..{})",
            *offset as usize + bytes.len()
        ),
        other => format!("{:?} (message {k} of {total})", other.kind()),
    }
}

/// The `PixelRows` frames of one frame of pixels, concatenated (at most
/// [`MAX_PIXEL_BYTES`] of pixels per message).
pub fn encode_pixel_rows(frame: u32, pixels: &[u16]) -> Vec<u8> {
    let mut plan = PixelRowsPlan::new(frame, pixels, MAX_PIXEL_BYTES / 2);
    let mut scratch = vec![0u8; MAX_PIXEL_BYTES];
    let mut frame_buf = vec![0u8; MAX_FRAME_LEN];
    let mut out = Vec::with_capacity(pixels.len() * 2 + pixels.len() / 400 * 12 + 16);
    while let Some(message) = plan.next(&mut scratch) {
        let encoded = encode(&message, &mut frame_buf).expect("a PixelRows message fits a frame");
        out.extend_from_slice(encoded);
    }
    out
}

/// The frames of [`encode_pixel_rows`], one `Vec` per message (for tests
/// that damage one).
pub fn pixel_rows_frames(frame: u32, pixels: &[u16]) -> Vec<Vec<u8>> {
    let bytes = encode_pixel_rows(frame, pixels);
    bytes
        .split_inclusive(|&b| b == 0)
        .map(<[u8]>::to_vec)
        .collect()
}
