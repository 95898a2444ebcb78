//! [`DcmiSource`]: pixel runs, in raster order, from a circular DMA buffer.

use core::future::poll_fn;
use core::task::Poll;

use brightpix_protocol::wire::{CaptureStart, CropFault, PixelSourceKind, SyncFault};
use brightpix_protocol::{Camera, Crop};

use super::crop::frame_check;
use super::packing::{as_pixels, unpack, DataWidth};
use super::ring::{
    distance, DmaProgress, DmaRing, Mark, CACHE_LINE_WORDS, MARK_SLOTS, MAX_HOLD_BACK_WORDS,
    RING_GRANULE_WORDS,
};
use crate::device::{CameraRefused, PixelRun, PixelSource};

/// What the camera source has seen since it was made (all captures).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CameraStats {
    /// Frames whose every pixel was delivered, their length confirmed by
    /// the frame-end mark.
    pub frames_delivered: u32,
    /// Frames not delivered whole, for any of the reasons below.
    pub frames_dropped: u32,
    /// Times the consumer fell more than the ring behind the DMA.
    pub overruns: u32,
    /// Frames whose length (from frame end to frame end) was not the
    /// configured geometry's: pixels lost or added on the bus, or a camera
    /// configured with another geometry than it sends.
    pub length_errors: u32,
    /// Times a frame's end mark was overwritten before it was read (the
    /// consumer was more than `MARK_SLOTS` frames behind).
    pub marks_lost: u32,
}

/// Steps of [`DcmiSource::take_run`] before it gives up for this poll.
const MAX_STEPS: usize = 4 * MARK_SLOTS + 16;

enum Step {
    /// A run: frame, first pixel, words at the start of the word buffer.
    Run(u32, u32, usize),
    /// Nothing to deliver until the next DMA or camera event.
    Wait,
    /// More to do, in another poll.
    Yield,
}

fn bump(counter: &mut u32, by: u32) {
    *counter = counter.saturating_add(by);
}

/// The frame being delivered.
#[derive(Clone, Copy, Debug)]
struct Run {
    /// Words in a frame of the configured geometry.
    frame_words: u32,
    /// Frame number (frames ended before it since the capture started).
    frame: u32,
    /// Position of its first word (words since the DMA started, wrapping).
    start: u32,
    /// Position of the next word to deliver.
    read: u32,
    /// Deliver no more of this frame (it is dropped and counted); wait for
    /// its end.
    skipping: bool,
    /// Deliver exactly one word, then skip the rest of the frame: after an
    /// overrun, a run past the expected pixel tells the device loop it lost
    /// data (see [`PixelRun`]).
    gap: bool,
    /// Words in a camera row, if a row is whole words (else 0): runs are
    /// cut at row ends ([`cut_at_row_end`]).
    row_words: u32,
}

/// The words of a run of `n` words that starts `offset` words into a frame
/// of rows of `row_words` words: all of them if the run reaches no row's
/// end after its first word or ends at one, else up to the last row end it
/// reaches. Nothing is held back (the rest is the next run, in the same
/// poll when its words are there): the engine takes whole rows by its fast
/// path and a row's pieces one at a time, so a run that crosses a row end
/// costs two pieces where the same words cut at the row end cost one.
pub const fn cut_at_row_end(offset: u32, n: u32, row_words: u32) -> u32 {
    let into_row = offset % row_words;
    let past = (into_row + n) % row_words;
    if into_row + n > row_words && past != 0 {
        n - past
    } else {
        n
    }
}

/// A [`PixelSource`] over a circular DMA buffer that a camera interface
/// (the STM32 DCMI) fills: it cuts the words the DMA has written into pixel
/// runs of whole frames, in raster order, as they arrive.
///
/// - Frames: the capture starts at a frame start (the DCMI waits for
///   VSYNC), and every frame is `width * height` pixels, so each frame's
///   start follows from the last. The frame-end interrupt's marks confirm
///   it: a frame whose end is not where its geometry puts it is dropped
///   (never completed) and the next starts at the mark (resync).
/// - The last word of a frame is held back until its end mark has
///   confirmed the length, so the device never completes a frame of the
///   wrong length.
/// - Overrun: words are copied out, then the DMA position is read again;
///   if the DMA may have overwritten any of them the copy is discarded.
///   The frame is dropped, and the source delivers one word of the newest
///   data at its real position (a gap the device loop counts as an
///   overrun), then carries on with the next frame.
/// - Cache: right before each copy, the D-cache lines holding exactly the
///   words about to be copied are invalidated ([`DmaRing::invalidate_lines`]),
///   see the module documentation.
///
/// Cancel-safe: all state lives in the struct, and a run is only taken
/// from the ring in the poll that returns it.
pub struct DcmiSource<'b, R> {
    ring: R,
    width: DataWidth,
    words: &'b mut [u32],
    pixels: &'b mut [u16],
    run: Option<Run>,
    /// No run of the running capture delivered yet: the next one carries
    /// how the capture began.
    first_run: bool,
    /// The capture waits to be armed (the sync line's modes): an empty
    /// run tells the device loop when it is.
    arming: bool,
    stats: CameraStats,
}

impl<'b, R: DmaRing> DcmiSource<'b, R> {
    /// A stopped source. `words` is where a run's words are copied out of
    /// the ring, `pixels` where they are unpacked: a run is at most
    /// `min(words.len(), pixels.len() / pixels_per_word)` words.
    ///
    /// Panics if the ring's length is not a positive multiple of
    /// [`RING_GRANULE_WORDS`] below 2^30, or the buffers hold no word.
    pub fn new(ring: R, width: DataWidth, words: &'b mut [u32], pixels: &'b mut [u16]) -> Self {
        let len = ring.capacity();
        assert!(
            len > 0 && len.is_multiple_of(RING_GRANULE_WORDS) && len < 1 << 30,
            "DMA ring length"
        );
        assert!(
            !words.is_empty() && pixels.len() >= width.pixels_per_word(),
            "run buffers"
        );
        DcmiSource {
            ring,
            width,
            words,
            pixels,
            run: None,
            first_run: false,
            arming: false,
            stats: CameraStats::default(),
        }
    }

    pub fn stats(&self) -> CameraStats {
        self.stats
    }

    pub fn data_width(&self) -> DataWidth {
        self.width
    }

    pub fn ring(&mut self) -> &mut R {
        &mut self.ring
    }

    /// Whether a capture is running.
    pub fn is_running(&self) -> bool {
        self.run.is_some()
    }

    fn chunk_words(&self) -> usize {
        self.words
            .len()
            .min(self.pixels.len() / self.width.pixels_per_word())
    }

    /// The DMA's position, and its index in the ring (positions wrap at
    /// 2^32, which a ring of any length does not divide: the index of a
    /// position is found from a nearby position's index). A reading at most
    /// [`MAX_HOLD_BACK_WORDS`] behind `floor` (words already read, so known
    /// to be written) is `floor`: a DMA FIFO's hold-back, not an overrun.
    fn now(&self, floor: u32) -> (u32, usize) {
        let progress = DmaProgress::of(&self.ring);
        let len = self.ring.capacity();
        let position = progress.position(len);
        let index = progress.write_index as usize % len;
        let back = distance(position, floor);
        if back > 0 && back <= MAX_HOLD_BACK_WORDS as i64 {
            return (floor, (index + back as usize) % len);
        }
        (position, index)
    }

    /// Takes the next run out of the ring: `(frame, first_pixel, pixels)`
    /// with the pixels at the start of `self.pixels`.
    fn take_run(&mut self) -> Step {
        let len = self.ring.capacity();
        // Farthest the DMA may be ahead of the next word to read: a ring,
        // less the words a reading may hold back (still in the DMA's FIFO,
        // so not counted, but written before the next reading: the words
        // they land on must not be ones being copied).
        let reach = (len - MAX_HOLD_BACK_WORDS) as i64;
        let per_word = self.width.pixels_per_word() as u32;
        // Each step either delivers, waits, or moves on to a later frame or
        // position; bounded all the same, against a ring that misbehaves.
        for _ in 0..MAX_STEPS {
            let Some(mut run) = self.run else {
                return Step::Wait;
            };
            let (now, now_index) = self.now(run.read);
            let end = run.start.wrapping_add(run.frame_words);
            let confirmed = match self.ring.marks().get(run.frame) {
                Mark::Lost => {
                    bump(&mut self.stats.marks_lost, 1);
                    if (0..=reach).contains(&distance(run.read, now)) {
                        self.resync(run, now);
                    } else {
                        self.overrun(run, now);
                    }
                    continue;
                }
                Mark::Pending if run.skipping => return Step::Wait,
                Mark::Pending => false,
                Mark::At(at) => {
                    let mark = at.position(len);
                    if run.skipping || mark != end {
                        if !run.skipping {
                            bump(&mut self.stats.length_errors, 1);
                        }
                        self.jump(run, run.frame.wrapping_add(1), mark);
                        continue;
                    }
                    true
                }
            };
            if confirmed && run.read == end {
                bump(&mut self.stats.frames_delivered, 1);
                run.frame = run.frame.wrapping_add(1);
                run.start = end;
                self.run = Some(run);
                continue;
            }
            let behind = distance(run.read, now);
            if !(0..=reach).contains(&behind) {
                self.overrun(run, now);
                continue;
            }
            // The frame's last word waits for its end mark.
            let limit = if confirmed { end } else { end.wrapping_sub(1) };
            let mut n = (behind as u32)
                .min(limit.wrapping_sub(run.read))
                .min(self.chunk_words() as u32) as usize;
            if run.gap {
                n = n.min(1);
            } else if run.row_words != 0 {
                n = cut_at_row_end(run.read.wrapping_sub(run.start), n as u32, run.row_words)
                    as usize;
            }
            if n == 0 {
                return Step::Wait;
            }
            // `behind` <= len words before the DMA's index.
            let index = (now_index + len - behind as usize) % len;
            self.copy(index, n);
            let (after, _) = self.now(run.read);
            if !(0..=reach).contains(&distance(run.read, after)) {
                // Some of those words may have been overwritten meanwhile.
                self.overrun(run, after);
                continue;
            }
            let first_pixel = run.read.wrapping_sub(run.start).wrapping_mul(per_word);
            let frame = run.frame;
            run.read = run.read.wrapping_add(n as u32);
            if run.gap {
                run.gap = false;
                run.skipping = true;
                bump(&mut self.stats.frames_dropped, 1);
            } else if confirmed && run.read == end {
                bump(&mut self.stats.frames_delivered, 1);
                run.frame = run.frame.wrapping_add(1);
                run.start = end;
            }
            self.run = Some(run);
            return Step::Run(frame, first_pixel, n);
        }
        Step::Yield
    }

    /// Copies `n` words from ring index `index` on (wrapping) into
    /// `self.words`, invalidating their cache lines first.
    fn copy(&mut self, index: usize, n: usize) {
        let len = self.ring.capacity();
        let first = n.min(len - index);
        for (start, out) in [(index, 0..first), (0, first..n)] {
            let count = out.len();
            if count == 0 {
                continue;
            }
            let first_line = start / CACHE_LINE_WORDS;
            let end_line = (start + count).div_ceil(CACHE_LINE_WORDS);
            self.ring
                .invalidate_lines(first_line, end_line - first_line);
            self.ring.copy(start, &mut self.words[out]);
        }
    }

    /// Leaves frame `run.frame` (dropped unless already counted) and the
    /// frames before `frame` for frame `frame`, which starts at `start`.
    fn jump(&mut self, run: Run, frame: u32, start: u32) {
        let skipped = frame.wrapping_sub(run.frame);
        // The current frame was counted when it started skipping.
        bump(
            &mut self.stats.frames_dropped,
            skipped.saturating_sub(run.skipping as u32),
        );
        self.run = Some(Run {
            frame,
            start,
            read: start,
            skipping: false,
            gap: false,
            ..run
        });
    }

    /// The consumer fell behind by more than the ring at `now`.
    fn overrun(&mut self, run: Run, now: u32) {
        bump(&mut self.stats.overruns, 1);
        // Deliver the newest whole word (the DMA needs a whole ring to
        // reach it again) at its real place: a gap for the device loop.
        let newest = now.wrapping_sub(1);
        match self.locate(run, newest) {
            Some((frame, start)) => {
                self.jump(run, frame, start);
                let offset = distance(start, newest);
                let run = self.run.as_mut().expect("set by jump");
                if offset > 0 && offset < run.frame_words as i64 {
                    run.read = newest;
                    run.gap = true;
                } else if offset != 0 {
                    // Not a word of this frame as configured (it runs long,
                    // or the ring misbehaves): wait for the frame's end.
                    run.skipping = true;
                    bump(&mut self.stats.frames_dropped, 1);
                }
            }
            None => self.resync(run, now),
        }
    }

    /// The frame holding the word at `position` and its start, from the
    /// marks; `None` if the marks needed are lost.
    fn locate(&self, run: Run, position: u32) -> Option<(u32, u32)> {
        let marks = self.ring.marks();
        let len = self.ring.capacity();
        let mut frame = marks.ended();
        // Frames from the newest back to the current one.
        while distance(run.frame, frame) > 0 {
            let before = frame.wrapping_sub(1);
            match marks.get(before) {
                Mark::At(at) => {
                    let end = at.position(len);
                    if distance(end, position) >= 0 {
                        return Some((frame, end));
                    }
                }
                Mark::Lost | Mark::Pending => return None,
            }
            frame = before;
        }
        Some((run.frame, run.start))
    }

    /// Drops everything up to the frame in progress at the newest mark:
    /// delivers it from its start if that is still in the ring, or else
    /// waits for the next frame.
    fn resync(&mut self, run: Run, now: u32) {
        let marks = self.ring.marks();
        let ended = marks.ended();
        let newest = ended.wrapping_sub(1);
        match marks.get(newest) {
            Mark::At(at) if distance(run.frame, ended) > 0 => {
                let start = at.position(self.ring.capacity());
                self.jump(run, ended, start);
                if !(0..=self.ring.capacity() as i64).contains(&distance(start, now)) {
                    let run = self.run.as_mut().expect("set by jump");
                    run.skipping = true;
                    bump(&mut self.stats.frames_dropped, 1);
                }
            }
            _ => {
                // No newer mark (or it was rewritten just now): skip the
                // current frame and try again at its end.
                let mut run = run;
                if !run.skipping {
                    run.skipping = true;
                    bump(&mut self.stats.frames_dropped, 1);
                }
                self.run = Some(run);
            }
        }
    }
}

impl<R: DmaRing> PixelSource for DcmiSource<'_, R> {
    fn kind(&self) -> PixelSourceKind {
        PixelSourceKind::Camera
    }

    /// A frame of the rectangle must be whole words of the bus, and the
    /// ring's camera interface able to crop it.
    fn check_crop(&self, camera: Camera, crop: Crop) -> Result<(), CropFault> {
        frame_check(camera, self.width.pixels_per_word())?;
        self.ring.check_crop(camera, crop)
    }

    /// Starts the DMA and the camera interface for frames of `camera`'s
    /// geometry, cropped at `crop` of the sensor if given. Refused if the
    /// camera's bit depth is above the interface's data width, a frame is
    /// not a whole number of 32-bit words, or the interface cannot crop
    /// the rectangle.
    fn start(&mut self, camera: Camera, crop: Option<Crop>) -> Result<(), CameraRefused> {
        let per_word = self.width.pixels_per_word();
        let pixels = camera.pixel_count();
        if camera.bit_depth > self.width.bits() || pixels == 0 || !pixels.is_multiple_of(per_word) {
            return Err(CameraRefused);
        }
        if let Some(crop) = crop {
            self.check_crop(camera, crop).map_err(|_| CameraRefused)?;
        }
        if self.run.is_some() {
            self.ring.stop();
        }
        self.ring.set_crop(camera, crop);
        self.ring.marks().reset();
        let origin = DmaProgress {
            half_events: self.ring.start(),
            write_index: 0,
        }
        .position(self.ring.capacity());
        self.run = Some(Run {
            frame_words: (pixels / per_word) as u32,
            frame: 0,
            start: origin,
            read: origin,
            skipping: false,
            gap: false,
            row_words: if (camera.width as usize).is_multiple_of(per_word) {
                (camera.width as usize / per_word) as u32
            } else {
                0
            },
        });
        self.first_run = true;
        self.arming = !self.ring.armed();
        Ok(())
    }

    fn set_start(&mut self, start: CaptureStart) -> Result<(), SyncFault> {
        self.ring.set_start(start)
    }

    fn armed(&self) -> bool {
        self.ring.armed()
    }

    fn stop(&mut self) {
        if self.run.take().is_some() {
            self.ring.stop();
        }
    }

    /// Besides pixels: one empty run when a capture that waited to be
    /// armed is (the device loop then acknowledges it).
    async fn next(&mut self) -> PixelRun<'_> {
        let (frame, first_pixel, words) = poll_fn(|cx| {
            if self.run.is_none() {
                // Stopped: only `start` (from the device loop, which then
                // polls a new future) changes that.
                return Poll::Pending;
            }
            // Register before looking, so an event in between still wakes.
            self.ring.register_waker(cx.waker());
            if self.arming {
                if !self.ring.armed() {
                    return Poll::Pending;
                }
                self.arming = false;
                return Poll::Ready((0, 0, 0));
            }
            match self.take_run() {
                Step::Run(frame, first_pixel, n) => Poll::Ready((frame, first_pixel, n)),
                Step::Wait => Poll::Pending,
                Step::Yield => {
                    cx.waker().wake_by_ref();
                    Poll::Pending
                }
            }
        })
        .await;
        // The ring said how the capture began before its first word.
        let began = (words > 0 && core::mem::take(&mut self.first_run)).then(|| self.ring.began());
        let words = &self.words[..words];
        let pixels = match as_pixels(self.width, words) {
            Some(pixels) => pixels,
            None => {
                let n = unpack(self.width, words, self.pixels);
                &self.pixels[..n]
            }
        };
        PixelRun {
            frame,
            first_pixel,
            pixels,
            began,
        }
    }
}
