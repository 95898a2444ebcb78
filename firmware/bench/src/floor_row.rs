//! The floor's row kernel: one camera row of a regular grid, every window's
//! segment tested two pixels at a time against its raw floor (`UQSUB16`),
//! the pixels that pass calibrated and summed above the window's level.
//!
//! [`floor_row`] is the kernel: on Cortex-M an assembly routine that keeps
//! everything in registers (a word pair costs seven instructions when
//! neither pixel passes), elsewhere [`floor_row_portable`], its twin, which
//! the benchmark's self-test compares it with on random rows.
//!
//! Positions are not tracked per pixel: the kernel sums `w * x`, `x` the
//! address of the pixel's background value (`bg_row + 4 column`, which it
//! computes anyway to load it), and a window's fold turns that into
//! `sum(w * column)` with one multiply: `sum(w x) - bg_row sum(w) = 4
//! sum(w column)`.

/// One window of the current grid row, as the kernel reads and writes it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FloorWindow {
    /// The raw floor less one in both 16-bit lanes; all ones: no pixel
    /// passes.
    pub lanes: u32,
    /// Weights are `p - level` above it.
    pub level: i32,
    pub sum_w: u64,
    /// `sum(w * camera column)`.
    pub sum_wcol: u64,
    pub sum_wj: u64,
}

/// What the kernel needs for one row.
#[repr(C)]
pub struct FloorRow {
    /// The row's first pixel, word-aligned.
    pub row: *const u16,
    /// The windows crossing the row, left to right, contiguous from the
    /// row's first pixel, `segment_bytes / 2` pixels each.
    pub windows: *mut FloorWindow,
    pub windows_end: *mut FloorWindow,
    /// `2 * side`, a multiple of 4.
    pub segment_bytes: u32,
    /// `bg_row - 2 row - 16` (wrapping): the background address of a pair
    /// of words read at `p - 8` is `bg_delta + 2 p`.
    pub bg_delta: usize,
    /// The address of the row's first background value (any value without
    /// a background map: the fold only needs it to be the one `bg_delta`
    /// was made from).
    pub bg_row: usize,
    /// The row's index in its windows.
    pub j: u32,
}

impl FloorRow {
    /// The arguments for `row` with `background` (its row of the map, or
    /// `None`) over `windows`.
    pub fn new(
        row: &[u16],
        background: Option<&[i32]>,
        windows: &mut [FloorWindow],
        side: usize,
        j: usize,
    ) -> FloorRow {
        assert!(row.as_ptr() as usize & 3 == 0 && side.is_multiple_of(2) && side > 0);
        assert!(row.len() >= windows.len() * side);
        let bg_row = match background {
            Some(b) => {
                assert!(b.len() >= windows.len() * side);
                b.as_ptr() as usize
            }
            None => 0,
        };
        let range = windows.as_mut_ptr_range();
        FloorRow {
            row: row.as_ptr(),
            windows: range.start,
            windows_end: range.end,
            segment_bytes: 2 * side as u32,
            bg_delta: bg_row
                .wrapping_sub(2 * row.as_ptr() as usize)
                .wrapping_sub(16),
            bg_row,
            j: j as u32,
        }
    }
}

/// The kernel: for every window, the pixels `r` of its segment with
/// `r > lanes` (as a 16-bit lane) and `w = 16 r - B - level > 0` added to
/// its sums (`B` 0 without a background map). At least one window.
///
/// # Safety
/// `args` as [`FloorRow::new`] makes them, from slices that are still
/// alive.
#[inline(always)]
pub unsafe fn floor_row<const BACKGROUND: bool>(args: &FloorRow) {
    #[cfg(target_arch = "arm")]
    // SAFETY: the caller's contract.
    unsafe {
        if BACKGROUND {
            dsp::floor_row_background(args)
        } else {
            dsp::floor_row_plain(args)
        }
    }
    #[cfg(not(target_arch = "arm"))]
    // SAFETY: the caller's contract.
    unsafe {
        floor_row_portable::<BACKGROUND>(args)
    }
}

/// The definition of [`floor_row`].
///
/// # Safety
/// As [`floor_row`].
pub unsafe fn floor_row_portable<const BACKGROUND: bool>(args: &FloorRow) {
    let side = args.segment_bytes as usize / 2;
    // SAFETY: the caller's contract: the windows and the row are alive.
    let windows = unsafe {
        core::slice::from_raw_parts_mut(
            args.windows,
            args.windows_end.offset_from(args.windows) as usize,
        )
    };
    let row = unsafe { core::slice::from_raw_parts(args.row, windows.len() * side) };
    for (k, window) in windows.iter_mut().enumerate() {
        let below = window.lanes as u16;
        let (mut f, mut fcol) = (0u64, 0u64);
        for i in 0..side {
            let column = k * side + i;
            let r = row[column];
            if r <= below {
                continue;
            }
            let b = if BACKGROUND {
                let at = args.bg_row + 4 * column;
                // SAFETY: the caller's contract: the map's row covers it.
                unsafe { *(at as *const i32) }
            } else {
                0
            };
            let w = ((r as i32) << 4) - b - window.level;
            if w > 0 {
                f += w as u64;
                fcol += w as u64 * column as u64;
            }
        }
        window.sum_w = window.sum_w.wrapping_add(f);
        window.sum_wcol = window.sum_wcol.wrapping_add(fcol);
        window.sum_wj = window.sum_wj.wrapping_add(f.wrapping_mul(args.j as u64));
    }
}

#[cfg(target_arch = "arm")]
mod dsp {
    use super::FloorRow;

    /// The end of one lane's handler, its calibrated value in r3: the
    /// weight above the level, added to the sums, else on to `$skip`.
    macro_rules! lane {
        ($skip:literal) => {
            concat!(
                "subs r3, r3, r8\n",
                "ble ",
                $skip,
                "\n",
                "add r9, r9, r3\n",
                "umlal r10, r11, r3, r4\n",
            )
        };
    }

    /// The kernel, `$bg` selecting the background loads. Registers: r0
    /// test/temp, r1 r2 the word pair, r3 the weight, r4 the background
    /// address, r5 the pixel pointer, r6 the segment's end, r7 the lanes,
    /// r8 the level, r9 the segment's flux, r10:r11 its `sum(w x)`, r12
    /// `bg_delta`, lr the window.
    macro_rules! kernel {
        ($name:ident, $bg:tt) => {
            #[unsafe(naked)]
            pub unsafe extern "C" fn $name(args: &FloorRow) {
                core::arch::naked_asm!(
                    "push {{r4-r11, lr}}",
                    "sub sp, #16",
                    "ldr r1, [r0, #12]",
                    "str r1, [sp, #0]",
                    "ldr r1, [r0, #8]",
                    "str r1, [sp, #4]",
                    "ldr r1, [r0, #20]",
                    "str r1, [sp, #8]",
                    "ldr r1, [r0, #24]",
                    "str r1, [sp, #12]",
                    "ldr r5, [r0, #0]",
                    "ldr lr, [r0, #4]",
                    "ldr r12, [r0, #16]",
                    "mov.w r9, #0",
                    "mov.w r10, #0",
                    "mov.w r11, #0",
                    // A window: its lanes and level; an odd word first.
                    "2:",
                    "ldrd r7, r8, [lr]",
                    "ldr r6, [sp, #0]",
                    "tst r6, #4",
                    "add r6, r5, r6",
                    "bne 9f",
                    // Word pairs.
                    "3:",
                    "ldrd r1, r2, [r5], #8",
                    "uqsub16 r0, r1, r7",
                    "cbnz r0, 6f",
                    "4:",
                    "uqsub16 r0, r2, r7",
                    "cbnz r0, 5f",
                    "7:",
                    "cmp r5, r6",
                    "bne 3b",
                    "cmp r9, #0",
                    "bne 8f",
                    // The next window.
                    "1:",
                    "add lr, lr, #32",
                    "ldr r0, [sp, #4]",
                    "cmp lr, r0",
                    "bne 2b",
                    "add sp, #16",
                    "pop {{r4-r11, pc}}",
                    // The second word's pixels (at p - 4, p - 2).
                    "5:",
                    "lsls r3, r0, #16",
                    "beq 51f",
                    bg_load!($bg, 8),
                    "uxth r0, r2",
                    calibrate!($bg),
                    lane!("51f"),
                    "51:",
                    "uqsub16 r0, r2, r7",
                    "cmp r0, #0x10000",
                    "blo 7b",
                    bg_load!($bg, 12),
                    "lsrs r0, r2, #16",
                    calibrate!($bg),
                    lane!("7b"),
                    "b 7b",
                    // The first word's pixels (at p - 8, p - 6).
                    "6:",
                    "lsls r3, r0, #16",
                    "beq 61f",
                    bg_load!($bg, 0),
                    "uxth r0, r1",
                    calibrate!($bg),
                    lane!("61f"),
                    "61:",
                    "uqsub16 r0, r1, r7",
                    "cmp r0, #0x10000",
                    "blo 4b",
                    bg_load!($bg, 4),
                    "lsrs r0, r1, #16",
                    calibrate!($bg),
                    lane!("4b"),
                    "b 4b",
                    // A segment with an odd number of words: its first word
                    // as a pair's second.
                    "9:",
                    "ldr r2, [r5], #4",
                    "b 4b",
                    // A window's fold: 4 sum(w column) = sum(w x) - bg_row f.
                    "8:",
                    "ldr r0, [sp, #8]",
                    "umull r1, r2, r9, r0",
                    "subs r10, r10, r1",
                    "sbc r11, r11, r2",
                    "lsrs r10, r10, #2",
                    "orr r10, r10, r11, lsl #30",
                    "lsrs r11, r11, #2",
                    "ldrd r1, r2, [lr, #16]",
                    "adds r1, r1, r10",
                    "adc r2, r2, r11",
                    "strd r1, r2, [lr, #16]",
                    "ldrd r1, r2, [lr, #8]",
                    "adds r1, r1, r9",
                    "adc r2, r2, #0",
                    "strd r1, r2, [lr, #8]",
                    "ldrd r1, r2, [lr, #24]",
                    "ldr r0, [sp, #12]",
                    "umlal r1, r2, r9, r0",
                    "strd r1, r2, [lr, #24]",
                    "mov.w r9, #0",
                    "mov.w r10, #0",
                    "mov.w r11, #0",
                    "b 1b",
                )
            }
        };
    }

    /// r4 = the lane's background address (`bg_delta + 2 p + offset`), and
    /// with a map r3 = its value.
    macro_rules! bg_load {
        (true, $offset:literal) => {
            concat!(
                "add r4, r12, r5, lsl #1\n",
                "ldr r3, [r4, #",
                stringify!($offset),
                "]!\n"
            )
        };
        (false, $offset:literal) => {
            concat!(
                "add r4, r12, r5, lsl #1\n",
                "add r4, r4, #",
                stringify!($offset),
                "\n"
            )
        };
    }

    /// r3 = 16 r0 - r3 (with a map) or 16 r0.
    macro_rules! calibrate {
        (true) => {
            "rsb r3, r3, r0, lsl #4\n"
        };
        (false) => {
            "lsl r3, r0, #4\n"
        };
    }

    kernel!(floor_row_background, true);
    kernel!(floor_row_plain, false);
}
