//! brightpix on QEMU mps2-an386 (Cortex-M4F).
//!
//! Board bring-up: defmt over semihosting, embassy executor (WFI loop) and time
//! driver (SysTick), async UART0. For now `main` runs an echo loop on UART0
//! (byte 0x04 ends the emulation with exit code 0); the device loop replaces it.
//!
//! Semihosting command line (`-semihosting-config enable=on,target=native,arg=brightpix-qemu,arg=X`),
//! for tests of the board itself:
//! - `X` = a host path: read that file first and log its length and FNV-1a hash
//!   (smoke check of `hostfs`);
//! - `X` = `selftest=panic` / `selftest=udf`: panic / execute an undefined
//!   instruction, to check that both end QEMU with exit code 101 / 102.
#![no_std]
#![no_main]

mod hostfs;
mod interrupts;
mod time_driver;
mod uart;

use core::sync::atomic::{AtomicBool, Ordering};

use brightpix_board_common::executor;
use cortex_m_rt::{entry, exception, ExceptionFrame};
use defmt_semihosting as _;
use embassy_executor::Spawner;
use embassy_time::{Instant, Timer};
use embedded_io_async::{Read, Write};

use crate::uart::Uart0;

/// Exit codes seen by whoever runs QEMU.
pub mod exit_code {
    pub const OK: i32 = 0;
    pub const PANIC: i32 = 101;
    pub const HARD_FAULT: i32 = 102;
}

/// End of transmission: the echo loop exits QEMU when it receives it.
const EOT: u8 = 0x04;

defmt::timestamp!("{=u64:us}", Instant::now().as_micros());

#[entry]
fn main() -> ! {
    let cp = cortex_m::Peripherals::take().unwrap();
    time_driver::init(cp.SYST);
    defmt::info!("brightpix-qemu: hello from mps2-an386");
    executor::run(|spawner: Spawner| {
        spawner.spawn(startup(spawner).unwrap());
    })
}

#[embassy_executor::task]
async fn startup(spawner: Spawner) {
    let t0 = Instant::now();
    Timer::after_millis(10).await;
    defmt::info!("timer: 10 ms took {=u64} us", t0.elapsed().as_micros());

    command_line_checks();

    let uart = Uart0::new().unwrap();
    spawner.spawn(echo(uart).unwrap());
}

/// Board self-tests selected by the semihosting command line (see the crate docs).
fn command_line_checks() {
    let Ok(args) = semihosting::experimental::env::args::<256>() else {
        return;
    };
    match (&args).nth(1) {
        Some(Ok("selftest=panic")) => panic!("selftest"),
        Some(Ok("selftest=udf")) => cortex_m::asm::udf(),
        Some(Ok(path)) => smoke_check_hostfs(path),
        _ => defmt::info!("hostfs: no path argument, smoke check skipped"),
    }
}

/// Read a host file through semihosting and log its length and hash.
fn smoke_check_hostfs(path: &str) {
    let mut chunk = [0u8; 512];
    match hostfs::digest(path, &mut chunk) {
        Ok((flen, len, hash)) => defmt::info!(
            "hostfs: {=str}: {=u64} bytes read (SYS_FLEN {=u64}), fnv1a32 {=u32:#010x}",
            path,
            len,
            flen,
            hash
        ),
        Err(e) => defmt::warn!("hostfs: {=str}: error {}", path, defmt::Debug2Format(&e)),
    }
}

/// Echo every byte received on UART0; exit QEMU (code 0) on EOT (0x04).
#[embassy_executor::task]
async fn echo(mut uart: Uart0) {
    defmt::info!("uart0: echo loop ready (send 0x04 to exit)");
    let mut buf = [0u8; 64];
    let mut total = 0usize;
    loop {
        let Ok(n) = uart.read(&mut buf).await;
        let data = &buf[..n];
        let (data, eot) = match data.iter().position(|&b| b == EOT) {
            Some(i) => (&data[..i], true),
            None => (data, false),
        };
        let Ok(()) = uart.write_all(data).await;
        total += data.len();
        if eot {
            let Ok(()) = uart.flush().await;
            defmt::info!(
                "uart0: EOT after {=usize} bytes echoed, {}; exiting",
                total,
                uart::stats()
            );
            exit(exit_code::OK);
        }
    }
}

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
