//! `brightpix rig capture`: every board of a rig captures from its own
//! camera at once (one camera's bus fanned out to the boards, each board's
//! camera interface cropping the rectangle its configuration carries,
//! PROTOCOL.md §4), and their results are merged by frame number; with
//! `--verify`, every merged frame is checked bit for bit against the
//! whole-camera reference on the simulated camera's frames
//! (`simulate-device --camera sim:SEED` on every board).
//!
//! The boards start on one camera frame only with the rig's sync line
//! (`[sync]` in rig.toml, PROTOCOL.md §9): then the default; without one
//! the capture warns that frames may be misaligned, and with `--start
//! sync` it refuses to merge boards that began without the edge.

use anyhow::{bail, Context, Result};
use brightpix_protocol::wire::PixelSourceKind;
use clap::{Args, ValueEnum};

use super::merged::MergedArgs;
use super::stream::{report, Outcome};
use super::{open_clients, CheckArgs};
use crate::io::{Raw, Results};
use crate::link::Client;
use crate::rig::{MergedFrame, Rig, RigRun, RigStart, RigStream};
use crate::sim_device::CameraFrames;

#[derive(Args)]
pub struct CaptureArgs {
    #[command(flatten)]
    rig: CheckArgs,
    /// Frames to capture (each board numbers them from its own capture start: one camera frame on
    /// every board only with the sync line, see --start).
    #[arg(long, value_name = "N", value_parser = crate::cli::at_least_one)]
    count: usize,
    /// How the boards start: sync (followers armed on the rig's sync line, then the leader raises
    /// it after a frame start: all begin on the same camera frame; needs [sync] in rig.toml),
    /// immediate (each board on the frame after its own request: boards may begin frames apart),
    /// or auto: sync when the rig declares a sync line, else immediate with a warning.
    #[arg(long, value_enum, default_value_t = StartArg::Auto)]
    start: StartArg,
    /// Check every merged frame against the whole-camera reference on the simulated camera's
    /// frames (the boards run `simulate-device --camera sim:SEED`).
    #[arg(long)]
    verify: bool,
    /// Seed of the boards' simulated camera, for --verify.
    #[arg(long, default_value_t = 1, requires = "verify")]
    seed: u64,
    #[command(flatten)]
    merged: MergedArgs,
    /// Mismatches to print with --verify.
    #[arg(long, default_value_t = 10)]
    show: usize,
}

/// `--start`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum StartArg {
    Auto,
    Sync,
    Immediate,
}

/// The start `--start` asks for on `rig`.
pub(super) fn rig_start(rig: &Rig, start: StartArg) -> Result<RigStart> {
    match (start, rig.sync) {
        (StartArg::Sync | StartArg::Auto, Some(sync)) => Ok(RigStart::Sync {
            leader: sync.leader,
        }),
        (StartArg::Sync, None) => bail!(
            "--start sync: the rig declares no sync line; wire one GPIO to every board (STM32H743: PF13) and add [sync] leader = \"NAME\" to rig.toml (docs/CONFIG.md)"
        ),
        (StartArg::Auto, None) | (StartArg::Immediate, _) => {
            eprintln!(
                "brightpix: warning: the boards start without a sync line: each begins on the camera frame after its own Capture request, so boards may begin frames apart and a merged frame may combine different camera frames (README, \"Which frame is which\"; [sync] in rig.toml)"
            );
            Ok(RigStart::Immediate)
        }
    }
}

pub fn run(args: CaptureArgs) -> Result<()> {
    let rig = Rig::load(&args.rig.rig)?;
    let start = rig_start(&rig, args.start)?;
    args.merged.check_out(&[&args.rig.rig])?;
    let count = u32::try_from(args.count).context("--count: at most 4294967295 frames")?;
    let mut clients = open_clients(&rig, &args.rig.ports)?;
    refuse_boards_without_camera(&rig, &clients)?;
    args.merged.configure(&rig, &mut clients)?;
    let outcome = capture_and_report(
        &rig,
        &mut clients,
        count,
        start,
        args.verify.then_some(args.seed),
        args.show,
    )?;
    check_alignment(&rig, &outcome.run)?;
    args.merged.write(
        &rig,
        &outcome.results,
        "brightpix rig capture (merged from the boards)",
        "the boards' camera".into(),
    )?;
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
    start: RigStart,
    seed: Option<u64>,
    show: usize,
) -> Result<Outcome> {
    let mut results = Results::new(rig.whole.windows.len());
    let progress = crate::cli::progress::Progress::new(u64::from(count), "frames");
    let mut on_frame = |m: &MergedFrame| {
        for r in &m.results {
            results.push(r.map(Raw::from));
        }
        progress.inc(1);
    };
    // The camera every board sees: the whole sensor, remade frame by frame.
    let camera = seed.map(|s| CameraFrames::new(rig.whole.camera, s));
    let mut camera_frame =
        |k: u32| -> Option<Vec<u16>> { camera.as_ref()?.frames(u64::from(k), 1).pop() };
    let mut capture = RigStream::new(rig, seed.is_some());
    capture.capture(clients, count, start, &mut camera_frame, &mut on_frame);
    let run = capture.finish(&mut on_frame);
    print_starts(rig, &run);
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

/// Each board's first camera frame, as far as it knows it.
fn print_starts(rig: &Rig, run: &RigRun) {
    for (board, r) in rig.boards.iter().zip(&run.boards) {
        let Some(began) = r.began else { continue };
        println!(
            "  {} began on {}{}",
            board.name,
            began
                .camera_frame
                .map_or("a camera frame it cannot number".into(), |f| format!(
                    "camera frame {f}"
                )),
            if began.synced {
                " (the first after the sync edge)"
            } else {
                ""
            }
        );
    }
}

/// Refuses a sync capture in which a board began without the edge or
/// boards began on different camera frames; warns of the latter without
/// the sync line. Refuses any capture in which boards sharing a camera row
/// disagree on it (`rig plan --shared-rows`).
pub(super) fn check_alignment(rig: &Rig, run: &RigRun) -> Result<()> {
    let edges = &run.edge_check;
    if !edges.pairs.is_empty() {
        let names: Vec<String> = edges
            .pairs
            .iter()
            .map(|&(a, b)| format!("{}/{}", rig.boards[a].name, rig.boards[b].name))
            .collect();
        println!(
            "  shared rows ({}): {} merged frames checked, {} with boards on different camera frames",
            names.join(", "),
            edges.frames_checked,
            edges.frames_disagreeing
        );
        if edges.frames_disagreeing > 0 {
            bail!(
                "boards sharing a camera row saw different pixels there in {} merged frames (first: {:?}): they are not on the same camera frame; nothing was written",
                edges.frames_disagreeing,
                edges.first_disagreeing
            );
        }
    }
    let sync = matches!(run.start, Some(RigStart::Sync { .. }));
    if sync {
        for (board, r) in rig.boards.iter().zip(&run.boards) {
            if r.began.is_some_and(|b| !b.synced) {
                bail!(
                    "board {:?} says it began without the sync edge: its frames are not aligned with the other boards'; nothing was merged from this capture (check the sync wiring and its firmware)",
                    board.name
                );
            }
        }
    }
    let known: Vec<(&str, u32)> = rig
        .boards
        .iter()
        .zip(&run.boards)
        .filter_map(|(board, r)| Some((board.name.as_str(), r.began?.camera_frame?)))
        .collect();
    if known.windows(2).any(|w| w[0].1 != w[1].1) {
        let list: Vec<String> = known
            .iter()
            .map(|(name, f)| format!("{name} on {f}"))
            .collect();
        let what = format!(
            "the boards began on different camera frames ({}): merged frame k combines different camera frames",
            list.join(", ")
        );
        if sync {
            bail!("{what}, although they started on the sync line");
        }
        eprintln!("brightpix: warning: {what} (no sync line)");
    }
    Ok(())
}
