//! A simulated DCMI + circular DMA + Cortex-M7 D-cache, for testing the
//! firmware's camera source (`brightpix_firmware::camera`) on the host.
//!
//! - The camera: a queue of 32-bit words (frames packed as the DCMI packs
//!   them) and frame ends.
//! - The DMA: writes those words into the ring, memory only (behind the
//!   cache); counts half events like the board's interrupt, optionally one
//!   event late (an interrupt that has not run yet), and records frame ends
//!   in the real `FrameMarks` the way the frame-end interrupt does.
//! - The D-cache: 8-word lines; a read of a line that is not cached fills
//!   it from memory, and later reads see the cached (possibly stale) copy
//!   until the line is invalidated. Lines are also filled at random times
//!   (the M7's speculative reads). A source that forgets to invalidate, or
//!   invalidates too early, reads stale words.
//! - Races: the DMA can write more words in the middle of a copy, and the
//!   half-event counter can change between the two reads of a snapshot.
#![allow(dead_code)]

use std::cell::RefCell;
use std::collections::VecDeque;
use std::future::Future;
use std::pin::pin;
use std::rc::Rc;
use std::task::{Context, Poll, Waker};

use brightpix_firmware::camera::packing::pack;
use brightpix_firmware::camera::{
    DataWidth, DcmiSource, DmaProgress, DmaRing, FrameMarks, CACHE_LINE_WORDS,
};
use brightpix_firmware::device::PixelSource;

/// A small deterministic generator (xorshift64).
#[derive(Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// Uniform in `lo..=hi`.
    pub fn range(&mut self, lo: usize, hi: usize) -> usize {
        lo + (self.next() % (hi - lo + 1) as u64) as usize
    }
    pub fn chance(&mut self, percent: u64) -> bool {
        self.next() % 100 < percent
    }
}

enum Item {
    Word(u32),
    FrameEnd,
}

/// What the simulated hardware does besides writing words.
#[derive(Clone, Copy, Debug, Default)]
pub struct Behaviour {
    /// The half-event interrupt runs late: an event stays uncounted until
    /// the next event, or until a read of the DMA index (half the time).
    pub late_events: bool,
    /// Words the DMA writes in the middle of each copy.
    pub race_words: usize,
    /// Percent chance, per word written, that some line of the ring is
    /// filled into the cache (speculative read).
    pub speculate_percent: u64,
    /// `half_events` at start (even); positions then wrap 2^32 early on.
    pub start_events: u32,
    /// Readings go through `DmaProgress::through_fifo` (the STM32H743's),
    /// the FIFO reading not empty at random while words are coming: held
    /// back by 4 words, sometimes behind an earlier exact reading.
    pub fifo_hold_back: bool,
}

pub struct SimState {
    capacity: usize,
    memory: Vec<u32>,
    cache: Vec<Option<[u32; CACHE_LINE_WORDS]>>,
    /// Words written since the DMA started.
    pub written: u64,
    /// Half events that happened / that the "interrupt" has counted.
    happened: u64,
    counted: u64,
    pub behaviour: Behaviour,
    pub running: bool,
    feed: VecDeque<Item>,
    rng: Rng,
    /// Lines invalidated, words copied.
    pub lines_invalidated: u64,
    pub words_copied: u64,
    pub starts: u32,
    /// Words the DMA writes in the middle of the next copy only.
    pub race_once: usize,
    pub waker: Option<Waker>,
    marks: Rc<FrameMarks>,
}

/// The [`DmaRing`] the source owns; the test keeps another handle.
#[derive(Clone)]
pub struct SimRing {
    pub state: Rc<RefCell<SimState>>,
    marks: Rc<FrameMarks>,
}

impl SimRing {
    pub fn new(capacity: usize, behaviour: Behaviour, seed: u64) -> Self {
        assert_eq!(behaviour.start_events % 2, 0);
        let marks = Rc::new(FrameMarks::new());
        let state = SimState {
            capacity,
            memory: vec![0xDEAD_BEEF; capacity],
            cache: vec![None; capacity / CACHE_LINE_WORDS],
            written: 0,
            happened: 0,
            counted: 0,
            behaviour,
            running: false,
            feed: VecDeque::new(),
            rng: Rng::new(seed),
            lines_invalidated: 0,
            words_copied: 0,
            starts: 0,
            race_once: 0,
            waker: None,
            marks: marks.clone(),
        };
        SimRing {
            state: Rc::new(RefCell::new(state)),
            marks,
        }
    }

    /// Queues words the camera sends, then the frame's end.
    pub fn send_frame_words(&self, words: &[u32]) {
        let mut s = self.state.borrow_mut();
        s.feed.extend(words.iter().map(|&w| Item::Word(w)));
        s.feed.push_back(Item::FrameEnd);
    }

    /// Queues a frame of pixels, packed as the DCMI packs them.
    pub fn send_frame(&self, width: DataWidth, pixels: &[u16]) {
        let mut words = vec![0; pixels.len() / width.pixels_per_word()];
        pack(width, pixels, &mut words);
        self.send_frame_words(&words);
    }

    /// Words the camera has queued and the DMA not yet written.
    pub fn queued(&self) -> usize {
        self.state
            .borrow()
            .feed
            .iter()
            .filter(|i| matches!(i, Item::Word(_)))
            .count()
    }

    pub fn idle(&self) -> bool {
        self.state.borrow().feed.is_empty()
    }

    /// The DMA writes up to `words` more words (frame ends are recorded as
    /// they are reached, and take no time).
    pub fn advance(&self, words: usize) {
        self.state.borrow_mut().advance(words);
    }

    pub fn written(&self) -> u64 {
        self.state.borrow().written
    }
}

impl SimState {
    fn half(&self) -> usize {
        self.capacity / 2
    }

    fn advance(&mut self, words: usize) {
        if !self.running {
            return;
        }
        let mut left = words;
        loop {
            // Frame ends at the front are recorded at once (blanking).
            while let Some(Item::FrameEnd) = self.feed.front() {
                self.feed.pop_front();
                let at = DmaProgress {
                    half_events: self.events_seen(),
                    write_index: (self.written % self.capacity as u64) as u32,
                };
                self.marks.record(at);
                self.wake();
            }
            if left == 0 {
                break;
            }
            let Some(Item::Word(w)) = self.feed.pop_front() else {
                break;
            };
            let index = (self.written % self.capacity as u64) as usize;
            self.memory[index] = w;
            self.written += 1;
            left -= 1;
            if self.written.is_multiple_of(self.half() as u64) {
                self.happened += 1;
                if self.behaviour.late_events {
                    // The previous event's interrupt has run by now; this
                    // one is pending.
                    self.counted = self.happened - 1;
                } else {
                    self.counted = self.happened;
                }
                self.wake();
            }
            if self.behaviour.speculate_percent > 0
                && self.rng.chance(self.behaviour.speculate_percent)
            {
                // Speculatively fill a line: often the one being written.
                let lines = self.cache.len();
                let line = if self.rng.chance(50) {
                    index / CACHE_LINE_WORDS
                } else {
                    self.rng.range(0, lines - 1)
                };
                self.fill(line);
            }
        }
    }

    fn events_seen(&self) -> u32 {
        self.behaviour
            .start_events
            .wrapping_add(self.counted as u32)
    }

    fn fill(&mut self, line: usize) {
        let base = line * CACHE_LINE_WORDS;
        let mut data = [0; CACHE_LINE_WORDS];
        data.copy_from_slice(&self.memory[base..base + CACHE_LINE_WORDS]);
        self.cache[line] = Some(data);
    }

    fn read(&mut self, index: usize) -> u32 {
        let line = index / CACHE_LINE_WORDS;
        if self.cache[line].is_none() {
            self.fill(line);
        }
        self.cache[line].unwrap()[index % CACHE_LINE_WORDS]
    }

    fn wake(&mut self) {
        if let Some(w) = self.waker.take() {
            w.wake();
        }
    }
}

impl DmaRing for SimRing {
    fn capacity(&self) -> usize {
        self.state.borrow().capacity
    }

    fn start(&mut self) -> u32 {
        let mut s = self.state.borrow_mut();
        s.running = true;
        // The camera interface starts at the next frame start: what was
        // queued before is not captured.
        s.feed.clear();
        s.written = 0;
        s.happened = 0;
        s.counted = 0;
        s.starts += 1;
        s.behaviour.start_events
    }

    fn stop(&mut self) {
        self.state.borrow_mut().running = false;
    }

    fn half_events(&self) -> u32 {
        self.state.borrow().events_seen()
    }

    fn write_index(&self) -> usize {
        let mut s = self.state.borrow_mut();
        // A late interrupt may run right here, between the two reads of
        // the event count around this one.
        if s.counted < s.happened && s.rng.chance(50) {
            s.counted = s.happened;
        }
        (s.written % s.capacity as u64) as usize
    }

    fn marks(&self) -> &FrameMarks {
        &self.marks
    }

    fn progress(&self) -> DmaProgress {
        if !self.state.borrow().behaviour.fifo_hold_back {
            return DmaProgress::read(|| self.half_events(), || self.write_index());
        }
        let capacity = self.capacity();
        DmaProgress::through_fifo(
            || self.half_events(),
            || capacity - self.write_index(),
            || {
                let mut s = self.state.borrow_mut();
                // Words still coming may sit in the FIFO; in blanking it
                // has drained.
                !(matches!(s.feed.front(), Some(Item::Word(_))) && s.rng.chance(50))
            },
            capacity,
            4,
        )
    }

    fn invalidate_lines(&mut self, first_line: usize, count: usize) {
        let mut s = self.state.borrow_mut();
        assert!(count > 0 && first_line + count <= s.cache.len());
        for line in &mut s.cache[first_line..first_line + count] {
            *line = None;
        }
        s.lines_invalidated += count as u64;
    }

    fn copy(&mut self, start: usize, out: &mut [u32]) {
        let mut s = self.state.borrow_mut();
        assert!(start + out.len() <= s.capacity);
        let race_at = out.len() / 2;
        for (k, w) in out.iter_mut().enumerate() {
            if k == race_at {
                let n = s.behaviour.race_words + std::mem::take(&mut s.race_once);
                s.advance(n);
            }
            *w = s.read(start + k);
        }
        s.words_copied += out.len() as u64;
    }

    fn register_waker(&mut self, waker: &Waker) {
        self.state.borrow_mut().waker = Some(waker.clone());
    }
}

/// A ring that ignores invalidation: to show the cache model catches it.
#[derive(Clone)]
pub struct NoInvalidate(pub SimRing);

impl DmaRing for NoInvalidate {
    fn capacity(&self) -> usize {
        self.0.capacity()
    }
    fn start(&mut self) -> u32 {
        self.0.start()
    }
    fn stop(&mut self) {
        self.0.stop()
    }
    fn half_events(&self) -> u32 {
        self.0.half_events()
    }
    fn write_index(&self) -> usize {
        self.0.write_index()
    }
    fn marks(&self) -> &FrameMarks {
        self.0.marks()
    }
    fn invalidate_lines(&mut self, _first_line: usize, _count: usize) {}
    fn copy(&mut self, start: usize, out: &mut [u32]) {
        self.0.copy(start, out)
    }
    fn register_waker(&mut self, waker: &Waker) {
        self.0.register_waker(waker)
    }
}

/// One run the source delivered.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Run {
    pub frame: u32,
    pub first_pixel: u32,
    pub pixels: Vec<u16>,
}

/// Polls `source.next()` once.
pub fn poll_next<S: PixelSource>(source: &mut S) -> Option<Run> {
    let mut cx = Context::from_waker(Waker::noop());
    let mut future = pin!(source.next());
    match future.as_mut().poll(&mut cx) {
        Poll::Ready(run) => Some(Run {
            frame: run.frame,
            first_pixel: run.first_pixel,
            pixels: run.pixels.to_vec(),
        }),
        Poll::Pending => None,
    }
}

/// Drives the source against the simulated DMA until the camera has sent
/// everything and the source has nothing more: between polls that find
/// nothing, the DMA writes `chunk(rng)` words; `stall(written)` may return
/// a number of words the DMA writes while the consumer is not looking.
pub fn drive<R: DmaRing>(
    source: &mut DcmiSource<'_, R>,
    sim: &SimRing,
    rng: &mut Rng,
    mut chunk: impl FnMut(&mut Rng) -> usize,
    mut stall: impl FnMut(u64) -> usize,
) -> Vec<Run> {
    let mut runs = Vec::new();
    let mut idle_polls = 0;
    loop {
        let stalled = stall(sim.written());
        if stalled > 0 {
            sim.advance(stalled);
        }
        match poll_next(source) {
            Some(run) => {
                idle_polls = 0;
                runs.push(run);
                // Sometimes the DMA moves while the consumer works.
                if rng.chance(30) {
                    sim.advance(chunk(rng));
                }
            }
            None => {
                if sim.idle() {
                    idle_polls += 1;
                    if idle_polls > 2 {
                        break;
                    }
                }
                sim.advance(chunk(rng));
            }
        }
    }
    runs
}

/// The pixel value of pixel `index` of frame `frame` at `bits` bits: a
/// hash, so a misplaced or stale word shows.
pub fn pixel(frame: u32, index: usize, bits: u8) -> u16 {
    let mut x = (frame as u64) << 32 | index as u64;
    x = x.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    x ^= x >> 29;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 32;
    (x & ((1u64 << bits) - 1)) as u16
}

pub fn frame_pixels(frame: u32, count: usize, bits: u8) -> Vec<u16> {
    (0..count).map(|k| pixel(frame, k, bits)).collect()
}

/// What the device loop makes of the runs (the rules of
/// `brightpix_firmware::device`): a run continuing the frame in progress
/// is appended; a run at pixel 0 starts a frame (one in progress is
/// incomplete); anything else is a gap: an overrun, the frame is dropped
/// and the rest of that frame ignored.
#[derive(Debug, Default)]
pub struct Assembler {
    pub frame_len: usize,
    current: Option<(u32, Vec<u16>)>,
    skipping: Option<u32>,
    pub completed: Vec<(u32, Vec<u16>)>,
    pub incomplete: Vec<u32>,
    pub gaps: u32,
}

impl Assembler {
    pub fn new(frame_len: usize) -> Self {
        Assembler {
            frame_len,
            ..Default::default()
        }
    }

    pub fn push(&mut self, run: &Run) {
        assert!(!run.pixels.is_empty(), "empty run");
        match &mut self.current {
            Some((f, buf)) if *f == run.frame && buf.len() == run.first_pixel as usize => {
                buf.extend_from_slice(&run.pixels);
            }
            _ if run.first_pixel == 0 => {
                if let Some((f, _)) = self.current.take() {
                    self.incomplete.push(f);
                }
                self.skipping = None;
                self.current = Some((run.frame, run.pixels.clone()));
            }
            _ => {
                if self.skipping == Some(run.frame) {
                    return;
                }
                self.gaps += 1;
                if let Some((f, _)) = self.current.take() {
                    self.incomplete.push(f);
                }
                self.skipping = Some(run.frame);
                return;
            }
        }
        let (f, buf) = self.current.as_ref().unwrap();
        assert!(
            buf.len() <= self.frame_len,
            "frame {f}: {} pixels, more than a frame",
            buf.len()
        );
        if buf.len() == self.frame_len {
            let (f, buf) = self.current.take().unwrap();
            if let Some((last, _)) = self.completed.last() {
                assert!(*last < f, "frames complete in order");
            }
            self.completed.push((f, buf));
        }
    }

    pub fn completed_frames(&self) -> Vec<u32> {
        self.completed.iter().map(|(f, _)| *f).collect()
    }
}

/// Every pixel of every run equals the camera's, except in frames listed
/// in `damaged` (which then must never complete).
pub fn check_runs(runs: &[Run], bits: u8, damaged: &[u32]) {
    for run in runs {
        if damaged.contains(&run.frame) {
            continue;
        }
        for (k, &p) in run.pixels.iter().enumerate() {
            let index = run.first_pixel as usize + k;
            assert_eq!(
                p,
                pixel(run.frame, index, bits),
                "frame {} pixel {index}: wrong value",
                run.frame
            );
        }
    }
}
