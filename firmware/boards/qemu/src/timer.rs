//! CMSDK APB timer0 (0x4000_0000) as a free-running 32-bit tick counter.
//!
//! It counts down at the peripheral clock, 25 MHz of QEMU's virtual time
//! (40 ns per tick). Under `-icount shift=S` every instruction takes 2^S ns
//! of virtual time, so a tick count converts to instructions exactly:
//! `instructions = ticks * 40 / 2^S` (the benchmark measures the ratio
//! instead of trusting `S`, see `src/bench/`). DWT's cycle counter does not
//! exist in QEMU. The counter wraps after 2^32 ticks (172 s virtual).

use core::ptr::{read_volatile, write_volatile};

const BASE: usize = 0x4000_0000;
const CTRL: usize = 0x00;
const VALUE: usize = 0x04;
const RELOAD: usize = 0x08;
const CTRL_ENABLE: u32 = 1;

/// Nanoseconds per tick of the mps2 peripheral clock (25 MHz).
pub const NS_PER_TICK: u32 = 40;

/// Starts timer0 counting down from 2^32 - 1, reloading, no interrupt.
pub fn start() {
    // SAFETY: valid, aligned MMIO registers of timer0, not used elsewhere.
    unsafe {
        write_volatile((BASE + CTRL) as *mut u32, 0);
        write_volatile((BASE + RELOAD) as *mut u32, u32::MAX);
        write_volatile((BASE + VALUE) as *mut u32, u32::MAX);
        write_volatile((BASE + CTRL) as *mut u32, CTRL_ENABLE);
    }
}

/// Ticks since [`start`], modulo 2^32 (subtract two readings with
/// `wrapping_sub`).
#[inline(always)]
pub fn ticks() -> u32 {
    // SAFETY: a valid, aligned MMIO register of timer0.
    !unsafe { read_volatile((BASE + VALUE) as *const u32) }
}
