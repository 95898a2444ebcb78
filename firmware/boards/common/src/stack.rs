//! The main stack: a guard against overflow and a high-water mark.
//!
//! cortex-m-rt puts the stack at the top of RAM, growing down towards the
//! end of `.bss`/`.uninit` (`_stack_end`), where the statics (the task pool,
//! the RTT buffers, the engine's memory) live: an overflow would overwrite
//! them silently. [`guard`] makes the lowest [`GUARD_BYTES`] of the stack a
//! no-access MPU region, so an overflow faults instead. The guard must be
//! larger than any function's stack frame (plus the exception frame): a
//! function whose frame is larger could move the stack pointer past the
//! guard and write the statics below without touching it. The largest
//! frames of the STM32H743 build are 5,824 bytes (embassy's task spawn,
//! which builds the device task's future on the stack), 2,856 (the device
//! loop) and 1,000 (`scripts/board-memory` lists them from the ELF and
//! fails if one reaches the guard), hence 8 KiB, the next MPU region size
//! (a power of two, aligned to itself).
//!
//! An overflow into the guard faults while the core stacks the exception
//! (the stack pointer is in the guard), so the core locks up and the
//! watchdog resets it: faulted at once, nothing overwritten, but no fault
//! record (`fault.rs` records every other fault). [`paint`] fills the
//! unused stack with a pattern at boot; [`usage`] finds the deepest word
//! that changed (the high-water mark, reported in `Status.health.stack`).
//!
//! The MPU is ARMv7-M PMSA (Cortex-M4 and M7 alike; QEMU models it): region
//! 0 at the guard, the default memory map everywhere else (PRIVDEFENA), so
//! nothing else changes.

use brightpix_protocol::wire::StackUsage;
use core::sync::atomic::{AtomicBool, Ordering};

extern "C" {
    /// Top of the stack (cortex-m-rt's link.x).
    static _stack_start: u32;
    /// Lowest address the stack may use (link.x; the boards' memory.x).
    static _stack_end: u32;
}

/// What unused stack holds after [`paint`].
const PAINT: u32 = 0x5AC5_5AC5;
/// The guard region: larger than the largest stack frame plus an exception
/// frame (module documentation); an MPU region size (a power of two).
pub const GUARD_BYTES: usize = 8192;
const _: () = assert!(GUARD_BYTES.is_power_of_two() && GUARD_BYTES >= 32);
/// Left unpainted below the stack pointer of [`paint`]'s own frame.
const PAINT_MARGIN: usize = 256;

static GUARDED: AtomicBool = AtomicBool::new(false);

/// The guard's size, kept in the ELF for `scripts/board-memory` (which
/// checks it against the largest stack frame).
#[no_mangle]
#[used]
pub static BRIGHTPIX_STACK_GUARD: u32 = GUARD_BYTES as u32;

fn top() -> usize {
    core::ptr::addr_of!(_stack_start) as usize
}

/// The lowest usable stack address: above the guard region.
fn bottom() -> usize {
    let end = core::ptr::addr_of!(_stack_end) as usize;
    end.next_multiple_of(GUARD_BYTES) + GUARD_BYTES
}

/// Fills the stack from its bottom to a little below the current stack
/// pointer with the pattern. Call once, first thing in `main`.
#[inline(never)]
pub fn paint() {
    let sp = cortex_m::register::msp::read() as usize;
    let mut word = bottom();
    let end = sp.saturating_sub(PAINT_MARGIN) & !3;
    while word < end {
        // SAFETY: between the statics' end and this frame's stack pointer
        // (minus a margin): stack memory nothing uses yet.
        unsafe { (word as *mut u32).write_volatile(PAINT) };
        word += 4;
    }
}

/// Makes the lowest [`GUARD_BYTES`] of the stack (aligned to its size, just
/// above `_stack_end`) inaccessible through the MPU. Call once, in `main`.
pub fn guard(mpu: &mut cortex_m::peripheral::MPU) {
    // Referenced, so the linker keeps the symbol.
    core::hint::black_box(&BRIGHTPIX_STACK_GUARD);
    let base = bottom() - GUARD_BYTES;
    // SAFETY: region 0 (no other code uses the MPU); it covers only the
    // guard bytes, which no data lives in; the default map stays for the
    // rest of memory (MPU_CTRL.PRIVDEFENA), so nothing else changes.
    unsafe {
        cortex_m::asm::dmb();
        mpu.ctrl.write(0);
        mpu.rnr.write(0);
        mpu.rbar.write(base as u32);
        // RASR (ARMv7-M B3.5.9): XN (bit 28), AP = 0b000 no access
        // (bits 26:24), SIZE (bits 5:1: 2^(SIZE+1) bytes), ENABLE.
        let size = GUARD_BYTES.trailing_zeros() - 1;
        mpu.rasr.write((1 << 28) | (size << 1) | 1);
        // MPU_CTRL: ENABLE, PRIVDEFENA (bit 2); HFNMIENA off.
        mpu.ctrl.write(0b101);
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
    }
    GUARDED.store(true, Ordering::Relaxed);
}

/// The stack's size and the most of it used so far (from the pattern
/// [`paint`] left; 0 if it never ran).
pub fn usage() -> StackUsage {
    let (bottom, top) = (bottom(), top());
    let mut word = bottom;
    // SAFETY: reads of stack memory below the live stack pointer or in use
    // by callers: plain words, read only.
    while word < top && unsafe { (word as *const u32).read_volatile() } == PAINT {
        word += 4;
    }
    StackUsage {
        size: (top - bottom) as u32,
        peak: (top - word) as u32,
        guarded: GUARDED.load(Ordering::Relaxed),
    }
}
