//! The engine benchmark's workloads, shared by every place that measures
//! the engine on Cortex-M: the QEMU bench (`boards/qemu/src/bench/`,
//! instructions under `-icount`) and the boards' bench mode (the device
//! loop's `Bench` request, PROTOCOL.md §14: DWT cycles on the STM32H743,
//! instructions on the QEMU board). One implementation, so a board's figures
//! and the QEMU tables are measured on the same frames against the same
//! floor.
//!
//! - [`frames`]: deterministic frames generated on the device (spots,
//!   closed-loop spots, ramp, flat noise, all equal; noise and a patterned
//!   background as asked);
//! - [`workloads`]: the workloads ([`workloads::ALL`]) and how one is
//!   measured ([`workloads::measure`]): the engine one camera row per push,
//!   the work after the frame's last row, and the floor on the same frames;
//! - [`floor`], [`floor_row`]: the honest floor, a streaming centre of
//!   gravity above each window's known `v(N+1)` whose slopes equal the
//!   engine's subtract-next slopes bit for bit (checked);
//! - [`sort`]: the paper's sort per sub-aperture, and the floor's known
//!   levels;
//! - [`camera_feed`]: the board's camera path (its `DcmiSource` over a
//!   DMA ring in RAM), for the workload that pushes through it;
//! - [`device`]: one workload measured for the device loop's bench request,
//!   in memory the device lends (its engine memory and staging slot).
//!
//! What counts is the caller's: a [`Counter`].
//!
//! The QEMU bench (`brightpix-qemu-bench`) compiles these source files as
//! modules of its own binary (`#[path]`) rather than linking this crate:
//! the same code, but in one crate with its timed loops, as it always was.
//! Moving it behind a crate boundary changes what LLVM inlines around the
//! timed calls, which moved the CANARY engine figure by 0.01-0.03 instr/px
//! and the sort's by 0.4: the QEMU tables stay as they were only this way.
//! So `camera_feed.rs`, `counter.rs`, `floor.rs`, `floor_row.rs`, `frames.rs`, `sort.rs` and
//! `workloads.rs` refer to each other as `crate::...` and to nothing else
//! of this crate.
#![no_std]

pub use counter::Counter;

pub mod camera_feed;
mod counter;
pub mod device;
pub mod floor;
pub mod floor_row;
pub mod frames;
pub mod sort;
pub mod workloads;
