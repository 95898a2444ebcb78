//! Temporal filtering of the subtracted level (SPEC.md §4).

use brightpix_protocol::LEVEL_FILTER_FRACTION_BITS;

/// One sub-aperture's filtered level `F`, in 2^-8 of a calibrated unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelFilterState {
    /// `F ^ i64::MIN`: all zero bits (the reset state, so that a `static`
    /// of them lands in `.bss`) mean `ready = false`, which no `F` can be
    /// mistaken for since SPEC.md §4 bounds `|F| < 2^33`.
    biased: i64,
}

const BIAS: i64 = i64::MIN;

impl LevelFilterState {
    pub const RESET: LevelFilterState = LevelFilterState { biased: 0 };

    /// Feeds this frame's instantaneous level; returns the level to subtract.
    /// `gain_shift` is a validated configuration's, 1..=16.
    pub fn update(&mut self, level: Option<i32>, gain_shift: u8) -> Option<i32> {
        Some(self.filter(level?, gain_shift))
    }

    /// [`update`](Self::update) with a level (none leaves the state as it
    /// is). The state is `Copy`: an end that may still give up updates a
    /// copy and stores it once it cannot.
    #[inline(always)]
    pub fn filter(&mut self, level: i32, gain_shift: u8) -> i32 {
        let target = (level as i64) << LEVEL_FILTER_FRACTION_BITS;
        let state = if self.biased == 0 {
            target
        } else {
            let state = self.biased ^ BIAS;
            // `gain_shift` is 1..=16 (SPEC.md §4): below 32, which the
            // mask tells the compiler (a 64-bit shift then needs no test
            // for 32 or more on Cortex-M).
            state + ((target - state) >> (gain_shift & 31))
        };
        self.biased = state ^ BIAS;
        (state >> LEVEL_FILTER_FRACTION_BITS) as i32
    }
}
