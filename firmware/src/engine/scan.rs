//! The hot loop: one window's run of pixels in a row, admitted into its
//! candidate buffer (see `select.rs` for the tiers).
//!
//! Pixels are read two at a time as a word; one `UQSUB16` against the
//! window's raw floor in both lanes tells whether either can reach the
//! admission threshold (`prefilter.rs`), and only those are calibrated.
//!
//! [`admit_words`] is the loop most of the engine's time goes to: on
//! Cortex-M, for a background map, it is assembly (`dsp`), whose portable
//! twin [`admit_words_portable`] the QEMU benchmark's self-test compares it
//! with on random runs; both are public only for that test.

use super::calibrate::{self, Steps};
use super::prefilter;
use super::select::Entry;
use super::window::OpenWindow;

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

/// The hot loop: admits the pixels of a segment that reach the window's
/// raw floor and calibrate to at least its admission threshold. In the
/// scan the tiers are only two: `p >= hint` goes to the front, below it to
/// the back (pixels equal to the hint or to `low` stay individual entries;
/// only a compaction gathers them into tie buckets, see `select.rs`).
#[inline(always)]
pub(super) fn scan<S: Steps, const CHECK: bool>(
    window: &mut OpenWindow,
    entries: &mut [Entry],
    segment: &Segment<'_>,
) -> Stop {
    let Segment {
        raw,
        start,
        background,
        gain,
        ..
    } = *segment;
    let capacity = entries.len();
    let hint = window.hint;
    let admit = window.admit;
    let floor = window.floor;
    let (front, back) = (window.front as usize, window.back as usize);
    // The maps cover the whole segment; the scan reads offsets `start ..`.
    let end = start + raw.len();
    assert!((!S::BACKGROUND || background.len() >= end) && (!S::GAIN || gain.len() >= end));
    assert!(front + back <= capacity);
    let mut filled = Tiers2 {
        front,
        back,
        capacity,
    };
    let admission = Admission { floor, admit, hint };
    let stop = if capacity - front - back >= raw.len() {
        // Room for every pixel of the run: no check of room per pixel.
        scan_run::<S, CHECK, false>(segment, admission, entries, &mut filled)
    } else {
        scan_run::<S, CHECK, true>(segment, admission, entries, &mut filled)
    };
    window.front = filled.front as u16;
    window.back = filled.back as u16;
    stop
}

/// How much of a candidate buffer the front and back fill.
pub(super) struct Tiers2 {
    pub(super) front: usize,
    pub(super) back: usize,
    pub(super) capacity: usize,
}

/// A window's admission for one run: the raw floor of its pre-filter, the
/// calibrated threshold, and the hint that splits front from back.
#[derive(Clone, Copy)]
pub(super) struct Admission {
    pub(super) floor: u32,
    pub(super) admit: i32,
    pub(super) hint: i32,
}

/// The pixel loop of [`scan`]; `ROOM`: check for room before each store.
#[inline(always)]
pub(super) fn scan_run<S: Steps, const CHECK: bool, const ROOM: bool>(
    segment: &Segment<'_>,
    admission: Admission,
    entries: &mut [Entry],
    filled: &mut Tiers2,
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
    let Admission { floor, admit, hint } = admission;
    let capacity = filled.capacity;
    debug_assert!(capacity <= entries.len());
    let origin = entries.as_mut_ptr();
    // SAFETY (for every pointer below): `front` and `back` are the tiers'
    // ends, front + back <= capacity <= entries.len(); a store happens only
    // where room was proved: for the whole run by the caller (`!ROOM`,
    // capacity - front - back >= raw.len() and each pixel stores at most
    // once) or just before it (`ROOM`).
    let mut ends = unsafe {
        TierEnds {
            front_end: origin.add(filled.front),
            back_start: origin.add(capacity - filled.back),
        }
    };
    let mut stop = Stop::End;
    // One pixel: r at offset k of the segment (k < end, within the maps).
    macro_rules! pixel {
        ($out:lifetime, $k:expr, $r:expr) => {{
            let (k, r) = ($k, $r);
            if CHECK && r > max_raw {
                stop = Stop::OutOfRange(k);
                break $out;
            }
            // SAFETY: k < start + raw.len() <= the maps' lengths (asserted
            // by `scan`).
            let p =
                unsafe { calibrate::value_in_run_unchecked::<S>(r, k, background, gain, fixed) };
            if p >= admit {
                let entry = Entry {
                    value: p,
                    position: (base + k as u16) as u32,
                };
                if ROOM && ends.front_end == ends.back_start {
                    stop = Stop::Full { k, entry };
                    break $out;
                }
                // SAFETY: see above.
                unsafe { ends.put(entry, hint) };
            }
        }};
    }
    #[allow(clippy::never_loop)]
    'scan: loop {
        if floor == 0 {
            for (k, &r) in raw.iter().enumerate() {
                pixel!('scan, start + k, r);
            }
            break 'scan;
        }
        // floor <= 2^16 - 1 here: a floor of 2^16 skips the segment.
        let below = (floor - 1) as u16;
        let lanes = below as u32 * 0x0001_0001;
        // SAFETY: any pair of u16 is a valid u32; align_to only splits the
        // slice where the words are aligned.
        let (head, words, tail) = unsafe { raw.align_to::<u32>() };
        let mut k = start;
        for &r in head {
            if r > below {
                pixel!('scan, k, r);
            }
            k += 1;
        }
        let pairs = k;
        if ROOM {
            for (w, &word) in words.iter().enumerate() {
                let passing = prefilter::uqsub16(word, lanes);
                if passing != 0 {
                    let k = pairs + 2 * w;
                    if passing & 0xffff != 0 {
                        pixel!('scan, k, word as u16);
                    }
                    if passing >> 16 != 0 {
                        pixel!('scan, k + 1, (word >> 16) as u16);
                    }
                }
            }
        } else {
            let run = WordRun {
                first: pairs,
                background,
                gain,
                fixed,
                lanes,
                admit,
                hint,
                base,
                max_raw,
            };
            // SAFETY: room for every pixel is proved (`!ROOM`); the words'
            // pixels are at offsets `pairs .. pairs + 2 words.len()` of the
            // segment, within the maps.
            let bad = unsafe { admit_words::<S, CHECK>(words, &run, &mut ends) };
            if let Some(k) = bad {
                stop = Stop::OutOfRange(k);
                break 'scan;
            }
        }
        for (k, &r) in (pairs + 2 * words.len()..).zip(tail) {
            if r > below {
                pixel!('scan, k, r);
            }
        }
        break 'scan;
    }
    // SAFETY: both pointers stay within the buffer (see above).
    unsafe {
        filled.front = ends.front_end.offset_from(origin) as usize;
        filled.back = capacity - ends.back_start.offset_from(origin) as usize;
    }
    stop
}

/// The ends of a window's two tiers in its candidate buffer: the front
/// grows up from the start, the back down from the end.
pub struct TierEnds {
    pub front_end: *mut Entry,
    pub back_start: *mut Entry,
}

impl TierEnds {
    /// Puts an admitted candidate at the end of its tier: the front if it is
    /// at or above the hint, else the back.
    ///
    /// # Safety
    /// Room for one entry between the two ends.
    #[inline(always)]
    unsafe fn put(&mut self, entry: Entry, hint: i32) {
        // SAFETY: the caller's contract.
        unsafe {
            if entry.value >= hint {
                self.front_end.write(entry);
                self.front_end = self.front_end.add(1);
            } else {
                self.back_start = self.back_start.sub(1);
                self.back_start.write(entry);
            }
        }
    }

    /// [`put`](Self::put) without a branch, for any candidate: it is
    /// written at both free ends and kept by advancing the end of its tier
    /// if `admitted`. Where the two writes meet they write the same entry.
    ///
    /// # Safety
    /// Room for one entry between the two ends.
    #[cfg(not(target_arch = "arm"))]
    #[inline(always)]
    unsafe fn put_branch_free(&mut self, entry: Entry, admitted: bool, hint: i32) {
        let upper = entry.value >= hint;
        // SAFETY: the caller's contract.
        unsafe {
            self.front_end.write(entry);
            self.back_start.sub(1).write(entry);
            self.front_end = self.front_end.add((admitted & upper) as usize);
            self.back_start = self.back_start.sub((admitted & !upper) as usize);
        }
    }
}

/// What [`admit_words`] needs besides the words, read once into registers.
pub struct WordRun<'a> {
    /// Offset in the segment of the first word's low pixel.
    pub first: usize,
    /// The whole segment's maps (see [`Segment`]).
    pub background: &'a [i32],
    pub gain: &'a [u16],
    pub fixed: i32,
    /// The raw floor less one, in both 16-bit lanes.
    pub lanes: u32,
    pub admit: i32,
    pub hint: i32,
    pub base: u16,
    pub max_raw: u16,
}

/// The word loop of a run whose room is proved: [`admit_words_portable`],
/// or on Cortex-M for the usual calibration (a background map, no gain, no
/// fixed threshold) its twin in assembly
/// (`dsp::admit_words_background`), which the benchmark's self-test checks
/// against it in QEMU.
///
/// # Safety
/// As [`admit_words_portable`].
#[inline(always)]
pub unsafe fn admit_words<S: Steps, const CHECK: bool>(
    words: &[u32],
    run: &WordRun<'_>,
    ends: &mut TierEnds,
) -> Option<usize> {
    #[cfg(target_arch = "arm")]
    if S::BACKGROUND && !S::GAIN && !S::THRESHOLD {
        // SAFETY: the caller's contract; `background` covers the words'
        // pixels (S::BACKGROUND).
        return unsafe { dsp::admit_words_background::<CHECK>(words, run, ends) };
    }
    // SAFETY: the caller's contract.
    unsafe { admit_words_portable::<S, CHECK>(words, run, ends) }
}

/// The definition of [`admit_words`]. Same admission as [`scan_run`]'s per-pixel path; returns the offset of a
/// pixel above `max_raw` (`CHECK`), where it stopped.
///
/// # Safety
/// The pixels of `words` are at offsets `first .. first + 2 words.len()` of
/// the segment, within `background` (if `S::BACKGROUND`) and `gain` (if
/// `S::GAIN`); the buffer between `front_end` and `back_start` has room for
/// every one of them.
#[inline(always)]
pub unsafe fn admit_words_portable<S: Steps, const CHECK: bool>(
    words: &[u32],
    run: &WordRun<'_>,
    ends: &mut TierEnds,
) -> Option<usize> {
    let WordRun {
        first,
        background,
        gain,
        fixed,
        lanes,
        admit,
        hint,
        base,
        max_raw,
    } = *run;
    // Hosts: a bit mask of the pixels that reach the floor (a segment is
    // at most 64 pixels: MAX_WINDOW_SIDE), then one iteration per such
    // pixel. A word loop's branches are taken at random in a hot segment,
    // which costs a superscalar core more than this.
    #[cfg(not(target_arch = "arm"))]
    {
        // SAFETY: `words` is `2 words.len()` pixels (u16 pairs).
        let raw =
            unsafe { core::slice::from_raw_parts(words.as_ptr() as *const u16, 2 * words.len()) };
        let mut mask = prefilter::mask_at_least(raw, (lanes as u16).wrapping_add(1));
        while mask != 0 {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            // SAFETY: i < raw.len() (a bit of the mask).
            let r = unsafe { *raw.get_unchecked(i) };
            let k = first + i;
            if CHECK && r > max_raw {
                return Some(k);
            }
            // SAFETY: k is within the maps (the caller's contract).
            let p =
                unsafe { calibrate::value_in_run_unchecked::<S>(r, k, background, gain, fixed) };
            let entry = Entry {
                value: p,
                position: (base + k as u16) as u32,
            };
            // SAFETY: room for every pixel (the caller's contract), each
            // pixel stored at most once.
            unsafe { ends.put_branch_free(entry, p >= admit, hint) };
        }
        None
    }
    #[cfg(target_arch = "arm")]
    {
        let mut bad = None;
        macro_rules! lane {
            ($k:expr, $r:expr) => {{
                let (k, r) = ($k, $r);
                if CHECK && r > max_raw {
                    bad = Some(k);
                    break;
                }
                // SAFETY: k is within the maps (the caller's contract).
                let p = unsafe {
                    calibrate::value_in_run_unchecked::<S>(r, k, background, gain, fixed)
                };
                if p >= admit {
                    let entry = Entry {
                        value: p,
                        position: (base + k as u16) as u32,
                    };
                    // SAFETY: room is proved for every pixel (the caller's
                    // contract), and each pixel stores at most once.
                    unsafe { ends.put(entry, hint) };
                }
            }};
        }
        for (w, &word) in words.iter().enumerate() {
            let passing = prefilter::uqsub16(word, lanes);
            if passing != 0 {
                let k = first + 2 * w;
                if passing & 0xffff != 0 {
                    lane!(k, word as u16);
                }
                if passing >> 16 != 0 {
                    lane!(k + 1, (word >> 16) as u16);
                }
            }
        }
        bad
    }
}

#[cfg(target_arch = "arm")]
mod dsp {
    use super::{TierEnds, WordRun};

    /// The range check of one pixel in `v`, when `$check`: branches to
    /// `$out` if it is above `max_raw` (the third word at `k`).
    macro_rules! range_check {
        (true, $out:literal) => {
            concat!("ldr {t}, [{k}, #8]\n", "cmp {v}, {t}\n", "bhi ", $out, "\n")
        };
        (false, $out:literal) => {
            ""
        };
    }

    /// The loop of [`admit_words_background`], with or without the range
    /// check of each pixel the pre-filter lets through (a pixel above the
    /// bit depth always passes it, see `OpenWindow::floor`). On a pixel out
    /// of range, leaves its position in `w` and stops; else `w` is
    /// `u32::MAX`.
    macro_rules! admit_loop {
        ($check:tt, $p:expr, $end:expr, $lanes:expr, $d:expr, $c:expr, $k:expr, $fe:expr, $bs:expr) => {{
            let w: u32;
            core::arch::asm!(
                "mov {w}, #-1",
                "cmp {p}, {end}",
                "beq 9f",
                "1:",
                "ldr {w}, [{p}], #4",
                "uqsub16 r0, {w}, {lanes}",
                "cbnz r0, 3f",
                "2:",
                "cmp {p}, {end}",
                "bne 1b",
                "mov {w}, #-1",
                "b 9f",
                // The low pixel.
                "3:",
                "lsls {v}, r0, #16",
                "beq 5f",
                "uxth {v}, {w}",
                range_check!($check, "6f"),
                "add {t}, {d}, {p}, lsl #1",
                "ldr {t}, [{t}]",
                "rsb {v}, {t}, {v}, lsl #4",
                "ldr {t}, [{k}]",
                "cmp {v}, {t}",
                "blt 5f",
                "ldr {t}, [{k}, #4]",
                "cmp {v}, {t}",
                "add {t}, {c}, {p}, lsr #1",
                "ite ge",
                "strdge {v}, {t}, [{fe}], #8",
                "strdlt {v}, {t}, [{bs}, #-8]!",
                // The high pixel.
                "5:",
                "cmp r0, #0x10000",
                "blo 2b",
                "lsrs {v}, {w}, #16",
                range_check!($check, "7f"),
                "add {t}, {d}, {p}, lsl #1",
                "ldr {t}, [{t}, #4]",
                "rsb {v}, {t}, {v}, lsl #4",
                "ldr {t}, [{k}]",
                "cmp {v}, {t}",
                "blt 2b",
                "ldr {t}, [{k}, #4]",
                "cmp {v}, {t}",
                "add {t}, {c}, {p}, lsr #1",
                "add {t}, {t}, #1",
                "ite ge",
                "strdge {v}, {t}, [{fe}], #8",
                "strdlt {v}, {t}, [{bs}, #-8]!",
                "b 2b",
                // Out of range: the position of the low or the high pixel.
                "6:",
                "add {w}, {c}, {p}, lsr #1",
                "b 9f",
                "7:",
                "add {w}, {c}, {p}, lsr #1",
                "add {w}, {w}, #1",
                "9:",
                p = inout(reg) $p => _,
                end = in(reg) $end,
                lanes = in(reg) $lanes,
                d = in(reg) $d,
                c = in(reg) $c,
                k = in(reg) $k,
                fe = inout(reg) $fe,
                bs = inout(reg) $bs,
                w = out(reg) w,
                v = out(reg) _,
                t = out(reg) _,
                out("r0") _,
                options(nostack),
            );
            w
        }};
    }

    /// [`super::admit_words_portable`] for a background map without gain or
    /// fixed threshold: a word whose two pixels are below the floor costs
    /// five instructions (`LDR`, `UQSUB16`, `CBNZ`, `CMP`, `BNE`), an
    /// admitted pixel about fifteen (three more with `CHECK`), with no
    /// register spilled. Returns the offset of a pixel above `max_raw`
    /// (`CHECK`), where it stopped.
    ///
    /// Positions and background addresses are derived from the word
    /// pointer: after `LDR w, [p], #4` the word's low pixel has background
    /// at `2 p + D` and position `p / 2 + C` (`D`, `C` fixed for the run,
    /// in wrapping arithmetic; the run is word-aligned, so `p / 2` is
    /// exact).
    ///
    /// # Safety
    /// As [`super::admit_words_portable`], and `run.background` covers the
    /// words' pixels.
    #[inline(always)]
    pub unsafe fn admit_words_background<const CHECK: bool>(
        words: &[u32],
        run: &WordRun<'_>,
        ends: &mut TierEnds,
    ) -> Option<usize> {
        let start = words.as_ptr() as usize;
        let end = start + 4 * words.len();
        let background = run.background.as_ptr() as usize + 4 * run.first;
        let d = background.wrapping_sub(2 * start).wrapping_sub(8);
        let c = (run.base as usize + run.first)
            .wrapping_sub(start >> 1)
            .wrapping_sub(2);
        let constants = [run.admit, run.hint, run.max_raw as i32];
        let k = constants.as_ptr();
        // SAFETY: reads the words, their background values and `constants`
        // only; each admitted pixel is stored once, at the front's end or
        // below the back's start, where the caller proved room. r0 is
        // clobbered.
        let stopped = unsafe {
            if CHECK {
                admit_loop!(
                    true,
                    start,
                    end,
                    run.lanes,
                    d,
                    c,
                    k,
                    ends.front_end,
                    ends.back_start
                )
            } else {
                admit_loop!(
                    false,
                    start,
                    end,
                    run.lanes,
                    d,
                    c,
                    k,
                    ends.front_end,
                    ends.back_start
                )
            }
        };
        // A position is base + offset, below 2^16.
        (stopped != u32::MAX).then(|| stopped as usize - run.base as usize)
    }
}
