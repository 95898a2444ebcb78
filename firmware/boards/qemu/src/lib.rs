//! Board support for QEMU `mps2-an386` (Cortex-M4F), shared by the device
//! firmware (`brightpix-qemu`, `src/main.rs`) and the engine benchmark
//! (`brightpix-qemu-bench`, `src/bench/`).
//!
//! - [`fault`]: panic and HardFault handlers that end QEMU with an exit code;
//! - [`time_driver`]: embassy-time on SysTick;
//! - [`uart`]: CMSDK UART0 as an async byte transport (the host link);
//! - [`hostfs`], [`pixels`]: host files through semihosting, and the pixel
//!   source that reads `PixelRows` frames from one;
//! - [`args`]: the semihosting command line;
//! - [`storage`]: the device's buffers, sized for the board's 4 MiB of RAM;
//! - [`timer`]: the CMSDK timer0, a 32-bit tick counter (benchmarks);
//! - `interrupts`: the device interrupt vector table.
#![no_std]

pub mod args;
pub mod fault;
pub mod hostfs;
mod interrupts;
pub mod pixels;
pub mod storage;
pub mod time_driver;
pub mod timer;
pub mod uart;

pub use fault::{exit, exit_code};

/// The name the device reports in `HelloReply`.
pub const BOARD_NAME: &str = "qemu-mps2-an386";
