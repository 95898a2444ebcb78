//! The state the engine keeps for a window while it is open (from its first
//! row to its last), and for every sub-aperture between frames.

use super::calibrate::{WindowBounds, FLOOR_NONE};
use super::centroid::Moments;
use super::level_filter::LevelFilterState;
use super::prefilter;
use super::seed::Seed;
use super::select::Ties;

/// What a sub-aperture carries from frame to frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SubapertureState {
    /// The temporally filtered level (SPEC.md §4).
    pub level: LevelFilterState,
    /// Where the next frame's admission threshold starts (speed only).
    pub seed: Seed,
    /// Of its calibration maps, for the pre-filter; derived from the
    /// configuration whenever an engine is built.
    pub bounds: WindowBounds,
}

impl SubapertureState {
    /// All zero bits, so that a `static` of them lands in `.bss` (the
    /// bounds are set when an engine is built).
    pub const RESET: SubapertureState = SubapertureState {
        level: LevelFilterState::RESET,
        seed: Seed::RESET,
        bounds: WindowBounds {
            background_min: 0,
            gain_max: 0,
        },
    };
}

/// A window that has started receiving pixels in this frame.
#[derive(Clone, Copy, Debug)]
pub struct OpenWindow {
    pub(crate) index: u16,
    pub(crate) x: u16,
    pub(crate) end_column: u16,
    pub(crate) y: u16,
    pub(crate) last_row: u16,
    pub(crate) width: u16,
    pub(crate) height: u16,
    /// Its first entry in the candidate pool (its slot times the pool's
    /// stride).
    pub(crate) base: u32,
    pub(crate) finished: bool,
    /// N of this window (SPEC.md §3).
    pub(crate) n: u16,
    /// Candidate buffer capacity; 0: no selection (every pixel weighs).
    pub(crate) capacity: u16,
    /// Candidates at or above the hint, at the buffer's start (`select.rs`).
    pub(crate) front: u16,
    /// Front entries equal to the hint (the rest are above it).
    pub(crate) at_hint: u16,
    /// Front entries whose ties with the hint `at_hint` counts (the rest
    /// are counted when needed, see `stream::settle_at_hint`).
    pub(crate) counted: u16,
    /// Candidates between `low` and the hint, at the buffer's end.
    pub(crate) back: u16,
    pub(crate) hint: i32,
    pub(crate) hint_ties: Ties,
    /// The admission threshold (`<= hint`).
    pub(crate) low: i32,
    /// Pixels equal to `low`, when `low < hint`.
    pub(crate) low_ties: Ties,
    /// Admission is `p > low` (see `select::Buffer::strict`).
    pub(crate) strict: bool,
    /// The calibrated value a pixel needs to become a candidate
    /// ([`OpenWindow::admission`] of `low`, `hint` and `strict`), kept with
    /// `floor` and `lanes` by `stream::update_admission` whenever one of
    /// them changes: the hot loop reads it instead of deciding again.
    pub(crate) admit: i32,
    /// `floor - 1` in both 16-bit lanes, for the hot loop's `UQSUB16`.
    pub(crate) lanes: u32,
    /// Smallest raw value that can reach `low` (see
    /// `calibrate::raw_floor`), lowered to one above the camera's largest
    /// raw value when that is below 2^16, so that an out-of-range pixel
    /// always reaches the per-pixel check. Always 0 (every segment passes,
    /// to `Engine::segment_rest`) for a window without selection or awaiting
    /// a rescan, so that the row loop tests one field, not three.
    pub(crate) floor: u32,
    /// `low` left out a needed pixel or the buffer could not be compacted:
    /// the window is computed again from the row history at its end.
    pub(crate) rescan: bool,
    pub(crate) bounds: WindowBounds,
    /// Weighted sums of a window without selection.
    pub(crate) moments: Moments,
}

impl OpenWindow {
    pub const CLOSED: OpenWindow = OpenWindow {
        index: 0,
        x: 0,
        end_column: 0,
        y: 0,
        last_row: 0,
        width: 0,
        height: 0,
        base: 0,
        finished: true,
        n: 0,
        capacity: 0,
        front: 0,
        at_hint: 0,
        counted: 0,
        back: 0,
        hint: 0,
        hint_ties: Ties::NONE,
        low: 0,
        low_ties: Ties::NONE,
        strict: false,
        admit: 0,
        lanes: 0,
        floor: 0,
        rescan: false,
        bounds: WindowBounds::NONE,
        moments: Moments::ZERO,
    };

    /// Pixels in the window.
    pub(crate) fn pixels(&self) -> u16 {
        self.width * self.height
    }

    /// The calibrated value a pixel needs to become a candidate: `low`, or
    /// just above the hint once admission is strict (the definition of the
    /// `admit` field).
    #[inline(always)]
    pub(crate) fn admission(&self) -> i32 {
        if self.strict {
            self.hint.saturating_add(1)
        } else {
            self.low
        }
    }

    /// Where a row segment of this window goes: the pre-filter rejects it
    /// whole (`floor` is capped so that an out-of-range pixel is never
    /// rejected), or it has candidates, or the window is one the general
    /// path takes (floor 0: every pixel passes, no selection, a rescan).
    #[inline(always)]
    pub(crate) fn path(&self, raw: &[u16]) -> SegmentPath {
        match self.floor {
            0 => SegmentPath::General,
            floor if floor < FLOOR_NONE && prefilter::any_above_lanes(raw, self.lanes) => {
                SegmentPath::Candidates
            }
            _ => SegmentPath::Rejected,
        }
    }
}

/// See [`OpenWindow::path`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum SegmentPath {
    Rejected,
    Candidates,
    General,
}
