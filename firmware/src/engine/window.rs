//! The state the engine keeps for a window while it is open (from its first
//! row to its last), and for every sub-aperture between frames.

use super::calibrate::{WindowBounds, FLOOR_NONE};
use super::centroid::Moments;
use super::level_filter::LevelFilterState;
use super::prefilter;
use super::seed::Seed;
use super::select::{Entry, Ties};

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

/// Bytes of one candidate entry.
const ENTRY: usize = core::mem::size_of::<Entry>();

/// What the row kernel does when a window's front reaches `attention`
/// (`OpenWindow::raise`), in the byte its assembly reads:
/// - 0 ([`Raise::NONE`]): stop, for the engine (`Engine::attend`);
/// - 1 and 2 ([`Raise::AT_HINT`], [`Raise::ABOVE_HINT`]): raise admission
///   to the hint, `admit = hint + (raise - 1)`, `strict = raise - 1`;
/// - 4 ([`Raise::LOWER`]): lower the hint to `hint - 1` where the back
///   tier holds a copy of it, then raise as `ABOVE_HINT` (of the lowered
///   hint); else stop (the kernel's dispatch tells it from the counting
///   raises last, so that the others pay nothing for it);
/// - `2 + 4 c` ([`Raise::counting`]`(c)`, `c` in 1..=16): first count the
///   front's copies of the hint that arrived since the last count
///   (`at_hint`, `counted`), then, if N front values are above the hint
///   and the hint has `c` copies (with its ties), raise as `ABOVE_HINT`,
///   else set the next `attention` (`stream::admission::attention`).
///
/// `raise_lane` is the raw floor of the raised admission, worked out when
/// the raise is prepared: at the hint for `AT_HINT` and `LOWER` (whose
/// raised admission `p > hint - 1` is `p >= hint`), above it otherwise: bit
/// 1 of the byte says which (set: above), one test where the opening of
/// every window works it out (a comparison with `AT_HINT` cost CANARY
/// 0.04 instructions a pixel more, 8x8 windows 0.1). So `LOWER` is 4, not
/// 3: as 3 its bit 1 set (3ca79bd to c01d428) gave it the floor of
/// `hint + 1`, and the lanes then dropped a pixel equal to the old hint
/// whose background was the window's least (`engine_limits`'
/// `lowered_hint_keeps_the_old_hints_copies`).
#[repr(transparent)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Raise(u8);

impl Raise {
    pub const NONE: Raise = Raise(0);
    /// Admit `p >= hint` (`threshold`: `v(N)` may be the hint, whose
    /// copies are then kept).
    pub const AT_HINT: Raise = Raise(1);
    /// Admit `p > hint` (`subtract-next`: strict at once).
    pub const ABOVE_HINT: Raise = Raise(2);
    /// `subtract-next-distinct` without hint ties, its front at N: the hint
    /// lowered to the previous level, `hint - 1`, at the first copy of it
    /// in the back tier (from `back_start` up), which becomes the hint's
    /// one tie, and admission raised above it, `p >= hint` (the old hint);
    /// what `stream::admission::raise_below_front` does when the back holds
    /// such a copy. Without one, a stop (the engine then takes the back's
    /// largest value).
    pub const LOWER: Raise = Raise(4);

    /// Count the hint's copies first and raise once N front values are
    /// above it and it has `copies` (1 to 16) copies
    /// (`subtract-next-distinct`: 1; `subtract-mean`: M).
    pub const fn counting(copies: u8) -> Raise {
        Raise(2 + 4 * copies)
    }

    /// The copies a counting raise needs; `None` for the others.
    pub const fn copies(self) -> Option<u8> {
        // 2 + 4 c: above `LOWER`.
        if self.0 > 4 {
            Some(self.0 / 4)
        } else {
            None
        }
    }

    /// Whether the raised admission takes the hint's value as it stands
    /// when the raise is prepared (`AT_HINT`; `LOWER`, whose raise lowers
    /// the hint by one first), so that `raise_lane` is the hint's raw
    /// floor, not the floor of one above it.
    pub const fn admits_hint(self) -> bool {
        self.0 & 2 == 0
    }
}

/// A window that has started receiving pixels in this frame.
///
/// The open windows are kept in the engine's memory in order of first
/// column, so the row kernel (`scan::row`) walks them one after the other.
/// It reads and writes the fields before `buffer` (and, when it raises a
/// window's admission itself, `low`, `floor` and `strict`: see `raise`),
/// at the offsets `scan`'s assembly takes from `offset_of!`; the candidate buffer's two tiers are
/// kept as addresses (`front_end`, `back_start`) because that is what the
/// kernel stores through, and everything else derives the tiers' lengths
/// from them (`OpenWindow::front`, `OpenWindow::back`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct OpenWindow {
    /// Byte offsets in its camera row of the first pixel and of the end of
    /// the window's row segment (`2 x`, `2 end_column`), for the row
    /// kernel; equal (an empty segment, which the kernel skips) while the
    /// window's segments take the general path (see
    /// [`OpenWindow::kernel_ready`]).
    pub(crate) segment_start: u32,
    pub(crate) segment_end: u32,
    /// `floor - 1` in both 16-bit lanes, for `UQSUB16`.
    pub(crate) lanes: u32,
    /// The calibrated value a pixel needs to become a candidate
    /// ([`OpenWindow::admission`] of `low`, `hint` and `strict`), kept with
    /// `floor` and `lanes` by `stream::admission::update_admission` whenever one of
    /// them changes; higher in a window prepared for the frame's last row
    /// (`stream::last_row`: just above its `v(N+1)` so far).
    pub(crate) admit: i32,
    /// `-(y << 6) - x` (wrapping): a pixel's packed position is this plus
    /// `(row << 6) + column`.
    pub(crate) position_base: u32,
    /// Candidates at or above it go to the front, below it to the back.
    pub(crate) hint: i32,
    /// The address after the front tier's last entry.
    pub(crate) front_end: usize,
    /// The address of the back tier's first entry (the back grows down from
    /// the buffer's end).
    pub(crate) back_start: usize,
    /// When a segment leaves `front_end` at or past this address, the row
    /// kernel stops at the window (see `stream::admission::attention`);
    /// `stream::last_row::PREPARED`, an address never reached, marks a
    /// window prepared for the frame's last row.
    pub(crate) attention: usize,
    /// `floor - 1` (a lane of `lanes`) for the admission a raise sets: see
    /// `raise`.
    pub(crate) raise_lane: u16,
    /// When a segment leaves at most this many bytes between the tiers,
    /// less than the next segment may take (`8 (width - 1)`), the kernel
    /// stops at the window. The high half of the word after `attention`,
    /// which the kernel loads with it (one `LDRD`) and compares with the
    /// bytes left shifted up 16: `raise_lane`, in the low half, is below
    /// what one more byte left adds.
    pub(crate) short_of_room: u16,

    /// The candidate buffer's first entry.
    pub(crate) buffer: usize,
    /// Candidate buffer capacity; 0: no selection (every pixel weighs).
    pub(crate) capacity: u16,
    /// Which of the pool's buffers it is (for the free list).
    pub(crate) buffer_number: u16,
    pub(crate) index: u16,
    pub(crate) x: u16,
    pub(crate) end_column: u16,
    pub(crate) y: u16,
    pub(crate) last_row: u16,
    pub(crate) width: u16,
    pub(crate) height: u16,
    /// N of this window (SPEC.md §3).
    pub(crate) n: u16,
    /// Front entries equal to the hint (the rest are above it).
    pub(crate) at_hint: u16,
    /// Front entries whose ties with the hint `at_hint` counts (the rest
    /// are counted when needed, see `stream::admission::settle_at_hint`).
    pub(crate) counted: u16,
    pub(crate) hint_ties: Ties,
    /// The admission threshold (`<= hint`).
    pub(crate) low: i32,
    /// Pixels equal to `low`, when `low < hint`.
    pub(crate) low_ties: Ties,
    /// Smallest raw value that can reach `low` (see
    /// `calibrate::raw_floor`), lowered to one above the camera's largest
    /// raw value when that is below 2^16, so that an out-of-range pixel
    /// always reaches the per-pixel check. Always 0 (every segment passes,
    /// to the general path) for a window without selection or awaiting a
    /// rescan, so that the general path tests one field, not three.
    pub(crate) floor: u32,
    pub(crate) finished: bool,
    /// Admission is `p > low` (see `select::Buffer::strict`).
    pub(crate) strict: bool,
    /// When the front reaches `attention`, the row kernel raises admission
    /// to the hint itself instead of stopping, where reaching `attention`
    /// always proves the cutoff at or above the hint (see
    /// `stream::admission::prepare_raise`): it writes `floor` and `lanes`
    /// (from `raise_lane`), `admit`, `low` (the hint), `strict`,
    /// `back_start` (the buffer's end: the back tier dropped) and
    /// `attention` (never again), as `raise_to_hint` would.
    pub(crate) raise: Raise,
    /// `low` left out a needed pixel or the buffer could not be compacted:
    /// the window is computed again from the row history at its end. Also
    /// set for every window selecting the complement
    /// (`stream::complement`), which ends its own way if it can.
    pub(crate) rescan: bool,
    pub(crate) bounds: WindowBounds,
    /// Weighted sums of a window without selection.
    pub(crate) moments: Moments,
}

impl OpenWindow {
    pub const CLOSED: OpenWindow = OpenWindow {
        segment_start: 0,
        segment_end: 0,
        lanes: 0,
        admit: 0,
        position_base: 0,
        hint: 0,
        front_end: 0,
        back_start: 0,
        attention: 0,
        raise_lane: 0,
        short_of_room: 0,
        buffer: 0,
        capacity: 0,
        buffer_number: 0,
        index: 0,
        x: 0,
        end_column: 0,
        y: 0,
        last_row: 0,
        width: 0,
        height: 0,
        n: 0,
        at_hint: 0,
        counted: 0,
        hint_ties: Ties::NONE,
        low: 0,
        low_ties: Ties::NONE,
        floor: 0,
        finished: true,
        strict: false,
        raise: Raise::NONE,
        rescan: false,
        bounds: WindowBounds::NONE,
        moments: Moments::ZERO,
    };

    /// Makes this slot the end of the row kernel's window range (see
    /// `scan::row`): a segment that ends before it starts, which no window
    /// has (an empty one starts where it ends). Only the segment is
    /// touched: [`OpenWindow::unmark_end`] puts back what it was.
    #[inline(always)]
    pub(crate) fn mark_end(&mut self) -> (u32, u32) {
        let was = (self.segment_start, self.segment_end);
        (self.segment_start, self.segment_end) = (1, 0);
        was
    }

    /// Whether this slot is an end mark ([`OpenWindow::mark_end`]).
    #[inline(always)]
    pub(crate) fn is_end_mark(&self) -> bool {
        self.segment_end < self.segment_start
    }

    /// Undoes [`OpenWindow::mark_end`], given what it returned.
    #[inline(always)]
    pub(crate) fn unmark_end(&mut self, was: (u32, u32)) {
        (self.segment_start, self.segment_end) = was;
    }

    /// Pixels in the window.
    pub(crate) fn pixels(&self) -> u16 {
        self.width * self.height
    }

    /// Entries in the front tier.
    #[inline(always)]
    pub(crate) fn front(&self) -> usize {
        (self.front_end - self.buffer) / ENTRY
    }

    /// Entries in the back tier.
    #[inline(always)]
    pub(crate) fn back(&self) -> usize {
        (self.buffer_end() - self.back_start) / ENTRY
    }

    #[inline(always)]
    pub(crate) fn set_front(&mut self, front: usize) {
        self.front_end = self.buffer + front * ENTRY;
    }

    #[inline(always)]
    pub(crate) fn set_back(&mut self, back: usize) {
        self.back_start = self.buffer_end() - back * ENTRY;
    }

    /// Entries of room between the tiers.
    #[inline(always)]
    pub(crate) fn room_left(&self) -> usize {
        (self.back_start - self.front_end) / ENTRY
    }

    #[inline(always)]
    fn buffer_end(&self) -> usize {
        self.buffer + self.capacity as usize * ENTRY
    }

    /// The candidate buffer, which the window does not own (it lies in the
    /// engine's pool): hence a lifetime of the caller's choosing.
    ///
    /// # Safety
    /// `buffer` and `capacity` describe a live buffer of the engine's pool
    /// (set when the window was opened), and no other reference to it is
    /// alive while the one returned is.
    #[inline(always)]
    #[allow(clippy::mut_from_ref)]
    pub(crate) unsafe fn entries<'a>(&self) -> &'a mut [Entry] {
        // SAFETY: the caller's contract.
        unsafe {
            core::slice::from_raw_parts_mut(self.buffer as *mut Entry, self.capacity as usize)
        }
    }

    /// Whether the row kernel takes this window's segments: it selects,
    /// is not awaiting a rescan, has room for a whole segment, and its
    /// segments are whole words (even first column and width) in a
    /// word-aligned row.
    #[inline(always)]
    pub(crate) fn kernel_ready(&self) -> bool {
        self.floor != 0 && (self.x | self.width) & 1 == 0 && self.room_left() >= self.width as usize
    }

    /// Sets the segment the row kernel sees: the window's, or an empty one
    /// when it is not [`kernel_ready`](Self::kernel_ready). Returns whether
    /// it is ready.
    #[inline(always)]
    pub(crate) fn update_kernel_segment(&mut self) -> bool {
        let ready = self.kernel_ready();
        self.segment_start = 2 * self.x as u32;
        self.segment_end = if ready {
            2 * self.end_column as u32
        } else {
            self.segment_start
        };
        ready
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

    /// Where a row segment of this window goes on the general path: the
    /// pre-filter rejects it whole (`floor` is capped so that an
    /// out-of-range pixel is never rejected), or it has candidates, or the
    /// window is one the general path takes pixel by pixel (floor 0: every
    /// pixel passes, no selection, a rescan).
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

// The STM32H743 keeps 128 open windows in DTCM, budgeted to the byte
// (boards/stm32h743/src/storage.rs): a field that grows the window state
// goes in its padding or replaces another.
#[cfg(target_pointer_width = "32")]
const _: () = assert!(core::mem::size_of::<OpenWindow>() <= 136);
