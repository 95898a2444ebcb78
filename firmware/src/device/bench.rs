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

use brightpix_protocol::wire::{Ack, BenchFault, BenchReport, DeviceMessage, ALL_WORKLOADS};
use brightpix_protocol::SubapertureWindow;
use embedded_io_async::{Read, Write};

use super::fmt::log_info;
use super::{reborrow, saturate, ConfigSlot, Core, LinkResult, Watchdog};
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

impl<T: Read + Write, W: Watchdog> Core<'_, T, W> {
    /// A bench request, checked before anything changes.
    pub(super) fn check_bench(&self, workload: &str, frames: u32) -> Result<BenchPlan, BenchFault> {
        let Some(runner) = self.bench.as_deref() else {
            return Err(BenchFault::NotSupported);
        };
        if self.frame.is_some() || self.capture.is_some() {
            return Err(BenchFault::Streaming);
        }
        if self.upload.is_some() {
            return Err(BenchFault::UploadInProgress);
        }
        let max = runner.max_frames();
        if frames > max {
            return Err(BenchFault::TooManyFrames { max });
        }
        let all = runner.workloads();
        if workload == ALL_WORKLOADS {
            return Ok(BenchPlan {
                first: 0,
                count: all,
                frames,
            });
        }
        match (0..all).find(|&k| runner.name(k) == workload) {
            Some(first) => Ok(BenchPlan {
                first,
                count: 1,
                frames,
            }),
            None => Err(BenchFault::UnknownWorkload),
        }
    }

    /// Runs a checked bench in the engine's memory and the staging slot's
    /// tables, one report per workload, then `Ack(BenchDone)`. The engine
    /// is built afresh afterwards.
    pub(super) async fn bench(
        &mut self,
        plan: BenchPlan,
        memory: &mut EngineMemory<'_>,
        staging: &mut ConfigSlot<'_>,
    ) -> LinkResult<(), T::Error> {
        self.fresh_engine = true;
        // Its tables are about to be overwritten: never activate them.
        staging.header = None;
        log_info!(
            "device: bench of {=usize} workloads, {=u32} frames each (0: their own)",
            plan.count,
            plan.frames
        );
        for index in plan.first..plan.first + plan.count {
            self.watchdog.feed();
            let Some(runner) = self.bench.as_deref_mut() else {
                break;
            };
            let report = runner.run(
                index,
                plan.frames,
                BenchMemory {
                    engine: reborrow(memory),
                    windows: staging.windows,
                    background: staging.background,
                    gain: staging.gain,
                },
            );
            self.watchdog.feed();
            self.send(&DeviceMessage::BenchReport(report)).await?;
            self.flush_link().await?;
        }
        self.send(&DeviceMessage::Ack(Ack::BenchDone {
            workloads: saturate(plan.count),
        }))
        .await
    }
}
