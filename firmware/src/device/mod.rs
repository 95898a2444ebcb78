//! The device loop, independent of the board: it speaks the wire protocol
//! (`shared/PROTOCOL.md`) over a byte transport, keeps an active and a
//! staging configuration, runs the streaming [`Engine`] on the pixels that
//! arrive (in `PixelRows` messages or from a [`PixelSource`]) and streams
//! the slopes back.
//!
//! A board provides:
//! - the link: one value implementing `embedded_io_async::{Read, Write}`
//!   (a UART, a USB CDC-ACM class, ...). Its `read` must be cancel-safe if
//!   the board also has a pixel source (the two are raced);
//! - a [`PixelSource`] ([`LinkOnly`] when the host emulates the camera);
//! - storage: a [`DeviceStorage`] in a `static` (or [`DeviceBuffers`]
//!   assembled from buffers in different memories);
//!
//! and runs it:
//!
//! ```text
//! type Storage = DeviceStorage<256, { 128 * 128 }, 16, { 16 * 74 }, { 16 * 128 }, 256, 64>;
//! static STORAGE: ConstStaticCell<Storage> = ConstStaticCell::new(Storage::new());
//!
//! let mut device = Device::new(uart, LinkOnly, STORAGE.take().borrow(), "qemu-mps2-an386");
//! loop {
//!     let Err(e) = device.run().await;
//!     // the link failed or closed: configuration and counters are kept
//! }
//! ```
//!
//! Every input is checked before it changes anything: a garbled frame, a
//! bad upload or a bad pixel leaves the device as it was (and is counted
//! and answered with an `Error`). A configuration is uploaded into the
//! staging slot, vetted completely there (validation, engine memory, result
//! queue) while the active configuration keeps running, and only then
//! swapped in.
//!
//! The engine borrows its configuration and memory, so the device does not
//! store it: [`Device::run`] builds it from the active slot (with
//! `Engine::resume`, which keeps the level filters; `Engine::new` after a
//! new configuration) and rebuilds it after a swap.
//!
//! Here: the loop, the session and the requests; in `upload`, a
//! configuration's upload into the staging slot; in `pixels`, frames into
//! the engine and results back; in `bench`, the bench request; in
//! `link_test`, the link test.

pub mod bench;
mod capture;
mod fmt;
mod link_test;
mod pixels;
pub mod source;
pub mod storage;
mod upload;
pub mod vet;
pub mod watchdog;

use core::convert::Infallible;

use brightpix_protocol::wire::{
    decode_body, encode, hello_in_body, unstuff, Ack, Capabilities, DeviceError, DeviceMessage,
    FrameFault, FrameReader, Health, Hello, HelloReply, HostMessage, MessageKind, Received,
    ResetReason, Status, WireError, MAX_BOARD_NAME_LEN, MAX_FRAME_LEN,
};
use embassy_futures::select::{select, select3, Either, Either3};
use embedded_io_async::{Read, Write};

use crate::engine::{Engine, EngineMemory, EngineStats, SubapertureResult};
use bench::BenchPlan;
use capture::Capture;
use fmt::{log_debug, log_info, log_warn};
use upload::Upload;

pub use bench::{BenchMemory, BenchRunner};
pub use embedded_io_async;
pub use source::{CameraRefused, CaptureBegin, LinkOnly, PixelRowsStream, PixelRun, PixelSource};
pub use storage::{ConfigSlot, DeviceBuffers, DeviceStorage, SlotStorage};
pub use watchdog::{NoWatchdog, Watchdog};

/// Why [`Device::run`] returned. The device keeps its configuration and
/// counters; call `run` again when the link is back.
#[derive(Debug, PartialEq, Eq)]
pub enum LinkError<E> {
    /// The transport failed.
    Io(E),
    /// The transport reached its end (a read returned 0 bytes).
    Closed,
}

/// The device: link, pixel source, configurations, engine memory, counters,
/// and the watchdog it feeds (none by default).
pub struct Device<'d, T, C, W = NoWatchdog> {
    rx: FrameReader<&'d mut [u8]>,
    source: C,
    slots: [ConfigSlot<'d>; 2],
    memory: EngineMemory<'d>,
    core: Core<'d, T, W>,
}

/// Everything but the receive buffer, the pixel source, the slots and the
/// engine memory (which the loop borrows separately).
struct Core<'d, T, W> {
    link: T,
    watchdog: W,
    tx: &'d mut [u8],
    pixels: &'d mut [u16],
    order: &'d mut [u16],
    scratch: &'d mut [u16],
    results: &'d mut [SubapertureResult],
    /// Results waiting in `results`.
    queued: usize,
    capabilities: Capabilities<'static>,
    /// Index of the active slot.
    active: usize,
    /// A swap is pending: build the engine afresh and acknowledge.
    applying: Option<Applying>,
    /// The staging slot's header must be cleared (a swap failed).
    discard_staging: bool,
    /// A matching Hello was received.
    session: bool,
    upload: Option<Upload>,
    /// The frame the engine is in the middle of.
    frame: Option<FrameProgress>,
    /// A frame whose remaining pixels are ignored after a fault.
    skipping: Option<u32>,
    capture: Option<Capture>,
    capture_finished: bool,
    counters: Status,
    /// The current engine's statistics as last added to
    /// `counters.engine` (`fold_engine`).
    engine_seen: EngineStats,
    /// Reads the board's health for `Status.health`.
    health: fn() -> Health,
    /// The board's bench mode, if it has one.
    bench: Option<&'d mut dyn BenchRunner>,
    /// A bench used the engine's memory: build the engine afresh.
    fresh_engine: bool,
}

struct Applying {
    config_id: u32,
    digest: u32,
}

#[derive(Clone, Copy)]
struct FrameProgress {
    frame: u32,
    /// Next pixel expected.
    next: u32,
    /// Results sent so far.
    sent: u32,
}

#[derive(PartialEq, Eq)]
enum Next {
    Continue,
    /// The active configuration changed: rebuild the engine.
    Rebuild,
    /// Run a bench (the engine is dropped first, and built afresh after).
    Bench(BenchPlan),
}

type LinkResult<T, E> = Result<T, LinkError<E>>;

/// The device logs its counters after the first frame and then every this
/// many frames (a board's only view of them without asking over the link).
const STATUS_LOG_FRAMES: u64 = 1000;

impl<'d, T: Read + Write, C: PixelSource> Device<'d, T, C, NoWatchdog> {
    /// A device with no configuration. `board` (at most
    /// [`MAX_BOARD_NAME_LEN`] bytes; longer is cut) is reported in
    /// `HelloReply`.
    pub fn new(link: T, source: C, buffers: DeviceBuffers<'d>, board: &'static str) -> Self {
        let DeviceBuffers {
            slots,
            engine,
            order,
            scratch,
            results,
            rx,
            tx,
            pixels,
        } = buffers;
        let engine_capacity = engine.capacity();
        let max_subapertures = slots
            .iter()
            .map(|s| s.subaperture_capacity())
            .chain([engine_capacity.subapertures, order.len(), scratch.len()])
            .min()
            .unwrap_or(0);
        let max_camera_pixels = slots.iter().map(|s| s.pixel_capacity()).min().unwrap_or(0);
        let capabilities = Capabilities {
            max_subapertures: saturate(max_subapertures),
            max_camera_pixels: saturate(max_camera_pixels),
            max_open_windows: saturate(engine_capacity.open_windows),
            pool_entries: saturate(engine_capacity.pool_entries),
            history_pixels: saturate(engine_capacity.history_pixels),
            scratch_entries: saturate(engine_capacity.scratch_entries),
            max_results_per_row: saturate(results.len()),
            max_frame_bytes: saturate((rx.len() + 1).min(MAX_FRAME_LEN)),
            pixel_source: source.kind(),
            board: truncate(board, MAX_BOARD_NAME_LEN),
        };
        Device {
            rx: FrameReader::new(rx),
            source,
            slots,
            memory: engine,
            core: Core {
                link,
                watchdog: NoWatchdog,
                tx,
                pixels,
                order,
                scratch,
                results,
                queued: 0,
                capabilities,
                active: 0,
                applying: None,
                discard_staging: false,
                session: false,
                upload: None,
                frame: None,
                skipping: None,
                capture: None,
                capture_finished: false,
                counters: Status::default(),
                engine_seen: EngineStats::default(),
                health: Health::default,
                bench: None,
                fresh_engine: false,
            },
        }
    }

    /// The device with `watchdog`, fed by its loop (`watchdog` module).
    pub fn with_watchdog<W: Watchdog>(self, watchdog: W) -> Device<'d, T, C, W> {
        let Device {
            rx,
            source,
            slots,
            memory,
            core,
        } = self;
        let mut counters = core.counters;
        counters.watchdog_ms = watchdog.timeout_ms();
        Device {
            rx,
            source,
            slots,
            memory,
            core: Core {
                link: core.link,
                watchdog,
                tx: core.tx,
                pixels: core.pixels,
                order: core.order,
                scratch: core.scratch,
                results: core.results,
                queued: core.queued,
                capabilities: core.capabilities,
                active: core.active,
                applying: core.applying,
                discard_staging: core.discard_staging,
                session: core.session,
                upload: core.upload,
                frame: core.frame,
                skipping: core.skipping,
                capture: core.capture,
                capture_finished: core.capture_finished,
                counters,
                engine_seen: core.engine_seen,
                health: core.health,
                bench: core.bench,
                fresh_engine: core.fresh_engine,
            },
        }
    }
}

impl<'d, T: Read + Write, C: PixelSource, W: Watchdog> Device<'d, T, C, W> {
    /// Why the device last started, from the board's reset controller
    /// (reported in `Status.reset_reason`).
    pub fn set_reset_reason(&mut self, reason: ResetReason) {
        self.core.counters.reset_reason = reason;
    }

    /// How the board reads its health (`Status.health`), called for every
    /// `StatusRequest`. Without it every part is `None`: not read.
    pub fn set_health(&mut self, read: fn() -> Health) {
        self.core.health = read;
    }

    /// The board's bench mode (the `Bench` request); without it the device
    /// answers `Error(Bench(NotSupported))`.
    pub fn set_bench(&mut self, runner: &'d mut dyn BenchRunner) {
        self.core.bench = Some(runner);
    }

    /// The watchdog (e.g. to feed it while the board waits for a link).
    pub fn watchdog(&mut self) -> &mut W {
        &mut self.core.watchdog
    }

    /// What the device reports in `HelloReply`.
    pub fn capabilities(&self) -> &Capabilities<'static> {
        &self.core.capabilities
    }

    /// What the device reports in `Status`.
    pub fn status(&self) -> Status {
        self.core.status()
    }

    /// The transport.
    pub fn link(&mut self) -> &mut T {
        &mut self.core.link
    }

    /// The pixel source.
    pub fn source(&mut self) -> &mut C {
        &mut self.source
    }

    /// Serves the host until the link fails or closes.
    pub async fn run(&mut self) -> Result<Infallible, LinkError<T::Error>> {
        let Device {
            rx,
            source,
            slots,
            memory,
            core,
        } = self;
        if let Some(progress) = core.frame.take() {
            // The engine of the previous run held this frame's state.
            core.counters.frames_dropped += 1;
            core.skipping = Some(progress.frame);
            core.queued = 0;
        }
        loop {
            let [a, b] = &mut *slots;
            let (active, staging) = if core.active == 0 { (a, b) } else { (b, a) };
            if core.discard_staging {
                core.discard_staging = false;
                staging.header = None;
            }
            let mut engine = None;
            if let Some(config) = active.config() {
                let memory = reborrow(memory);
                let fresh = core.applying.is_some() || core::mem::take(&mut core.fresh_engine);
                let built = if fresh {
                    Engine::new(config, memory)
                } else {
                    Engine::resume(config, memory)
                };
                match built {
                    Ok(e) => {
                        // A new engine counts from 0.
                        core.engine_seen = EngineStats::default();
                        engine = Some(e);
                    }
                    Err(e) => {
                        // Cannot happen: the configuration was vetted with the
                        // same plan. Go back to the previous one, if any.
                        log_warn!("device: engine refused a vetted configuration");
                        if core.applying.take().is_some() {
                            core.active ^= 1;
                            core.discard_staging = true;
                            core.send(&DeviceMessage::Error(DeviceError::Config(e.into())))
                                .await?;
                            continue;
                        }
                        active.header = None;
                        core.counters.config_id = None;
                        core.counters.config_digest = None;
                        continue;
                    }
                }
            }
            if let (Some(applying), Some(engine)) = (core.applying.take(), &engine) {
                let needed = engine.memory_needed();
                core.counters.config_id = Some(applying.config_id);
                core.counters.config_digest = Some(applying.digest);
                log_info!(
                    "device: configuration {=u32} applied ({=usize} sub-apertures)",
                    applying.config_id,
                    needed.subapertures
                );
                core.send(&DeviceMessage::Ack(Ack::ConfigApplied {
                    config_id: applying.config_id,
                    open_windows: saturate(needed.open_windows),
                    pool_entries: saturate(needed.pool_entries),
                }))
                .await?;
            }
            let served = core.serve(rx, source, &mut engine, staging).await;
            if let Some(engine) = &engine {
                core.fold_engine(engine);
            }
            if let Some(plan) = served? {
                core.bench(plan, memory, staging).await?;
            }
        }
    }
}

impl<T: Read + Write, W: Watchdog> Core<'_, T, W> {
    fn status(&self) -> Status {
        Status {
            upload_id: self.upload.as_ref().map(|u| u.id),
            capturing: self.capture.is_some(),
            health: (self.health)(),
            ..self.counters
        }
    }

    /// Adds what `engine` did since the last call (or since it was built)
    /// to `Status.engine`. Called at every frame's end, so that the
    /// engine's 32-bit counts cannot wrap unseen.
    fn fold_engine(&mut self, engine: &Engine<'_, '_>) {
        let now = engine.stats();
        let seen = core::mem::replace(&mut self.engine_seen, now);
        let total = &mut self.counters.engine;
        let add = |total: &mut u64, now: u32, seen: u32| {
            *total = total.saturating_add(u64::from(now.wrapping_sub(seen)));
        };
        add(&mut total.windows, now.windows, seen.windows);
        add(&mut total.candidates, now.candidates, seen.candidates);
        add(&mut total.compactions, now.compactions, seen.compactions);
        add(&mut total.rescans, now.rescans, seen.rescans);
        add(&mut total.attentions, now.attentions, seen.attentions);
        add(
            &mut total.kernel_frames,
            now.kernel_frames,
            seen.kernel_frames,
        );
    }

    /// Handles frames and pixels until the active configuration changes
    /// (`None`) or a bench needs the engine's memory.
    async fn serve<C: PixelSource>(
        &mut self,
        rx: &mut FrameReader<&mut [u8]>,
        source: &mut C,
        engine: &mut Option<Engine<'_, '_>>,
        staging: &mut ConfigSlot<'_>,
    ) -> LinkResult<Option<BenchPlan>, T::Error> {
        loop {
            // Alive: every pass of the loop feeds the watchdog.
            self.watchdog.feed();
            while let Some(received) = rx.next_frame() {
                let message = match received {
                    Received::TooLong => {
                        bump(&mut self.counters.decode_errors, 1);
                        log_debug!("device: frame too long, dropped");
                        self.send_error(DeviceError::FrameTooLong).await?;
                        continue;
                    }
                    Received::Frame(bytes) => match unstuff(bytes) {
                        Err(WireError::Crc { .. }) => {
                            bump(&mut self.counters.crc_errors, 1);
                            log_debug!("device: frame with a bad CRC, dropped");
                            self.send_error(DeviceError::Crc).await?;
                            continue;
                        }
                        Err(_) => None,
                        Ok(body) => match decode_body::<HostMessage>(body) {
                            Ok(message) => Some(message),
                            // A host of another protocol version: its Hello
                            // keeps the frozen prefix; answer it as a Hello.
                            Err(_) => hello_in_body(body).map(|protocol| HostMessage::Hello {
                                protocol,
                                session: 0,
                            }),
                        },
                    },
                };
                let Some(message) = message else {
                    bump(&mut self.counters.decode_errors, 1);
                    log_debug!("device: frame that does not decode, dropped");
                    self.send_error(DeviceError::Decode).await?;
                    continue;
                };
                match self.handle(message, source, engine, staging).await? {
                    Next::Continue => {}
                    Next::Rebuild => return Ok(None),
                    Next::Bench(plan) => return Ok(Some(plan)),
                }
            }
            self.flush_link().await?;
            let waited = select3(
                self.link.read(rx.space()),
                source.next(),
                self.watchdog.due(),
            )
            .await;
            match waited {
                Either3::First(Ok(0)) => return Err(LinkError::Closed),
                Either3::First(Ok(n)) => rx.advance(n),
                Either3::First(Err(e)) => return Err(LinkError::Io(e)),
                Either3::Second(run) => {
                    if let Some(began) = run.began {
                        self.capture_began(began).await?;
                    }
                    if let Some(engine) = engine {
                        self.feed(engine, run.frame, run.first_pixel, run.pixels)
                            .await?;
                    }
                }
                Either3::Third(()) => {} // fed at the top of the loop
            }
            self.acknowledge_capture(source.armed()).await?;
            if core::mem::take(&mut self.capture_finished) {
                source.stop();
                let frames = self.capture.take().map_or(0, |c| c.done);
                log_info!("device: capture of {=u32} frames done", frames);
                self.send(&DeviceMessage::Ack(Ack::CaptureStopped { frames }))
                    .await?;
            }
        }
    }

    async fn handle<C: PixelSource>(
        &mut self,
        message: HostMessage<'_>,
        source: &mut C,
        engine: &mut Option<Engine<'_, '_>>,
        staging: &mut ConfigSlot<'_>,
    ) -> LinkResult<Next, T::Error> {
        if let HostMessage::Hello { protocol, session } = message {
            if protocol.matches_current() {
                self.end_session(source, engine);
                self.session = true;
                self.counters.session = Some(session);
                log_info!("device: session {=u32:#x} started", session);
            } else {
                // Another version's client: answered, and nothing changes
                // (a session in progress goes on).
                log_warn!(
                    "device: host speaks protocol {=u16} schema {=u64:#x}, device {=u16} {=u64:#x}: refused",
                    protocol.version,
                    protocol.schema,
                    Hello::CURRENT.version,
                    Hello::CURRENT.schema
                );
            }
            let reply = DeviceMessage::HelloReply(HelloReply {
                version: Hello::CURRENT.version,
                schema: Hello::CURRENT.schema,
                session,
                capabilities: self.capabilities.clone(),
            });
            self.send(&reply).await?;
            return Ok(Next::Continue);
        }
        if !self.session {
            self.send_error(DeviceError::HelloRequired).await?;
            return Ok(Next::Continue);
        }
        let reply = match message {
            HostMessage::Hello { .. } => unreachable_hello(),
            HostMessage::ConfigBegin { upload_id, header } => {
                // Before anything is stored: a rectangle the camera
                // interface cannot crop is refused outright.
                let crop = match header.crop {
                    Some(crop) => source
                        .check_crop(header.camera, crop)
                        .map_err(DeviceError::Crop),
                    None => Ok(()),
                };
                self.begin(upload_id, header, crop, staging)
                    .map(|upload_id| Ack::UploadStarted { upload_id })
            }
            HostMessage::ConfigChunk {
                upload_id,
                table,
                offset,
                bytes,
            } => self.chunk(upload_id, table, offset, bytes, staging),
            HostMessage::ConfigCommit { upload_id, crc32 } => {
                match self.commit(upload_id, crc32, staging) {
                    Ok(()) => {
                        if let Some(capture) = self.capture.take() {
                            source.stop();
                            self.send(&DeviceMessage::Ack(Ack::CaptureStopped {
                                frames: capture.done,
                            }))
                            .await?;
                        }
                        if let Some(engine) = engine {
                            self.drop_frame(engine, FrameFault::Reconfigured).await?;
                        }
                        self.active ^= 1;
                        self.applying = Some(Applying {
                            config_id: upload_id,
                            digest: crc32,
                        });
                        return Ok(Next::Rebuild);
                    }
                    Err(e) => Err(e),
                }
            }
            HostMessage::ConfigAbort => {
                let upload_id = self.upload.take().map(|u| u.id);
                Ok(Ack::UploadAborted { upload_id })
            }
            HostMessage::StatusRequest => {
                if let Some(engine) = engine {
                    self.fold_engine(engine);
                }
                let status = self.status();
                self.send(&DeviceMessage::Status(status)).await?;
                return Ok(Next::Continue);
            }
            HostMessage::ResetLevelFilters => match engine {
                Some(engine) => {
                    engine.reset_level_filters();
                    Ok(Ack::LevelFiltersReset)
                }
                None => Err(DeviceError::NotConfigured),
            },
            HostMessage::PixelRows {
                frame,
                first_pixel,
                pixels,
            } => {
                let result = match (engine, self.capture.is_some()) {
                    (_, true) => Err(DeviceError::Unexpected {
                        message: MessageKind::PixelRows,
                    }),
                    (None, _) => Err(DeviceError::NotConfigured),
                    (Some(_), _) if pixels.len() % 2 != 0 => Err(DeviceError::Frame {
                        frame,
                        fault: FrameFault::OddLength,
                    }),
                    (Some(engine), _) => {
                        self.feed_le(engine, frame, first_pixel, pixels).await?;
                        Ok(())
                    }
                };
                if let Err(e) = result {
                    self.send_error(e).await?;
                }
                return Ok(Next::Continue);
            }
            HostMessage::Capture {
                frames,
                start,
                edge_rows,
            } => {
                match self.start_capture(frames, start, edge_rows, source, engine) {
                    Ok(Some(ack)) => Ok(ack),
                    // Acknowledged once armed.
                    Ok(None) => return Ok(Next::Continue),
                    Err(e) => Err(e),
                }
            }
            HostMessage::Bench { workload, frames } => match self.check_bench(workload, frames) {
                Ok(plan) => return Ok(Next::Bench(plan)),
                Err(e) => Err(DeviceError::Bench(e)),
            },
            HostMessage::StopCapture => Ok(self.stop_capture(source, engine).await?),
            HostMessage::LinkTest { bytes, chunk } => match self.check_link_test(bytes, chunk) {
                Ok(()) => Ok(self.link_test(bytes, chunk).await?),
                Err(e) => Err(DeviceError::LinkTest(e)),
            },
        };
        match reply {
            Ok(ack) => self.send(&DeviceMessage::Ack(ack)).await?,
            Err(e) => self.send_error(e).await?,
        }
        Ok(Next::Continue)
    }

    /// A matching `Hello`: whatever the previous client left in progress
    /// is abandoned (PROTOCOL.md §6). Its frame in progress is counted in
    /// `frames_dropped` but not reported (its results would reach the new
    /// client), its upload is discarded, its capture stopped, and the level
    /// filters start afresh, so the new session's results depend only on
    /// what it sends. The active configuration and the counters stay.
    fn end_session<C: PixelSource>(&mut self, source: &mut C, engine: &mut Option<Engine<'_, '_>>) {
        if self.capture.take().is_some() {
            source.stop();
        }
        self.capture_finished = false;
        if let Some(engine) = engine {
            if self.frame.take().is_some() {
                engine.abort_frame();
                self.counters.frames_dropped += 1;
            }
            engine.reset_level_filters();
        }
        self.frame = None;
        self.skipping = None;
        self.queued = 0;
        if let Some(upload) = self.upload.take() {
            log_debug!(
                "device: upload {=u32} discarded by a new session",
                upload.id
            );
        }
    }

    // --- output ---------------------------------------------------------------

    async fn send_error(&mut self, error: DeviceError) -> LinkResult<(), T::Error> {
        self.send(&DeviceMessage::Error(error)).await
    }

    async fn send(&mut self, message: &DeviceMessage<'_>) -> LinkResult<(), T::Error> {
        let Core {
            link, tx, watchdog, ..
        } = self;
        match encode(message, tx) {
            Ok(frame) => fed(watchdog, link.write_all(frame))
                .await
                .map_err(LinkError::Io),
            Err(_) => {
                // Only with a transmit buffer below MAX_FRAME_LEN.
                log_warn!("device: a reply did not fit the transmit buffer");
                Ok(())
            }
        }
    }

    async fn flush_link(&mut self) -> LinkResult<(), T::Error> {
        let Core { link, watchdog, .. } = self;
        fed(watchdog, link.flush()).await.map_err(LinkError::Io)
    }
}

/// Awaits `io`, feeding `watchdog` whenever it is due meanwhile: a host
/// that reads slowly makes the loop wait, it does not hang it. (The write
/// is never cancelled, only polled again.)
async fn fed<F: core::future::Future, W: Watchdog>(watchdog: &mut W, io: F) -> F::Output {
    let mut io = core::pin::pin!(io);
    loop {
        match select(io.as_mut(), watchdog.due()).await {
            Either::First(done) => return done,
            Either::Second(()) => watchdog.feed(),
        }
    }
}

fn unreachable_hello() -> Result<Ack, DeviceError> {
    Err(DeviceError::Unexpected {
        message: MessageKind::Hello,
    })
}

fn reborrow<'a>(memory: &'a mut EngineMemory<'_>) -> EngineMemory<'a> {
    EngineMemory {
        order: memory.order,
        subapertures: memory.subapertures,
        open: memory.open,
        free: memory.free,
        entries: memory.entries,
        history: memory.history,
        scratch: memory.scratch,
        rescan: memory.rescan,
    }
}

/// Counters stop at their maximum instead of wrapping (or panicking).
fn bump(counter: &mut u32, by: u32) {
    *counter = counter.saturating_add(by);
}

fn saturate(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

fn truncate(s: &str, max: usize) -> &str {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}
