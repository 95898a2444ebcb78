//! Temporal filtering of the subtracted level (SPEC.md §4).

use brightpix_protocol::LEVEL_FILTER_FRACTION_BITS;

/// One sub-aperture's filtered level, in 2^-8 of a calibrated unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelFilterState {
    state: i64,
    ready: bool,
}

impl LevelFilterState {
    pub const RESET: LevelFilterState = LevelFilterState {
        state: 0,
        ready: false,
    };

    /// Feeds this frame's instantaneous level; returns the level to subtract.
    pub fn update(&mut self, level: Option<i32>, gain_shift: u8) -> Option<i32> {
        let target = (level? as i64) << LEVEL_FILTER_FRACTION_BITS;
        if self.ready {
            self.state += (target - self.state) >> gain_shift;
        } else {
            self.state = target;
            self.ready = true;
        }
        Some((self.state >> LEVEL_FILTER_FRACTION_BITS) as i32)
    }
}
