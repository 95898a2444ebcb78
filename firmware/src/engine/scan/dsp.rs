//! The row kernel in assembly. Registers while a window is scanned:
//! r0 test and temporary, r1 r2 the word pair, r3 a pixel's value, r4
//! temporary (background, position), r5 the pixel pointer, r6 the
//! segment's end, r7 the lanes, r8 `admit`, r9 the window's position
//! constant, r10 `front_end`, r11 `back_start`, r12 `bg_delta` (without
//! a background map, the window's hint in the hot loop), lr the window. On
//! the stack: the row and `position_delta` (one `LDRD` a window),
//! `max_raw`, the arguments (and a word for the stack's 8-byte
//! alignment). The windows are walked to the end mark after the last
//! (see `scan::row`).
//!
//! A segment is scanned by the *cold* loop until some pixel passes the
//! lanes; the pixel handlers return into the *hot* copy of the loop,
//! whose exit stores the tiers' ends and checks room and attention (a
//! cold segment touches none of it).

use super::RowScan;
use crate::engine::window::OpenWindow;
use core::mem::offset_of;

/// The range check of the raw pixel in r3: none (`false`), against
/// `max_raw` on the stack (`true`), or, for the bit depths that have a
/// kernel of their own, a test of the bits above the depth against an
/// immediate mask (`0xF000` for 12 bits: one instruction fewer a pixel
/// that passes the lanes than the load and comparison); out to `$out`.
macro_rules! check {
    (true, $out:literal) => {
        concat!("ldr r4, [sp, #8]\n", "cmp r3, r4\n", "bhi ", $out, "\n")
    };
    (false, $out:literal) => {
        ""
    };
    ($mask:literal, $out:literal) => {
        concat!("tst r3, #", stringify!($mask), "\n", "bne ", $out, "\n")
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

/// r3 (calibrated) against the window's hint: with a background map from
/// the window (r12 holds `bg_delta`), without one from r12, where the hot
/// loop's entry put it (`hint_to_r12`).
macro_rules! against_hint {
    (true) => {
        concat!("ldr r4, [lr, #{hint}]\n", "cmp r3, r4\n")
    };
    (false) => {
        "cmp r3, r12\n"
    };
}

/// Without a background map r12 is free: a segment's hint goes there as
/// its hot loop begins (its first pixel past the lanes), so that an
/// admission does not load it (one instruction a segment with candidates
/// instead of one a candidate).
macro_rules! hint_to_r12 {
    (true) => {
        ""
    };
    (false) => {
        "ldr r12, [lr, #{hint}]\n"
    };
}

/// The value in r3 (calibrated) admitted if `>= admit`, to its tier;
/// else on to `$skip`.
macro_rules! admit {
    ($bg:tt, $lane:tt, $skip:literal) => {
        concat!(
            "cmp r3, r8\n",
            "blt ",
            $skip,
            "\n",
            against_hint!($bg),
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
                "ldr r1, [r0, #{a_position}]",
                "str r1, [sp, #4]",
                "ldr r1, [r0, #{a_max_raw}]",
                "str r1, [sp, #8]",
                "str r0, [sp, #12]",
                "ldr lr, [r0, #{a_first}]",
                "ldr r12, [r0, #{a_bg}]",
                // A window: its segment (empty: the next window; ending
                // before it starts: the end mark), lanes, admission and
                // position constant (its tiers when a pixel first passes
                // the lanes).
                "2:",
                "ldm lr, {{r5, r6, r7, r8, r9}}",
                "subs r0, r6, r5",
                "bls 8f",
                "ldrd r3, r4, [sp, #0]",
                "add r5, r5, r3",
                "add r6, r6, r3",
                "add r9, r9, r4",
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
                "b 2b",
                // An empty segment: the next window; the end mark: done.
                "8:",
                "beq 1b",
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
                "ldrd r10, r11, [lr, #{front_end}]",
                hint_to_r12!($bg),
                "b 6f",
                "32:",
                "ldrd r10, r11, [lr, #{front_end}]",
                hint_to_r12!($bg),
                "b 5f",
                // The hot loop and its exit, then the handlers: the
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
                // The hot loop's exit: the tiers' ends stored, attention
                // and room checked (r3: `raise_lane` and, above it,
                // `short_of_room`; the bytes left, shifted up, against it).
                // At attention, 20: checks room first, then raises or
                // stops.
                "strd r10, r11, [lr, #{front_end}]",
                "ldrd r0, r3, [lr, #{attention}]",
                "cmp r10, r0",
                "bhs 20f",
                "sub r0, r11, r10",
                "cmp r3, r0, lsl #16",
                "blo 1b",
                "b 18f",
                // The second word's pixels (at p - 4, p - 2); its high
                // pixel after the first word's handler.
                "5:",
                "lsls r3, r0, #16",
                "beq 51f",
                "uxth r3, r2",
                check!($check, "92f"),
                calibrate!($bg, 8),
                admit!($bg, 2, "51f"),
                // r0 still holds the word's test: a pixel's handler
                // leaves it alone.
                "51:",
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
                admit!($bg, 0, "61f"),
                "61:",
                "cmp r0, #0x10000",
                "blo 14b",
                "lsrs r3, r1, #16",
                check!($check, "91f"),
                calibrate!($bg, 4),
                admit!($bg, 1, "14b"),
                "b 14b",
                "52:",
                "lsrs r3, r2, #16",
                check!($check, "93f"),
                calibrate!($bg, 12),
                admit!($bg, 3, "17b"),
                "b 17b",
                "20:",
                "sub r0, r11, r10",
                "cmp r3, r0, lsl #16",
                "bhs 18f",
                // The front reached `attention` with room left: the raise,
                // if the engine prepared it (see `raise_admission`), else a
                // stop.
                // `raise - 1` is the raised admission's strictness
                // (`Raise`): `admit = hint + strict`; 4: the hint lowered
                // first (76:, told apart at 70: by this comparison's
                // flags); above, a counting raise of `raise / 4`
                // copies (70:).
                "ldrb r0, [lr, #{raise}]",
                "cbz r0, 18f",
                "cmp r0, #4",
                "bhs 70f",
                "subs r0, #1",
                "71:",
                "strb r0, [lr, #{strict}]",
                "ldr r3, [lr, #{hint}]",
                "str r3, [lr, #{low}]",
                "add r3, r0",
                "str r3, [lr, #{admit}]",
                "ldrh r0, [lr, #{raise_lane}]",
                "adds r3, r0, #1",
                "str r3, [lr, #{floor}]",
                "orr r0, r0, r0, lsl #16",
                "str r0, [lr, #{lanes}]",
                "ldr r0, [lr, #{buffer}]",
                "ldrh r3, [lr, #{capacity}]",
                "add r0, r0, r3, lsl #3",
                "str r0, [lr, #{back_start}]",
                "mov r0, #-1",
                "str r0, [lr, #{attention}]",
                "b 1b",
                "18:",
                "mov r0, lr",
                "b 81b",
                // A counting raise (`count_and_prove`; r4-r9 are free
                // here, the next window reloads them): the front's copies
                // of the hint since `counted` added to `at_hint` (r7),
                // then the proof (N above the hint, `raise / 4` copies
                // with its ties) or the next attention.
                "70:",
                "beq 76f",
                "lsrs r8, r0, #2",
                "ldr r4, [lr, #{buffer}]",
                "ldrh r0, [lr, #{counted}]",
                "add r5, r4, r0, lsl #3",
                "ldr r6, [lr, #{hint}]",
                "ldrh r7, [lr, #{at_hint}]",
                // Two entries a pass, after the first alone if their
                // number is odd.
                "subs r0, r10, r5",
                "beq 73f",
                "tst r0, #8",
                "beq 72f",
                "ldr r3, [r5], #8",
                "cmp r3, r6",
                "it eq",
                "addeq r7, r7, #1",
                "cmp r5, r10",
                "beq 73f",
                "72:",
                "ldr r3, [r5], #8",
                "ldr r9, [r5], #8",
                "cmp r3, r6",
                "it eq",
                "addeq r7, r7, #1",
                "cmp r9, r6",
                "it eq",
                "addeq r7, r7, #1",
                "cmp r5, r10",
                "blo 72b",
                "73:",
                "strh r7, [lr, #{at_hint}]",
                "sub r0, r10, r4",
                "lsrs r0, r0, #3",
                "strh r0, [lr, #{counted}]",
                "sub r3, r0, r7",
                "ldrh r5, [lr, #{n}]",
                "ldrh r6, [lr, #{hint_ties}]",
                "add r6, r6, r7",
                "cmp r3, r5",
                "blo 74f",
                "cmp r6, r8",
                "bhs 75f",
                // Not proved: attention at N + at_hint + the copies still
                // needed entries, and past the front.
                "74:",
                "subs r8, r8, r6",
                "it lo",
                "movlo r8, #0",
                "add r8, r8, r5",
                "add r8, r8, r7",
                "adds r0, #1",
                "cmp r8, r0",
                "it lo",
                "movlo r8, r0",
                "add r8, r4, r8, lsl #3",
                "str r8, [lr, #{attention}]",
                "b 1b",
                "75:",
                "movs r0, #1",
                "b 71b",
                // Lowering the hint (`Raise::LOWER`, `raise_below_front`;
                // r1-r9 are free): the first copy of `hint - 1` in the back
                // tier, from `back_start` up (none: a stop), becomes the
                // hint and its one tie (the window had none), nothing in
                // the front equals it (`at_hint` 0, all counted); then the
                // raise above it.
                "76:",
                "ldr r6, [lr, #{hint}]",
                "ldr r7, [lr, #{buffer}]",
                "ldrh r3, [lr, #{capacity}]",
                "sub r6, r6, #1",
                "add r4, r7, r3, lsl #3",
                "mov r5, r11",
                "77:",
                "cmp r5, r4",
                "bhs 18b",
                "ldrd r1, r2, [r5], #8",
                "cmp r1, r6",
                "bne 77b",
                "str r6, [lr, #{hint}]",
                "and r3, r2, #63",
                "str r3, [lr, #{ties_i}]",
                "ubfx r3, r2, #6, #10",
                "str r3, [lr, #{ties_j}]",
                "movs r3, #1",
                "strh r3, [lr, #{hint_ties}]",
                "movs r3, #0",
                "strh r3, [lr, #{at_hint}]",
                "sub r3, r10, r7",
                "lsrs r3, r3, #3",
                "strh r3, [lr, #{counted}]",
                "movs r0, #1",
                "b 71b",
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
                "ldr r0, [sp, #12]",
                "str r3, [r0, #{a_bad}]",
                "orr r0, lr, #1",
                "b 81b",
                a_row = const offset_of!(RowScan, row),
                a_first = const offset_of!(RowScan, first),
                a_bg = const offset_of!(RowScan, bg_delta),
                a_position = const offset_of!(RowScan, position_delta),
                a_max_raw = const offset_of!(RowScan, max_raw),
                a_bad = const offset_of!(RowScan, bad),
                front_end = const offset_of!(OpenWindow, front_end),
                hint = const offset_of!(OpenWindow, hint),
                attention = const offset_of!(OpenWindow, attention),
                counted = const offset_of!(OpenWindow, counted),
                at_hint = const offset_of!(OpenWindow, at_hint),
                n = const offset_of!(OpenWindow, n),
                hint_ties = const offset_of!(OpenWindow, hint_ties.count),
                ties_i = const offset_of!(OpenWindow, hint_ties.sum_i),
                ties_j = const offset_of!(OpenWindow, hint_ties.sum_j),
                raise = const offset_of!(OpenWindow, raise),
                raise_lane = const offset_of!(OpenWindow, raise_lane),
                buffer = const offset_of!(OpenWindow, buffer),
                capacity = const offset_of!(OpenWindow, capacity),
                floor = const offset_of!(OpenWindow, floor),
                lanes = const offset_of!(OpenWindow, lanes),
                admit = const offset_of!(OpenWindow, admit),
                low = const offset_of!(OpenWindow, low),
                back_start = const offset_of!(OpenWindow, back_start),
                strict = const offset_of!(OpenWindow, strict),
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
    // The exit's `ldrd r0, r3` of `attention` and the word after it, whose
    // high half is `short_of_room`.
    assert!(offset_of!(OpenWindow, attention) % 4 == 0);
    assert!(offset_of!(OpenWindow, raise_lane) == offset_of!(OpenWindow, attention) + 4);
    assert!(offset_of!(OpenWindow, short_of_room) == offset_of!(OpenWindow, attention) + 6);
    assert!(core::mem::size_of::<OpenWindow>() < 4096);
};

kernel!(row_background, true, false);
kernel!(row_background_checked, true, true);
kernel!(row_plain, false, false);
kernel!(row_plain_checked, false, true);
// The usual camera depths, checked against their masks (`check!`).
kernel!(row_background_checked_8, true, 0xFF00);
kernel!(row_background_checked_10, true, 0xFC00);
kernel!(row_background_checked_12, true, 0xF000);
kernel!(row_background_checked_14, true, 0xC000);
kernel!(row_plain_checked_8, false, 0xFF00);
kernel!(row_plain_checked_10, false, 0xFC00);
kernel!(row_plain_checked_12, false, 0xF000);
kernel!(row_plain_checked_14, false, 0xC000);
