//! Board support for QEMU `mps2-an386` (Cortex-M4F) and `mps2-an500`
//! (Cortex-M7, the same firmware built with `-C target-cpu=cortex-m7`: the
//! code generation the STM32H743 gets), shared by the device
//! firmware (`brightpix-qemu`, `src/main.rs`) and the engine benchmark
//! (`brightpix-qemu-bench`, `src/bench/`).
//!
//! - [`fault`]: panic and HardFault handlers that end QEMU with an exit code;
//! - [`time_driver`]: embassy-time on SysTick;
//! - [`uart`]: CMSDK UART0 as an async byte transport (the host link);
//! - [`hostfs`], [`pixels`]: host files through semihosting, and the pixel
//!   source that reads `PixelRows` frames from one;
//! - [`camera`]: the simulated camera, frames from the host in the camera
//!   ring at the board's frame rate;
//! - [`args`]: the semihosting command line;
//! - [`storage`]: the device's buffers, sized for the board's 4 MiB of RAM;
//! - [`timer`]: the CMSDK timer0, a 32-bit tick counter (benchmarks);
//! - `interrupts`: the device interrupt vector table.
#![no_std]

pub mod args;
pub mod camera;
pub mod fault;
pub mod hostfs;
mod interrupts;
pub mod pixels;
pub mod storage;
pub mod time_driver;
pub mod timer;
pub mod uart;

pub use fault::{exit, exit_code};

use brightpix_protocol::wire::Health;

/// The name the device reports in `HelloReply` on mps2-an386 (Cortex-M4).
pub const BOARD_NAME: &str = "qemu-mps2-an386";

/// The name it reports on mps2-an500 (Cortex-M7).
pub const BOARD_NAME_M7: &str = "qemu-mps2-an500";

/// The board's name, from the core QEMU emulates (SCB CPUID.PARTNO,
/// bits 15:4: 0xC24 Cortex-M4, 0xC27 Cortex-M7).
pub fn board_name() -> &'static str {
    // SAFETY: a read of a read-only system register.
    let cpuid = unsafe { (*cortex_m::peripheral::CPUID::PTR).base.read() };
    if (cpuid >> 4) & 0xFFF == 0xC27 {
        BOARD_NAME_M7
    } else {
        BOARD_NAME
    }
}

/// What this board can read of its health (`Status.health`): the stack
/// and the fault record. Silicon, clocks, USB clock trimming and a camera interface are
/// the STM32H743's (`None` here: not read); QEMU's DWT cycle counter reads
/// 0, so neither is the CPU's idle time.
pub fn health() -> Health {
    Health {
        stack: Some(brightpix_board_common::stack::usage()),
        faults: Some(brightpix_board_common::fault::log()),
        ..Health::default()
    }
}
