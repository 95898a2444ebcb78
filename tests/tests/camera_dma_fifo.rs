//! A model of the STM32H743's DMA1 stream in FIFO mode, reading the DCMI
//! into a circular ring, against the arithmetic that turns its registers
//! into "words in memory" (`DmaProgress::through_fifo`, which the board's
//! `dcmi.rs` calls with the real registers).
//!
//! The model: the DCMI hands words to the DMA one at a time, with pauses
//! (line and frame blanking); the DMA counts each in NDTR as it enters a
//! 4-word FIFO, and writes the FIFO to memory in bursts of 4, one beat at a
//! time (the DCMI may refill freed slots during a burst). The half-transfer
//! and transfer-complete flags are raised either as NDTR crosses the half
//! (before the last burst has landed: RM0433 does not say HTIF waits for
//! the FIFO) or once the burst completing the half has landed; the
//! interrupt that counts them runs late by up to one event (and less than
//! a quarter ring of words). A reader takes
//! readings whose register reads race the DMA (the model steps between
//! them), and every reading is checked against memory: a word claimed
//! written that is not is a stale read the engine would take for pixels.
//!
//! The board's code before this fix (clamped to the last counted half) is
//! kept here verbatim as `old_write_index`, to show the model finds its
//! stale readings; the new arithmetic must have none.

use std::cell::RefCell;
use std::collections::VecDeque;

use brightpix_firmware::camera::{DmaProgress, MAX_HOLD_BACK_WORDS};

const FIFO_WORDS: usize = 4;

/// When the half/complete flag is raised.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Flag {
    /// As NDTR crosses the half: the FIFO may still hold the last words.
    AtNdtr,
    /// Once the burst that completes the half has landed.
    AfterBurst,
}

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn chance(&mut self, percent: u64) -> bool {
        self.below(100) < percent
    }
}

struct Dma {
    len: usize,
    flag: Flag,
    /// Words read from the DCMI (what NDTR counts).
    read: u64,
    /// Positions in the FIFO, not yet in memory.
    fifo: VecDeque<u64>,
    /// Beats left in the burst in progress.
    burst: usize,
    /// Words in memory.
    written: u64,
    /// The position each ring word holds (`u64::MAX`: never written).
    memory: Vec<u64>,
    raised: u64,
    counted: u64,
    /// `read` when the last flag was raised.
    raised_at: u64,
    /// Steps the DCMI stays silent (blanking).
    pause: u64,
    rng: Rng,
}

impl Dma {
    fn new(len: usize, flag: Flag, seed: u64) -> Self {
        Dma {
            len,
            flag,
            read: 0,
            fifo: VecDeque::new(),
            burst: 0,
            written: 0,
            memory: vec![u64::MAX; len],
            raised: 0,
            counted: 0,
            raised_at: 0,
            pause: 0,
            rng: Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1),
        }
    }

    fn half(&self) -> u64 {
        self.len as u64 / 2
    }

    fn raise(&mut self) {
        // The interrupt is at most one event late: it has run for the
        // previous flag before this one is raised.
        self.counted = self.raised;
        self.raised += 1;
        self.raised_at = self.read;
        if self.rng.chance(50) {
            self.counted = self.raised;
        }
    }

    /// One bus event: a DCMI word, a burst beat, or the interrupt running.
    fn step(&mut self) {
        // However late, the interrupt (the highest priority, a few
        // instructions) runs before the DMA has read a quarter ring more:
        // the board's ring is 1,920 words, read at most a word every few
        // hundred cycles.
        if self.counted < self.raised && self.read - self.raised_at >= self.half() / 2 {
            self.counted = self.raised;
        }
        match self.rng.below(3) {
            0 => {
                if self.pause > 0 {
                    self.pause -= 1;
                } else if self.fifo.len() < FIFO_WORDS {
                    self.fifo.push_back(self.read);
                    self.read += 1;
                    if self.flag == Flag::AtNdtr && self.read.is_multiple_of(self.half()) {
                        self.raise();
                    }
                    // Blanking after some words: the FIFO may sit part full.
                    if self.rng.chance(3) {
                        self.pause = self.rng.below(40);
                    }
                }
            }
            1 => {
                if self.burst == 0 && self.fifo.len() == FIFO_WORDS {
                    self.burst = FIFO_WORDS;
                }
                if self.burst > 0 {
                    let position = self.fifo.pop_front().expect("a burst's word");
                    self.memory[(position % self.len as u64) as usize] = position;
                    self.written += 1;
                    self.burst -= 1;
                    if self.burst == 0
                        && self.flag == Flag::AfterBurst
                        && self.written.is_multiple_of(self.half())
                    {
                        self.raise();
                    }
                }
            }
            _ => {
                if self.rng.chance(30) {
                    self.counted = self.raised;
                }
            }
        }
    }

    /// The DMA moves on a little between two register reads.
    fn race(&mut self) {
        for _ in 0..self.rng.below(4) {
            self.step();
        }
    }

    fn ndtr(&self) -> usize {
        self.len - (self.read % self.len as u64) as usize
    }
}

/// The board's `write_index` before this fix, verbatim but for the
/// registers (closures here), with `DmaProgress::read` around it as the
/// board had.
fn old_progress(dma: &RefCell<Dma>, len: usize) -> DmaProgress {
    let half_events = || {
        dma.borrow_mut().race();
        dma.borrow().counted as u32
    };
    let write_index = || {
        let ndt = {
            dma.borrow_mut().race();
            dma.borrow().ndtr()
        };
        let empty = {
            dma.borrow_mut().race();
            dma.borrow().fifo.is_empty()
        };
        let index = (len - ndt.min(len)) % len;
        if empty {
            return index;
        }
        let half = len / 2;
        let counted = (half_events() as usize & 1) * half;
        let beyond = (index + len - counted) % len;
        let held = (beyond / FIFO_WORDS * FIFO_WORDS).saturating_sub(FIFO_WORDS);
        (counted + held) % len
    };
    DmaProgress::read(half_events, write_index)
}

fn new_progress(dma: &RefCell<Dma>, len: usize) -> DmaProgress {
    DmaProgress::through_fifo(
        || {
            dma.borrow_mut().race();
            dma.borrow().counted as u32
        },
        || {
            dma.borrow_mut().race();
            dma.borrow().ndtr()
        },
        || {
            dma.borrow_mut().race();
            dma.borrow().fifo.is_empty()
        },
        len,
        FIFO_WORDS,
    )
}

#[derive(Debug, Default)]
struct Findings {
    readings: u64,
    /// Readings that claimed a word not yet in memory.
    stale_readings: u64,
    /// The largest number of such words in one reading.
    worst_stale_words: u64,
    /// The largest lag behind memory right after a reading.
    worst_lag: u64,
    /// The largest step back from the reading before.
    worst_step_back: i64,
}

fn run(len: usize, flag: Flag, readings: u64, seed: u64, new: bool) -> Findings {
    let dma = RefCell::new(Dma::new(len, flag, seed));
    let mut found = Findings::default();
    let mut previous = 0u32;
    for _ in 0..readings {
        {
            let mut d = dma.borrow_mut();
            let n = d.rng.below(24);
            for _ in 0..n {
                d.step();
            }
        }
        let progress = if new {
            new_progress(&dma, len)
        } else {
            old_progress(&dma, len)
        };
        let claimed = progress.position(len);
        let d = dma.borrow();
        found.readings += 1;
        // Positions stay far below 2^32 here: compare them as integers.
        let claimed = claimed as i32 as i64;
        let stale = (claimed - d.written as i64).max(0) as u64;
        if stale > 0 {
            found.stale_readings += 1;
            found.worst_stale_words = found.worst_stale_words.max(stale);
            // What the source would copy: ring words that do not hold the
            // positions claimed.
            let wrong = (d.written as i64..claimed)
                .filter(|&p| d.memory[(p as u64 % len as u64) as usize] != p as u64)
                .count() as u64;
            assert_eq!(wrong, stale, "claimed words are the unwritten ones");
        } else {
            found.worst_lag = found.worst_lag.max((d.written as i64 - claimed) as u64);
        }
        found.worst_step_back = found.worst_step_back.max(previous as i32 as i64 - claimed);
        previous = claimed as u32;
    }
    found
}

const READINGS: u64 = 100_000;

#[test]
fn the_model_finds_the_clamped_hold_back_stale_when_the_flag_comes_first() {
    for len in [16, 1920] {
        let old = run(len, Flag::AtNdtr, READINGS, 1, false);
        eprintln!("old code, {len} words, flag at NDTR: {old:?}");
        assert!(old.stale_readings > 0, "{old:?}");
        assert!(old.worst_stale_words <= FIFO_WORDS as u64);
    }
}

#[test]
fn through_fifo_never_claims_a_word_not_in_memory_with_either_flag_timing() {
    for len in [16, 32, 1920] {
        for flag in [Flag::AtNdtr, Flag::AfterBurst] {
            for seed in 1..4 {
                let new = run(len, flag, READINGS, seed, true);
                eprintln!("new code, {len} words, {flag:?}, seed {seed}: {new:?}");
                assert_eq!(new.stale_readings, 0, "{new:?}");
                // Never far behind memory: the FIFO's words and what the
                // DMA wrote during the reading's own register reads.
                assert!(new.worst_lag <= (FIFO_WORDS + 3 * 3) as u64, "{new:?}");
                assert!(new.worst_step_back <= MAX_HOLD_BACK_WORDS as i64, "{new:?}");
            }
        }
    }
}

#[test]
fn the_old_code_was_safe_only_when_the_flag_waits_for_the_burst() {
    // What made the bug hard to see: with the flag after the burst (as
    // RM0433 documents for transfer-complete) the old clamp was safe.
    for len in [16, 1920] {
        let old = run(len, Flag::AfterBurst, READINGS, 2, false);
        assert_eq!(old.stale_readings, 0, "{old:?}");
    }
}
