//! The HardFault handler: the fault's registers into the record that the
//! next boot reports (`brightpix_board_common::fault`), then a reset.
//! Without it a fault locked the core in cortex-m-rt's default loop until
//! the watchdog bit, and left nothing to say where.
//!
//! A panic ends here too: panic-probe logs it over defmt, then executes
//! UDF (CFSR.UNDEFINSTR, PC in panic-probe). A stack overflow that hits the
//! MPU guard faults while stacking the exception itself: the core locks up
//! and the watchdog resets it, with no record (`doctor` says so).

use brightpix_board_common::fault;
use cortex_m_rt::{exception, ExceptionFrame};

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    fault::record(frame.pc(), frame.lr());
    cortex_m::peripheral::SCB::sys_reset()
}
