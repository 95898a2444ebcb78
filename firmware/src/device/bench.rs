//! The bench request (PROTOCOL.md §14): the board measures the engine on
//! its own workloads, in memory the device lends it.
//!
//! The device loop checks the request (not while streaming or uploading),
//! drops its engine, lends the board's [`BenchRunner`] the engine's memory
//! and the staging slot's tables, sends one `BenchReport` per workload and
//! `Ack(BenchDone)`, and then builds the engine again from the active
//! configuration (afresh: the level filters start again, as after a new
//! session). The active slot is never touched, so the configuration and its
//! digest are unchanged.

use brightpix_protocol::wire::BenchReport;
use brightpix_protocol::SubapertureWindow;

use crate::engine::EngineMemory;

/// What the device lends a bench: memory that no configuration uses while
/// the bench runs.
pub struct BenchMemory<'a> {
    /// The engine's memory (the device's engine is dropped meanwhile).
    pub engine: EngineMemory<'a>,
    /// The staging slot's tables (no upload is in progress).
    pub windows: &'a mut [SubapertureWindow],
    pub background: &'a mut [i32],
    /// The staging slot's gain map, for the frames (u16 pixels).
    pub gain: &'a mut [u16],
}

/// A board's bench mode: its workloads and how it measures one.
pub trait BenchRunner {
    /// How many workloads the board has.
    fn workloads(&self) -> usize;
    /// Workload `index`'s name (at most `MAX_WORKLOAD_NAME_LEN` bytes).
    fn name(&self, index: usize) -> &'static str;
    /// Most frames it measures per workload.
    fn max_frames(&self) -> u32;
    /// Measures workload `index` over `frames` frames (0: the workload's
    /// own count). Runs synchronously: it must keep the board's watchdog
    /// fed itself.
    fn run(&mut self, index: usize, frames: u32, memory: BenchMemory<'_>) -> BenchReport<'static>;
}

/// A checked bench request: workloads `first .. first + count`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct BenchPlan {
    pub first: usize,
    pub count: usize,
    pub frames: u32,
}
