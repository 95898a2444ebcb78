//! Instruction counting under QEMU `-icount`.
//!
//! Under `-icount shift=S` every instruction takes 2^S ns of virtual time,
//! and the CMSDK timer0 ticks every 40 ns, so a tick count is an
//! instruction count. The meter measures ticks per instruction on a loop of
//! known length rather than trusting S, and says so if QEMU does not run
//! with `-icount` (the figures are then host-time noise, not counts).
//!
//! Used by both binaries: the bench (`brightpix-qemu-bench`) and the
//! device's bench request (`src/bench_request.rs`).

use core::sync::atomic::{compiler_fence, Ordering};

use brightpix_board_qemu::timer;

// `brightpix-bench`'s trait: its source file compiled into the bench
// binary, the crate's own in the device binary (each says `mod counter`).
use crate::counter::Counter;

/// Converts timer ticks to instructions.
pub struct Meter {
    pub ticks_per_instruction: f64,
    /// Ticks of two back-to-back timer readings.
    overhead: u32,
}

impl Meter {
    /// Measures ticks per instruction on a loop of known length; also
    /// returns the `-icount` shift it implies, if it is one.
    pub fn calibrate() -> (Meter, Option<u32>) {
        timer::start();
        let mut overhead = u32::MAX;
        for _ in 0..16 {
            let t0 = timer::ticks();
            let t1 = timer::ticks();
            overhead = overhead.min(t1.wrapping_sub(t0));
        }
        const ITERATIONS: u32 = 1_000_000;
        let t0 = timer::ticks();
        // SAFETY: a register-only countdown loop, two instructions per iteration.
        unsafe {
            core::arch::asm!(
                "2:",
                "subs {n}, {n}, #1",
                "bne 2b",
                n = inout(reg) ITERATIONS => _,
                options(nomem, nostack),
            );
        }
        let t1 = timer::ticks();
        let ticks = t1.wrapping_sub(t0).saturating_sub(overhead);
        let ticks_per_instruction = ticks as f64 / (2.0 * ITERATIONS as f64);
        // -icount shift=S: 2^S ns per instruction, 40 ns per tick.
        let ns = ticks_per_instruction * timer::NS_PER_TICK as f64;
        let shift = (0..=10).find(|&s| {
            let exact = (1u32 << s) as f64;
            (ns - exact).abs() < exact * 0.001
        });
        let meter = Meter {
            ticks_per_instruction,
            overhead,
        };
        (meter, shift)
    }
}

impl Counter for Meter {
    /// Instructions `f` takes (from ticks, less the timer overhead).
    #[inline(always)]
    fn count<R>(&self, f: impl FnOnce() -> R) -> (f64, R) {
        compiler_fence(Ordering::SeqCst);
        let t0 = timer::ticks();
        compiler_fence(Ordering::SeqCst);
        let r = f();
        compiler_fence(Ordering::SeqCst);
        let t1 = timer::ticks();
        compiler_fence(Ordering::SeqCst);
        let ticks = t1.wrapping_sub(t0).saturating_sub(self.overhead);
        // The conversion is software double arithmetic on Cortex-M4 (~250
        // instructions), which the compiler may otherwise move past the
        // next count's first reading, into its measured work: `black_box`
        // computes it here, between the two.
        let count = core::hint::black_box(ticks as f64 / self.ticks_per_instruction);
        (count, r)
    }
}

/// The core QEMU emulates, from the CPUID register: `cortex-m4` or
/// `cortex-m7` (what the benchmark's JSON lines call it).
pub fn core_name() -> &'static str {
    // SAFETY: CPUID (0xE000ED00) is a read-only System Control Block
    // register present on every Cortex-M.
    let cpuid = unsafe { core::ptr::read_volatile(0xE000_ED00 as *const u32) };
    match (cpuid >> 4) & 0xfff {
        0xc24 => "cortex-m4",
        0xc27 => "cortex-m7",
        0xc23 => "cortex-m3",
        _ => "cortex-m?",
    }
}
