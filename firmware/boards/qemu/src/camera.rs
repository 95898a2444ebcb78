//! The simulated camera (`--camera DIR`): the board's DMA, played by a task
//! that reads frames the host generates through semihosting and writes them
//! into the camera ring ([`SoftRing`]) at the pace of the board's own frame
//! clock. The device reads them through `SimulatedCamera`, i.e. the same
//! `DcmiSource` the STM32H743's DCMI feeds.
//!
//! The exchange with the host, in directory `DIR` (firmware/boards/qemu/README.md,
//! "The simulated camera"):
//! 1. when a capture starts, the task writes one line to `DIR/requests`
//!    (which it keeps open, each line after the last):
//!    `capture ID WIDTH HEIGHT BIT_DEPTH START` (ID counts captures from
//!    1; START `immediate`, `on-sync` or `drive-sync`, the request's
//!    `CaptureStart`): the whole sensor's geometry, which with a crop (a
//!    board of a rig) is larger than the configured camera: the task keeps
//!    the rectangle of every frame, as the STM32H743's DCMI crop does
//!    (`brightpix_firmware::camera::SensorCrop`);
//! 2. on the sync line (`on-sync`, `drive-sync`; only with
//!    `--camera-sync`), the host creates the empty file `DIR/armed-ID` once
//!    it has armed the board on its simulated line; the task then marks the
//!    capture armed (the device acknowledges `Capture` only then);
//! 3. when the capture begins (the next frame start of the host's camera
//!    timeline, or the first after the sync edge), the host creates the
//!    FIFO `DIR/camera-ID.fifo` and writes into it an 8-byte header, `FLAGS
//!    CAMERA_FRAME` (u32 little-endian each; FLAGS bit 0: the capture began
//!    on a sync edge, bit 1: CAMERA_FRAME, the camera's number of its first
//!    frame, is known: a camera shared by a rig's boards), then frames of
//!    that geometry from that one on, pixels as 16-bit little-endian, row
//!    after row (a frame is `WIDTH * HEIGHT * 2` bytes), for as long as the
//!    board reads;
//! 4. every frame period (`--camera-fps`) the task reads one frame, 4 KiB
//!    at a time, into the ring (yielding to the device between pieces) and
//!    marks its end; when the capture stops it closes the FIFO, and the
//!    host stops writing.
//!
//! The task polls for the files (a missing file's open fails at once), so
//! the board keeps serving its link while it waits for the edge.
//!
//! A new FIFO per capture means no byte of an earlier capture can reach a
//! later one. The frame clock does not wait for the device: a device that
//! falls a ring behind loses frames (counted overruns), as behind a camera.
//! A semihosting read blocks the whole emulated machine while the FIFO is
//! empty, so the host generates frames ahead.

use core::fmt::Write as _;

use brightpix_firmware::camera::{DataWidth, SensorCrop, SimulatedCamera, SoftRing};
use brightpix_firmware::device::CaptureBegin;
use brightpix_protocol::wire::CaptureStart;
use embassy_time::{Duration, Instant, Timer};
use heapless::String;
use semihosting::fs::{File, OpenOptions};
use semihosting::io::Write as _;
use static_cell::ConstStaticCell;

use crate::hostfs::{HostFile, MAX_PATH};
use crate::pixels::READ_CHUNK;

/// Words in the camera ring: 64 KiB, two and a half frames of 112x112.
pub const RING_WORDS: usize = 16 * 1024;
/// Words (two pixels each) of one run the source hands the device.
pub const RUN_WORDS: usize = 1024;
/// The simulated camera's bus: 16 bits, two pixels a word.
const BUS: DataWidth = DataWidth::Bits16;

/// The ring. Its frame-end marks are not all zero, so it sits in `.data`.
pub static RING: SoftRing<RING_WORDS> = SoftRing::new();
static RUN_WORDS_BUF: ConstStaticCell<[u32; RUN_WORDS]> = ConstStaticCell::new([0; RUN_WORDS]);
static RUN_PIXELS: ConstStaticCell<[u16; 2 * RUN_WORDS]> = ConstStaticCell::new([0; 2 * RUN_WORDS]);

/// The device's pixel source over [`RING`]. Panics if called twice.
pub fn source() -> SimulatedCamera<'static, 'static, RING_WORDS> {
    SimulatedCamera::new(&RING, BUS, RUN_WORDS_BUF.take(), RUN_PIXELS.take())
}

/// How long the task waits for the host's FIFO of a capture.
const FIFO_WAIT_MS: u64 = 10_000;
/// How often it looks for a new capture.
const IDLE_POLL_MS: u64 = 1;

/// Feeds [`RING`] from the host's frames in `dir`, `fps` frames a second.
#[embassy_executor::task]
pub async fn feed(dir: String<MAX_PATH>, fps: u32) {
    let period = Duration::from_micros(1_000_000 / u64::from(fps.max(1)));
    let mut bytes = [0u8; READ_CHUNK];
    let mut pixels = [0u16; READ_CHUNK / 2];
    // One more than the chunk's: a word started in the previous chunk.
    let mut words = [0u32; READ_CHUNK / 4 + 1];
    let mut last = 0;
    defmt::info!(
        "camera: simulated, frames from the host in {=str}, {=u32} frames/s",
        dir.as_str(),
        fps
    );
    let Some(mut requests) = open_requests(&dir) else {
        return;
    };
    loop {
        let capture = loop {
            match RING.capture() {
                Some(c) if c.id != last => break c,
                _ => Timer::after_millis(IDLE_POLL_MS).await,
            }
        };
        last = capture.id;
        let camera = capture.sensor();
        let mut crop = SensorCrop::new(BUS, capture.camera, capture.crop);
        let frame_bytes = camera.pixel_count() * 2;
        if !request(&mut requests, capture.id, camera, capture.start) {
            continue;
        }
        if capture.start != CaptureStart::Immediate {
            if !wait_for_file(&dir, capture.id).await {
                continue;
            }
            RING.arm(capture.id);
        }
        // On the sync line the host makes the FIFO only after the edge.
        let wait = match capture.start {
            CaptureStart::Immediate => FIFO_WAIT_MS,
            _ => WAIT_FOREVER,
        };
        let Some(mut file) = open_fifo(&dir, capture.id, wait).await else {
            continue;
        };
        let mut header = [0u8; 8];
        if let Err(e) = file.read_exact(&mut header) {
            defmt::error!(
                "camera: reading the host's capture header failed ({}); capture {=u32} gets no frames",
                defmt::Debug2Format(&e),
                capture.id
            );
            continue;
        }
        let word =
            |k: usize| u32::from_le_bytes([header[k], header[k + 1], header[k + 2], header[k + 3]]);
        let began = CaptureBegin {
            synced: word(0) & 1 != 0,
            camera_frame: (word(0) & 2 != 0).then_some(word(4)),
        };
        RING.begin(capture.id, began);
        defmt::info!(
            "camera: capture {=u32}: {=u16}x{=u16}, {=u8} bits, from camera frame {=u32}{=str}",
            capture.id,
            camera.width,
            camera.height,
            camera.bit_depth,
            word(4),
            if began.synced {
                " (on the sync edge)"
            } else {
                ""
            }
        );
        let mut next = Instant::now();
        let mut frames = 0u32;
        'frames: loop {
            let mut left = frame_bytes;
            while left > 0 {
                let n = left.min(READ_CHUNK);
                if let Err(e) = file.read_exact(&mut bytes[..n]) {
                    defmt::error!(
                        "camera: reading the host's frames failed ({}); capture {=u32} gets no more",
                        defmt::Debug2Format(&e),
                        capture.id
                    );
                    break 'frames;
                }
                for (p, b) in pixels.iter_mut().zip(bytes[..n].chunks_exact(2)) {
                    *p = u16::from_le_bytes([b[0], b[1]]);
                }
                let kept = crop.keep_packed(&pixels[..n / 2], &mut words);
                if !RING.write(capture.id, &words[..kept]) {
                    break 'frames;
                }
                left -= n;
                // The device takes the piece before the next one comes.
                embassy_futures::yield_now().await;
            }
            crop.end_frame();
            if !RING.end_frame(capture.id) {
                break;
            }
            frames += 1;
            // The frame clock: one period after the last frame's start; a
            // late one does not catch up.
            next += period;
            let now = Instant::now();
            if next < now {
                next = now;
            }
            Timer::at(next).await;
            if !RING.is_running(capture.id) {
                break;
            }
        }
        defmt::info!(
            "camera: capture {=u32} ended after {=u32} frames",
            capture.id,
            frames
        );
        // Dropping `file` closes the FIFO: the host stops writing.
    }
}

/// Opens `DIR/requests` for the task's request lines. It stays open: QEMU
/// 7.2 does not honour semihosting's append mode (a reopened file is
/// written from its start again), so the lines follow one another through
/// the one file position.
fn open_requests(dir: &str) -> Option<File> {
    let mut path: String<{ MAX_PATH + 1 }> = String::new();
    if write!(path, "{dir}/requests\0").is_err() {
        defmt::error!("camera: the request path is too long");
        return None;
    }
    let cpath = core::ffi::CStr::from_bytes_until_nul(path.as_bytes()).ok()?;
    match OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .open(cpath)
    {
        Ok(file) => Some(file),
        Err(e) => {
            defmt::error!(
                "camera: cannot open {=str}/requests ({}); no frames",
                dir,
                defmt::Debug2Format(&e)
            );
            None
        }
    }
}

/// Writes the request line of capture `id`.
fn request(
    requests: &mut File,
    id: u32,
    camera: brightpix_protocol::Camera,
    start: CaptureStart,
) -> bool {
    let mut line: String<64> = String::new();
    let start = match start {
        CaptureStart::Immediate => "immediate",
        CaptureStart::OnSync => "on-sync",
        CaptureStart::DriveSync => "drive-sync",
    };
    if writeln!(
        line,
        "capture {id} {} {} {} {start}",
        camera.width, camera.height, camera.bit_depth
    )
    .is_err()
    {
        return false;
    }
    if let Err(e) = requests.write_all(line.as_bytes()) {
        defmt::error!(
            "camera: cannot write a request ({})",
            defmt::Debug2Format(&e)
        );
        return false;
    }
    true
}

/// No bound on a wait, in effect (the sync edge comes when the host releases the
/// leader; the capture's stop ends the wait).
const WAIT_FOREVER: u64 = 1 << 40;

/// Waits until the host has made `DIR/armed-ID` (a regular file), while
/// capture `id` runs; false if it ended first.
async fn wait_for_file(dir: &str, id: u32) -> bool {
    let mut path: String<MAX_PATH> = String::new();
    if write!(path, "{dir}/armed-{id}").is_err() {
        defmt::error!("camera: the path of armed-{=u32} is too long", id);
        return false;
    }
    loop {
        if !RING.is_running(id) {
            return false;
        }
        if HostFile::open_str(&path).is_ok() {
            return true;
        }
        Timer::after_millis(IDLE_POLL_MS).await;
    }
}

/// Opens `DIR/camera-ID.fifo` once the host has made it (the open returns
/// when the host opens it for writing), while capture `id` runs, for at
/// most `wait_ms`.
async fn open_fifo(dir: &str, id: u32, wait_ms: u64) -> Option<HostFile> {
    let mut path: String<MAX_PATH> = String::new();
    if write!(path, "{dir}/camera-{id}.fifo").is_err() {
        defmt::error!("camera: the FIFO path is too long");
        return None;
    }
    let started = Instant::now();
    loop {
        if !RING.is_running(id) {
            return None;
        }
        match HostFile::open_str(&path) {
            Ok(file) => return Some(file),
            Err(_) if started.elapsed() < Duration::from_millis(wait_ms) => {
                Timer::after_millis(IDLE_POLL_MS).await
            }
            Err(e) => {
                defmt::error!(
                    "camera: the host made no {=str} ({}); capture {=u32} gets no frames",
                    path.as_str(),
                    defmt::Debug2Format(&e),
                    id
                );
                return None;
            }
        }
    }
}
