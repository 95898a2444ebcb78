//! A thread-mode executor that sleeps with WFI.
//!
//! embassy-executor's stock cortex-m thread executor sleeps with WFE, which QEMU
//! does not halt on: it spins at 100% host CPU (and burns virtual time under
//! `-icount`). This loop polls `raw::Executor` and sleeps with WFI when no task
//! is ready; on real hardware it is equivalent (every wake-up that matters comes
//! from an interrupt or from thread mode, both handled below). Interrupts are masked between the "anything pending?" check and the
//! WFI, so a wake-up from an interrupt handler in between cannot be lost (a
//! pending interrupt ends WFI even while PRIMASK is set; it is then taken right
//! after `cpsie`).

use core::cell::Cell;
use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m::interrupt::Mutex;
use cortex_m::peripheral::DWT;
use embassy_executor::{raw, Spawner};

/// Core clock cycles spent in WFI, by the DWT cycle counter (which the
/// board must have started; QEMU's reads 0, so this stays 0 there).
static IDLE_CYCLES: Mutex<Cell<u64>> = Mutex::new(Cell::new(0));

/// Core clock cycles the executor has slept since start (see
/// [`IDLE_CYCLES`]). A single sleep must be shorter than the cycle
/// counter's wrap (10.7 s at 400 MHz): any timer or interrupt ends it.
pub fn idle_cycles() -> u64 {
    cortex_m::interrupt::free(|cs| IDLE_CYCLES.borrow(cs).get())
}

/// Set by the pender (any context) when a task was woken; cleared before each poll.
static WORK_PENDING: AtomicBool = AtomicBool::new(true);

// Called by embassy-executor whenever a task becomes ready (from thread or interrupt
// context). It must not poll; it only records that a poll is due.
#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    WORK_PENDING.store(true, Ordering::Release);
}

/// Run the executor forever. `init` spawns the initial tasks.
pub fn run(init: impl FnOnce(Spawner)) -> ! {
    let executor: &'static raw::Executor =
        cortex_m::singleton!(: raw::Executor = raw::Executor::new(core::ptr::null_mut()))
            .expect("executor::run called twice");
    init(executor.spawner());
    loop {
        WORK_PENDING.store(false, Ordering::Release);
        // SAFETY: poll is only ever called from this loop, never re-entrantly.
        unsafe { executor.poll() };
        cortex_m::interrupt::disable();
        if !WORK_PENDING.load(Ordering::Acquire) {
            let asleep = DWT::cycle_count();
            cortex_m::asm::wfi();
            // Still masked: the interrupt that ended WFI has not run yet.
            let slept = DWT::cycle_count().wrapping_sub(asleep);
            cortex_m::interrupt::free(|cs| {
                let idle = IDLE_CYCLES.borrow(cs);
                idle.set(idle.get() + u64::from(slept));
            });
        }
        // SAFETY: interrupts were enabled on entry to this loop (we are in thread mode
        // and nothing else in this firmware keeps them disabled across the call).
        unsafe { cortex_m::interrupt::enable() };
    }
}
