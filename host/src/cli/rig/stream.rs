//! `brightpix rig stream`: recorded frames streamed to a rig's boards,
//! their results merged by frame number, reported and written.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;

use crate::io::{FrameSource, Raw, Results};
use crate::link::Client;
use crate::rig::{self, Rig, RigRun, RigStream};

use super::merged::MergedArgs;
use super::{open_clients, CheckArgs};

#[derive(Args)]
pub(super) struct StreamArgs {
    #[command(flatten)]
    rig: CheckArgs,
    /// Frames of the whole camera: .npy or FITS cube.
    #[arg(long, value_name = "PATH")]
    frames: PathBuf,
    /// FITS HDU of the frames: an index or EXTNAME.
    #[arg(long, value_name = "HDU")]
    hdu: Option<String>,
    /// Stream only the first N frames.
    #[arg(long, value_name = "N", value_parser = crate::cli::at_least_one)]
    count: Option<usize>,
    /// Check every merged frame against the whole-camera reference.
    #[arg(long)]
    verify: bool,
    #[command(flatten)]
    merged: MergedArgs,
    #[command(flatten)]
    live: crate::cli::view::ViewFlag,
}

pub(super) fn run(args: StreamArgs) -> Result<()> {
    let rig = Rig::load(&args.rig.rig)?;
    args.merged.check_out(&[&args.rig.rig, &args.frames])?;
    let mut source = FrameSource::open_hdu(&args.frames, args.hdu.as_deref())?;
    source.set_camera(&rig.whole.camera)?;
    let total = args.count.unwrap_or(usize::MAX).min(source.len());
    let live = args.live.start()?;
    let mut clients = open_clients(&rig, &args.rig.ports)?;
    args.merged.configure(&rig, &mut clients)?;
    let source_name = args.frames.display().to_string();
    // Read and streamed in batches: a cube of any length goes through.
    let read = |first: usize, count: usize| -> Result<Vec<Vec<u16>>> {
        let mut batch = vec![Vec::new(); count];
        for (k, frame) in batch.iter_mut().enumerate() {
            source.read_frame_into(first + k, frame)?;
        }
        Ok(batch)
    };
    if let Some(live) = &live {
        live.hub.set_setup(super::view::rig_view_setup(
            &rig,
            format!(
                "rig stream of {} to {} boards",
                args.frames.display(),
                rig.boards.len()
            ),
            args.rig.rig.display().to_string(),
        ));
    }
    let hub = live.as_ref().map(|l| l.hub.as_ref());
    let outcome = run_and_report(&rig, &mut clients, total, read, args.verify, 10, hub)?;
    args.merged.write(
        &rig,
        &outcome.results,
        "brightpix rig stream (merged from the boards)",
        source_name,
    )?;
    outcome.verdict(args.verify, total)
}

/// A run's merged results and totals.
pub(super) struct Outcome {
    pub results: Results,
    pub run: RigRun,
}

impl Outcome {
    /// Fails when a frame was partial, a board stopped, or (with
    /// `verify`) a frame differs from the reference.
    pub fn verdict(&self, verify: bool, total: usize) -> Result<()> {
        let stopped: Vec<String> = self
            .run
            .boards
            .iter()
            .enumerate()
            .filter_map(|(b, r)| r.error.as_ref().map(|e| format!("board {b} stopped: {e}")))
            .collect();
        if !stopped.is_empty() {
            bail!("{}", stopped.join("; "));
        }
        if self.run.frames_partial > 0 {
            bail!(
                "{} of {total} frames lack some board's results",
                self.run.frames_partial
            );
        }
        if let Some(v) = self.run.verifier.as_ref().filter(|_| verify) {
            if !v.all_match() || v.frames_verified != total as u64 {
                bail!("the merged results differ from the whole-camera reference");
            }
        }
        Ok(())
    }
}

/// Frames read and streamed at a time.
const BATCH: usize = 256;

/// Streams `total` frames, `read(first, count)` a batch at a time, merges
/// and prints a report: per board its rate and counts, and the merge's
/// totals (and the verification's).
pub(super) fn run_and_report(
    rig: &Rig,
    clients: &mut [Client],
    total: usize,
    mut read: impl FnMut(usize, usize) -> Result<Vec<Vec<u16>>>,
    verify: bool,
    show: usize,
    live: Option<&crate::view::Hub>,
) -> Result<Outcome> {
    let subapertures = rig.whole.windows.len();
    let mut results = Results::new(subapertures);
    let progress = crate::cli::progress::Progress::new(total as u64, "frames");
    let live_boards = std::cell::RefCell::new(super::view::LiveBoards::new(rig));
    let mut on_frame = |m: &rig::MergedFrame| {
        if let Some(hub) = live {
            live_boards.borrow_mut().count(m);
            hub.offer(
                u64::from(m.frame),
                !m.missing_boards.is_empty(),
                || m.results.clone(),
                None,
            );
        }
        for r in &m.results {
            results.push(r.map(Raw::from));
        }
        progress.inc(1);
    };
    let mut stream = RigStream::new(rig, verify);
    let mut first = 0;
    while first < total {
        let count = BATCH.min(total - first);
        let batch = read(first, count)?;
        if let Some(hub) = live.filter(|h| h.pixels_due()) {
            hub.offer_pixels(first as u64, batch[0].clone());
        }
        stream.run(clients, &batch, first as u32, &mut on_frame);
        if let Some(hub) = live {
            // Between batches, as `stream` checks its device's digest.
            hub.set_health(live_boards.borrow().health(rig, clients));
        }
        first += count;
    }
    let run = stream.finish(&mut on_frame);
    progress.finish();
    report(rig, &run, verify, show, rig.camera_rate_hz);
    Ok(Outcome { results, run })
}

/// Per board its counts and measured frame rate (and whether it keeps up
/// with a camera of `camera_rate` frames/s), the merge's totals and the
/// verification's.
pub(super) fn report(rig: &Rig, run: &RigRun, verify: bool, show: usize, camera_rate: Option<f64>) {
    for (board, r) in rig.boards.iter().zip(&run.boards) {
        println!(
            "  {}: {} sub-apertures, {} pixels a frame: {} frames done, {} dropped, {} missing{}{}",
            board.name,
            board.windows.len(),
            board.rectangle.pixels(),
            r.counts.frames_done,
            r.counts.frames_dropped,
            r.counts.frames_missing,
            if r.error.is_none() {
                format!(", {:.1} frames/s", r.frames_per_second())
            } else {
                String::new()
            },
            r.error
                .as_ref()
                .map_or(String::new(), |e| format!("; stopped: {e}"))
        );
        if let Some(rate) = camera_rate.filter(|&c| r.keeps_up_with(c) == Some(false)) {
            println!(
                "  warning: {} is slower than the camera: {:.1} frames/s measured against the camera's {rate:.1}; its {} sub-apertures are invalid in the {} frames it did not deliver",
                board.name,
                r.frames_per_second(),
                board.windows.len(),
                r.counts.frames_dropped + r.counts.frames_missing
            );
        }
    }
    println!(
        "  merged: {} frames by frame number, {} complete, {} with a board's results missing, in {:.3} s ({:.0} frames/s)",
        run.frames_complete + run.frames_partial,
        run.frames_complete,
        run.frames_partial,
        run.elapsed.as_secs_f64(),
        run.frames_complete as f64 / run.elapsed.as_secs_f64().max(1e-9)
    );
    if let Some(v) = run.verifier.as_ref().filter(|_| verify) {
        println!(
            "  verified: {} merged frames, {} sub-aperture results compared bit for bit with the whole-camera reference: {} mismatches, {} frames incomplete",
            v.frames_verified, v.slopes_compared, v.mismatch_count, v.frames_dropped
        );
        for m in v.mismatches.iter().take(show) {
            println!("    mismatch: {m}");
        }
    }
}
