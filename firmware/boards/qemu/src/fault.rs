//! How the firmware ends: semihosting exit codes for the process that runs
//! QEMU, on success, panic and HardFault.

use core::sync::atomic::{AtomicBool, Ordering};

use brightpix_board_common::fault;

use cortex_m_rt::{exception, ExceptionFrame};
use defmt_semihosting as _;
use embassy_time::Instant;

/// Exit codes seen by whoever runs QEMU.
pub mod exit_code {
    pub const OK: i32 = 0;
    pub const PANIC: i32 = 101;
    pub const HARD_FAULT: i32 = 102;
}

// Microseconds since boot (0 until the time driver is started).
defmt::timestamp!("{=u64:us}", Instant::now().as_micros());

/// End the emulation with `code` (semihosting SYS_EXIT_EXTENDED).
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

/// Set on the first panic or fault, so a fault while reporting does not recurse.
static FAILING: AtomicBool = AtomicBool::new(false);

/// A HardFault resets the board (as the STM32H743's does) instead of
/// ending QEMU (`--reset-on-fault`, `selftest=fault-once`).
static RESET_ON_FAULT: AtomicBool = AtomicBool::new(false);

/// From the command line, at boot.
pub fn reset_on_fault(on: bool) {
    RESET_ON_FAULT.store(on, Ordering::Relaxed);
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    if !FAILING.swap(true, Ordering::Relaxed) {
        defmt::error!("panic: {}", defmt::Display2Format(info));
    }
    exit(exit_code::PANIC)
}

// panic-probe is not used: its UDF would end in the default HardFault loop
// and QEMU would hang.
#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    // First, before anything that could fault again: the record the next
    // boot reports (`Status.health.faults`).
    fault::record(frame.pc(), frame.lr());
    if !FAILING.swap(true, Ordering::Relaxed) {
        defmt::error!(
            "HardFault: pc={=u32:#010x} lr={=u32:#010x}",
            frame.pc(),
            frame.lr()
        );
    }
    if RESET_ON_FAULT.load(Ordering::Relaxed) {
        // QEMU resets the machine on SYSRESETREQ and keeps RAM, the
        // record included.
        cortex_m::peripheral::SCB::sys_reset()
    }
    exit(exit_code::HARD_FAULT)
}

/// Any interrupt without a handler (see interrupts.rs) is a bug.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    panic!("unexpected interrupt/exception {}", irqn);
}
