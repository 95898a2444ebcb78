//! The hot loop of a *complement* window (`stream::complement`: a
//! `subtract-next` window keeping most of its pixels): every pixel's
//! calibrated value added to the window's sums, and the pixels at or below
//! its ceiling kept as candidates.
//!
//! The window's fields it uses: `hint` (the ceiling), `front_end` (the
//! candidates are appended there, in order of column, with window-relative
//! packed positions) and `moments`, which for a complement window hold the
//! sums of every pixel so far: `sum_w` of `p`, `sum_wi` of `2 p i` (twice:
//! what the assembly sums without a shift), `sum_wj` of `p j`.
//!
//! Two forms, as for the row kernel: [`segment`], one window's pixels (the
//! definition, and the general path's), and [`row`], every window of a
//! camera row when all open windows select the complement: on Cortex-M,
//! for a background map or no map, an assembly routine (`complement_dsp`)
//! whose twin is [`row_portable`].

use super::{RowScan, RowStop};
use crate::engine::calibrate::{self, Steps};
use crate::engine::select::{pack, Entry};
use crate::engine::window::OpenWindow;

/// One segment of a complement window: columns `i0 ..` of its row `j`,
/// with the run's maps (as `calibrate::run_maps` gives them). The window's
/// buffer must have room for the segment. Returns the offset of the first
/// pixel above `max_raw` (`CHECK`); the window is then left as it was.
#[inline(always)]
pub fn segment<S: Steps, const CHECK: bool>(
    window: &mut OpenWindow,
    raw: &[u16],
    (background, gain, fixed): (&[i32], &[u16], i32),
    i0: u16,
    j: u16,
    max_raw: u16,
) -> Result<(), usize> {
    assert!(
        (!S::BACKGROUND || background.len() >= raw.len())
            && (!S::GAIN || gain.len() >= raw.len())
            && window.room_left() >= raw.len()
    );
    if CHECK {
        if let Some(bad) = raw.iter().position(|&r| r > max_raw) {
            return Err(bad);
        }
    }
    let ceiling = window.hint;
    let base = pack(i0, j) as u32;
    let mut out = window.front_end as *mut Entry;
    // |p| < 2^21, at most 64 pixels: the plain sum fits 32 bits.
    let (mut sum, mut sum_i) = (0i32, 0i64);
    for (k, &r) in raw.iter().enumerate() {
        // SAFETY: k < raw.len(), within the maps (asserted above).
        let p = unsafe { calibrate::value_in_run_unchecked::<S>(r, k, background, gain, fixed) };
        sum += p;
        sum_i += p as i64 * (i0 as usize + k) as i64;
        if p <= ceiling {
            // SAFETY: room for the whole segment (asserted above).
            unsafe {
                out.write(Entry {
                    value: p,
                    position: base + k as u32,
                });
                out = out.add(1);
            }
        }
    }
    window.front_end = out as usize;
    let sum = sum as i64;
    window.moments.sum_w += sum;
    window.moments.sum_wi += 2 * sum_i;
    window.moments.sum_wj += j as i64 * sum;
    Ok(())
}

/// Every window's segment of one camera row, for open windows that all
/// select the complement, each with room for its segment (its buffer
/// holds all its pixels); each window's segment is its columns `x ..
/// end_column` (`segment_start` and `segment_end` are the row kernel's,
/// empty for these windows). Stops only at a pixel above `max_raw`
/// (`CHECK`): that window is left as it was, the ones before it are done.
///
/// # Safety
/// As [`super::row`]: `args` from live slices, the row holds every
/// window's columns, the background map (`S::BACKGROUND`) covers the row.
#[inline(always)]
pub unsafe fn row<S: Steps, const CHECK: bool>(args: &mut RowScan) -> RowStop {
    #[cfg(target_arch = "arm")]
    if !S::GAIN && !S::THRESHOLD {
        // SAFETY: the caller's contract; the routine's register use and
        // offsets are its own (see `complement_dsp`).
        let stop = unsafe {
            match (S::BACKGROUND, CHECK) {
                (true, false) => super::complement_dsp::row_background(args),
                (true, true) => super::complement_dsp::row_background_checked(args),
                (false, false) => super::complement_dsp::row_plain(args),
                (false, true) => super::complement_dsp::row_plain_checked(args),
            }
        };
        return match stop {
            0 => RowStop::Done,
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
/// fixed thresholds: [`segment`] over each window.
///
/// # Safety
/// As [`row`].
pub unsafe fn row_portable<S: Steps, const CHECK: bool>(args: &mut RowScan) -> RowStop {
    // The row's index: `position_delta` is `(row << 6) - 4 - row_address / 2`.
    let row_index = (args
        .position_delta
        .wrapping_add(4)
        .wrapping_add((args.row >> 1) as u32)
        >> 6) as u16;
    let mut at = args.first;
    while at != args.end {
        // SAFETY: `first .. end` are consecutive live open windows (the
        // caller's contract).
        let window = unsafe { &mut *(at as *mut OpenWindow) };
        let (x, end) = (window.x as usize, window.end_column as usize);
        // SAFETY: the row holds the window's columns (the caller's
        // contract).
        let raw = unsafe { core::slice::from_raw_parts((args.row as *const u16).add(x), end - x) };
        let background = if S::BACKGROUND {
            let bg_row = args.bg_delta.wrapping_add(2 * args.row).wrapping_add(16);
            // SAFETY: the map covers the row.
            unsafe { core::slice::from_raw_parts((bg_row as *const i32).add(x), end - x) }
        } else {
            &[][..]
        };
        let gain = if S::GAIN {
            // SAFETY: as the background.
            unsafe { core::slice::from_raw_parts((args.gain_row as *const u16).add(x), end - x) }
        } else {
            &[][..]
        };
        let j = row_index.wrapping_sub(window.y);
        let maps = (background, gain, args.threshold);
        if let Err(bad) = segment::<S, CHECK>(window, raw, maps, 0, j, args.max_raw as u16) {
            args.bad = raw.as_ptr() as usize + 2 * bad;
            return RowStop::OutOfRange {
                window: at,
                pixel: args.bad,
            };
        }
        at += core::mem::size_of::<OpenWindow>();
    }
    RowStop::Done
}
