//! The complement row kernel in assembly ([`super::complement::row`]; its
//! twin is `complement::row_portable`). Registers while a window is
//! scanned: r0 a pixel's value, r1 the segment's end, r2 r3 the
//! background pair (r2 also the handlers' temporary), r4 the pixel pointer,
//! r5 the background pointer, r6 the sum of the values, r7:r8 the sum of
//! each value times its pixel's address (plus two), r9 the ceiling, r10
//! the union of the raw values (`CHECK`), r11 `front_end`, r12 the
//! window's position constant, lr the window. On the stack: the row, the
//! windows' end, `position_delta + 3`, `max_raw`, the arguments,
//! `bg_delta + 16`, the row's index, the segment's first address.
//!
//! The column-weighted sum is taken against the pixels' addresses (one
//! `SMLAL` a pixel, no column counter) and brought to the segment's start
//! at its end: `sum p (a + 2) - (a0 + 2) sum p = sum p (a - a0) = 2 sum p
//! i`, hence the doubled `sum_wi` (see `complement`). Addresses are taken
//! as signed 32-bit values: a row never straddles 2^31, so their
//! differences are exact.

use super::RowScan;
use crate::engine::centroid::Moments;
use crate::engine::window::OpenWindow;
use core::mem::offset_of;

/// r10 |= the raw pixel in r0 (`CHECK`).
macro_rules! union {
    (true) => {
        "orr r10, r10, r0\n"
    };
    (false) => {
        ""
    };
}

/// r0 = the calibrated value of the raw pixel in r0, its background in
/// `$bg` (with a map).
macro_rules! calibrate {
    (true, $bg:literal) => {
        concat!("rsb r0, ", $bg, ", r0, lsl #4\n")
    };
    (false, $bg:literal) => {
        "lsls r0, r0, #4\n"
    };
}

/// The window's background pointer from its first pixel's address in r4.
macro_rules! background_pointer {
    (true) => {
        "ldr r5, [sp, #20]\nadd r5, r5, r4, lsl #1\n"
    };
    (false) => {
        ""
    };
}

/// The next background pair (with a map).
macro_rules! background_pair {
    (true) => {
        "ldrd r2, r3, [r5], #8\n"
    };
    (false) => {
        ""
    };
}

/// The pixels above `max_raw` (`CHECK`): out to `90f`.
macro_rules! range {
    (true) => {
        "ldr r0, [sp, #12]\ncmp r10, r0\nbhi 90f\n"
    };
    (false) => {
        ""
    };
}

macro_rules! clear_union {
    (true) => {
        "movs r10, #0\n"
    };
    (false) => {
        ""
    };
}

/// One pixel at r4: its value in the sums, to `$keep` if at or below the
/// ceiling.
macro_rules! pixel {
    ($bg:tt, $check:tt, $background:literal, $keep:literal) => {
        concat!(
            "ldrh r0, [r4], #2\n",
            union!($check),
            calibrate!($bg, $background),
            "add r6, r6, r0\n",
            "smlal r7, r8, r0, r4\n",
            "cmp r0, r9\n",
            "ble ",
            $keep,
            "\n",
        )
    };
}

macro_rules! kernel {
    ($name:ident, $bg:tt, $check:tt) => {
        #[unsafe(naked)]
        pub unsafe extern "C" fn $name(args: &mut RowScan) -> usize {
            core::arch::naked_asm!(
                "push {{r4-r11, lr}}",
                "sub sp, #36",
                "ldr r1, [r0, #{a_row}]",
                "str r1, [sp, #0]",
                "ldr r2, [r0, #{a_end}]",
                "str r2, [sp, #4]",
                "ldr r3, [r0, #{a_position}]",
                "adds r4, r3, #3",
                "str r4, [sp, #8]",
                // The row's index: `position_delta + 4 + row / 2` is
                // `index << 6`.
                "adds r3, r3, #4",
                "add r3, r3, r1, lsr #1",
                "lsrs r3, r3, #6",
                "str r3, [sp, #24]",
                "ldr r4, [r0, #{a_max_raw}]",
                "str r4, [sp, #12]",
                "str r0, [sp, #16]",
                "ldr r4, [r0, #{a_bg}]",
                "adds r4, #16",
                "str r4, [sp, #20]",
                "ldr lr, [r0, #{a_first}]",
                "cmp lr, r2",
                "beq 80f",
                // A window: its segment (its columns), ceiling, candidates'
                // end and position constant; the sums cleared.
                "2:",
                "ldrh r4, [lr, #{x}]",
                "ldrh r1, [lr, #{end_column}]",
                "cmp r4, r1",
                "beq 1f",
                "ldr r0, [sp, #0]",
                "add r4, r0, r4, lsl #1",
                "add r1, r0, r1, lsl #1",
                "str r4, [sp, #28]",
                background_pointer!($bg),
                "ldr r9, [lr, #{hint}]",
                "ldr r11, [lr, #{front_end}]",
                "ldr r12, [lr, #{position_base}]",
                "ldr r0, [sp, #8]",
                "add r12, r12, r0",
                "movs r6, #0",
                "movs r7, #0",
                "movs r8, #0",
                clear_union!($check),
                // Two pixels a turn (segments are whole words).
                "3:",
                background_pair!($bg),
                pixel!($bg, $check, "r2", "5f"),
                "4:",
                pixel!($bg, $check, "r3", "6f"),
                "7:",
                "cmp r4, r1",
                "bne 3b",
                // The segment's end: the range, then the candidates' end
                // and the sums stored.
                range!($check),
                "str r11, [lr, #{front_end}]",
                "ldrd r2, r3, [lr, #{sum_w}]",
                "adds r2, r2, r6",
                "adc r3, r3, r6, asr #31",
                "strd r2, r3, [lr, #{sum_w}]",
                "ldr r0, [sp, #28]",
                "adds r0, #2",
                "negs r0, r0",
                "smlal r7, r8, r0, r6",
                "ldrd r2, r3, [lr, #{sum_wi}]",
                "adds r2, r2, r7",
                "adc r3, r3, r8",
                "strd r2, r3, [lr, #{sum_wi}]",
                "ldr r0, [sp, #24]",
                "ldrh r2, [lr, #{y}]",
                "subs r0, r0, r2",
                "ldrd r2, r3, [lr, #{sum_wj}]",
                "smlal r2, r3, r0, r6",
                "strd r2, r3, [lr, #{sum_wj}]",
                // The next window.
                "1:",
                "add lr, lr, #{size}",
                "ldr r0, [sp, #4]",
                "cmp lr, r0",
                "bne 2b",
                "80:",
                "movs r0, #0",
                "81:",
                "add sp, #36",
                "pop {{r4-r11, pc}}",
                // A candidate (the first or second pixel of the pair):
                // value and packed position (`r12 + r4 / 2`, r4 past it).
                "5:",
                "add r2, r12, r4, lsr #1",
                "strd r0, r2, [r11], #8",
                "b 4b",
                "6:",
                "add r2, r12, r4, lsr #1",
                "strd r0, r2, [r11], #8",
                "b 7b",
                // Out of range: the first such pixel's address, and the
                // window tagged; nothing of it stored.
                "90:",
                "ldr r4, [sp, #28]",
                "ldr r0, [sp, #12]",
                "91:",
                "ldrh r2, [r4], #2",
                "cmp r2, r0",
                "bls 91b",
                "subs r4, #2",
                "ldr r0, [sp, #16]",
                "str r4, [r0, #{a_bad}]",
                "orr r0, lr, #1",
                "b 81b",
                a_row = const offset_of!(RowScan, row),
                a_first = const offset_of!(RowScan, first),
                a_end = const offset_of!(RowScan, end),
                a_bg = const offset_of!(RowScan, bg_delta),
                a_position = const offset_of!(RowScan, position_delta),
                a_max_raw = const offset_of!(RowScan, max_raw),
                a_bad = const offset_of!(RowScan, bad),
                x = const offset_of!(OpenWindow, x),
                end_column = const offset_of!(OpenWindow, end_column),
                y = const offset_of!(OpenWindow, y),
                hint = const offset_of!(OpenWindow, hint),
                front_end = const offset_of!(OpenWindow, front_end),
                position_base = const offset_of!(OpenWindow, position_base),
                sum_w = const offset_of!(OpenWindow, moments) + offset_of!(Moments, sum_w),
                sum_wi = const offset_of!(OpenWindow, moments) + offset_of!(Moments, sum_wi),
                sum_wj = const offset_of!(OpenWindow, moments) + offset_of!(Moments, sum_wj),
                size = const core::mem::size_of::<OpenWindow>(),
            )
        }
    };
}

kernel!(row_background, true, false);
kernel!(row_background_checked, true, true);
kernel!(row_plain, false, false);
kernel!(row_plain_checked, false, true);
