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
/// a count and an eighth. Calibrated values of one window differ by whole
/// counts without a gain map, so a margin below 16 admits nothing below the
/// hint, and any fall of the cutoff costs a rescan.
///
/// The margin is this plus half the spread up to `KNEE` and one and a half
/// times it beyond. Chosen on the QEMU bench (Cortex-M4, instructions a
/// pixel) on its faint spots (a peak of ~14 counts over +-3 of noise, where
/// one count level holds ~20 pixels of a window, so each level of margin
/// costs ~20 admissions) and on spots 10 and 30 times brighter (where
/// levels are sparse and a rescan costs more than a wide margin). The
/// previous margin, one and a half times the spread plus 1/16 count:
/// CANARY subtract-next 14.13 faint, 11.63 and 11.98 bright; half the
/// spread plus 20/16 everywhere: 13.22 faint but 12.72 and 13.98 bright.
/// Since a rescan widens the spread by half its change, not twice (see
/// [`Seed::observe`]), on three generator seeds of the bench frames
/// (subtract-next / threshold / N = 5 / bright x10 / closed loop, the
/// bench's seed): 24/16 count 12.57 / 13.41 / 8.72 / 10.91 / 12.31,
/// 20/16 12.21 / 13.39 / 9.07 / 11.01 / 11.73, 18/16 12.12 / 13.33 /
/// 9.13 / 11.05 / 11.69, 16/16 12.11 / 13.30 / 9.37 / 11.10 / 11.65,
/// 8/16 12.20 / 13.43 / 10.09 / 11.19 / 12.29 (more rescans); the two
/// other seeds rank them alike. 18 gains most of 16's on the N = 20
/// rules without its cost at N = 5.
const MARGIN_FLOOR: i32 = 18;

/// Up to this spread (in calibrated units, 3 counts) the margin follows
/// half of it; see [`MARGIN_FLOOR`].
const KNEE: i32 = 48;

/// The spread a sub-aperture starts with, before its cutoff has moved:
/// one count.
const INITIAL_SPREAD: i32 = 16 << 4;

impl Seed {
    pub const RESET: Seed = Seed {
        biased: 0,
        spread: 0,
    };

    fn previous(&self) -> i32 {
        self.biased ^ NONE
    }

    /// The next frame's hint (the previous cutoff) and admission threshold
    /// (the hint less the margin); both `i32::MIN` before the first frame.
    #[inline(always)]
    pub fn thresholds(&self) -> (i32, i32) {
        let previous = self.previous();
        if previous == NONE {
            return (NONE, NONE);
        }
        // Half the largest recent change up to `KNEE`, one and a half times
        // it beyond, plus a count and an eighth (`MARGIN_FLOOR`).
        // Saturating: a cutoff is below 2^26 in magnitude, the spread below
        // 2^30.
        let spread = self.spread >> 4;
        let margin = (spread + (spread >> 1) - spread.min(KNEE)).saturating_add(MARGIN_FLOOR);
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
