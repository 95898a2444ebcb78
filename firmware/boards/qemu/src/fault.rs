//! How the firmware ends: semihosting exit codes for the process that runs
//! QEMU, on success, panic and HardFault.

use core::sync::atomic::{AtomicBool, Ordering};

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
    if !FAILING.swap(true, Ordering::Relaxed) {
        defmt::error!(
            "HardFault: pc={=u32:#010x} lr={=u32:#010x}",
            frame.pc(),
            frame.lr()
        );
    }
    exit(exit_code::HARD_FAULT)
}

/// Any interrupt without a handler (see interrupts.rs) is a bug.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    panic!("unexpected interrupt/exception {}", irqn);
}
