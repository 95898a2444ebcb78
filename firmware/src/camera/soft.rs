//! A camera ring that software fills: the simulated camera of the simulated
//! devices (`brightpix simulate-device --camera sim`), fed through the same
//! [`DcmiSource`] as the STM32 board's DCMI.
//!
//! [`SoftRing`] plays the DMA: a producer (a host thread for the in-process
//! device, a task reading frames from the host for the QEMU board) writes
//! packed camera words into the ring with [`SoftRing::write`] and marks each
//! frame's end with [`SoftRing::end_frame`], at the pace of its own frame
//! clock; it keeps the half-ring event count and the write index exactly as
//! the DMA interrupt and NDTR would, so the camera source cannot tell the
//! difference (overruns included: the producer never waits). [`SoftDma`]
//! is the consumer's [`DmaRing`], and [`SimulatedCamera`] the device's
//! [`PixelSource`]: a [`DcmiSource`] that also tells the producer which
//! geometry the capture expects (a simulated camera makes frames of the
//! configured camera, where a real one has its own). With a crop (a board
//! of a rig), the producer makes frames of the whole sensor and keeps the
//! rectangle with a [`SensorCrop`](super::crop::SensorCrop), as the DCMI's
//! crop would.
//!
//! A capture may start on the rig's sync line ([`CaptureStart`]): the
//! producer then plays the board's sync glue as well. It tells the ring
//! when the capture is armed ([`SoftRing::arm`]; the device acknowledges
//! `Capture` only then), waits for the edge on its simulated line, and
//! says how the capture began ([`SoftRing::begin`]: on the edge or not,
//! and the camera frame it began on) before its first words. A ring
//! accepts the sync modes only if its producer has a line
//! ([`SoftRing::set_sync_line`]).
//!
//! Captures are numbered: [`SoftRing::capture`] gives the producer the
//! current one, and writes for any other (a capture stopped or restarted
//! meanwhile) are refused, so a producer that was slow to notice cannot put
//! an old frame's words into a new capture. A small spin lock orders the
//! producer's writes against the consumer's start and stop: it is never
//! contended on a single core whose producer is a task of the same executor,
//! and held for one copy of at most half a ring on the host.

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use core::task::Waker;

use atomic_waker::AtomicWaker;
use brightpix_protocol::wire::{CaptureStart, CropFault, PixelSourceKind, SyncFault};
use brightpix_protocol::{Camera, Crop};

use super::packing::DataWidth;
use super::ring::{DmaProgress, DmaRing, FrameMarks, RING_GRANULE_WORDS};
use super::source::{CameraStats, DcmiSource};
use crate::device::{CameraRefused, CaptureBegin, PixelRun, PixelSource};

/// A capture as the producer sees it: its number and the geometry of its
/// frames: `camera`, cut at `crop` from a larger sensor if there is one
/// (the producer then makes the sensor's frames and keeps the rectangle).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SoftCapture {
    pub id: u32,
    pub camera: Camera,
    pub crop: Option<Crop>,
    /// How its frame 0 is chosen.
    pub start: CaptureStart,
}

impl SoftCapture {
    /// The frames the camera makes: the whole sensor.
    pub fn sensor(&self) -> Camera {
        self.crop.map_or(self.camera, |c| c.sensor(self.camera))
    }
}

/// The ring of `WORDS` 32-bit words (a multiple of
/// [`RING_GRANULE_WORDS`]) with its DMA state. Lives in a `static` on a
/// board, in an `Arc` on the host.
pub struct SoftRing<const WORDS: usize> {
    words: [AtomicU32; WORDS],
    lock: AtomicBool,
    half_events: AtomicU32,
    write_index: AtomicU32,
    /// Captures started so far (the current one's id).
    captures: AtomicU32,
    running: AtomicBool,
    /// The expected camera: `width << 16 | height`, and the bit depth.
    size: AtomicU32,
    bit_depth: AtomicU32,
    /// The crop, if any: `x << 16 | y` and `sensor_width << 16 |
    /// sensor_height`.
    cropped: AtomicBool,
    crop_origin: AtomicU32,
    sensor_size: AtomicU32,
    /// The producer can play a sync line.
    sync_line: AtomicBool,
    /// The next capture's start ([`start_code`]), then the running one's.
    start: AtomicU32,
    /// The running capture is armed.
    armed: AtomicBool,
    /// How it began: `began` once known, then `synced` and the camera
    /// frame (`u32::MAX` stands for unknown).
    began: AtomicBool,
    began_synced: AtomicBool,
    began_frame: AtomicU32,
    marks: FrameMarks,
    waker: AtomicWaker,
}

const fn start_code(start: CaptureStart) -> u32 {
    match start {
        CaptureStart::Immediate => 0,
        CaptureStart::OnSync => 1,
        CaptureStart::DriveSync => 2,
    }
}

const fn start_of(code: u32) -> CaptureStart {
    match code {
        1 => CaptureStart::OnSync,
        2 => CaptureStart::DriveSync,
        _ => CaptureStart::Immediate,
    }
}

impl<const WORDS: usize> SoftRing<WORDS> {
    const CHECK: () = assert!(
        WORDS > 0 && WORDS.is_multiple_of(RING_GRANULE_WORDS) && WORDS < 1 << 30,
        "the ring's length must be a positive multiple of RING_GRANULE_WORDS"
    );

    pub const fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::CHECK;
        SoftRing {
            words: [const { AtomicU32::new(0) }; WORDS],
            lock: AtomicBool::new(false),
            half_events: AtomicU32::new(0),
            write_index: AtomicU32::new(0),
            captures: AtomicU32::new(0),
            running: AtomicBool::new(false),
            size: AtomicU32::new(0),
            bit_depth: AtomicU32::new(0),
            cropped: AtomicBool::new(false),
            crop_origin: AtomicU32::new(0),
            sensor_size: AtomicU32::new(0),
            sync_line: AtomicBool::new(false),
            start: AtomicU32::new(0),
            armed: AtomicBool::new(false),
            began: AtomicBool::new(false),
            began_synced: AtomicBool::new(false),
            began_frame: AtomicU32::new(u32::MAX),
            marks: FrameMarks::new(),
            waker: AtomicWaker::new(),
        }
    }

    fn locked<T>(&self, f: impl FnOnce() -> T) -> T {
        while self
            .lock
            .compare_exchange_weak(false, true, Ordering::Acquire, Ordering::Relaxed)
            .is_err()
        {
            core::hint::spin_loop();
        }
        let out = f();
        self.lock.store(false, Ordering::Release);
        out
    }

    // --- the producer ------------------------------------------------------------

    /// The running capture, if any.
    pub fn capture(&self) -> Option<SoftCapture> {
        self.locked(|| {
            self.running.load(Ordering::Relaxed).then(|| {
                let size = self.size.load(Ordering::Relaxed);
                let origin = self.crop_origin.load(Ordering::Relaxed);
                let sensor = self.sensor_size.load(Ordering::Relaxed);
                SoftCapture {
                    id: self.captures.load(Ordering::Relaxed),
                    camera: Camera {
                        width: (size >> 16) as u16,
                        height: size as u16,
                        bit_depth: self.bit_depth.load(Ordering::Relaxed) as u8,
                    },
                    crop: self.cropped.load(Ordering::Relaxed).then_some(Crop {
                        x: (origin >> 16) as u16,
                        y: origin as u16,
                        sensor_width: (sensor >> 16) as u16,
                        sensor_height: sensor as u16,
                    }),
                    start: start_of(self.start.load(Ordering::Relaxed)),
                }
            })
        })
    }

    /// Says the producer can play a sync line (before captures start):
    /// the ring then accepts [`CaptureStart::OnSync`] and
    /// [`CaptureStart::DriveSync`].
    pub fn set_sync_line(&self, present: bool) {
        self.sync_line.store(present, Ordering::Relaxed);
    }

    /// Capture `id` is armed: the device may acknowledge it.
    pub fn arm(&self, id: u32) {
        let done = self.locked(|| {
            let current = self.current(id);
            if current {
                self.armed.store(true, Ordering::Release);
            }
            current
        });
        if done {
            self.waker.wake();
        }
    }

    /// How capture `id` began; called before its first [`write`](Self::write).
    pub fn begin(&self, id: u32, began: CaptureBegin) {
        self.locked(|| {
            if self.current(id) {
                self.began_synced.store(began.synced, Ordering::Relaxed);
                self.began_frame
                    .store(began.camera_frame.unwrap_or(u32::MAX), Ordering::Relaxed);
                self.began.store(true, Ordering::Release);
            }
        });
    }

    /// Whether capture `id` is still running.
    pub fn is_running(&self, id: u32) -> bool {
        self.locked(|| self.current(id))
    }

    fn current(&self, id: u32) -> bool {
        self.running.load(Ordering::Relaxed) && self.captures.load(Ordering::Relaxed) == id
    }

    /// Writes `words` at the DMA's position, as the DMA would (overwriting
    /// whatever the consumer has not read), and wakes the consumer. Returns
    /// false, writing nothing, if capture `id` is no longer running.
    pub fn write(&self, id: u32, words: &[u32]) -> bool {
        let half = WORDS / 2;
        let mut rest = words;
        while !rest.is_empty() {
            // At most half a ring under the lock at a time.
            let written = self.locked(|| {
                if !self.current(id) {
                    return None;
                }
                let mut index = self.write_index.load(Ordering::Relaxed) as usize;
                let mut taken = 0;
                while taken < rest.len() && taken < half {
                    // Up to the next half boundary: one event at most.
                    let boundary = if index < half { half } else { WORDS };
                    let n = (boundary - index).min(rest.len() - taken);
                    for (slot, &w) in self.words[index..index + n]
                        .iter()
                        .zip(&rest[taken..taken + n])
                    {
                        slot.store(w, Ordering::Relaxed);
                    }
                    index += n;
                    taken += n;
                    // The index first: a reader that sees it before the
                    // event counts at most one event late, which
                    // `DmaProgress::position` allows for.
                    self.write_index
                        .store((index % WORDS) as u32, Ordering::Release);
                    if index == boundary {
                        self.half_events.fetch_add(1, Ordering::Release);
                        index %= WORDS;
                    }
                }
                Some(taken)
            });
            match written {
                Some(n) => rest = &rest[n..],
                None => return false,
            }
            self.waker.wake();
        }
        true
    }

    /// Marks the end of a frame where the DMA is now (the frame-end
    /// interrupt) and wakes the consumer; false if capture `id` is no
    /// longer running.
    pub fn end_frame(&self, id: u32) -> bool {
        let done = self.locked(|| {
            if !self.current(id) {
                return false;
            }
            self.marks.record(DmaProgress::read(
                || self.half_events.load(Ordering::Acquire),
                || self.write_index.load(Ordering::Acquire) as usize,
            ));
            true
        });
        if done {
            self.waker.wake();
        }
        done
    }

    // --- the consumer's side ----------------------------------------------------------

    fn set_camera(&self, camera: Camera, crop: Option<Crop>) {
        self.locked(|| {
            self.size.store(
                (camera.width as u32) << 16 | camera.height as u32,
                Ordering::Relaxed,
            );
            self.bit_depth
                .store(camera.bit_depth as u32, Ordering::Relaxed);
            self.cropped.store(crop.is_some(), Ordering::Relaxed);
            if let Some(c) = crop {
                self.crop_origin
                    .store((c.x as u32) << 16 | c.y as u32, Ordering::Relaxed);
                self.sensor_size.store(
                    (c.sensor_width as u32) << 16 | c.sensor_height as u32,
                    Ordering::Relaxed,
                );
            }
        });
    }
}

impl<const WORDS: usize> Default for SoftRing<WORDS> {
    fn default() -> Self {
        Self::new()
    }
}

/// The consumer's handle on a [`SoftRing`]: the [`DmaRing`] of the
/// simulated camera's [`DcmiSource`].
pub struct SoftDma<'r, const WORDS: usize> {
    ring: &'r SoftRing<WORDS>,
}

impl<'r, const WORDS: usize> SoftDma<'r, WORDS> {
    pub fn new(ring: &'r SoftRing<WORDS>) -> Self {
        SoftDma { ring }
    }
}

impl<const WORDS: usize> DmaRing for SoftDma<'_, WORDS> {
    fn capacity(&self) -> usize {
        WORDS
    }

    /// A new capture: the producer starts again at word 0 with its next
    /// frame.
    fn start(&mut self) -> u32 {
        let r = self.ring;
        r.locked(|| {
            r.half_events.store(0, Ordering::Relaxed);
            r.write_index.store(0, Ordering::Relaxed);
            r.captures.fetch_add(1, Ordering::Relaxed);
            r.running.store(true, Ordering::Relaxed);
            let immediate = r.start.load(Ordering::Relaxed) == 0;
            r.armed.store(immediate, Ordering::Relaxed);
            r.began.store(false, Ordering::Relaxed);
        });
        0
    }

    /// The sync modes only if the producer has a line.
    fn set_start(&mut self, start: CaptureStart) -> Result<(), SyncFault> {
        let r = self.ring;
        if start != CaptureStart::Immediate && !r.sync_line.load(Ordering::Relaxed) {
            return Err(SyncFault::NoSyncLine);
        }
        r.locked(|| r.start.store(start_code(start), Ordering::Relaxed));
        Ok(())
    }

    fn armed(&self) -> bool {
        self.ring.armed.load(Ordering::Acquire)
    }

    fn began(&self) -> CaptureBegin {
        let r = self.ring;
        r.locked(|| {
            if !r.began.load(Ordering::Acquire) {
                return CaptureBegin::default();
            }
            let frame = r.began_frame.load(Ordering::Relaxed);
            CaptureBegin {
                synced: r.began_synced.load(Ordering::Relaxed),
                camera_frame: (frame != u32::MAX).then_some(frame),
            }
        })
    }

    fn stop(&mut self) {
        let r = self.ring;
        r.locked(|| r.running.store(false, Ordering::Relaxed));
    }

    fn half_events(&self) -> u32 {
        self.ring.half_events.load(Ordering::Acquire)
    }

    fn write_index(&self) -> usize {
        self.ring.write_index.load(Ordering::Acquire) as usize
    }

    fn marks(&self) -> &FrameMarks {
        &self.ring.marks
    }

    /// No cache between the producer and this ring.
    fn invalidate_lines(&mut self, _first_line: usize, _count: usize) {}

    fn copy(&mut self, start: usize, out: &mut [u32]) {
        for (w, slot) in out.iter_mut().zip(&self.ring.words[start..]) {
            *w = slot.load(Ordering::Relaxed);
        }
    }

    fn register_waker(&mut self, waker: &Waker) {
        self.ring.waker.register(waker);
    }
}

/// The simulated camera as the device's pixel source: a [`DcmiSource`]
/// over a [`SoftRing`] that, when a capture starts, also tells the producer
/// the configured geometry.
pub struct SimulatedCamera<'r, 'b, const WORDS: usize> {
    ring: &'r SoftRing<WORDS>,
    source: DcmiSource<'b, SoftDma<'r, WORDS>>,
}

impl<'r, 'b, const WORDS: usize> SimulatedCamera<'r, 'b, WORDS> {
    /// `width`: the bus the producer packs pixels for ([`DataWidth::Bits16`]
    /// takes every bit depth); `words`, `pixels`: as for [`DcmiSource::new`].
    pub fn new(
        ring: &'r SoftRing<WORDS>,
        width: DataWidth,
        words: &'b mut [u32],
        pixels: &'b mut [u16],
    ) -> Self {
        SimulatedCamera {
            ring,
            source: DcmiSource::new(SoftDma::new(ring), width, words, pixels),
        }
    }

    pub fn stats(&self) -> CameraStats {
        self.source.stats()
    }
}

impl<const WORDS: usize> PixelSource for SimulatedCamera<'_, '_, WORDS> {
    fn kind(&self) -> PixelSourceKind {
        PixelSourceKind::Camera
    }

    fn check_crop(&self, camera: Camera, crop: Crop) -> Result<(), CropFault> {
        self.source.check_crop(camera, crop)
    }

    fn start(&mut self, camera: Camera, crop: Option<Crop>) -> Result<(), CameraRefused> {
        self.ring.set_camera(camera, crop);
        self.source.start(camera, crop)
    }

    fn set_start(&mut self, start: CaptureStart) -> Result<(), SyncFault> {
        self.source.set_start(start)
    }

    fn armed(&self) -> bool {
        self.source.armed()
    }

    fn stop(&mut self) {
        self.source.stop();
    }

    async fn next(&mut self) -> PixelRun<'_> {
        self.source.next().await
    }
}
