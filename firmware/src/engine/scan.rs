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
//! - [`scan`], the **general path**: one window's pixels, with the room
//!   checked before every store, for what the kernel leaves (a chunk that
//!   ends inside a window, a window short of room, odd columns).

use super::calibrate::{self, Steps};
use super::prefilter;
use super::select::Entry;
use super::window::OpenWindow;

/// What the row kernel needs for one camera row (read by the assembly at
/// these offsets).
#[repr(C)]
pub struct RowScan {
    /// Address of the row's first pixel (column 0), word-aligned.
    pub row: usize,
    /// The windows to scan, `first .. end` (addresses of `OpenWindow`s,
    /// consecutive).
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
}

impl RowScan {
    /// The arguments for the row `row_index` at `row` (word-aligned) with
    /// `background` and `gain` (the maps' values from the row's first
    /// pixel, if any) and the fixed `threshold`, over the open windows
    /// `windows`.
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
        let range = windows.as_mut_ptr_range();
        RowScan {
            row: row_address,
            first: range.start as usize,
            end: range.end as usize,
            bg_delta: bg_row.wrapping_sub(2 * row_address).wrapping_sub(16),
            position_delta: ((row_index as u32) << 6)
                .wrapping_sub(4)
                .wrapping_sub((row_address >> 1) as u32),
            max_raw: max_raw as u32,
            bad: 0,
            gain_row: gain.map_or(0, |g| g.as_ptr() as usize),
            threshold: threshold.unwrap_or(i32::MIN),
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
/// `back_start - front_end < room` or `front_end >= attention`.
///
/// # Safety
/// `args` as [`RowScan::new`] makes them from live slices: the row holds
/// every window's segment, the background map (`S::BACKGROUND`) covers the
/// row, every window with a non-empty segment is word-aligned there and
/// its buffer has `room` bytes between its tiers.
#[inline(always)]
pub unsafe fn row<S: Steps, const CHECK: bool>(args: &mut RowScan) -> RowStop {
    #[cfg(target_arch = "arm")]
    if !S::GAIN && !S::THRESHOLD {
        // SAFETY: the caller's contract; the routine's register use and
        // offsets are its own (see `dsp`).
        let stop = unsafe {
            match (S::BACKGROUND, CHECK) {
                (true, false) => dsp::row_background(args),
                (true, true) => dsp::row_background_checked(args),
                (false, false) => dsp::row_plain(args),
                (false, true) => dsp::row_plain_checked(args),
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
                let r = raw[i];
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
                let entry = Entry {
                    value: p,
                    position: position.wrapping_add(i as u32),
                };
                // Without a branch (they mispredict on hosts): written at
                // both free ends, kept by moving the end of its tier. The
                // buffer has room for the segment (the caller's contract)
                // and each pixel stores once, so both writes are in the
                // free space, and where they meet they are one.
                let admitted = p >= admit;
                let upper = p >= hint;
                const ENTRY: usize = core::mem::size_of::<Entry>();
                // SAFETY: see above.
                unsafe {
                    (front_end as *mut Entry).write(entry);
                    ((back_start - ENTRY) as *mut Entry).write(entry);
                }
                front_end += ENTRY * (admitted & upper) as usize;
                back_start -= ENTRY * (admitted & !upper) as usize;
            }
            window.front_end = front_end;
            window.back_start = back_start;
            if passed
                && (window.back_start - window.front_end < window.room as usize
                    || window.front_end >= window.attention)
            {
                return RowStop::Attention(at);
            }
        }
        at += core::mem::size_of::<OpenWindow>();
    }
    RowStop::Done
}

/// The pixels of `raw` (at most 64) above `lanes`' low half, as a bit
/// mask. On x86-64 eight at a time (`prefilter::mask_at_least`); on
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

#[cfg(target_arch = "arm")]
mod dsp {
    //! The row kernel in assembly. Registers while a window is scanned:
    //! r0 test and temporary, r1 r2 the word pair, r3 a pixel's value, r4
    //! temporary (background, position), r5 the pixel pointer, r6 the
    //! segment's end, r7 the lanes, r8 `admit`, r9 the window's position
    //! constant, r10 `front_end`, r11 `back_start`, r12 `bg_delta`, lr the
    //! window. On the stack: the row, the windows' end, `position_delta`,
    //! `max_raw`, the arguments.
    //!
    //! A segment is scanned by the *cold* loop until some pixel passes the
    //! lanes; the pixel handlers return into the *hot* copy of the loop,
    //! whose exit stores the tiers' ends and checks room and attention (a
    //! cold segment touches none of it).

    use super::super::window::OpenWindow;
    use super::RowScan;
    use core::mem::offset_of;

    /// The range check of the pixel in r3 when `$check`: out to `$out`.
    macro_rules! check {
        (true, $out:literal) => {
            concat!("ldr r4, [sp, #12]\n", "cmp r3, r4\n", "bhi ", $out, "\n")
        };
        (false, $out:literal) => {
            ""
        };
    }

    /// r3 = the calibrated value of the raw pixel in r3, whose background
    /// is at `bg_delta + 2 p + $offset`.
    macro_rules! calibrate {
        (true, 0) => {
            concat!("ldr.w r4, [r12, r5, lsl #1]\n", "rsb r3, r4, r3, lsl #4\n")
        };
        (true, $offset:literal) => {
            concat!(
                "add r4, r12, r5, lsl #1\n",
                "ldr r4, [r4, #",
                stringify!($offset),
                "]\n",
                "rsb r3, r4, r3, lsl #4\n"
            )
        };
        (false, $offset:literal) => {
            "lsl r3, r3, #4\n"
        };
    }

    /// r4 = the packed position of the lane `$lane` (0-3) of the pair.
    macro_rules! position {
        (0) => {
            "add r4, r9, r5, lsr #1\n"
        };
        ($lane:literal) => {
            concat!(
                "add r4, r9, r5, lsr #1\n",
                "add r4, r4, #",
                stringify!($lane),
                "\n"
            )
        };
    }

    /// The value in r3 (calibrated) admitted if `>= admit`, to its tier;
    /// else on to `$skip`.
    macro_rules! admit {
        ($lane:tt, $skip:literal) => {
            concat!(
                "cmp r3, r8\n",
                "blt ",
                $skip,
                "\n",
                "ldr r4, [lr, #{hint}]\n",
                "cmp r3, r4\n",
                position!($lane),
                "ite ge\n",
                "strdge r3, r4, [r10], #8\n",
                "strdlt r3, r4, [r11, #-8]!\n",
            )
        };
    }

    macro_rules! kernel {
        ($name:ident, $bg:tt, $check:tt) => {
            #[unsafe(naked)]
            pub unsafe extern "C" fn $name(args: &mut RowScan) -> usize {
                core::arch::naked_asm!(
                    "push {{r4-r11, lr}}",
                    "sub sp, #20",
                    "ldr r1, [r0, #{a_row}]",
                    "str r1, [sp, #0]",
                    "ldr r1, [r0, #{a_end}]",
                    "str r1, [sp, #4]",
                    "ldr r1, [r0, #{a_position}]",
                    "str r1, [sp, #8]",
                    "ldr r1, [r0, #{a_max_raw}]",
                    "str r1, [sp, #12]",
                    "str r0, [sp, #16]",
                    "ldr lr, [r0, #{a_first}]",
                    "ldr r12, [r0, #{a_bg}]",
                    "ldr r0, [sp, #4]",
                    "cmp lr, r0",
                    "beq 80f",
                    // A window: its segment (empty: the next window), lanes,
                    // admission, position constant and tiers.
                    "2:",
                    "ldm lr, {{r5, r6, r7, r8, r9}}",
                    "subs r0, r6, r5",
                    "beq 1f",
                    "ldrd r10, r11, [lr, #{front_end}]",
                    "ldr r3, [sp, #0]",
                    "add r5, r5, r3",
                    "add r6, r6, r3",
                    "ldr r3, [sp, #8]",
                    "add r9, r9, r3",
                    "tst r0, #4",
                    "bne 9f",
                    // The cold loop.
                    "3:",
                    "ldrd r1, r2, [r5], #8",
                    "uqsub16 r0, r1, r7",
                    "cbnz r0, 31f",
                    "4:",
                    "uqsub16 r0, r2, r7",
                    "cbnz r0, 32f",
                    "cmp r5, r6",
                    "bne 3b",
                    // The next window.
                    "1:",
                    "add lr, lr, #{size}",
                    "ldr r0, [sp, #4]",
                    "cmp lr, r0",
                    "bne 2b",
                    "80:",
                    "movs r0, #0",
                    "81:",
                    "add sp, #20",
                    "pop {{r4-r11, pc}}",
                    // A segment of an odd number of words: its first word
                    // as a pair's second.
                    "9:",
                    "ldr r2, [r5], #4",
                    "b 4b",
                    "31:",
                    "b 6f",
                    "32:",
                    "b 5f",
                    // The hot loop (its exit after the handlers): the
                    // second word's handler comes first, so that both
                    // `cbnz` reach theirs.
                    "13:",
                    "ldrd r1, r2, [r5], #8",
                    "uqsub16 r0, r1, r7",
                    "cbnz r0, 6f",
                    "14:",
                    "uqsub16 r0, r2, r7",
                    "cbnz r0, 5f",
                    "17:",
                    "cmp r5, r6",
                    "bne 13b",
                    "b 19f",
                    // The second word's pixels (at p - 4, p - 2); its high
                    // pixel after the first word's handler.
                    "5:",
                    "lsls r3, r0, #16",
                    "beq 51f",
                    "uxth r3, r2",
                    check!($check, "92f"),
                    calibrate!($bg, 8),
                    admit!(2, "51f"),
                    "51:",
                    "uqsub16 r0, r2, r7",
                    "cmp r0, #0x10000",
                    "blo 17b",
                    "b 52f",
                    // The first word's pixels (at p - 8, p - 6).
                    "6:",
                    "lsls r3, r0, #16",
                    "beq 61f",
                    "uxth r3, r1",
                    check!($check, "90f"),
                    calibrate!($bg, 0),
                    admit!(0, "61f"),
                    "61:",
                    "uqsub16 r0, r1, r7",
                    "cmp r0, #0x10000",
                    "blo 14b",
                    "lsrs r3, r1, #16",
                    check!($check, "91f"),
                    calibrate!($bg, 4),
                    admit!(1, "14b"),
                    "b 14b",
                    "52:",
                    "lsrs r3, r2, #16",
                    check!($check, "93f"),
                    calibrate!($bg, 12),
                    admit!(3, "17b"),
                    "b 17b",
                    // The hot loop's exit: the tiers' ends stored, room and
                    // attention checked.
                    "19:",
                    "strd r10, r11, [lr, #{front_end}]",
                    "sub r0, r11, r10",
                    "ldr r3, [lr, #{room}]",
                    "cmp r0, r3",
                    "blo 18f",
                    "ldr r0, [lr, #{attention}]",
                    "cmp r10, r0",
                    "blo 1b",
                    "18:",
                    "mov r0, lr",
                    "b 81b",
                    // Out of range: the pixel's address, and the window
                    // tagged.
                    "90:",
                    "sub r3, r5, #8",
                    "b 95f",
                    "91:",
                    "sub r3, r5, #6",
                    "b 95f",
                    "92:",
                    "sub r3, r5, #4",
                    "b 95f",
                    "93:",
                    "sub r3, r5, #2",
                    "95:",
                    "ldr r0, [sp, #16]",
                    "str r3, [r0, #{a_bad}]",
                    "orr r0, lr, #1",
                    "b 81b",
                    a_row = const offset_of!(RowScan, row),
                    a_first = const offset_of!(RowScan, first),
                    a_end = const offset_of!(RowScan, end),
                    a_bg = const offset_of!(RowScan, bg_delta),
                    a_position = const offset_of!(RowScan, position_delta),
                    a_max_raw = const offset_of!(RowScan, max_raw),
                    a_bad = const offset_of!(RowScan, bad),
                    front_end = const offset_of!(OpenWindow, front_end),
                    hint = const offset_of!(OpenWindow, hint),
                    attention = const offset_of!(OpenWindow, attention),
                    room = const offset_of!(OpenWindow, room),
                    size = const core::mem::size_of::<OpenWindow>(),
                )
            }
        };
    }

    // The `ldm` above loads these five fields in this order.
    const _: () = {
        assert!(offset_of!(OpenWindow, segment_start) == 0);
        assert!(offset_of!(OpenWindow, segment_end) == 4);
        assert!(offset_of!(OpenWindow, lanes) == 8);
        assert!(offset_of!(OpenWindow, admit) == 12);
        assert!(offset_of!(OpenWindow, position_base) == 16);
        assert!(offset_of!(OpenWindow, back_start) == offset_of!(OpenWindow, front_end) + 4);
        assert!(core::mem::size_of::<OpenWindow>() < 4096);
    };

    kernel!(row_background, true, false);
    kernel!(row_background_checked, true, true);
    kernel!(row_plain, false, false);
    kernel!(row_plain_checked, false, true);
}

/// What [`check_row_kernel`] found different.
#[derive(Clone, Copy, Debug)]
pub struct KernelMismatch {
    pub what: &'static str,
    /// The round it happened in.
    pub round: usize,
    /// Where: a window, or a detail of the difference.
    pub window: usize,
    /// The kernel's and the twin's candidates that differ.
    pub entries: [Entry; 2],
}

/// The row kernel ([`row`]) against its twin ([`row_portable`]) on random
/// rows, windows, thresholds, maps, fill levels and bit depths: the same
/// stops, out-of-range pixels, candidates (values, positions, order) and
/// tier ends. On Cortex-M this compares the assembly with its definition
/// (the QEMU benchmark runs it before timing anything); elsewhere both are
/// the twin. `Err` says what differed, in which round.
pub fn check_row_kernel(seed: u64, rounds: usize) -> Result<(), KernelMismatch> {
    use super::calibrate::With;
    const PIXELS: usize = 224;
    #[repr(C, align(4))]
    struct Pixels([u16; PIXELS]);
    let mut state = seed | 1;
    let mut next = move |below: u32| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        ((state >> 16) as u32) % below.max(1)
    };
    let mut pixels = Pixels([0; PIXELS]);
    let mut background = [0i32; PIXELS];
    // Each window gets `SHARE` entries, more than its widest segment.
    const SHARE: usize = 40;
    let mut buffers = [[Entry::ZERO; 7 * SHARE]; 2];
    for round in 0..rounds {
        let top = 1 + next(5) * 13_000 + next(300);
        let max_raw: u16 = [255, 4_095, u16::MAX][round % 3];
        let check = max_raw != u16::MAX;
        for r in pixels.0.iter_mut() {
            *r = next(top).min(max_raw as u32) as u16;
            if check && next(400) == 0 {
                *r = max_raw + 1 + next(50) as u16;
            }
        }
        for b in background.iter_mut() {
            *b = next(16 * top) as i32 - (16 * top / 3) as i32;
        }
        let with_background = round % 4 != 3;
        // Up to seven windows from the row's start, even columns and widths,
        // with gaps; both copies share the layout, each its own buffers.
        let mut windows = [[OpenWindow::CLOSED; 7]; 2];
        let count = 1 + next(7) as usize;
        let mut x = 2 * next(3) as u16;
        let mut made = 0;
        for k in 0..count {
            let width = 2 + 2 * next(16) as u16;
            if (x + width) as usize > PIXELS {
                break;
            }
            let floor = next(top + 2);
            let admit = next(16 * top) as i32 - (16 * top / 4) as i32;
            let hint = admit + next(16 * top / 2 + 1) as i32;
            let lanes = if floor == 0 || next(9) == 0 {
                u32::MAX
            } else {
                (floor - 1).min(65_534) * 0x0001_0001
            };
            for copies in windows.iter_mut() {
                let w = &mut copies[k];
                *w = OpenWindow::CLOSED;
                w.segment_start = 2 * x as u32;
                w.segment_end = 2 * (x + width) as u32;
                w.lanes = lanes;
                w.admit = admit;
                w.hint = hint;
                w.position_base = (k as u32) << 6;
                w.room = 8 * width as u32;
                made = k + 1;
            }
            x += width + 2 * next(2) as u16;
        }
        if made == 0 {
            continue;
        }
        // Buffers: partly filled, the room never below a segment.
        let share = SHARE;
        for k in 0..made {
            let front = next(4) as usize;
            let back = next(4) as usize;
            let attention = next(share as u32 + 2) as usize;
            for (copies, buffer) in windows.iter_mut().zip(buffers.iter_mut()) {
                let w = &mut copies[k];
                let start =
                    buffer.as_mut_ptr() as usize + k * share * core::mem::size_of::<Entry>();
                let width = (w.segment_end - w.segment_start) as usize / 2;
                w.buffer = start;
                w.capacity = share as u16;
                let keep = share.saturating_sub(width);
                w.set_front(front.min(keep));
                w.set_back(back.min(keep - front.min(keep)));
                w.attention = start + attention * core::mem::size_of::<Entry>();
            }
        }
        for buffer in buffers.iter_mut() {
            buffer.fill(Entry::ZERO);
        }
        let run = |windows: &mut [OpenWindow], twin: bool| {
            let map = with_background.then_some(&background[..]);
            let mut args = RowScan::new(&pixels.0, 0, map, None, None, windows, max_raw);
            let mut stops = [RowStop::Done; 8];
            let mut n = 0;
            loop {
                // SAFETY: arguments from live slices; every window's segment
                // is inside the row, word-aligned, with room for it.
                let stop = unsafe {
                    match (with_background, check, twin) {
                        (true, false, false) => row::<With<true, false, false>, false>(&mut args),
                        (true, true, false) => row::<With<true, false, false>, true>(&mut args),
                        (false, false, false) => row::<With<false, false, false>, false>(&mut args),
                        (false, true, false) => row::<With<false, false, false>, true>(&mut args),
                        (true, false, true) => {
                            row_portable::<With<true, false, false>, false>(&mut args)
                        }
                        (true, true, true) => {
                            row_portable::<With<true, false, false>, true>(&mut args)
                        }
                        (false, false, true) => {
                            row_portable::<With<false, false, false>, false>(&mut args)
                        }
                        (false, true, true) => {
                            row_portable::<With<false, false, false>, true>(&mut args)
                        }
                    }
                };
                let first = windows.as_ptr() as usize;
                let relative = match stop {
                    RowStop::Done => RowStop::Done,
                    RowStop::Attention(w) => RowStop::Attention(w - first),
                    RowStop::OutOfRange { window, pixel } => RowStop::OutOfRange {
                        window: window - first,
                        pixel: pixel - pixels.0.as_ptr() as usize,
                    },
                };
                stops[n] = relative;
                n += 1;
                match stop {
                    RowStop::Attention(w) if n < stops.len() => {
                        args.first = w + core::mem::size_of::<OpenWindow>();
                    }
                    _ => return (stops, n),
                }
            }
        };
        let (a, b) = windows.split_at_mut(1);
        let (kernel, twin) = (&mut a[0][..made], &mut b[0][..made]);
        let (stops_kernel, n_kernel) = run(kernel, false);
        let (stops_twin, n_twin) = run(twin, true);
        if stops_kernel[..n_kernel] != stops_twin[..n_twin] {
            return Err(KernelMismatch {
                what: "the row kernel stopped elsewhere than its twin",
                round,
                window: n_kernel,
                entries: [Entry::ZERO; 2],
            });
        }
        if matches!(stops_kernel[n_kernel - 1], RowStop::OutOfRange { .. }) {
            continue;
        }
        for (k, t) in kernel.iter().zip(twin.iter()) {
            let (kb, tb) = (
                k.buffer - buffers[0].as_ptr() as usize,
                t.buffer - buffers[1].as_ptr() as usize,
            );
            if kb != tb || k.front() != t.front() || k.back() != t.back() {
                return Err(KernelMismatch {
                    what: "the row kernel's tiers differ from its twin's",
                    round,
                    window: (k.front() << 16) | t.front(),
                    entries: [Entry::ZERO; 2],
                });
            }
        }
        // The tiers' contents (the twin also writes into the free space).
        let in_tiers = |i: usize| {
            let k = i / share;
            if k >= made {
                return false;
            }
            let (front, back) = (kernel[k].front(), kernel[k].back());
            let at = i % share;
            at < front || at >= share - back
        };
        if let Some(at) =
            (0..buffers[0].len()).find(|&i| in_tiers(i) && buffers[0][i] != buffers[1][i])
        {
            return Err(KernelMismatch {
                what: "the row kernel's candidates differ from its twin's",
                round,
                window: at,
                entries: [buffers[0][at], buffers[1][at]],
            });
        }
    }
    Ok(())
}
