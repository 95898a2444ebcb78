//! The circular DMA buffer as the camera source sees it: where the DMA is,
//! where frames ended, and the cache maintenance hook.

use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Waker;

use brightpix_protocol::wire::{CaptureStart, CropFault, SyncFault};
use brightpix_protocol::{Camera, Crop};

/// Bytes in one Cortex-M7 D-cache line.
pub const CACHE_LINE_BYTES: usize = 32;
/// 32-bit words in one D-cache line.
pub const CACHE_LINE_WORDS: usize = CACHE_LINE_BYTES / 4;
/// The ring's length (in words) must be a multiple of this: each half of
/// the ring is then a whole number of cache lines.
pub const RING_GRANULE_WORDS: usize = 2 * CACHE_LINE_WORDS;

/// A circular DMA buffer that a camera interface fills with 32-bit words,
/// seen through the few things the camera source needs. Implemented by the
/// board over the DMA registers, and by simulations on the host.
///
/// Requirements on the implementation:
/// - the ring is [`capacity`](Self::capacity) words, 32-byte aligned, a multiple
///   of [`RING_GRANULE_WORDS`], and nothing else shares its cache lines;
/// - [`half_events`](Self::half_events) counts the DMA's half-transfer and
///   transfer-complete events (each one more half of the ring written) and
///   lags the DMA by at most one event: the interrupt that counts them has
///   the highest priority and is short;
/// - [`write_index`](Self::write_index) only counts words that are already in
///   memory (a DMA with a FIFO overrides [`progress`](Self::progress)
///   instead, see [`DmaProgress::through_fifo`]); successive readings may go
///   back by at most [`MAX_HOLD_BACK_WORDS`];
/// - the frame-end interrupt records each frame's end in
///   [`marks`](Self::marks) while the camera is between frames (vertical
///   blanking), after the camera interface's FIFO has drained.
pub trait DmaRing {
    /// Words in the ring.
    fn capacity(&self) -> usize;

    /// Starts (or restarts) the DMA at word 0 of the ring, then the camera
    /// interface (which begins with the next frame). Before the DMA starts,
    /// no line of the ring may be left in the D-cache (invalidate it whole:
    /// a dirty line left by start-up code, evicted later, would overwrite
    /// what the DMA wrote). Returns the value of
    /// [`half_events`](Self::half_events) at that moment, which must be even.
    fn start(&mut self) -> u32;

    /// Stops the camera interface and the DMA.
    fn stop(&mut self);

    /// Half-ring events (half-transfer and transfer-complete) counted so
    /// far; wraps.
    fn half_events(&self) -> u32;

    /// Index (`0..capacity`) of the word the DMA writes next (`capacity - NDTR`).
    fn write_index(&self) -> usize;

    /// Frame ends, recorded by the frame-end interrupt.
    fn marks(&self) -> &FrameMarks;

    /// A consistent reading of where the DMA is. The default reads the
    /// event count around [`write_index`](Self::write_index); a DMA whose
    /// FIFO may still hold counted words overrides it with
    /// [`DmaProgress::through_fifo`], whose reading may lie just behind the
    /// last counted half (which an index alone cannot say).
    fn progress(&self) -> DmaProgress {
        DmaProgress::read(|| self.half_events(), || self.write_index())
    }

    /// Invalidates the D-cache lines `first_line .. first_line + count` of
    /// the ring (line `k` holds words `8k .. 8k + 8`). Called right before
    /// those words are copied; a no-op without a D-cache.
    fn invalidate_lines(&mut self, first_line: usize, count: usize);

    /// Copies words `start .. start + out.len()` of the ring (no wrap).
    fn copy(&mut self, start: usize, out: &mut [u32]);

    /// Wakes `waker` at the next DMA or camera event (half/full transfer,
    /// frame end, and optionally every few lines).
    fn register_waker(&mut self, waker: &Waker);

    /// Why the camera interface cannot crop `camera` (a configuration's
    /// camera: the rectangle) at `crop` of its sensor. By default any
    /// rectangle: a simulated camera crops in software
    /// ([`SensorCrop`](super::crop::SensorCrop)); the source checks that
    /// frames are whole words.
    fn check_crop(&self, camera: Camera, crop: Crop) -> Result<(), CropFault> {
        let _ = (camera, crop);
        Ok(())
    }

    /// The crop the next [`start`](Self::start) captures (`None`: the whole
    /// sensor, `camera`). By default nothing: a simulated camera's producer
    /// learns it from its ring and crops.
    fn set_crop(&mut self, camera: Camera, crop: Option<Crop>) {
        let _ = (camera, crop);
    }

    /// How the next [`start`](Self::start) begins: at once (the camera
    /// interface takes the next frame start), or on the rig's sync line
    /// (the board's glue enables the capture from the line's edge: see
    /// `PixelSource::set_start`). By default no sync line.
    fn set_start(&mut self, start: CaptureStart) -> Result<(), SyncFault> {
        match start {
            CaptureStart::Immediate => Ok(()),
            CaptureStart::OnSync | CaptureStart::DriveSync => Err(SyncFault::NoSyncLine),
        }
    }

    /// Whether the capture [`start`](Self::start)ed last is armed
    /// (`PixelSource::armed`). By default at once.
    fn armed(&self) -> bool {
        true
    }

    /// How the running capture's first frame began (`PixelSource::began`).
    fn began(&self) -> crate::device::CaptureBegin {
        crate::device::CaptureBegin::default()
    }
}

/// Where the DMA was at one moment: half-ring events counted and the index
/// of the next word.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DmaProgress {
    pub half_events: u32,
    pub write_index: u32,
}

impl DmaProgress {
    /// A consistent reading: the event count before and after the index
    /// must agree (an event counted in between means the index may belong
    /// to either side, so read again).
    pub fn read(half_events: impl Fn() -> u32, write_index: impl Fn() -> usize) -> Self {
        loop {
            let before = half_events();
            let index = write_index();
            if half_events() == before {
                return DmaProgress {
                    half_events: before,
                    write_index: index as u32,
                };
            }
        }
    }

    /// A consistent reading of `ring`.
    pub fn of(ring: &impl DmaRing) -> Self {
        ring.progress()
    }

    /// A consistent reading of a circular DMA stream with a FIFO of
    /// `fifo_words` words between the peripheral and memory (the
    /// STM32H743's DMA1 in FIFO mode: 4 words), from its registers:
    /// `ndtr` (words left before the reload: `len - ndtr` words read from
    /// the peripheral), `fifo_empty` (read after `ndtr`) and the half
    /// events counted by the interrupt, read before and after.
    ///
    /// NDTR counts words read from the peripheral, up to `fifo_words` of
    /// which may still be in the FIFO. If the FIFO reads empty after NDTR,
    /// every word NDTR counted is in memory; otherwise the reading is held
    /// back by a whole FIFO. That may put it behind the last half the
    /// interrupt counted, when the half-transfer flag was raised as NDTR
    /// crossed the half, before the FIFO's last burst landed (RM0433 says
    /// transfer-complete waits for the FIFO in peripheral-to-memory mode,
    /// and says nothing of half-transfer): the reading is then given
    /// against the event before, which [`position`](Self::position)
    /// computes exactly. Clamping to the counted half instead (as the board
    /// once did) claims up to `fifo_words` words not yet written, which a
    /// host model of the DMA found (`tests/tests/camera_dma_fifo.rs`).
    ///
    /// A reading held back may lie up to `fifo_words` before an earlier
    /// exact one (FIFO empty then, not now): [`MAX_HOLD_BACK_WORDS`].
    pub fn through_fifo(
        half_events: impl Fn() -> u32,
        ndtr: impl Fn() -> usize,
        fifo_empty: impl Fn() -> bool,
        len: usize,
        fifo_words: usize,
    ) -> Self {
        debug_assert!(fifo_words <= MAX_HOLD_BACK_WORDS && fifo_words <= len / 2);
        loop {
            let before = half_events();
            let ndt = ndtr();
            let empty = fifo_empty();
            // Reads of the ring that follow must not be hoisted above these.
            core::sync::atomic::fence(Ordering::Acquire);
            if half_events() != before {
                continue;
            }
            // NDTR counts down from `len` and reloads at 0 (circular mode).
            let index = (len - ndt.min(len)) % len;
            if empty {
                return DmaProgress {
                    half_events: before,
                    write_index: index as u32,
                };
            }
            let half = len / 2;
            let counted_index = (before as usize & 1) * half;
            let beyond = (index + len - counted_index) % len;
            let held = (index + len - fifo_words) % len;
            // Behind the counted half: the same position, counted from the
            // half before.
            let events = if beyond < fifo_words {
                before.wrapping_sub(1)
            } else {
                before
            };
            return DmaProgress {
                half_events: events,
                write_index: held as u32,
            };
        }
    }

    /// Words written since the DMA started, modulo 2^32, for a ring of
    /// `len` words, counting from `start_events * len / 2` (the value
    /// [`DmaRing::start`] returned).
    ///
    /// `half_events * len / 2` words were written at least; the index gives
    /// the rest. This is exact as long as at most one event is not yet
    /// counted (the DMA is less than one half past the last counted event),
    /// which covers an event that happened but whose interrupt has not run.
    pub fn position(self, len: usize) -> u32 {
        let len = len as u32;
        let half = len / 2;
        let counted = self.half_events.wrapping_mul(half);
        let counted_index = (self.half_events & 1) * half;
        let beyond = (self.write_index % len + len - counted_index) % len;
        counted.wrapping_add(beyond)
    }
}

/// Copies `out.len()` words of a DMA ring from `from` on into `out`: a
/// board's [`DmaRing::copy`], once the camera source knows the DMA has
/// written them. Each word is read once, as it is then (the DMA writes
/// this memory outside the program's knowledge): on Cortex-M the engine's
/// word copy, eight words a load (`engine::prefilter::copy_words_from`;
/// a volatile read per word cost the STM32H743's camera path 0.88
/// instructions a pixel more on Cortex-M4, the bench's
/// `canary-12bit-dcmi`: 16.81 against 15.93 before the pixels were read in
/// place, `packing::as_pixels`).
///
/// # Safety
/// `from` is aligned and valid for reads of `out.len()` words.
#[inline(always)]
pub unsafe fn copy_from_ring(from: *const u32, out: &mut [u32]) {
    // SAFETY: the caller's contract.
    unsafe { crate::engine::prefilter::copy_words_from(from, out) }
}

/// How far a reading of [`DmaRing::progress`] may go back from an earlier
/// one: a DMA FIFO's words, counted once they are in memory (FIFO empty) and
/// held back at the next reading (FIFO not empty). The camera source takes
/// such a step back as "nothing new", not as an overrun.
pub const MAX_HOLD_BACK_WORDS: usize = 4;

/// `later - earlier` for positions that wrap, as a signed distance.
pub(crate) fn distance(earlier: u32, later: u32) -> i64 {
    later.wrapping_sub(earlier) as i32 as i64
}

/// Frame-end marks kept for this many frames.
pub const MARK_SLOTS: usize = 16;

/// What [`FrameMarks::get`] knows of a frame's end.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    /// The frame ended when the DMA was here.
    At(DmaProgress),
    /// Not ended yet.
    Pending,
    /// Ended more than [`MARK_SLOTS`] frames ago: the mark is gone.
    Lost,
}

/// Where the last [`MARK_SLOTS`] frames ended, recorded by the frame-end
/// interrupt (one producer), read by the camera source in thread mode (one
/// consumer), without locks: each slot is stamped with its frame's number,
/// and a reader that finds the stamp changed under it knows the slot was
/// rewritten.
pub struct FrameMarks {
    /// Frames ended since the capture started.
    ended: AtomicU32,
    slots: [MarkSlot; MARK_SLOTS],
}

struct MarkSlot {
    /// The frame whose end this slot holds; any other value while it is
    /// being written.
    frame: AtomicU32,
    half_events: AtomicU32,
    write_index: AtomicU32,
}

impl MarkSlot {
    const fn new(frame: u32) -> Self {
        MarkSlot {
            frame: AtomicU32::new(frame),
            half_events: AtomicU32::new(0),
            write_index: AtomicU32::new(0),
        }
    }
}

impl FrameMarks {
    pub const fn new() -> Self {
        // Slot k may hold frames k, k + MARK_SLOTS, ...: mark it as holding
        // frame k + 1, which never maps to it.
        let mut slots = [const { MarkSlot::new(1) }; MARK_SLOTS];
        let mut k = 0;
        while k < MARK_SLOTS {
            slots[k] = MarkSlot::new(k as u32 + 1);
            k += 1;
        }
        FrameMarks {
            ended: AtomicU32::new(0),
            slots,
        }
    }

    /// Forgets all marks; the next frame to end is frame 0. Only while the
    /// producer is stopped.
    pub fn reset(&self) {
        for (k, slot) in self.slots.iter().enumerate() {
            slot.frame.store(k as u32 + 1, Ordering::Relaxed);
        }
        self.ended.store(0, Ordering::Release);
    }

    /// Records that the next frame ended at `at` (the producer: the
    /// frame-end interrupt).
    pub fn record(&self, at: DmaProgress) {
        let frame = self.ended.load(Ordering::Relaxed);
        let slot = &self.slots[frame as usize % MARK_SLOTS];
        // A stamp that never maps to this slot: "being written".
        slot.frame.store(frame.wrapping_add(1), Ordering::Relaxed);
        core::sync::atomic::fence(Ordering::Release);
        slot.half_events.store(at.half_events, Ordering::Relaxed);
        slot.write_index.store(at.write_index, Ordering::Relaxed);
        slot.frame.store(frame, Ordering::Release);
        self.ended.store(frame.wrapping_add(1), Ordering::Release);
    }

    /// Frames ended since the capture started (wraps).
    pub fn ended(&self) -> u32 {
        self.ended.load(Ordering::Acquire)
    }

    /// Where frame `frame` (counted from 0 since the capture started) ended.
    pub fn get(&self, frame: u32) -> Mark {
        let ended = self.ended();
        let age = ended.wrapping_sub(frame);
        if age == 0 || age > u32::MAX / 2 {
            return Mark::Pending;
        }
        if age as usize > MARK_SLOTS {
            return Mark::Lost;
        }
        let slot = &self.slots[frame as usize % MARK_SLOTS];
        if slot.frame.load(Ordering::Acquire) != frame {
            return Mark::Lost;
        }
        let at = DmaProgress {
            half_events: slot.half_events.load(Ordering::Relaxed),
            write_index: slot.write_index.load(Ordering::Relaxed),
        };
        core::sync::atomic::fence(Ordering::Acquire);
        if slot.frame.load(Ordering::Relaxed) != frame {
            // Rewritten while we read it (the producer is MARK_SLOTS ahead).
            return Mark::Lost;
        }
        Mark::At(at)
    }
}

impl Default for FrameMarks {
    fn default() -> Self {
        Self::new()
    }
}
