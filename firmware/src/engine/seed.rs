//! Where a window's admission threshold starts: its *seed*, from the cutoff
//! of its previous frames (see [`super::select`]).
//!
//! A sub-aperture's spot changes little between frames, so its previous
//! cutoff (e.g. `v(N+1)`) less a margin is a threshold that almost every
//! pixel fails and that almost never leaves out a pixel the rule needs. The
//! margin follows how much the cutoff moves from frame to frame (the largest
//! recent change, decaying slowly), and grows by half when the seed was too
//! high.
//! Only speed depends on the seed, never a result: a seed too high costs a
//! rescan of the window, a seed too low more candidates.

/// A sub-aperture's memory of its cutoffs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Seed {
    /// The previous frame's cutoff; `NONE` before the first frame. Stored
    /// as `previous ^ NONE`, so that the reset state is all zero bits.
    biased: i32,
    /// The largest recent change of the cutoff between frames, decaying by
    /// 1/32 a frame (`DECAY_BITS`), in 1/16 of a calibrated unit.
    spread: i32,
}

/// No seed: every pixel is a candidate.
const NONE: i32 = i32::MIN;

/// The spread decays by 2^-DECAY_BITS of itself each frame.
const DECAY_BITS: u32 = 5;

/// The part of the margin that does not follow the spread, in 1/16 count:
/// five eighths of a count. Calibrated values of one window differ by
/// whole counts without a gain map, so a steady cutoff's window admits
/// nothing below its hint's level, and a fall of the cutoff costs a rescan;
/// after one, the spread keeps the margin at a count or more for about
/// nine frames (half the spread of a one-count fall is 8/16: 18 in all).
///
/// The margin is this plus half the spread up to `KNEE` and one and a half
/// times it beyond. Chosen on the QEMU bench (Cortex-M4, instructions a
/// pixel, every workload) on three generator seeds of its frames, floors
/// from 8/16 to 18/16 (18/16 had been chosen the same way on an earlier
/// engine). With 10/16 here and 18/16 in the last row
/// ([`LAST_ROW_MARGIN_FLOOR`]), against 18/16 everywhere, averaged over
/// the seeds: subtract-next -0.06, threshold -0.24, distinct -0.25, mean
/// -0.11, the board's camera path -0.09, closed-loop spots -0.17, noise
/// +-6 on a patterned background -0.12, N = 60 -0.80 (distinct at N = 60
/// -0.73), 32x32 windows -0.54, 8x8 -0.05, ELT -0.05, last rows unchanged;
/// dearer N = 5 +0.43 (its cutoff lies on the spot's steep flank, where a
/// frame's fall is often more than a count: 18 -> 31 rescans on the
/// bench's seed) and bright spots +0.07. 11/16 and 12/16 (everywhere)
/// gained a little more on subtract-next (-0.09, -0.08 against 10/16's
/// -0.04) and cost N = 5 a little less (+0.41, +0.36 against +0.46), but
/// none of N = 60's gain; 8/16 and 9/16 rescanned more (subtract-next
/// +0.13, +0.10; 8x8 windows +0.50, +0.46; 8/16 N = 200 +2.07).
const MARGIN_FLOOR: i32 = 10;

/// [`MARGIN_FLOOR`] for a window that ends in the frame's last camera row:
/// a count and an eighth, so that a steady cutoff admits one count below
/// it. Its rescan would come after the frame's last pixel, in the latency
/// the engine exists to keep short: at 10/16 there too, the bench's last
/// rows grew where its rescans fell there (32x32 windows 2,398 -> 3,693
/// instructions, the 12-bit runs of 1,024 pixels 4,872 -> 5,573). Against
/// 10/16 everywhere this floor costs N = 60 0.16 instructions a pixel,
/// 32x32 windows 0.13 and the other rows less than 0.05 (averages over
/// three generator seeds).
const LAST_ROW_MARGIN_FLOOR: i32 = 18;

/// Up to this spread (in calibrated units, 3 counts) the margin follows
/// half of it; see [`MARGIN_FLOOR`].
const KNEE: i32 = 48;

/// The spread a sub-aperture starts with, before its cutoff has moved:
/// one count.
const INITIAL_SPREAD: i32 = 16 << 4;

/// The part of a window's margin that does not follow the spread:
/// [`MARGIN_FLOOR`], or [`LAST_ROW_MARGIN_FLOOR`] for a window that ends in
/// the frame's last row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MarginFloor(i32);

impl MarginFloor {
    pub const ORDINARY: MarginFloor = MarginFloor(MARGIN_FLOOR);
    pub const LAST_ROW: MarginFloor = MarginFloor(LAST_ROW_MARGIN_FLOOR);

    /// The floor of a window that ends in the frame's last row or not.
    #[inline(always)]
    pub fn of(in_last_row: bool) -> MarginFloor {
        if in_last_row {
            Self::LAST_ROW
        } else {
            Self::ORDINARY
        }
    }
}

impl Seed {
    pub const RESET: Seed = Seed {
        biased: 0,
        spread: 0,
    };

    fn previous(&self) -> i32 {
        self.biased ^ NONE
    }

    /// The next frame's hint (the previous cutoff) and admission threshold
    /// (the hint less the margin, whose floor is `floor`); both `i32::MIN`
    /// before the first frame.
    #[inline(always)]
    pub fn thresholds(&self, floor: MarginFloor) -> (i32, i32) {
        let previous = self.previous();
        if previous == NONE {
            return (NONE, NONE);
        }
        // Half the largest recent change up to `KNEE`, one and a half times
        // it beyond, plus the floor. Saturating: a cutoff is below 2^26 in
        // magnitude, the spread below 2^30.
        let spread = self.spread >> 4;
        let margin = (spread + (spread >> 1) - spread.min(KNEE)).saturating_add(floor.0);
        (previous, previous.saturating_sub(margin))
    }

    /// The frame's cutoff is known; `too_high` if the seed left out a pixel
    /// the rule needed (the window was rescanned).
    pub fn observe(&mut self, cutoff: i32, too_high: bool) {
        let previous = self.previous();
        if previous != NONE {
            // Spread in 1/16 units: 16 * |change|, at most 2^29. In 32
            // bits, capped before the shift (the same value for any two
            // `i32`s; the 64-bit difference cost ~5 instructions a window
            // on Cortex-M4).
            let change = (cutoff.abs_diff(previous).min(1 << 25) << 4) as i32;
            let decayed = self.spread - (self.spread >> DECAY_BITS);
            let mut next = decayed.max(change);
            // A seed too high: the spread at least one and a half times the
            // change. Twice, as before, kept the margins (and admissions) of
            // the next ~32 frames wider than the rescans it saved were worth:
            // CANARY subtract-next on Cortex-M4, three generator seeds,
            // 12.33 / 11.90 / 11.96 instr/px at twice, 12.21 / 11.78 / 11.88
            // at one and a half, 12.20 / 11.77 / 11.87 at once; bright spots
            // 11.05 / 11.47 / 10.95, 11.01 / 10.83 / 10.90 and
            // 11.08 / 11.06 / 10.88 (more rescans at once).
            if too_high {
                next = next.max(change + change / 2);
            }
            self.spread = next;
        } else {
            self.spread = INITIAL_SPREAD;
        }
        self.biased = cutoff ^ NONE;
    }
}
