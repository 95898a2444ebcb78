//! The hand-over between a data path and the view: latest-value slots.
//!
//! A data path (stream, capture, a rig, the view's own sources) calls
//! [`Hub::offer`] for every frame. That costs a few atomic increments and
//! a clock read; only when the view's display period has passed since the
//! last sample does it copy the frame's results (and, less often, its
//! pixels) into a slot, replacing whatever was there. Nothing ever waits
//! for the view: a sample the page has not taken yet is overwritten (a
//! display frame dropped, never a data frame), and the slots' locks are
//! held only to swap an `Arc`.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use brightpix_protocol::wire::{SlopeEntry, Status};
use brightpix_protocol::{Camera, SubapertureWindow};
use serde::Serialize;

use crate::config_file::ProcessingConfig;

/// Shortest time between two samples of results: 60 Hz, above the page's
/// 25 Hz floor with margin, and at most 60 copies a second from a data path
/// of any rate.
pub const SAMPLE_PERIOD: Duration = Duration::from_micros(16_600);
/// Shortest time between two samples of pixels (a camera frame is far
/// larger than its results, and its selection is computed on the view's
/// side for every one shown).
pub const PIXEL_PERIOD: Duration = Duration::from_millis(100);

/// What the view shows about the run that does not change from frame to
/// frame: the geometry, N per window, the configuration's digest, where
/// the data come from. Replaced when the source reconfigures (a device
/// that came back).
#[derive(Clone, Debug)]
pub struct Setup {
    pub source: String,
    pub config_name: String,
    pub config: ProcessingConfig,
    pub digest: u32,
    /// Per rig board: its name and the sub-apertures it computes.
    pub boards: Vec<(String, Vec<usize>)>,
    /// Whether the source can show pixels at all (a capture from a real
    /// camera, or a replay without frames, cannot).
    pub pixels: bool,
}

impl Setup {
    pub fn new(source: String, config_name: String, config: ProcessingConfig) -> Setup {
        let digest = brightpix_protocol::wire::tables::config_digest(&config.view());
        Setup {
            source,
            config_name,
            config,
            digest,
            boards: Vec::new(),
            pixels: false,
        }
    }

    pub fn camera(&self) -> Camera {
        self.config.camera
    }

    pub fn windows(&self) -> &[SubapertureWindow] {
        &self.config.windows
    }
}

/// One frame's results, sampled.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    pub frame: u64,
    /// Per sub-aperture, `None` where the device sent nothing (a dropped
    /// frame's later windows, a rig board that gave nothing).
    pub results: Vec<Option<SlopeEntry>>,
}

/// One camera frame, sampled, with the frame number it belongs to.
#[derive(Clone, Debug, PartialEq)]
pub struct PixelSample {
    pub frame: u64,
    pub pixels: Vec<u16>,
}

/// A rig board's health line.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct BoardHealth {
    pub name: String,
    /// Predicted share of the board's cycles at the camera rate (0..1), if
    /// the rig file gives a rate.
    pub load: Option<f64>,
    pub frames_done: u64,
    pub frames_dropped: u64,
    pub error: Option<String>,
}

/// The device's counters as its last `Status` gave them, or a replay's.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Health {
    pub frames_processed: Option<u64>,
    pub frames_dropped: Option<u64>,
    pub crc_errors: Option<u32>,
    pub decode_errors: Option<u32>,
    pub overruns: Option<u32>,
    pub pixel_errors: Option<u32>,
    pub config_digest: Option<u32>,
    pub boards: Vec<BoardHealth>,
}

impl Health {
    pub fn from_status(status: &Status) -> Health {
        Health {
            frames_processed: Some(status.frames_processed),
            frames_dropped: Some(status.frames_dropped),
            crc_errors: Some(status.crc_errors),
            decode_errors: Some(status.decode_errors),
            overruns: Some(status.overruns),
            pixel_errors: Some(status.pixel_errors),
            config_digest: status.config_digest,
            boards: Vec::new(),
        }
    }
}

/// A value with a generation number, so that readers tell new from seen.
struct Slot<T> {
    value: Mutex<Option<Arc<T>>>,
    generation: AtomicU64,
}

impl<T> Default for Slot<T> {
    fn default() -> Self {
        Slot {
            value: Mutex::new(None),
            generation: AtomicU64::new(0),
        }
    }
}

impl<T> Slot<T> {
    fn put(&self, value: T) {
        let value = Arc::new(value);
        // Swapped under the lock, dropped (the old value) outside it.
        let old = lock(&self.value).replace(value);
        self.generation.fetch_add(1, Ordering::Release);
        drop(old);
    }

    fn clear(&self) {
        let old = lock(&self.value).take();
        self.generation.fetch_add(1, Ordering::Release);
        drop(old);
    }

    /// The value if its generation is not `seen`, with its generation.
    fn take_newer(&self, seen: u64) -> Option<(u64, Option<Arc<T>>)> {
        let generation = self.generation.load(Ordering::Acquire);
        if generation == seen {
            return None;
        }
        Some((generation, lock(&self.value).clone()))
    }
}

/// A poisoned lock still holds a whole value (every writer only swaps).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The latest of everything the view shows (see the module docs).
pub struct Hub {
    started: Instant,
    setup: Slot<Setup>,
    results: Slot<Sample>,
    pixels: Slot<PixelSample>,
    health: Slot<Health>,
    /// What is wrong, for the page's banner (`None`: nothing).
    message: Slot<Option<String>>,
    /// Frames offered and, of them, dropped (or incomplete): counted for
    /// every frame, not just the sampled ones.
    frames_seen: AtomicU64,
    frames_dropped: AtomicU64,
    /// Nanoseconds since `started` of the last results and pixel samples.
    last_sample: AtomicU64,
    last_pixels: AtomicU64,
}

impl Default for Hub {
    fn default() -> Self {
        Hub {
            started: Instant::now(),
            setup: Slot::default(),
            results: Slot::default(),
            pixels: Slot::default(),
            health: Slot::default(),
            message: Slot::default(),
            frames_seen: AtomicU64::new(0),
            frames_dropped: AtomicU64::new(0),
            last_sample: AtomicU64::new(0),
            last_pixels: AtomicU64::new(0),
        }
    }
}

/// What a reader last saw of each slot (all 0: nothing yet).
#[derive(Clone, Copy, Debug, Default)]
pub struct Seen {
    pub setup: u64,
    pub results: u64,
    pub pixels: u64,
    pub health: u64,
    pub message: u64,
}

impl Hub {
    pub fn new() -> Arc<Hub> {
        Arc::new(Hub::default())
    }

    /// A new geometry: the samples of the old one are cleared.
    pub fn set_setup(&self, setup: Setup) {
        self.results.clear();
        self.pixels.clear();
        self.setup.put(setup);
    }

    pub fn set_health(&self, health: Health) {
        self.health.put(health);
    }

    /// The banner: why nothing is coming (`None` once it comes again).
    pub fn set_message(&self, message: Option<String>) {
        self.message.put(message);
    }

    /// Called by the data path for every frame: `dropped` when the device
    /// dropped it (or left it incomplete). `results` and `pixels` are only
    /// called when a sample is due (see the module docs).
    pub fn offer(
        &self,
        frame: u64,
        dropped: bool,
        results: impl FnOnce() -> Vec<Option<SlopeEntry>>,
        pixels: Option<&[u16]>,
    ) {
        self.frames_seen.fetch_add(1, Ordering::Relaxed);
        if dropped {
            self.frames_dropped.fetch_add(1, Ordering::Relaxed);
        }
        let now = self.now();
        if due(&self.last_sample, now, SAMPLE_PERIOD) {
            self.results.put(Sample {
                frame,
                results: results(),
            });
        }
        if let Some(pixels) = pixels {
            if due(&self.last_pixels, now, PIXEL_PERIOD) {
                self.offer_pixels(frame, pixels.to_vec());
            }
        }
    }

    /// A camera frame made by the view's own side (e.g. regenerated from a
    /// simulated camera's seed), not taken from a data path.
    pub fn offer_pixels(&self, frame: u64, pixels: Vec<u16>) {
        self.pixels.put(PixelSample { frame, pixels });
    }

    /// Whether a pixel sample would be taken now: lets a source that must
    /// make its pixels (regenerate a simulated frame) skip the work.
    pub fn pixels_due(&self) -> bool {
        let now = self.now();
        let last = self.last_pixels.load(Ordering::Relaxed);
        now.saturating_sub(last) >= PIXEL_PERIOD.as_nanos() as u64 || last == 0
    }

    /// The frame number of the latest results sample, if any.
    pub fn latest_frame(&self) -> Option<u64> {
        lock(&self.results.value).as_ref().map(|s| s.frame)
    }

    pub fn frames_seen(&self) -> u64 {
        self.frames_seen.load(Ordering::Relaxed)
    }

    pub fn frames_dropped(&self) -> u64 {
        self.frames_dropped.load(Ordering::Relaxed)
    }

    pub fn setup_if_newer(&self, seen: &mut Seen) -> Option<Option<Arc<Setup>>> {
        let (g, v) = self.setup.take_newer(seen.setup)?;
        seen.setup = g;
        Some(v)
    }

    pub fn results_if_newer(&self, seen: &mut Seen) -> Option<Arc<Sample>> {
        let (g, v) = self.results.take_newer(seen.results)?;
        seen.results = g;
        v
    }

    pub fn pixels_if_newer(&self, seen: &mut Seen) -> Option<Arc<PixelSample>> {
        let (g, v) = self.pixels.take_newer(seen.pixels)?;
        seen.pixels = g;
        v
    }

    pub fn health_if_newer(&self, seen: &mut Seen) -> Option<Arc<Health>> {
        let (g, v) = self.health.take_newer(seen.health)?;
        seen.health = g;
        v
    }

    pub fn message_if_newer(&self, seen: &mut Seen) -> Option<Option<String>> {
        let (g, v) = self.message.take_newer(seen.message)?;
        seen.message = g;
        Some(v.and_then(|m| (*m).clone()))
    }

    fn now(&self) -> u64 {
        // Never 0, so that `last == 0` means "never sampled".
        self.started.elapsed().as_nanos() as u64 + 1
    }
}

/// Whether `period` has passed since `last` (then `last` becomes `now`).
/// A lost race between two data threads only skips one sample.
fn due(last: &AtomicU64, now: u64, period: Duration) -> bool {
    let before = last.load(Ordering::Relaxed);
    if before != 0 && now.saturating_sub(before) < period.as_nanos() as u64 {
        return false;
    }
    last.compare_exchange(before, now, Ordering::Relaxed, Ordering::Relaxed)
        .is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(index: u16) -> Option<SlopeEntry> {
        Some(SlopeEntry {
            index,
            slope_x: 1 << 16,
            slope_y: -(1 << 15),
            flux: 160,
            valid: true,
        })
    }

    #[test]
    fn the_latest_sample_wins_and_every_frame_is_counted() {
        let hub = Hub::new();
        let mut seen = Seen::default();
        assert!(hub.results_if_newer(&mut seen).is_none());
        let mut built = 0;
        // A fast data path: 1000 frames at once. Each is counted; results
        // are copied only when a sample is due (the first, here).
        for frame in 0..1000u64 {
            hub.offer(
                frame,
                frame % 10 == 0,
                || {
                    built += 1;
                    vec![entry(0)]
                },
                None,
            );
        }
        assert_eq!(hub.frames_seen(), 1000);
        assert_eq!(hub.frames_dropped(), 100);
        assert!((1..1000).contains(&built), "results copied {built} times");
        let sample = hub.results_if_newer(&mut seen).expect("a sample");
        assert_eq!(sample.results, vec![entry(0)]);
        // Nothing new until the next sample.
        assert!(hub.results_if_newer(&mut seen).is_none());
        std::thread::sleep(SAMPLE_PERIOD * 2);
        hub.offer(1000, false, || vec![entry(1)], None);
        let sample = hub.results_if_newer(&mut seen).expect("a newer sample");
        assert_eq!(
            (sample.frame, sample.results.clone()),
            (1000, vec![entry(1)])
        );
    }

    #[test]
    fn pixels_are_sampled_less_often_and_a_new_setup_clears_samples() {
        let hub = Hub::new();
        let mut seen = Seen::default();
        let frame = vec![7u16; 4];
        hub.offer(0, false, Vec::new, Some(&frame));
        hub.offer(1, false, Vec::new, Some(&[9u16; 4]));
        let p = hub.pixels_if_newer(&mut seen).expect("pixels");
        assert_eq!((p.frame, p.pixels.clone()), (0, frame));
        assert!(!hub.pixels_due());
        let config = crate::sil::canary_config();
        hub.set_setup(Setup::new("test".into(), "canary".into(), config));
        assert!(hub.setup_if_newer(&mut seen).is_some());
        assert!(hub.results_if_newer(&mut seen).is_none());
        assert!(hub.pixels_if_newer(&mut seen).is_none());
    }

    #[test]
    fn messages_come_and_go() {
        let hub = Hub::new();
        let mut seen = Seen::default();
        hub.set_message(Some("the device at /dev/pts/9 disappeared".into()));
        assert_eq!(
            hub.message_if_newer(&mut seen),
            Some(Some("the device at /dev/pts/9 disappeared".into()))
        );
        hub.set_message(None);
        assert_eq!(hub.message_if_newer(&mut seen), Some(None));
        assert_eq!(hub.message_if_newer(&mut seen), None);
    }
}
