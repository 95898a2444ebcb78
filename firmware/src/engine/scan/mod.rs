//! The hot loop: the pixels of a window's row segment admitted into its
//! candidate buffer (see `select.rs` for the tiers).
//!
//! Pixels are read two at a time as a word; one `UQSUB16` against the
//! window's raw floor in both lanes tells whether either can reach the
//! admission threshold (`prefilter.rs`), and only those are calibrated.
//! An admitted pixel goes to the front of the buffer if it is at or above
//! the window's hint, else to the back.
//!
//! Two forms:
//! - [`row`], the **row kernel**: every open window's segment of one camera
//!   row, in one call. On Cortex-M, for a background map or no map, it is
//!   one assembly routine (`dsp`) that keeps a window's whole scan state in
//!   registers: a word pair whose four pixels all fail costs seven
//!   instructions, a window with none passing about twenty besides its
//!   pairs. [`row_portable`] is its twin: the definition, what hosts and
//!   the other calibrations run, and what the QEMU benchmark's self-test
//!   compares the assembly with. The kernel reads and writes the head of
//!   each [`OpenWindow`] (the fields before `buffer`); it stops at a window
//!   that needs the engine's attention (its front reached
//!   `OpenWindow::attention`, or less room is left than a segment takes)
//!   and at a pixel above the bit depth.
//! - `scan`, the **general path**: one window's pixels, with the room
//!   checked before every store, for what the kernel leaves (a chunk that
//!   ends inside a window, a window short of room, odd columns).
//!
//! Windows that select the complement (`stream::complement`) have a hot
//! loop of their own, in both forms: `complement`.

use super::calibrate::{self, Steps};
use super::prefilter;
use super::select::{Entry, Ties};
use super::window::{OpenWindow, Raise};

/// What the row kernel needs for one camera row (read by the assembly at
/// these offsets).
#[repr(C)]
pub struct RowScan {
    /// Address of the row's first pixel (column 0), word-aligned.
    pub row: usize,
    /// The windows to scan, `first .. end` (addresses of `OpenWindow`s,
    /// consecutive); the slot at `end` holds an end mark
    /// (`OpenWindow::mark_end`), where the assembly stops.
    pub first: usize,
    pub end: usize,
    /// `bg_row - 2 row - 16` (wrapping), `bg_row` the address of the row's
    /// first background value (any value without a background map): the
    /// background of the low pixel of a word pair read at `p - 8` is at
    /// `bg_delta + 2 p`.
    pub bg_delta: usize,
    /// `(row index << 6) - 4 - row / 2` (wrapping): a packed position is
    /// `position_base + position_delta + p / 2`, for that low pixel.
    pub position_delta: u32,
    /// The largest raw value (with `CHECK`).
    pub max_raw: u32,
    /// Written on a pixel out of range: its address.
    pub bad: usize,
    /// For [`row_portable`] only: the row's gain values (from the row's
    /// first pixel; 0 without a map) and the fixed threshold (`i32::MIN`
    /// without one).
    pub gain_row: usize,
    pub threshold: i32,
    /// The range-checking kernels for `max_raw`'s bit depth.
    pub checked: CheckedKernels,
}

/// The assembly row kernels that check pixels against the bit depth, with
/// and without a background map, chosen once for a configuration's
/// `max_raw` ([`CheckedKernels::for_max_raw`]): 8, 10, 12 and 14 bits
/// test the bits above the depth against an immediate (one instruction a
/// candidate pixel fewer), the other depths compare with `max_raw`.
/// Chosen once: matching `max_raw` at each kernel call kept only 0.11 of
/// the 0.19 instructions a pixel the immediate saves the 12-bit rows on
/// Cortex-M4 (`canary-12bit-dcmi` 13.66 -> 13.55, through this 13.47).
/// Empty off Cortex-M.
#[derive(Clone, Copy)]
pub struct CheckedKernels {
    #[cfg(target_arch = "arm")]
    background: unsafe extern "C" fn(&mut RowScan) -> usize,
    #[cfg(target_arch = "arm")]
    plain: unsafe extern "C" fn(&mut RowScan) -> usize,
}

impl CheckedKernels {
    pub fn for_max_raw(max_raw: u16) -> CheckedKernels {
        #[cfg(target_arch = "arm")]
        {
            type Kernel = unsafe extern "C" fn(&mut RowScan) -> usize;
            let (background, plain): (Kernel, Kernel) = match max_raw {
                0xFF => (dsp::row_background_checked_8, dsp::row_plain_checked_8),
                0x3FF => (dsp::row_background_checked_10, dsp::row_plain_checked_10),
                0xFFF => (dsp::row_background_checked_12, dsp::row_plain_checked_12),
                0x3FFF => (dsp::row_background_checked_14, dsp::row_plain_checked_14),
                _ => (dsp::row_background_checked, dsp::row_plain_checked),
            };
            CheckedKernels { background, plain }
        }
        #[cfg(not(target_arch = "arm"))]
        {
            let _ = max_raw;
            CheckedKernels {}
        }
    }
}

impl RowScan {
    /// The arguments for the row `row_index` at `row` (word-aligned) with
    /// `background` and `gain` (the maps' values from the row's first
    /// pixel, if any) and the fixed `threshold`, over the open windows
    /// `windows` but the last, which becomes the range's end mark
    /// (`OpenWindow::mark_end`). Panics if `windows` is empty.
    pub fn new(
        row: &[u16],
        row_index: u16,
        background: Option<&[i32]>,
        gain: Option<&[u16]>,
        threshold: Option<i32>,
        windows: &mut [OpenWindow],
        max_raw: u16,
    ) -> RowScan {
        let row_address = row.as_ptr() as usize;
        let bg_row = background.map_or(0, |b| b.as_ptr() as usize);
        windows.last_mut().expect("the end mark's slot").mark_end();
        let range = windows.as_mut_ptr_range();
        RowScan {
            row: row_address,
            first: range.start as usize,
            end: range.end as usize - core::mem::size_of::<OpenWindow>(),
            bg_delta: bg_row.wrapping_sub(2 * row_address).wrapping_sub(16),
            position_delta: ((row_index as u32) << 6)
                .wrapping_sub(4)
                .wrapping_sub((row_address >> 1) as u32),
            max_raw: max_raw as u32,
            bad: 0,
            gain_row: gain.map_or(0, |g| g.as_ptr() as usize),
            threshold: threshold.unwrap_or(i32::MIN),
            checked: CheckedKernels::for_max_raw(max_raw),
        }
    }
}

/// Why the row kernel returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RowStop {
    /// Every window's segment is done.
    Done,
    /// The window at this address needs the engine (its segment is done):
    /// the kernel goes on from the next one when called again.
    Attention(usize),
    /// The pixel at this address, in the segment of the window at that
    /// one, is above `max_raw`; the row is abandoned.
    OutOfRange { window: usize, pixel: usize },
}

/// The row kernel: each window's segment of the row (its
/// `segment_start .. segment_end`, bytes from the row's first pixel; empty
/// ones are skipped), from `args.first` on: pixels `r` with `r > lanes`
/// (as a 16-bit lane) checked against `max_raw` (`CHECK`), calibrated,
/// and admitted if `p >= admit`, to the front (stored at `front_end`,
/// which grows) if `p >= hint`, else to the back (stored below
/// `back_start`, which falls), in order of column. After a segment in
/// which some pixel passed the lanes, it stops at the window if
/// `back_start - front_end <= short_of_room` or `front_end >= attention`.
///
/// # Safety
/// `args` as [`RowScan::new`] makes them from live slices: the row holds
/// every window's segment, the background map (`S::BACKGROUND`) covers the
/// row, every window with a non-empty segment is word-aligned there and
/// its buffer has more than `short_of_room` bytes between its tiers; and
/// the slot at `end` is a live `OpenWindow` marked as the range's end
/// (`OpenWindow::mark_end`): the assembly walks the windows to that mark,
/// one comparison a window fewer than counting them to `end`.
#[inline(always)]
pub unsafe fn row<S: Steps, const CHECK: bool>(args: &mut RowScan) -> RowStop {
    // SAFETY: a live slot (the caller's contract).
    debug_assert!(unsafe { &*(args.end as *const OpenWindow) }.is_end_mark());
    #[cfg(target_arch = "arm")]
    if !S::GAIN && !S::THRESHOLD {
        // SAFETY: the caller's contract; the routine's register use and
        // offsets are its own (see `dsp`).
        let stop = unsafe {
            match (S::BACKGROUND, CHECK) {
                (true, false) => dsp::row_background(args),
                (true, true) => (args.checked.background)(args),
                (false, false) => dsp::row_plain(args),
                (false, true) => (args.checked.plain)(args),
            }
        };
        return match stop {
            0 => RowStop::Done,
            w if w & 1 == 0 => RowStop::Attention(w),
            w => RowStop::OutOfRange {
                window: w & !1,
                pixel: args.bad,
            },
        };
    }
    // SAFETY: the caller's contract.
    unsafe { row_portable::<S, CHECK>(args) }
}

/// The definition of [`row`], and its form on hosts and for gain maps and
/// fixed thresholds.
///
/// # Safety
/// As [`row`].
pub unsafe fn row_portable<S: Steps, const CHECK: bool>(args: &mut RowScan) -> RowStop {
    let mut at = args.first;
    while at != args.end {
        // SAFETY: `first .. end` are consecutive live open windows (the
        // caller's contract).
        let window = unsafe { &mut *(at as *mut OpenWindow) };
        let (start, end) = (window.segment_start as usize, window.segment_end as usize);
        if start != end {
            let pixels = (end - start) / 2;
            // SAFETY: the row holds the segment (the caller's contract).
            let raw =
                unsafe { core::slice::from_raw_parts((args.row + start) as *const u16, pixels) };
            let column = start / 2;
            let background = if S::BACKGROUND {
                // SAFETY: the map covers the row: `bg_delta` was made from
                // its first value's address.
                let bg_row = args.bg_delta.wrapping_add(2 * args.row).wrapping_add(16);
                unsafe { core::slice::from_raw_parts((bg_row as *const i32).add(column), pixels) }
            } else {
                &[][..]
            };
            let gain = if S::GAIN {
                // SAFETY: as the background.
                unsafe {
                    core::slice::from_raw_parts((args.gain_row as *const u16).add(column), pixels)
                }
            } else {
                &[][..]
            };
            let position = window.position_base.wrapping_add(
                args.position_delta
                    .wrapping_add(4)
                    .wrapping_add((args.row >> 1) as u32)
                    .wrapping_add(column as u32),
            );
            let mask = hot_pixels(raw, window.lanes);
            let passed = mask != 0;
            let (mut front_end, mut back_start) = (window.front_end, window.back_start);
            let (admit, hint) = (window.admit, window.hint);
            let mut bits = mask;
            while bits != 0 {
                let i = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                debug_assert!(i < raw.len());
                // SAFETY: `hot_pixels` sets bits of `raw`'s pixels only.
                let r = unsafe { *raw.get_unchecked(i) };
                if CHECK && r as u32 > args.max_raw {
                    args.bad = raw.as_ptr() as usize + 2 * i;
                    return RowStop::OutOfRange {
                        window: at,
                        pixel: args.bad,
                    };
                }
                // SAFETY: i < pixels, within the segment's maps (or no map).
                let p = unsafe {
                    calibrate::value_in_run_unchecked::<S>(r, i, background, gain, args.threshold)
                };
                // The entry as one word (`Entry` is `repr(C)`, value
                // first): one store a copy, not two.
                let entry = Entry::word(p, position.wrapping_add(i as u32));
                // Without a branch (they mispredict on hosts): written at
                // both free ends, kept by moving the end of its tier. The
                // buffer has room for the segment (the caller's contract)
                // and each pixel stores once, so both writes are in the
                // free space, and where they meet they are one.
                let admitted = p >= admit;
                let upper = p >= hint;
                const ENTRY: usize = core::mem::size_of::<Entry>();
                // SAFETY: see above (`Entry`'s alignment is 4: unaligned
                // word stores).
                unsafe {
                    (front_end as *mut u64).write_unaligned(entry);
                    ((back_start - ENTRY) as *mut u64).write_unaligned(entry);
                }
                front_end += ENTRY * (admitted & upper) as usize;
                back_start -= ENTRY * (admitted & !upper) as usize;
            }
            window.front_end = front_end;
            window.back_start = back_start;
            if passed {
                if window.back_start - window.front_end <= window.short_of_room as usize {
                    return RowStop::Attention(at);
                }
                if window.front_end >= window.attention {
                    // A counting raise that does not prove sets the
                    // next attention instead; the others stop.
                    let raise = window.raise;
                    let proved = match raise {
                        Raise::NONE => return RowStop::Attention(at),
                        Raise::LOWER => {
                            if !lower_hint(window) {
                                return RowStop::Attention(at);
                            }
                            true
                        }
                        _ => match raise.copies() {
                            Some(copies) => count_and_prove(window, copies),
                            None => true,
                        },
                    };
                    if proved {
                        raise_admission(window);
                    }
                }
            }
        }
        at += core::mem::size_of::<OpenWindow>();
    }
    RowStop::Done
}

/// The kernel's raise of a window's admission to its hint (at it for
/// `Raise::AT_HINT`, else above it), as prepared by the engine
/// (`OpenWindow::raise`): the back tier dropped, `low` the hint, no
/// further attention.
#[inline(always)]
fn raise_admission(window: &mut OpenWindow) {
    let strict = window.raise != Raise::AT_HINT;
    let lane = window.raise_lane as u32;
    window.floor = lane + 1;
    window.lanes = lane.wrapping_mul(0x0001_0001);
    window.admit = window.hint + strict as i32;
    window.low = window.hint;
    window.strict = strict;
    window.back_start = window.buffer + window.capacity as usize * core::mem::size_of::<Entry>();
    window.attention = usize::MAX;
}

/// `Raise::LOWER` before its raise: the hint lowered to `hint - 1` at the
/// first copy of it in the back tier (from `back_start` up), which becomes
/// the hint's one tie (the window had none); every front entry is above
/// it. `false` (nothing changed) if the back holds no copy.
#[inline(always)]
fn lower_hint(window: &mut OpenWindow) -> bool {
    const ENTRY: usize = core::mem::size_of::<Entry>();
    let end = window.buffer + window.capacity as usize * ENTRY;
    // With a back tier, its values are below the hint: no overflow.
    let level = window.hint.wrapping_sub(1);
    let mut at = window.back_start;
    while at < end {
        // SAFETY: between `back_start` and the buffer's end: the window's
        // live back entries.
        let entry = unsafe { (at as *const Entry).read() };
        if entry.value == level {
            window.hint = level;
            window.hint_ties = Ties::NONE;
            window.hint_ties.add(entry.position as u16);
            window.at_hint = 0;
            window.counted = ((window.front_end - window.buffer) / ENTRY) as u16;
            return true;
        }
        at += ENTRY;
    }
    false
}

/// A counting raise (`Raise::counting`): the front's copies of the hint
/// since the last count added to `at_hint`; `true` if N front values are
/// above the hint and it has `copies` copies (with its ties), else the
/// window's next `attention` (`stream::admission::attention`'s for these
/// rules) set.
#[inline(always)]
fn count_and_prove(window: &mut OpenWindow, copies: u8) -> bool {
    const ENTRY: usize = core::mem::size_of::<Entry>();
    let front = (window.front_end - window.buffer) / ENTRY;
    let mut at = window.buffer + window.counted as usize * ENTRY;
    let mut at_hint = window.at_hint as usize;
    while at < window.front_end {
        // SAFETY: between the buffer's start and the front's end: the
        // window's live front entries.
        let value = unsafe { (at as *const Entry).read().value };
        at_hint += (value == window.hint) as usize;
        at += ENTRY;
    }
    window.at_hint = at_hint as u16;
    window.counted = front as u16;
    let (n, have) = (window.n as usize, at_hint + window.hint_ties.count as usize);
    if front - at_hint >= n && have >= copies as usize {
        return true;
    }
    let fewest = n + at_hint + (copies as usize).saturating_sub(have);
    window.attention = window.buffer + fewest.max(front + 1) * ENTRY;
    false
}

/// The pixels of `raw` (at most 64) above `lanes`' low half, as a bit
/// mask. On x86-64 sixteen at a time (`prefilter::mask_at_least`); on
/// Cortex-M (where this is the twin and the gain path) two at a time by
/// `UQSUB16`.
#[inline(always)]
fn hot_pixels(raw: &[u16], lanes: u32) -> u64 {
    let below = lanes as u16;
    if below == u16::MAX {
        return 0;
    }
    #[cfg(not(target_arch = "arm"))]
    {
        prefilter::mask_at_least(raw, below + 1)
    }
    #[cfg(target_arch = "arm")]
    {
        let mut mask = 0u64;
        for (w, pair) in raw.chunks(2).enumerate() {
            let word = pair[0] as u32 | (pair.get(1).copied().unwrap_or(0) as u32) << 16;
            let passing = prefilter::uqsub16(word, lanes);
            if passing != 0 {
                mask |= ((passing & 0xffff != 0) as u64) << (2 * w);
                mask |= ((passing >> 16 != 0 && pair.len() == 2) as u64) << (2 * w + 1);
            }
        }
        mask
    }
}

/// Why [`scan`] stopped before the end of its run.
pub(super) enum Stop {
    End,
    /// The pixel at this offset of the segment is above the bit depth.
    OutOfRange(usize),
    /// The buffer is full; the pixel at offset `k` is still to be placed.
    Full {
        k: usize,
        entry: Entry,
    },
}

/// One window's run of pixels to scan, with what calibrating them takes.
pub(super) struct Segment<'a> {
    /// Pixels `start ..` of the segment.
    pub(super) raw: &'a [u16],
    pub(super) start: usize,
    /// The whole segment's maps, as `calibrate::run_maps` gives them.
    pub(super) background: &'a [i32],
    pub(super) gain: &'a [u16],
    pub(super) fixed: i32,
    /// Packed position of the segment's first pixel.
    pub(super) base: u16,
    pub(super) max_raw: u16,
}

/// The general path: admits the pixels of a segment that reach the
/// window's raw floor and calibrate to at least its admission threshold,
/// checking for room before each store. In the scan the tiers are only
/// two: `p >= hint` goes to the front, below it to the back (pixels equal
/// to the hint or to `low` stay individual entries; only a compaction
/// gathers them into tie buckets, see `select.rs`).
#[inline(always)]
pub(super) fn scan<S: Steps, const CHECK: bool>(
    window: &mut OpenWindow,
    segment: &Segment<'_>,
) -> Stop {
    let Segment {
        raw,
        start,
        background,
        gain,
        fixed,
        base,
        max_raw,
    } = *segment;
    // The maps cover the whole segment; the scan reads offsets `start ..`.
    let end = start + raw.len();
    assert!((!S::BACKGROUND || background.len() >= end) && (!S::GAIN || gain.len() >= end));
    let (floor, admit, hint) = (window.floor, window.admit, window.hint);
    for (k, &r) in (start..).zip(raw) {
        if (r as u32) < floor {
            continue;
        }
        if CHECK && r > max_raw {
            return Stop::OutOfRange(k);
        }
        let p = calibrate::value_in_run::<S>(r, k, background, gain, fixed);
        if p < admit {
            continue;
        }
        let entry = Entry {
            value: p,
            position: (base + k as u16) as u32,
        };
        if window.front_end == window.back_start {
            return Stop::Full { k, entry };
        }
        // SAFETY: room for one entry between the tiers (checked), within
        // the window's buffer.
        unsafe {
            if p >= hint {
                (window.front_end as *mut Entry).write(entry);
                window.front_end += core::mem::size_of::<Entry>();
            } else {
                window.back_start -= core::mem::size_of::<Entry>();
                (window.back_start as *mut Entry).write(entry);
            }
        }
    }
    Stop::End
}

mod check;
pub mod complement;
#[cfg(target_arch = "arm")]
mod complement_dsp;
#[cfg(target_arch = "arm")]
mod dsp;

pub use check::{check_complement_row, check_row_kernel, KernelMismatch};
