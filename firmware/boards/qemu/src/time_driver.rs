//! embassy-time driver on SysTick (QEMU mps2: the core clock, 25 MHz of virtual time).
//!
//! SysTick is a 24-bit down-counter with no compare register, so it runs as a
//! periodic 1 ms tick: the interrupt extends the count to 64 bits and fires expired
//! timers. `now()` has 1 us resolution (embassy-time's default 1 MHz tick rate,
//! from the current counter value); timers expire on the first 1 ms tick at or
//! after their deadline, so they are up to 1 ms late.

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicBool, Ordering};
use core::task::Waker;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use cortex_m_rt::exception;
use critical_section::{CriticalSection, Mutex};
use embassy_time_driver::{Driver, TICK_HZ};
use embassy_time_queue_utils::Queue;

/// SysTick input clock (CLKSOURCE = core clock). QEMU's mps2 boards run it at 25 MHz.
pub const SYSTICK_HZ: u64 = 25_000_000;
/// Interrupt period in embassy ticks (1 ms at the default 1 MHz tick rate).
const PERIOD_TICKS: u64 = TICK_HZ / 1000;
const CYCLES_PER_TICK: u32 = (SYSTICK_HZ / TICK_HZ) as u32;
const RELOAD: u32 = (SYSTICK_HZ / 1000) as u32 - 1;
const _: () = assert!(SYSTICK_HZ.is_multiple_of(TICK_HZ) && RELOAD < (1 << 24));

struct SysTickDriver {
    started: AtomicBool,
    /// Completed SysTick periods since `init`.
    periods: Mutex<Cell<u64>>,
    /// Earliest deadline in `queue` (u64::MAX: none).
    alarm: Mutex<Cell<u64>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    started: AtomicBool::new(false),
    periods: Mutex::new(Cell::new(0)),
    alarm: Mutex::new(Cell::new(u64::MAX)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

impl SysTickDriver {
    fn now_cs(&self, cs: CriticalSection) -> u64 {
        if !self.started.load(Ordering::Acquire) {
            return 0;
        }
        let mut periods = self.periods.borrow(cs).get();
        // With interrupts masked, a wrap since the last SysTick interrupt shows up as
        // a pending SysTick exception. Check before and after reading the counter;
        // if it wrapped, re-read the counter (now certainly after the wrap).
        let wrapped_before = SCB::is_pendst_pending();
        let mut val = SYST::get_current();
        if wrapped_before || SCB::is_pendst_pending() {
            val = SYST::get_current();
            periods += 1;
        }
        periods * PERIOD_TICKS + u64::from((RELOAD - val.min(RELOAD)) / CYCLES_PER_TICK)
    }

    /// Wake expired timers and remember the next deadline.
    fn service_queue(&self, cs: CriticalSection) {
        let now = self.now_cs(cs);
        let next = self.queue.borrow_ref_mut(cs).next_expiration(now);
        self.alarm.borrow(cs).set(next);
    }
}

impl Driver for SysTickDriver {
    fn now(&self) -> u64 {
        critical_section::with(|cs| self.now_cs(cs))
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            if self.queue.borrow_ref_mut(cs).schedule_wake(at, waker) {
                self.service_queue(cs);
            }
        })
    }
}

/// Start SysTick. Call once, early (before any `Timer`).
pub fn init(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(RELOAD);
    syst.clear_current();
    DRIVER.started.store(true, Ordering::Release);
    syst.enable_interrupt();
    syst.enable_counter();
}

#[exception]
fn SysTick() {
    critical_section::with(|cs| {
        let periods = DRIVER.periods.borrow(cs);
        periods.set(periods.get() + 1);
        if DRIVER.now_cs(cs) >= DRIVER.alarm.borrow(cs).get() {
            DRIVER.service_queue(cs);
        }
    });
}
