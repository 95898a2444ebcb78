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
//!
//! The client by concern: this module opens a session (the handshake) and
//! holds the [`Client`]; `requests` are the calls with one reply each
//! (status, configuration upload); `frames` sends pixels and gathers each
//! frame's results ([`FrameOutcome`]); `transport` moves bytes (encoding,
//! writing with a stall timeout, reading and decoding what arrives);
//! `device_info` and `errors` are what the device says about itself and
//! how a call fails.

mod bench;
mod device_info;
mod errors;
mod frames;
pub mod limits;
mod link_test;
mod pacing;
mod port;
mod requests;
mod sink;
mod transport;
pub mod verify;

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use brightpix_protocol::wire::{
    DeviceError, FrameReader, Hello, HostMessage, PixelSourceKind, SlopeEntry, VersionMismatch,
    MAX_FRAME_LEN,
};
use brightpix_protocol::Camera;

pub use bench::BenchRow;
pub use device_info::DeviceInfo;
pub use errors::{Interrupted, LinkError};
pub use frames::{
    encode_pixel_rows, pixel_rows_frames, CaptureBegan, FrameOutcome, FrameSlopes, StreamReport,
};
pub use link_test::LinkTestReport;
pub use port::{open_port, Port, UnixPort};
pub use requests::{Configured, Reply};
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
    /// Longest silence between captured frames in [`Client::capture`]: the
    /// device's camera sets their pace (a slow camera, or a simulated one
    /// whose frames the host is still making), so it is longer than
    /// `timeout`.
    pub capture_timeout: Duration,
    /// Frames sent ahead of their results in [`Client::stream_frames`].
    pub frames_in_flight: usize,
}

impl Default for ClientOptions {
    fn default() -> Self {
        ClientOptions {
            timeout: Duration::from_millis(1500),
            connect_timeout: Duration::from_secs(4),
            capture_timeout: Duration::from_secs(10),
            frames_in_flight: 4,
        }
    }
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
    /// Pixel bytes in flight and the rate the device consumes them.
    pacing: pacing::Pacing,
    /// Unrequested errors that are not about a frame (e.g. `Crc` after a
    /// damaged frame from the host), oldest first.
    pub notices: Vec<DeviceError>,
    /// Frames from the device that did not decode (damaged on the way).
    pub damaged_frames: u64,
    /// Frame outcomes discarded because they were not of a frame the
    /// client was waiting for (an earlier stream's or session's).
    pub stale_outcomes: u64,
    camera: Option<Camera>,
    /// How the last capture began (`CaptureBegan`), once it did.
    capture_began: Option<frames::CaptureBegan>,
    /// `EdgeRows` of frames not finished yet.
    edge_rows: BTreeMap<u32, (u32, u32)>,
    /// The fill of the link test in progress, if one is.
    link_fills: Option<link_test::Tally>,
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
            pacing: pacing::Pacing::default(),
            notices: Vec::new(),
            damaged_frames: 0,
            stale_outcomes: 0,
            capture_began: None,
            edge_rows: BTreeMap::new(),
            link_fills: None,
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
}
