//! `brightpix rig capture`: every board of a rig captures from its own
//! camera at once (one camera's bus fanned out to the boards, each board's
//! camera interface cropping the rectangle its configuration carries,
//! PROTOCOL.md §4), and their results are merged by frame number; with
//! `--verify`, every merged frame is checked bit for bit against the
//! whole-camera reference on the simulated camera's frames
//! (`simulate-device --camera sim:SEED` on every board).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use brightpix_protocol::wire::PixelSourceKind;
use clap::Args;

use super::rig::{open_clients, report, CheckArgs, Outcome};
use crate::io::{check_result_outputs, write_results, Layout, Provenance, Raw, Results};
use crate::link::Client;
use crate::rig::{self, MergedFrame, Rig, RigStream};
use crate::sim_device::CameraFrames;

#[derive(Args)]
pub struct CaptureArgs {
    #[command(flatten)]
    rig: CheckArgs,
    /// Frames to capture (each board numbers them from its own capture start: simulated cameras
    /// start together; real boards are not yet started on one camera frame, see the README).
    #[arg(long, value_name = "N", value_parser = super::at_least_one)]
    count: usize,
    /// Check every merged frame against the whole-camera reference on the simulated camera's
    /// frames (the boards run `simulate-device --camera sim:SEED`).
    #[arg(long)]
    verify: bool,
    /// Seed of the boards' simulated camera, for --verify.
    #[arg(long, default_value_t = 1, requires = "verify")]
    seed: u64,
    /// Write the merged slopes, flux, validity and provenance (.npy set, FITS or CSV; NaN where a
    /// board gave nothing).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Slopes layout of --out.
    #[arg(long, value_enum, default_value_t = Layout::Pairs, requires = "out")]
    layout: Layout,
    /// The boards already run their parts: check their digests instead of uploading.
    #[arg(long)]
    no_configure: bool,
    /// Mismatches to print with --verify.
    #[arg(long, default_value_t = 10)]
    show: usize,
}

pub fn run(args: CaptureArgs) -> Result<()> {
    let rig = Rig::load(&args.rig.rig)?;
    if let Some(out) = &args.out {
        check_result_outputs(&[&args.rig.rig], &[out])?;
    }
    let count = u32::try_from(args.count).context("--count: at most 4294967295 frames")?;
    let mut clients = open_clients(&rig, &args.rig.ports)?;
    refuse_boards_without_camera(&rig, &clients)?;
    if args.no_configure {
        rig::check_configurations(&rig, &mut clients)?;
    } else {
        rig::configure(&rig, &mut clients)?;
    }
    let outcome = capture_and_report(
        &rig,
        &mut clients,
        count,
        args.verify.then_some(args.seed),
        args.show,
    )?;
    if let Some(out) = &args.out {
        let mut provenance = Provenance::of(
            "brightpix rig capture (merged from the boards)",
            &rig.whole.view(),
            rig.config_file.as_deref(),
        );
        provenance.frames_source = Some("the boards' camera".into());
        provenance.rig = Some(rig.describe());
        write_results(out, &outcome.results, &provenance, args.layout)?;
        eprintln!(
            "brightpix: {} holds {} merged frames (NaN where a board gave nothing)",
            out.display(),
            outcome.results.frames()
        );
    }
    outcome.verdict(args.verify, args.count)
}

/// Before any work: a board whose pixels come from the host cannot capture.
pub(super) fn refuse_boards_without_camera(rig: &Rig, clients: &[Client]) -> Result<()> {
    for (board, client) in rig.boards.iter().zip(clients) {
        if client.info().pixel_source != PixelSourceKind::Camera {
            bail!(
                "board {:?} on {} has no camera of its own (its pixels come from the host): `brightpix rig stream` feeds such boards",
                board.name,
                client.port_name()
            );
        }
    }
    Ok(())
}

/// Captures `count` frames on every board at once, merges them and prints
/// the report; with `seed`, verifies against the simulated camera's
/// whole-sensor frames of that seed.
pub(super) fn capture_and_report(
    rig: &Rig,
    clients: &mut [Client],
    count: u32,
    seed: Option<u64>,
    show: usize,
) -> Result<Outcome> {
    let mut results = Results::new(rig.whole.windows.len());
    let progress = super::progress::Progress::new(u64::from(count), "frames");
    let mut on_frame = |m: &MergedFrame| {
        for r in &m.results {
            results.push(r.map(|e| Raw {
                slope_x: e.slope_x,
                slope_y: e.slope_y,
                flux: e.flux,
                valid: e.valid,
            }));
        }
        progress.inc(1);
    };
    // The camera every board sees: the whole sensor, remade frame by frame.
    let camera = seed.map(|s| CameraFrames::new(rig.whole.camera, s));
    let mut camera_frame =
        |k: u32| -> Option<Vec<u16>> { camera.as_ref()?.frames(u64::from(k), 1).pop() };
    let mut capture = RigStream::new(rig, seed.is_some());
    capture.capture(clients, count, &mut camera_frame, &mut on_frame);
    let run = capture.finish(&mut on_frame);
    progress.finish();
    // The camera's rate: the rig file's, else what the boards saw of it
    // (the camera frames that passed during the fastest board's capture).
    let camera_rate = rig.camera_rate_hz.or_else(|| {
        run.boards
            .iter()
            .filter_map(|b| {
                let frames = f64::from(b.last_frame? + 1);
                Some(frames / b.report.elapsed.as_secs_f64().max(1e-9))
            })
            .reduce(f64::max)
    });
    report(rig, &run, seed.is_some(), show, camera_rate);
    Ok(Outcome { results, run })
}
