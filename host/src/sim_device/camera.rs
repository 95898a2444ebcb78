//! The simulated devices' own camera (`simulate-device --camera sim[:SEED]`):
//! Shack-Hartmann frames from the project's simulator, made on the host side
//! of the simulation and written into the firmware's camera ring
//! (`brightpix_firmware::camera::SoftRing`), which the device reads through
//! the same `DcmiSource` as the STM32H743's DCMI.
//!
//! - [`CameraFrames`]: frame `k` of seed `SEED` for a camera geometry: the
//!   paper's CANARY NGS spots (16x16 pixels each) tiled from the top-left
//!   corner as `brightpix demo` tiles them, the simulator's background
//!   elsewhere, saturated at the camera's bit depth. A device's camera of
//!   its own starts every capture at frame 0 (a camera triggered by the
//!   capture), so `capture --verify` regenerates exactly what the device
//!   saw from the seed and the configured camera. Boards of a rig share
//!   one free-running camera instead ([`SharedCamera`]: one timeline, one
//!   sync line): each begins on the camera frame current at its own start,
//!   reports it (`CaptureBegan.camera_frame`), and `rig capture --verify`
//!   regenerates from there.
//! - [`CameraOptions::begin`]: the board's start of a capture played on
//!   its camera (its DMA and sync glue): armed, then the first frame
//!   (after the start delay of a shared camera's test knob, and on the
//!   sync line after the edge).
//! - [`InProcessCamera`]: for the in-process device, a thread that plays
//!   camera and DMA: it writes each frame into the ring as a rolling
//!   readout (a few rows at a time across the frame period) at its frame
//!   rate, marking each frame's end, and never waits for the device.
//!
//! With a crop (a board of a rig) the camera makes the whole sensor's
//! frames (the same ones for every board on the same seed: one camera) and
//! the board keeps its rectangle of each, through the firmware's
//! `SensorCrop`, the DCMI crop's software twin: in-process by this
//! module's thread, on the QEMU board by its own camera task.
//! - [`QemuCameraHost`]: for the QEMU board, whose own task paces the
//!   frames (`firmware/boards/qemu/src/camera.rs`): the host answers each
//!   capture request the board appends to `DIR/requests` (`armed-ID` once
//!   armed on the sync line) by writing a header (synced, camera frame)
//!   and that capture's frames into the FIFO `DIR/camera-ID.fifo`, which
//!   the board reads through semihosting (firmware/boards/qemu/README.md,
//!   "The simulated camera").

use std::fs::File;
use std::io::{self, Read as _, Write as _};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use brightpix_firmware::camera::{DataWidth, SensorCrop, SoftRing};
use brightpix_firmware::device::CaptureBegin;
use brightpix_protocol::wire::CaptureStart;
use brightpix_protocol::Camera;

use super::timeline::{sleep_until, SharedCamera};
use super::{make_fifo, spawn};
use crate::simulator::{SimulationParams, Simulator};

/// Words in the in-process device's camera ring (256 KiB: ten frames of
/// 112x112).
pub const RING_WORDS: usize = 64 * 1024;

/// The in-process device's camera ring.
pub type CameraRing = SoftRing<RING_WORDS>;

/// Frames per second of the in-process device's camera by default.
pub const IN_PROCESS_FPS: u32 = 100;
/// Frames per second of the QEMU board's camera by default: an emulated
/// core, whose results (~0.7 KB per CANARY frame) leave on an emulated
/// UART of 0.1-0.3 MB/s (`brightpix bench --port PORT --link`).
pub const QEMU_FPS: u32 = 10;

/// `--camera sim[:SEED]`: the simulated camera and its seed (default 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CameraSpec {
    pub seed: u64,
}

impl FromStr for CameraSpec {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let expected = "expected sim or sim:SEED (SEED a whole number)";
        match s.split_once(':') {
            None if s == "sim" => Ok(CameraSpec { seed: 1 }),
            Some(("sim", seed)) => seed
                .parse()
                .map(|seed| CameraSpec { seed })
                .map_err(|_| format!("camera {s:?}: {expected}")),
            _ => Err(format!("camera {s:?}: {expected}")),
        }
    }
}

impl std::fmt::Display for CameraSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "sim:{}", self.seed)
    }
}

/// A simulated device's camera: what it shows and how fast.
#[derive(Clone, Debug)]
pub struct CameraOptions {
    pub spec: CameraSpec,
    /// Frames per second (at least 1).
    pub fps: u32,
    /// One camera shared with other boards, and this board's index on it
    /// ([`SharedCamera::board`]: its timeline and sync line; `spec` and
    /// `fps` are its own); `None`: a camera of the device's own, whose
    /// frames restart at 0 with every capture and which has no sync line.
    pub shared: Option<(Arc<SharedCamera>, usize)>,
}

impl CameraOptions {
    /// A camera of the device's own.
    pub fn own(spec: CameraSpec, fps: u32) -> CameraOptions {
        CameraOptions {
            spec,
            fps,
            shared: None,
        }
    }

    /// Whether the camera has a sync line (only a shared one can).
    pub fn has_sync_line(&self) -> bool {
        self.shared.as_ref().is_some_and(|(c, _)| c.has_sync_line())
    }

    /// Plays the board's start of a capture (its DMA and sync glue) on
    /// this camera: calls `armed` once the capture is armed, waits for its
    /// first frame's start, and gives that frame's number in the sequence
    /// of [`CameraFrames`] and what the board reports of it; `None` if
    /// `quit` first (the capture ended).
    pub fn begin(
        &self,
        start: CaptureStart,
        quit: &dyn Fn() -> bool,
        armed: &mut dyn FnMut(),
    ) -> Option<(u64, CaptureBegin)> {
        let Some((camera, board)) = &self.shared else {
            armed();
            let own = CaptureBegin {
                synced: false,
                camera_frame: None,
            };
            return Some((0, own));
        };
        // The request reaches the board's camera late (the test knob).
        if !sleep_until(Instant::now() + camera.start_delay(*board), quit) {
            return None;
        }
        let (first, synced) = match start {
            CaptureStart::Immediate => {
                armed();
                (camera.next_frame_after(Instant::now()), false)
            }
            CaptureStart::OnSync => {
                let arming = camera.arm();
                armed();
                (camera.wait_edge(arming, quit)? + 1, true)
            }
            CaptureStart::DriveSync => {
                armed();
                (camera.drive(quit)? + 1, true)
            }
        };
        if !sleep_until(camera.frame_start(first), quit) {
            return None;
        }
        let began = CaptureBegin {
            synced,
            camera_frame: Some(first as u32),
        };
        Some((first, began))
    }

    /// When frame `k` of a capture whose first frame started at `origin`
    /// starts: on the shared timeline, or `k` periods after `origin`.
    fn frame_start(&self, origin: Instant, first: u64, k: u64) -> Instant {
        match &self.shared {
            Some((camera, _)) => camera.frame_start(first + k),
            None => origin + period(self.fps).mul_f64(k as f64),
        }
    }

    /// A capture that drove the sync line ended: the line goes low.
    fn ended(&self, start: CaptureStart) {
        if let (Some((camera, _)), CaptureStart::DriveSync) = (&self.shared, start) {
            camera.lower();
        }
    }
}

fn period(fps: u32) -> Duration {
    Duration::from_secs_f64(1.0 / f64::from(fps.max(1)))
}

/// The simulated camera's frames for one geometry and seed (see the module
/// docs).
pub struct CameraFrames {
    sim: Simulator,
    camera: Camera,
    seed: u64,
    columns: usize,
    rows: usize,
}

impl CameraFrames {
    pub fn new(camera: Camera, seed: u64) -> CameraFrames {
        let sim =
            Simulator::new(SimulationParams::canary()).expect("the paper's parameters are valid");
        let size = sim.size();
        CameraFrames {
            columns: camera.width as usize / size,
            rows: camera.height as usize / size,
            sim,
            camera,
            seed,
        }
    }

    pub fn camera(&self) -> Camera {
        self.camera
    }

    /// Frames `first .. first + count`, row-major.
    pub fn frames(&self, first: u64, count: usize) -> Vec<Vec<u16>> {
        let (width, height) = (self.camera.width as usize, self.camera.height as usize);
        let size = self.sim.size();
        let max = u16::MAX >> (16 - u32::from(self.camera.bit_depth.clamp(1, 16)));
        let background = (self.sim.calibration_background().round() as u16).min(max);
        let per_frame = self.columns * self.rows;
        if per_frame == 0 {
            return vec![vec![background; width * height]; count];
        }
        let spots = self
            .sim
            .frames(self.seed, first * per_frame as u64, per_frame * count);
        spots
            .chunks(per_frame)
            .map(|tiles| {
                let mut frame = vec![background; width * height];
                for (t, spot) in tiles.iter().enumerate() {
                    let (x0, y0) = ((t % self.columns) * size, (t / self.columns) * size);
                    for y in 0..size {
                        let row = &mut frame[(y0 + y) * width + x0..][..size];
                        for (p, &v) in row.iter_mut().zip(&spot.raw[y * size..(y + 1) * size]) {
                            *p = v.min(max);
                        }
                    }
                }
                frame
            })
            .collect()
    }
}

/// Frames `first ..` generated ahead, in batches, on a thread of their
/// own; the thread ends when the receiver is dropped.
fn frames_ahead(
    camera: Camera,
    seed: u64,
    first: u64,
    batch: usize,
) -> io::Result<mpsc::Receiver<Vec<u16>>> {
    let (tx, rx) = mpsc::sync_channel(batch);
    spawn("brightpix-camera-frames", move || {
        let frames = CameraFrames::new(camera, seed);
        let start = first;
        let mut first = first;
        loop {
            // The first frame alone, as soon as it can be.
            let n = if first == start { 1 } else { batch };
            for frame in frames.frames(first, n) {
                if tx.send(frame).is_err() {
                    return;
                }
            }
            first += n as u64;
        }
    })?;
    Ok(rx)
}

/// Frames generated per batch.
const BATCH: usize = 4;

/// The in-process device's camera bus (`sim_device::in_process`).
pub const IN_PROCESS_BUS: DataWidth = DataWidth::Bits16;

// --- the in-process device's camera ---------------------------------------------------

/// Pieces a frame is written in, spread over the frame period.
const READOUT_PIECES: usize = 8;

/// The thread that plays camera and DMA for an in-process device (see the
/// module docs). Stops when dropped.
pub struct InProcessCamera {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl InProcessCamera {
    pub fn start(ring: Arc<CameraRing>, options: CameraOptions) -> io::Result<InProcessCamera> {
        ring.set_sync_line(options.has_sync_line());
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = spawn("brightpix-sim-camera", move || {
            run_in_process(&ring, options, &flag)
        })?;
        Ok(InProcessCamera {
            stop,
            thread: Some(thread),
        })
    }
}

impl Drop for InProcessCamera {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn run_in_process(ring: &CameraRing, options: CameraOptions, stop: &AtomicBool) {
    let period = period(options.fps);
    let mut last = 0;
    while !stop.load(Ordering::Relaxed) {
        let capture = match ring.capture() {
            Some(c) if c.id != last => c,
            _ => {
                thread::sleep(Duration::from_millis(1));
                continue;
            }
        };
        last = capture.id;
        let quit = || stop.load(Ordering::Relaxed) || !ring.is_running(capture.id);
        let begun = options.begin(capture.start, &quit, &mut || ring.arm(capture.id));
        let Some((first, began)) = begun else {
            options.ended(capture.start);
            continue;
        };
        ring.begin(capture.id, began);
        let Ok(frames) = frames_ahead(capture.sensor(), options.spec.seed, first, BATCH) else {
            options.ended(capture.start);
            continue;
        };
        let mut crop = SensorCrop::new(IN_PROCESS_BUS, capture.camera, capture.crop);
        let origin = Instant::now();
        let mut k = 0u64;
        'frames: while !stop.load(Ordering::Relaxed) {
            let Ok(frame) = frames.recv() else { break };
            let mut words = vec![0; frame.len() / 2 + 1];
            let n = crop.keep_packed(&frame, &mut words);
            crop.end_frame();
            words.truncate(n);
            // A late frame is written late, never skipped: frame numbers
            // stay the camera's.
            let start = options.frame_start(origin, first, k);
            let piece = words.len().div_ceil(READOUT_PIECES).max(1);
            for (i, part) in words.chunks(piece).enumerate() {
                sleep_until_or_stop(
                    start + period.mul_f64(i as f64 / READOUT_PIECES as f64),
                    stop,
                );
                if !ring.write(capture.id, part) {
                    break 'frames;
                }
            }
            if !ring.end_frame(capture.id) {
                break;
            }
            k += 1;
            sleep_until_or_stop(options.frame_start(origin, first, k), stop);
        }
        options.ended(capture.start);
    }
}

fn sleep_until_or_stop(at: Instant, stop: &AtomicBool) {
    loop {
        let now = Instant::now();
        if now >= at || stop.load(Ordering::Relaxed) {
            return;
        }
        thread::sleep((at - now).min(Duration::from_millis(50)));
    }
}

// --- the QEMU board's camera --------------------------------------------------------------

/// The host side of the QEMU board's simulated camera (see the module
/// docs). Stops when dropped.
pub struct QemuCameraHost {
    dir: PathBuf,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl QemuCameraHost {
    /// Serves captures in `dir` (created, with an empty `requests` file).
    pub fn start(dir: &Path, options: CameraOptions) -> io::Result<QemuCameraHost> {
        std::fs::create_dir_all(dir)?;
        File::create(dir.join("requests"))?;
        let stop = Arc::new(AtomicBool::new(false));
        let (flag, path) = (stop.clone(), dir.to_path_buf());
        let thread = spawn("brightpix-qemu-camera", move || {
            serve_requests(&path, &options, &flag)
        })?;
        Ok(QemuCameraHost {
            dir: dir.to_path_buf(),
            stop,
            thread: Some(thread),
        })
    }

    /// The directory the board is given (`--camera DIR`).
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Drop for QemuCameraHost {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A capture request: `capture ID WIDTH HEIGHT BIT_DEPTH START`.
fn parse_request(line: &str) -> Option<(u32, Camera, CaptureStart)> {
    let mut words = line.split_whitespace();
    if words.next()? != "capture" {
        return None;
    }
    let id = words.next()?.parse().ok()?;
    let camera = Camera {
        width: words.next()?.parse().ok()?,
        height: words.next()?.parse().ok()?,
        bit_depth: words.next()?.parse().ok()?,
    };
    let start = match words.next()? {
        "immediate" => CaptureStart::Immediate,
        "on-sync" => CaptureStart::OnSync,
        "drive-sync" => CaptureStart::DriveSync,
        _ => return None,
    };
    words.next().is_none().then_some((id, camera, start))
}

fn serve_requests(dir: &Path, options: &CameraOptions, stop: &Arc<AtomicBool>) {
    let Ok(mut requests) = File::open(dir.join("requests")) else {
        return;
    };
    let mut pending = String::new();
    let mut writers: Vec<(Arc<AtomicBool>, JoinHandle<()>)> = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        let mut text = String::new();
        if requests.read_to_string(&mut text).is_err() {
            return;
        }
        pending.push_str(&text);
        while let Some(end) = pending.find('\n') {
            let line: String = pending.drain(..=end).collect();
            let Some((id, camera, start)) = parse_request(&line) else {
                eprintln!("brightpix: the QEMU camera ignored the request {line:?}");
                continue;
            };
            // The board has moved on: earlier captures get no more frames.
            for (done, _) in &writers {
                done.store(true, Ordering::Relaxed);
            }
            let done = Arc::new(AtomicBool::new(false));
            let (flag, all, dir, options) = (
                done.clone(),
                stop.clone(),
                dir.to_path_buf(),
                options.clone(),
            );
            if let Ok(t) = spawn("brightpix-qemu-camera-frames", move || {
                let capture = QemuCapture {
                    dir: &dir,
                    id,
                    camera,
                    start,
                };
                capture.serve(&options, &flag, &all);
            }) {
                writers.push((done, t));
            }
        }
        writers.retain(|(_, t)| !t.is_finished());
        thread::sleep(Duration::from_millis(2));
    }
    for (done, t) in writers {
        done.store(true, Ordering::Relaxed);
        let _ = t.join();
    }
}

/// One capture of the QEMU board, as its camera task asked for it.
struct QemuCapture<'a> {
    dir: &'a Path,
    id: u32,
    camera: Camera,
    start: CaptureStart,
}

impl QemuCapture<'_> {
    /// Plays the board's start (`DIR/armed-ID` once armed on the sync
    /// line), then makes `DIR/camera-ID.fifo` when the capture begins and
    /// writes its header and frames until the board closes it or
    /// `done`/`stop`.
    fn serve(&self, options: &CameraOptions, done: &AtomicBool, stop: &AtomicBool) {
        let quit = || done.load(Ordering::Relaxed) || stop.load(Ordering::Relaxed);
        let armed_file = self.dir.join(format!("armed-{}", self.id));
        let fifo = self.dir.join(format!("camera-{}.fifo", self.id));
        let mut armed = || {
            if self.start != CaptureStart::Immediate {
                let _ = File::create(&armed_file);
            }
        };
        if let Some((first, began)) = options.begin(self.start, &quit, &mut armed) {
            if make_fifo(&fifo).is_ok() {
                self.write_frames(&fifo, options.spec.seed, first, began, &quit);
            }
        }
        options.ended(self.start);
        let _ = std::fs::remove_file(&fifo);
        let _ = std::fs::remove_file(&armed_file);
    }

    /// The header (`FLAGS CAMERA_FRAME`, u32 LE each; FLAGS bit 0 synced,
    /// bit 1 the camera frame known), then frames
    /// `first ..` into `fifo` for as long as the board reads.
    fn write_frames(
        &self,
        fifo: &Path,
        seed: u64,
        first: u64,
        began: CaptureBegin,
        quit: &dyn Fn() -> bool,
    ) {
        // Non-blocking open: fails until the board has opened its end.
        let started = Instant::now();
        let mut file = loop {
            match std::fs::OpenOptions::new()
                .write(true)
                .custom_flags(libc::O_NONBLOCK)
                .open(fifo)
            {
                Ok(f) => break f,
                Err(_) if quit() || started.elapsed() > Duration::from_secs(30) => return,
                Err(_) => thread::sleep(Duration::from_millis(1)),
            }
        };
        if set_blocking(&file).is_err() {
            return;
        }
        let mut header = Vec::with_capacity(8);
        let flags = u32::from(began.synced) | u32::from(began.camera_frame.is_some()) << 1;
        header.extend(flags.to_le_bytes());
        header.extend(began.camera_frame.unwrap_or(first as u32).to_le_bytes());
        if file.write_all(&header).is_err() {
            return;
        }
        let Ok(frames) = frames_ahead(self.camera, seed, first, BATCH) else {
            return;
        };
        let mut bytes = Vec::new();
        while !quit() {
            let Ok(frame) = frames.recv() else { return };
            bytes.clear();
            bytes.extend(frame.iter().flat_map(|p| p.to_le_bytes()));
            // Blocks while the FIFO is full; fails once the board closed it.
            if file.write_all(&bytes).is_err() {
                return;
            }
        }
    }
}

fn set_blocking(file: &File) -> io::Result<()> {
    use std::os::unix::io::AsRawFd;
    let fd = file.as_raw_fd();
    // SAFETY: fcntl on a file descriptor this function's caller owns.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_spec_parses_sim_and_a_seed() {
        assert_eq!("sim".parse(), Ok(CameraSpec { seed: 1 }));
        assert_eq!("sim:42".parse(), Ok(CameraSpec { seed: 42 }));
        for bad in ["", "sim:", "sim:x", "dcmi", "sim:1:2"] {
            let err = bad.parse::<CameraSpec>().unwrap_err();
            assert!(err.contains("expected sim or sim:SEED"), "{bad}: {err}");
        }
    }

    #[test]
    fn frames_are_the_demo_tiling_from_any_first_frame() {
        let camera = crate::sil::canary_config().camera;
        let frames = CameraFrames::new(camera, 3);
        let sim = Simulator::new(SimulationParams::canary()).unwrap();
        let expected = crate::sil::tiled_frames(&sim, camera, 7, 7, 3, 3);
        assert_eq!(frames.frames(0, 3), expected);
        assert_eq!(frames.frames(2, 1)[0], expected[2]);
    }

    #[test]
    fn frames_saturate_at_the_bit_depth_and_fill_small_cameras() {
        let camera = Camera {
            width: 40,
            height: 20,
            bit_depth: 6,
        };
        let frames = CameraFrames::new(camera, 1).frames(0, 2);
        assert_eq!(frames.len(), 2);
        assert!(frames.iter().all(|f| f.len() == 800));
        assert!(frames.iter().flatten().all(|&p| p <= 63));
        assert!(frames[0].contains(&63), "bright spot pixels saturate");
        let tiny = Camera {
            width: 8,
            height: 8,
            bit_depth: 16,
        };
        assert_eq!(CameraFrames::new(tiny, 1).frames(0, 1), vec![vec![50; 64]]);
    }

    #[test]
    fn requests_parse() {
        assert_eq!(
            parse_request("capture 3 112 112 16 on-sync\n"),
            Some((
                3,
                Camera {
                    width: 112,
                    height: 112,
                    bit_depth: 16
                },
                CaptureStart::OnSync
            ))
        );
        assert_eq!(parse_request("capture 3 112 112 16"), None);
        assert_eq!(parse_request("capture 3 112 112 16 later"), None);
        assert_eq!(parse_request("stop 3"), None);
    }

    /// Without a crop the bus carries every pixel, the first of a pair in
    /// the low half of its word.
    #[test]
    fn the_bus_puts_the_first_pixel_low() {
        let camera = Camera {
            width: 2,
            height: 2,
            bit_depth: 16,
        };
        let mut crop = SensorCrop::new(IN_PROCESS_BUS, camera, None);
        let mut words = [0; 3];
        let n = crop.keep_packed(&[1, 2, 0xFFFF, 4], &mut words);
        assert_eq!(words[..n], [0x0002_0001, 0x0004_FFFF]);
    }
}
