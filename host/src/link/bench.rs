//! The bench request (PROTOCOL.md §14): the board measures the engine on
//! its own workloads and sends one report per workload, then
//! `Ack(BenchDone)`.

use std::time::Duration;

use brightpix_protocol::wire::{Ack, BenchReport, BenchResult, CountUnit, HostMessage};

use super::errors::unexpected;
use super::requests::Reply;
use super::{Client, LinkError};

/// One workload's report, owned.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BenchRow {
    pub workload: String,
    pub unit: CountUnit,
    /// The core clock of the cycles, Hz.
    pub clock_hz: Option<u32>,
    /// Camera pixels per frame.
    pub pixels: u32,
    /// Frames measured.
    pub frames: u32,
    pub result: BenchResult,
}

impl BenchRow {
    pub fn of(report: &BenchReport<'_>) -> BenchRow {
        BenchRow {
            workload: report.workload.to_string(),
            unit: report.unit,
            clock_hz: report.clock_hz,
            pixels: report.pixels,
            frames: report.frames,
            result: report.result,
        }
    }
}

impl Client {
    /// `Bench { workload, frames }` (PROTOCOL.md §14; `workload` at most
    /// `MAX_WORKLOAD_NAME_LEN` bytes): the board's reports, one per workload
    /// (`workload`: a name or `"all"`; `frames` 0: each workload's own), in
    /// order, each also handed to `each` as it arrives. The device measures
    /// in silence: `per_workload` is the longest wait for the next report.
    pub fn bench(
        &mut self,
        workload: &str,
        frames: u32,
        per_workload: Duration,
        mut each: impl FnMut(&BenchRow),
    ) -> Result<Vec<BenchRow>, LinkError> {
        // (A name longer than MAX_WORKLOAD_NAME_LEN matches no workload:
        // the device answers UnknownWorkload itself.)
        self.move_replies_to_notices();
        self.close_pixel_fifo();
        let frame = self
            .encode(&HostMessage::Bench { workload, frames })?
            .to_vec();
        self.write_raw(&frame, "Bench")?;
        let mut rows = Vec::new();
        loop {
            let waiting = format!(
                "the bench's report {} (each workload measures in silence)",
                rows.len() + 1
            );
            let reply = self.wait_within(&waiting, per_workload, |c| c.replies.pop_front())?;
            match reply {
                Reply::Bench(row) => {
                    each(&row);
                    rows.push(row);
                }
                Reply::Ack(Ack::BenchDone { .. }) => return Ok(rows),
                // A late answer to an earlier Hello (QEMU's pty, PROTOCOL.md §10).
                Reply::Hello(_) => {}
                Reply::Error(error) => {
                    return Err(LinkError::Device {
                        request: "Bench".into(),
                        error,
                    })
                }
                other => return Err(unexpected("Bench", &other)),
            }
        }
    }
}
