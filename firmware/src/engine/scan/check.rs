//! The row kernels' self-tests: the assembly (`dsp`, `complement_dsp`)
//! against its portable twin on random rows, run by the QEMU benchmark
//! before it times anything.

use super::{complement, row, row_portable, RowScan, RowStop};
use crate::engine::select::Entry;
use crate::engine::window::{OpenWindow, Raise};

/// Pixels of the self-tests' camera row.
const PIXELS: usize = 224;

/// The self-tests' camera row, word-aligned as the kernels need.
#[repr(C, align(4))]
struct Pixels([u16; PIXELS]);

/// A xorshift generator from `seed`: each call, a number below its
/// argument (0 for 0).
fn uniform(seed: u64) -> impl FnMut(u32) -> u32 {
    let mut state = seed | 1;
    move |below: u32| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        ((state >> 16) as u32) % below.max(1)
    }
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
/// the twin. `Err` says what differed, in which round. Out of line, so
/// that the benchmark's `main`, which calls it once, keeps the same code
/// around its timed calls whatever the self-test holds.
#[inline(never)]
pub fn check_row_kernel(seed: u64, rounds: usize) -> Result<(), KernelMismatch> {
    use crate::engine::calibrate::With;
    let mut next = uniform(seed);
    let mut pixels = Pixels([0; PIXELS]);
    let mut background = [0i32; PIXELS];
    // Each window gets `SHARE` entries, more than its widest segment.
    const SHARE: usize = 40;
    let mut buffers = [[Entry::ZERO; 7 * SHARE]; 2];
    for round in 0..rounds {
        let top = 1 + next(5) * 13_000 + next(300);
        // The depths with kernels of their own (8, 10, 12, 14 bits), one
        // without (9), and 16 bits (no check); each with and without a
        // background map (`round % 4` below).
        let max_raw: u16 = [255, 1_023, 4_095, 16_383, 511, u16::MAX][(round / 4) % 6];
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
        let mut windows = [[OpenWindow::CLOSED; 8]; 2];
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
            let raise = match next(5) {
                0 => Raise::NONE,
                1 => Raise::AT_HINT,
                2 => Raise::ABOVE_HINT,
                // Found or not in the back entries below (`hint - 1` in
                // about one entry of three) or the row's.
                3 => Raise::LOWER,
                // Often few copies, where the proof turns on one.
                _ => {
                    let most = if next(2) == 0 { 3 } else { 16 };
                    Raise::counting(1 + next(most) as u8)
                }
            };
            let raise_floor = if raise == Raise::NONE {
                0
            } else {
                1 + next(top + 1)
            };
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
                w.short_of_room = 8 * (width - 1);
                // Four windows in five raise admission in the kernel when
                // the front reaches `attention`, at or above the hint,
                // after lowering it or after counting the hint's copies.
                w.raise = raise;
                w.raise_lane = raise_floor.wrapping_sub(1) as u16;
                w.low = admit;
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
        // What a counting raise reads: N, the hint's ties, the front's
        // entries (copies of the hint among them) and how many were
        // counted, with how many copies; and a lowering one, the back's
        // entries (the window has no hint ties).
        for k in 0..made {
            let most = if next(2) == 0 { 8 } else { share as u32 + 1 };
            let n = next(most) as u16;
            let ties = if windows[0][k].raise == Raise::LOWER {
                0
            } else {
                next(3) as u16
            };
            let front = windows[0][k].front();
            let counted = next(front as u32 + 1) as usize;
            let values: [i32; SHARE] =
                core::array::from_fn(|_| windows[0][k].hint + next(4) as i32);
            let at_hint = values[..counted]
                .iter()
                .filter(|&&v| v == windows[0][k].hint)
                .count() as u16;
            let below: [Entry; SHARE] = core::array::from_fn(|_| Entry {
                value: windows[0][k].hint.wrapping_sub(1 + next(3) as i32),
                position: next(u32::MAX),
            });
            for copies in windows.iter_mut() {
                let w = &mut copies[k];
                w.n = n;
                w.hint_ties.count = ties;
                w.counted = counted as u16;
                w.at_hint = at_hint;
                // The free space between the tiers holds copies of the
                // hint, so that a count that reads past the front's end
                // counts one too many.
                for e in 0..share {
                    // SAFETY: the window's own share of the buffer.
                    unsafe {
                        ((w.buffer + e * core::mem::size_of::<Entry>()) as *mut Entry).write(
                            Entry {
                                value: w.hint,
                                position: 0,
                            },
                        )
                    };
                }
                for (e, &value) in (0..front).zip(values.iter()) {
                    // SAFETY: the window's own front entries.
                    unsafe {
                        ((w.buffer + e * core::mem::size_of::<Entry>()) as *mut Entry).write(
                            Entry {
                                value,
                                position: e as u32,
                            },
                        )
                    };
                }
                let back = w.back();
                for (e, entry) in (share - back..share).zip(below) {
                    // SAFETY: the window's own back entries.
                    unsafe {
                        ((w.buffer + e * core::mem::size_of::<Entry>()) as *mut Entry).write(entry)
                    };
                }
            }
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
        // With the end mark's slot.
        let (kernel, twin) = (&mut a[0][..=made], &mut b[0][..=made]);
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
        for (k, t) in kernel[..made].iter().zip(&twin[..made]) {
            let (kb, tb) = (
                k.buffer - buffers[0].as_ptr() as usize,
                t.buffer - buffers[1].as_ptr() as usize,
            );
            // What a raise in the kernel writes (`attention` relative to
            // the buffer: the twin's and the kernel's buffers differ).
            let raised = |w: &OpenWindow| {
                (
                    (w.hint, w.hint_ties),
                    w.at_hint,
                    w.counted,
                    w.floor,
                    w.lanes,
                    w.admit,
                    w.low,
                    w.strict,
                    if w.attention == usize::MAX {
                        usize::MAX
                    } else {
                        w.attention - w.buffer
                    },
                )
            };
            if raised(k) != raised(t) {
                return Err(KernelMismatch {
                    what: "the row kernel raised admission unlike its twin",
                    round,
                    window: k.strict as usize | (t.strict as usize) << 1,
                    entries: [Entry::ZERO; 2],
                });
            }
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

/// The complement row kernel ([`complement::row`]) against its twin
/// ([`complement::row_portable`]) on random rows, windows, ceilings, maps
/// and bit depths: the same stop and out-of-range pixel, and for every
/// window the same candidates (values, positions, order) and sums; a
/// window with a pixel out of range left as it was. As
/// [`check_row_kernel`], run by the QEMU benchmark before it times
/// anything.
#[inline(never)]
pub fn check_complement_row(seed: u64, rounds: usize) -> Result<(), KernelMismatch> {
    use crate::engine::calibrate::With;
    use crate::engine::centroid::Moments;
    const SHARE: usize = 72;
    let mut next = uniform(seed);
    let mut pixels = Pixels([0; PIXELS]);
    let mut background = [0i32; PIXELS];
    let mut buffers = [[Entry::ZERO; 7 * SHARE]; 2];
    let mismatch = |what, round, window| KernelMismatch {
        what,
        round,
        window,
        entries: [Entry::ZERO; 2],
    };
    for round in 0..rounds {
        let top = 1 + next(5) * 13_000 + next(300);
        let max_raw: u16 = [255, 4_095, u16::MAX][round % 3];
        let check = max_raw != u16::MAX;
        for r in pixels.0.iter_mut() {
            *r = next(top).min(max_raw as u32) as u16;
            if check && next(300) == 0 {
                *r = max_raw + 1 + next(50) as u16;
            }
        }
        // The map's full range, sometimes.
        let spread = if next(8) == 0 { 1 << 21 } else { 16 * top };
        for b in background.iter_mut() {
            *b = (next(spread) as i32 - (spread / 2) as i32).clamp(-(1 << 20), 1 << 20);
        }
        let with_background = round % 4 != 3;
        let row_index = next(200) as u16 + 64;
        let mut windows = [[OpenWindow::CLOSED; 8]; 2];
        let (mut x, mut made) = (2 * next(3) as u16, 0);
        for k in 0..1 + next(7) as usize {
            let width = 2 + 2 * next(32) as u16;
            if (x + width) as usize > PIXELS {
                break;
            }
            let y = row_index - next(64) as u16;
            let ceiling = match next(6) {
                0 => i32::MAX,
                1 => i32::MIN,
                _ => next(32 * top) as i32 - (8 * top) as i32,
            };
            let front = next(4) as usize;
            let sums = Moments {
                sum_w: next(1 << 30) as i64 - (1 << 29),
                sum_wi: (next(1 << 30) as i64) << 8,
                sum_wj: -(next(1 << 30) as i64),
            };
            for (copies, buffer) in windows.iter_mut().zip(buffers.iter_mut()) {
                let w = &mut copies[k];
                *w = OpenWindow::CLOSED;
                (w.x, w.end_column, w.y, w.width) = (x, x + width, y, width);
                w.hint = ceiling;
                w.position_base = 0u32.wrapping_sub((y as u32) << 6).wrapping_sub(x as u32);
                w.buffer = buffer.as_mut_ptr() as usize + k * SHARE * core::mem::size_of::<Entry>();
                w.capacity = SHARE as u16;
                w.set_front(front);
                w.set_back(0);
                w.moments = sums;
            }
            made = k + 1;
            x += width + 2 * next(2) as u16;
        }
        if made == 0 {
            continue;
        }
        for buffer in buffers.iter_mut() {
            buffer.fill(Entry::ZERO);
        }
        let before = windows[0];
        let run = |windows: &mut [OpenWindow], twin: bool| {
            let map = with_background.then_some(&background[..]);
            let mut args = RowScan::new(&pixels.0, row_index, map, None, None, windows, max_raw);
            type B = With<true, false, false>;
            type P = With<false, false, false>;
            // SAFETY: arguments from live slices; every window's columns
            // are inside the row, at even columns, with room for them.
            let stop = unsafe {
                match (with_background, check, twin) {
                    (true, false, false) => complement::row::<B, false>(&mut args),
                    (true, true, false) => complement::row::<B, true>(&mut args),
                    (false, false, false) => complement::row::<P, false>(&mut args),
                    (false, true, false) => complement::row::<P, true>(&mut args),
                    (true, false, true) => complement::row_portable::<B, false>(&mut args),
                    (true, true, true) => complement::row_portable::<B, true>(&mut args),
                    (false, false, true) => complement::row_portable::<P, false>(&mut args),
                    (false, true, true) => complement::row_portable::<P, true>(&mut args),
                }
            };
            let first = windows.as_ptr() as usize;
            match stop {
                RowStop::Done => (made, None),
                RowStop::Attention(_) => (usize::MAX, None),
                RowStop::OutOfRange { window, pixel } => (
                    (window - first) / core::mem::size_of::<OpenWindow>(),
                    Some(pixel - pixels.0.as_ptr() as usize),
                ),
            }
        };
        let (a, b) = windows.split_at_mut(1);
        // With the end mark's slot.
        let (kernel, twin) = (&mut a[0][..=made], &mut b[0][..=made]);
        let stop_kernel = run(kernel, false);
        if stop_kernel != run(twin, true) {
            return Err(mismatch(
                "the complement kernel stopped elsewhere than its twin",
                round,
                stop_kernel.0,
            ));
        }
        for (k, (w, t)) in kernel[..made].iter().zip(&twin[..made]).enumerate() {
            if w.moments != t.moments || w.front() != t.front() {
                return Err(mismatch(
                    "the complement kernel's sums or candidate count differ from its twin's",
                    round,
                    k,
                ));
            }
            if k == stop_kernel.0
                && (w.moments != before[k].moments || w.front() != before[k].front())
            {
                return Err(mismatch(
                    "the complement kernel changed a window with a pixel out of range",
                    round,
                    k,
                ));
            }
            let at = k * SHARE;
            if let Some(i) = (at..at + w.front()).find(|&i| buffers[0][i] != buffers[1][i]) {
                return Err(KernelMismatch {
                    what: "the complement kernel's candidates differ from its twin's",
                    round,
                    window: i,
                    entries: [buffers[0][i], buffers[1][i]],
                });
            }
        }
    }
    Ok(())
}
