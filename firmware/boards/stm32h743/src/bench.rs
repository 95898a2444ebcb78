//! The bench request on the board (PROTOCOL.md §14): the engine and the
//! honest floor on the board's own generated workloads
//! (`brightpix_bench::workloads::ALL`), counted in core clock cycles by
//! the DWT cycle counter (CYCCNT, started in `main`), with the I- and
//! D-cache on as the board always runs. `brightpix bench --port PORT`.
//!
//! Where the work runs: the engine's memory in the DTCM and the AXI SRAM
//! (the device's own, lent while the bench runs; the engine is built afresh
//! from the active configuration afterwards), the frames in the staging
//! slot's gain map (D2 SRAM, cached; a camera's pixels reach the engine
//! from the DTCM run buffer instead), the background map in the staging
//! slot's (AXI SRAM, cached, as a configuration's is), the bench's own
//! buffers in the AXI SRAM. Code runs from flash through the I-cache (the
//! ART accelerator and the 16 KiB I-cache: a hot loop runs from the cache
//! after its first pass).
//!
//! NOT RUN ON HARDWARE: it builds; the same code path is exercised on the
//! QEMU board (instructions under `-icount`).

use brightpix_bench::device::{BenchBuffers, BoardBench, BoardCounter};
use brightpix_bench::Counter;
use brightpix_protocol::wire::CountUnit;
use core::sync::atomic::{compiler_fence, Ordering};
use cortex_m::peripheral::DWT;

use crate::health;

/// Windows of a workload the board measures (the bench's buffers).
pub const BENCH_WINDOWS: usize = 256;
/// Frames per workload, at most.
pub const BENCH_FRAMES: usize = 64;

pub type Buffers = BenchBuffers<BENCH_WINDOWS, BENCH_FRAMES>;
pub type Bench<'b> = BoardBench<'b, Cycles, BENCH_WINDOWS, BENCH_FRAMES>;

/// IWDG1's key register (RM0433: IWDG1 at 0x5800_4800, IWDG_KR at offset
/// 0): 0xAAAA reloads the counter.
const IWDG1_KR: *mut u32 = 0x5800_4800 as *mut u32;

/// Cycles by DWT CYCCNT (32 bits: a frame must take less than 2^32
/// cycles, 10 s at 400 MHz).
pub struct Cycles {
    /// Cycles of two back-to-back readings.
    overhead: u32,
}

impl Cycles {
    pub const fn new() -> Self {
        Cycles { overhead: 0 }
    }
}

/// Interrupts are masked during each timed call (one camera row's push or
/// floor row: tens of microseconds), so no handler's cycles (USB, the time
/// driver) are counted; pending ones run between the calls. (USB keeps
/// working: its interrupts wait at most one such call.)
impl Counter for Cycles {
    #[inline(always)]
    fn count<R>(&self, f: impl FnOnce() -> R) -> (f64, R) {
        cortex_m::interrupt::free(|_| {
            compiler_fence(Ordering::SeqCst);
            let t0 = DWT::cycle_count();
            compiler_fence(Ordering::SeqCst);
            let r = f();
            compiler_fence(Ordering::SeqCst);
            let t1 = DWT::cycle_count();
            compiler_fence(Ordering::SeqCst);
            let cycles = t1.wrapping_sub(t0).saturating_sub(self.overhead);
            (cycles as f64, r)
        })
    }

    /// Feeds the independent watchdog: a workload of many frames runs
    /// longer than its 2 s (the device loop feeds it between workloads).
    fn between_frames(&self) {
        // SAFETY: a write of the reload key to IWDG1_KR, which the device
        // loop's watchdog also writes (same value, no read-modify-write).
        unsafe { core::ptr::write_volatile(IWDG1_KR, 0xAAAA) };
    }
}

impl BoardCounter for Cycles {
    fn start(&mut self) -> (CountUnit, Option<u32>) {
        let mut overhead = u32::MAX;
        for _ in 0..16 {
            overhead = overhead.min(cortex_m::interrupt::free(|_| {
                compiler_fence(Ordering::SeqCst);
                let t0 = DWT::cycle_count();
                compiler_fence(Ordering::SeqCst);
                let t1 = DWT::cycle_count();
                t1.wrapping_sub(t0)
            }));
        }
        self.overhead = overhead;
        (CountUnit::Cycles, Some(health::cpu_clock_read_hz()))
    }
}
