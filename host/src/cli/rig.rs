//! `brightpix rig`: several boards on one camera. `plan` splits a
//! whole-camera configuration into board parts and writes `rig.toml`;
//! `check` loads one and prints it; `configure` uploads each board's part;
//! `stream` runs the boards together on recorded frames and merges their
//! results into one whole-camera output; `capture` (`rig_capture.rs`) does
//! so with each board's own camera. `brightpix demo --boards K`
//! (`rig_demo.rs`) is `stream` on simulated devices.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};

use crate::config_file::ProcessingConfig;
use crate::io::{
    check_result_outputs, write_results, FrameSource, Layout, Provenance, Raw, Results,
};
use crate::link::Client;
use crate::rig::{
    self, describe_load, BoardKind, CostModel, Rig, RigRun, RigStream, DCMI_MAX_PIXEL_CLOCK_HZ,
};

#[derive(Args)]
#[command(
    about = "Several boards on one camera: plan the split, configure the boards, stream and merge their results",
    after_help = "Examples:\n  \
brightpix rig plan --config examples/canary.toml --boards 3 --camera-rate 1000 --out rig.toml\n  \
brightpix rig check --rig rig.toml --board-configs boards/   # also boards/board-K.toml, one board's part each\n  \
brightpix configure --port /dev/ttyACM0 --config boards/board-0.toml   # one board alone\n  \
brightpix rig configure --rig rig.toml\n  \
brightpix rig stream --rig rig.toml --frames frames.npy --verify --out slopes.npy\n  \
brightpix rig capture --rig rig.toml --count 1000 --out slopes.npy   # each board's own camera\n  \
brightpix demo --boards 3            # three simulated devices on one simulated camera\n\n\
Each board captures a rectangle of the sensor and runs an ordinary configuration whose camera is\n\
that rectangle; results are merged by frame number into the whole camera's sub-aperture order.\n\
`rig stream` numbers the frames it sends, so they agree on every board. `rig capture` starts the\n\
boards on one camera frame only with a sync line wired to every board ([sync] leader = \"NAME\" in\n\
rig.toml; STM32H743: PF13): followers are armed first, then the leader raises the line after a\n\
frame start. Without one it warns: boards may begin frames apart. With `rig plan --shared-rows`\n\
neighbouring bands share a camera row, and `rig capture` refuses a capture in which their\n\
checksums of it disagree (a check without wiring)."
)]
pub struct RigArgs {
    #[command(subcommand)]
    command: RigCommand,
}

#[derive(Subcommand)]
enum RigCommand {
    /// Split a whole-camera configuration over K boards and write rig.toml.
    Plan(PlanArgs),
    /// Load a rig file, check it and print each board's part and predicted load.
    Check(CheckCommandArgs),
    /// Upload each board's part of the rig and check that every board runs it.
    Configure(CheckArgs),
    /// Stream recorded frames to the rig's boards and merge their results.
    Stream(StreamArgs),
    /// Capture with every board's own camera (one camera's bus fanned out, each board cropping
    /// its rectangle) and merge their results by frame number; on the rig's sync line if it has
    /// one.
    Capture(super::rig_capture::CaptureArgs),
}

#[derive(Args)]
struct PlanArgs {
    /// The whole camera's configuration (TOML, docs/CONFIG.md).
    #[arg(long, value_name = "C.toml")]
    config: PathBuf,
    /// Boards to split over.
    #[arg(long, value_parser = super::at_least_one)]
    boards: usize,
    /// The boards: stm32h743 (480 MHz Cortex-M7, DCMI crop), qemu-m4 or qemu-m7.
    #[arg(long, default_value = "stm32h743", value_parser = BoardKind::parse)]
    board: BoardKind,
    /// The camera's frame rate, Hz: each board's load, and the fewest boards whose cores and
    /// links (stm32h743: USB full speed, about 1 MB/s of results) keep up.
    #[arg(long, value_name = "HZ")]
    camera_rate: Option<f64>,
    /// Instructions per pixel measured for this configuration on whole rows (`brightpix bench
    /// --config`) instead of the model fitted to the bench's tables; the board's camera interface
    /// is added (stm32h743: what its camera path adds, from the bench's
    /// `canary-12bit-dcmi` row).
    #[arg(long, value_name = "X")]
    instr_per_px: Option<f64>,
    /// The boards' results link, MB/s, as measured (`brightpix bench --port PORT --link`) instead
    /// of the board's own (stm32h743: USB full speed, about 1 MB/s); kept in the rig file
    /// (`link_mb_per_s`), so `rig check` counts it too.
    #[arg(long, value_name = "MB/S")]
    link_rate: Option<f64>,
    /// Write the rig here (rig.toml); without it the file is printed.
    #[arg(long, value_name = "rig.toml")]
    out: Option<PathBuf>,
    /// Also write each board's own configuration, DIR/<board name>.toml (its rectangle as
    /// [camera.crop]), which `brightpix configure --config` takes for that board alone.
    #[arg(long, value_name = "DIR")]
    board_configs: Option<PathBuf>,
    /// Reach each band of rows one row into the band below, so neighbours share a camera row:
    /// `rig capture` then compares a checksum of it from both boards every frame, an alignment
    /// self-check that needs no wiring (each board captures one more row; loads as planned).
    #[arg(long)]
    shared_rows: bool,
}

#[derive(Args)]
struct CheckCommandArgs {
    #[command(flatten)]
    rig: CheckArgs,
    /// Also write each board's own configuration, DIR/<board name>.toml (its rectangle as
    /// [camera.crop]), which `brightpix configure --config` takes for that board alone.
    #[arg(long, value_name = "DIR")]
    board_configs: Option<PathBuf>,
}

#[derive(Args)]
pub(super) struct CheckArgs {
    /// The rig file (brightpix rig plan writes one).
    #[arg(long, value_name = "rig.toml")]
    pub(super) rig: PathBuf,
    /// Ports of the boards, in the file's board order, instead of the file's `port`s.
    #[arg(long, value_name = "P1,P2,..", value_delimiter = ',')]
    pub(super) ports: Vec<String>,
}

#[derive(Args)]
struct StreamArgs {
    #[command(flatten)]
    rig: CheckArgs,
    /// Frames of the whole camera: .npy or FITS cube.
    #[arg(long, value_name = "PATH")]
    frames: PathBuf,
    /// FITS HDU of the frames: an index or EXTNAME.
    #[arg(long, value_name = "HDU")]
    hdu: Option<String>,
    /// Stream only the first N frames.
    #[arg(long, value_name = "N", value_parser = super::at_least_one)]
    count: Option<usize>,
    /// Check every merged frame against the whole-camera reference.
    #[arg(long)]
    verify: bool,
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
    #[command(flatten)]
    live: super::view::ViewFlag,
}

pub fn run(args: RigArgs) -> Result<()> {
    match args.command {
        RigCommand::Plan(a) => plan(a),
        RigCommand::Check(a) => {
            let rig = Rig::load(&a.rig.rig)?;
            print_rig(&rig, &rig.cost_model(), None);
            if let Some(dir) = &a.board_configs {
                write_board_configs(&rig, dir, &[&a.rig.rig])?;
            }
            Ok(())
        }
        RigCommand::Configure(a) => {
            let rig = Rig::load(&a.rig)?;
            let mut clients = open_clients(&rig, &a.ports)?;
            rig::configure(&rig, &mut clients)?;
            for (b, c) in rig.boards.iter().zip(&clients) {
                println!(
                    "{}: configured on {} ({} sub-apertures)",
                    b.name,
                    c.port_name(),
                    b.windows.len()
                );
            }
            Ok(())
        }
        RigCommand::Stream(a) => stream(a),
        RigCommand::Capture(a) => super::rig_capture::run(a),
    }
}

fn model_for(
    kind: BoardKind,
    instr_per_px: Option<f64>,
    link_rate: Option<f64>,
) -> Result<CostModel> {
    let model = kind.cost_model();
    let model = match instr_per_px {
        Some(x) if x.is_finite() && x > 0.0 => CostModel::flat(x, &model),
        Some(x) => bail!("--instr-per-px {x}: must be a positive number"),
        None => model,
    };
    match link_rate {
        Some(r) => model
            .with_link_rate(r)
            .map_err(|e| anyhow::anyhow!("--link-rate {r}: {e}")),
        None => Ok(model),
    }
}

fn plan(args: PlanArgs) -> Result<()> {
    if let Some(rate) = args.camera_rate.filter(|r| !(r.is_finite() && *r > 0.0)) {
        bail!("--camera-rate {rate}: must be a positive number of frames per second");
    }
    if let Some(out) = &args.out {
        if out.extension().and_then(|e| e.to_str()) != Some("toml") {
            bail!(
                "--out {}: a rig file is TOML: name it *.toml",
                out.display()
            );
        }
        let same = |a: &Path, b: &Path| {
            std::fs::canonicalize(a)
                .ok()
                .zip(std::fs::canonicalize(b).ok())
                .is_some_and(|(a, b)| a == b)
        };
        if same(out, &args.config) {
            bail!(
                "--out {} is the configuration itself: write the rig to another file",
                out.display()
            );
        }
    }
    let whole = ProcessingConfig::load(&args.config)?;
    let model = model_for(args.board, args.instr_per_px, args.link_rate)?;
    let (plan, mut loads) =
        rig::plan_keeping_up(&whole, args.boards, args.board, &model, args.camera_rate)?;
    let mut rig = Rig::from_plan(whole, args.board, args.camera_rate, &plan)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    // Checked by `model_for`; kept in the rig file.
    rig.link_mb_per_s = args.link_rate;
    if args.shared_rows {
        if plan.cut != rig::Cut::Rows || rig.boards.len() < 2 {
            bail!("--shared-rows: the plan has no two bands of rows to overlap (it cut column strips, or one board)");
        }
        rig = rig
            .with_shared_rows()
            .map_err(|e| anyhow::anyhow!("--shared-rows: {e}"))?;
        // Each band is a row taller now: its loads again.
        loads = rig::loads(
            &rig.whole,
            &rig.shares(),
            args.board,
            &model,
            args.camera_rate,
            true,
        );
        if !loads.iter().all(rig::BoardLoad::keeps_up) {
            bail!(
                "--shared-rows: with the shared rows {}: plan more boards (--boards {})",
                rig::busiest(&loads, args.board, &model),
                rig.boards.len() + 1
            );
        }
    }
    println!(
        "rig plan: {} sub-apertures of {} over {} {} boards, cut in {}",
        rig.whole.windows.len(),
        args.config.display(),
        rig.boards.len(),
        args.board.name(),
        match plan.cut {
            rig::Cut::Rows => "row bands",
            rig::Cut::Columns => "column strips",
        }
    );
    print_rig(&rig, &model, Some(&loads));
    let config_name = match &args.out {
        Some(out) => relative_to(&args.config, out.parent().unwrap_or(Path::new(""))),
        None => args.config.clone(),
    };
    let text = rig.to_toml(&config_name, Some(&loads));
    match &args.out {
        Some(out) => {
            // Whole or not at all: a temporary file beside it, renamed.
            let staged = out.with_extension("toml.partial");
            std::fs::write(&staged, text)
                .and_then(|()| std::fs::rename(&staged, out))
                .with_context(|| format!("writing {}", out.display()))?;
            println!("wrote {}", out.display());
        }
        None => print!("\n{text}"),
    }
    if let Some(dir) = &args.board_configs {
        let mut keep: Vec<&Path> = vec![&args.config];
        if let Some(out) = &args.out {
            keep.push(out);
        }
        write_board_configs(&rig, dir, &keep)?;
    }
    Ok(())
}

/// Writes each board's configuration as `dir/<board name>.toml` (and the
/// sibling `.npy` files it may need): an ordinary configuration file whose
/// camera is the board's rectangle, placed on the sensor by `[camera.crop]`
/// (docs/CONFIG.md). Refuses to overwrite any of `keep` (the whole
/// configuration, the rig file).
fn write_board_configs(rig: &Rig, dir: &Path, keep: &[&Path]) -> Result<()> {
    let canonical = |p: &Path| std::fs::canonicalize(p).ok();
    for b in &rig.boards {
        let target = dir.join(format!("{}.toml", b.name));
        if let Some(t) = canonical(&target) {
            if keep.iter().any(|k| canonical(k).as_ref() == Some(&t)) {
                bail!(
                    "--board-configs {}: board {:?}'s configuration would overwrite {}: choose another directory",
                    dir.display(),
                    b.name,
                    target.display()
                );
            }
        }
        let path = b
            .config
            .save(dir, &b.name)
            .with_context(|| format!("board {:?}'s configuration", b.name))?;
        println!(
            "wrote {} (board {:?}: {} sub-apertures, rectangle {})",
            path.display(),
            b.name,
            b.windows.len(),
            b.rectangle.describe()
        );
    }
    Ok(())
}

/// `path` as the rig file in `dir` should name it: its file name when both
/// are in one directory, else absolute.
fn relative_to(path: &Path, dir: &Path) -> PathBuf {
    let canonical = |p: &Path| {
        std::fs::canonicalize(if p.as_os_str().is_empty() {
            Path::new(".")
        } else {
            p
        })
        .ok()
    };
    match (canonical(path), canonical(dir)) {
        (Some(p), Some(d)) if p.parent() == Some(d.as_path()) => {
            PathBuf::from(p.file_name().unwrap_or_default())
        }
        (Some(p), _) => p,
        _ => path.to_path_buf(),
    }
}

/// The boards, their parts and predicted loads, and the limits of a board
/// that sees only its rectangle.
/// How `rig capture` will start the boards on one camera frame, and check it.
fn describe_alignment(rig: &Rig) -> String {
    let start = match rig.sync {
        Some(sync) => format!(
            "sync line led by {} (rig capture starts every board on one camera frame)",
            rig.boards[sync.leader].name
        ),
        None => "no sync line ([sync] in rig.toml): rig capture warns that boards may begin frames apart".into(),
    };
    let pairs = rig.shared_rows();
    if pairs.is_empty() {
        return format!("alignment: {start}");
    }
    let names: Vec<String> = pairs
        .iter()
        .map(|&(a, b)| format!("{}/{}", rig.boards[a].name, rig.boards[b].name))
        .collect();
    format!(
        "alignment: {start}; shared rows checked every frame: {}",
        names.join(", ")
    )
}

/// `model`: what the loads were computed with (`rig.cost_model()` unless
/// the plan was given another).
pub(super) fn print_rig(rig: &Rig, model: &CostModel, loads: Option<&[rig::BoardLoad]>) {
    let computed;
    let loads = match loads {
        Some(l) => l,
        None => {
            computed = rig::loads(
                &rig.whole,
                &rig.shares(),
                rig.kind,
                model,
                rig.camera_rate_hz,
                !rig.shared_rows().is_empty(),
            );
            &computed
        }
    };
    for (b, load) in rig.boards.iter().zip(loads) {
        println!(
            "  {}{}: {}",
            b.name,
            b.port.as_ref().map_or(String::new(), |p| format!(" ({p})")),
            describe_load(load, b)
        );
    }
    println!("  {}", describe_alignment(rig));
    if let Some(rate) = rig.camera_rate_hz {
        let pixel_rate = rig.whole.camera.pixel_count() as f64 * rate;
        let link = model.link.map_or(String::new(), |l| {
            format!(
                "; results on its {} link: about {:.2} MB/s a board",
                l.name,
                l.bytes_per_s / 1e6
            )
        });
        println!(
            "  limits: every board on the fanned-out bus sees the camera's whole pixel clock, >= {:.1} MHz at {rate} Hz (the STM32H743's DCMI: {:.0} MHz at most){link}",
            pixel_rate / 1e6,
            DCMI_MAX_PIXEL_CLOCK_HZ / 1e6,
        );
        if pixel_rate > DCMI_MAX_PIXEL_CLOCK_HZ {
            println!("  warning: the camera's pixel clock exceeds what a DCMI can sample: split the camera's taps over boards");
        }
        if loads.iter().any(|l| l.link_load.is_some_and(|x| x > 1.0)) {
            println!(
                "  warning: {}: plan more boards or a lower rate",
                rig::busiest(loads, rig.kind, model)
            );
        }
    }
}

/// One client per board: `--ports` in board order, else the file's ports.
pub(super) fn open_clients(rig: &Rig, ports: &[String]) -> Result<Vec<Client>> {
    if !ports.is_empty() && ports.len() != rig.boards.len() {
        bail!(
            "--ports gives {} ports for {} boards",
            ports.len(),
            rig.boards.len()
        );
    }
    rig.boards
        .iter()
        .enumerate()
        .map(|(k, b)| {
            let port = ports.get(k).or(b.port.as_ref()).with_context(|| {
                format!(
                    "board {:?} has no port: add port = \"...\" to the rig file or give --ports",
                    b.name
                )
            })?;
            Client::open(port).with_context(|| format!("board {:?} on {port}", b.name))
        })
        .collect()
}

fn stream(args: StreamArgs) -> Result<()> {
    let rig = Rig::load(&args.rig.rig)?;
    if let Some(out) = &args.out {
        check_result_outputs(&[&args.rig.rig, &args.frames], &[out])?;
    }
    let mut source = FrameSource::open_hdu(&args.frames, args.hdu.as_deref())?;
    source.set_camera(&rig.whole.camera)?;
    let total = args.count.unwrap_or(usize::MAX).min(source.len());
    let live = args.live.start()?;
    let mut clients = open_clients(&rig, &args.rig.ports)?;
    if args.no_configure {
        rig::check_configurations(&rig, &mut clients)?;
    } else {
        rig::configure(&rig, &mut clients)?;
    }
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
        live.hub.set_setup(rig_view_setup(
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
    if let Some(out) = &args.out {
        let mut provenance = Provenance::of(
            "brightpix rig stream (merged from the boards)",
            &rig.whole.view(),
            rig.config_file.as_deref(),
        );
        provenance.frames_source = Some(source_name);
        provenance.rig = Some(rig.describe());
        write_results(out, &outcome.results, &provenance, args.layout)?;
        eprintln!(
            "brightpix: {} holds {} merged frames (NaN where a board gave nothing)",
            out.display(),
            outcome.results.frames()
        );
    }
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
    let progress = super::progress::Progress::new(total as u64, "frames");
    let live_boards = std::cell::RefCell::new(LiveBoards::new(rig));
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
            results.push(r.map(|e| Raw {
                slope_x: e.slope_x,
                slope_y: e.slope_y,
                flux: e.flux,
                valid: e.valid,
            }));
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

/// `view --rig`: the rig's boards fed `frames` over and over (as `rig
/// stream` feeds them, batch by batch), their merged results into the
/// view, until `stop()`.
pub(super) fn view_rig(
    rig_path: &Path,
    ports: &[String],
    frames: &Path,
    hdu: Option<&str>,
    hub: &crate::view::Hub,
    stop: &dyn Fn() -> bool,
) -> Result<()> {
    let rig = Rig::load(rig_path)?;
    let mut source = FrameSource::open_hdu(frames, hdu)?;
    source.set_camera(&rig.whole.camera)?;
    let total = source.len();
    if total == 0 {
        bail!("{} holds no frames", frames.display());
    }
    let mut clients = open_clients(&rig, ports)?;
    rig::configure(&rig, &mut clients)?;
    hub.set_setup(rig_view_setup(
        &rig,
        format!(
            "rig of {} boards, frames of {} over and over",
            rig.boards.len(),
            frames.display()
        ),
        rig_path.display().to_string(),
    ));
    let live = std::cell::RefCell::new(LiveBoards::new(&rig));
    let mut stream = RigStream::new(&rig, false);
    let mut on_frame = |m: &rig::MergedFrame| {
        live.borrow_mut().count(m);
        hub.offer(
            u64::from(m.frame),
            !m.missing_boards.is_empty(),
            || m.results.clone(),
            None,
        );
    };
    // Short batches: the view's health is read between two.
    const VIEW_BATCH: usize = 16;
    let mut next = 0u64;
    while !stop() {
        let first = (next % total as u64) as usize;
        let count = VIEW_BATCH.min(total - first);
        let mut batch = vec![Vec::new(); count];
        for (k, frame) in batch.iter_mut().enumerate() {
            source.read_frame_into(first + k, frame)?;
        }
        if hub.pixels_due() {
            hub.offer_pixels(next, batch[0].clone());
        }
        stream.run(&mut clients, &batch, next as u32, &mut on_frame);
        let health = live.borrow().health(&rig, &mut clients);
        let failed: Vec<String> = health
            .boards
            .iter()
            .filter_map(|b| b.error.as_ref().map(|e| format!("{}: {e}", b.name)))
            .collect();
        hub.set_message(
            (!failed.is_empty()).then(|| format!("boards not answering: {}", failed.join("; "))),
        );
        hub.set_health(health);
        next += count as u64;
    }
    stream.finish(&mut on_frame);
    Ok(())
}

/// Per board, for the view: frames merged with and without its results,
/// and its predicted load.
struct LiveBoards {
    done: Vec<u64>,
    dropped: Vec<u64>,
    loads: Vec<Option<f64>>,
}

impl LiveBoards {
    fn new(rig: &Rig) -> LiveBoards {
        let model = rig.cost_model();
        let loads = rig::loads(
            &rig.whole,
            &rig.shares(),
            rig.kind,
            &model,
            rig.camera_rate_hz,
            !rig.shared_rows().is_empty(),
        );
        LiveBoards {
            done: vec![0; rig.boards.len()],
            dropped: vec![0; rig.boards.len()],
            loads: loads.iter().map(|l| l.load).collect(),
        }
    }

    fn count(&mut self, m: &rig::MergedFrame) {
        for b in 0..self.done.len() {
            if m.missing_boards.contains(&b) {
                self.dropped[b] += 1;
            } else {
                self.done[b] += 1;
            }
        }
    }

    /// The boards' counters summed, and each board's line.
    fn health(&self, rig: &Rig, clients: &mut [Client]) -> crate::view::Health {
        let mut health = crate::view::Health::default();
        for (b, (board, client)) in rig.boards.iter().zip(clients.iter_mut()).enumerate() {
            let status = client.status();
            if let Ok(s) = &status {
                let add = |to: &mut Option<u64>, v: u64| *to = Some(to.unwrap_or(0) + v);
                add(&mut health.frames_processed, s.frames_processed);
                add(&mut health.frames_dropped, s.frames_dropped);
                let add32 =
                    |to: &mut Option<u32>, v: u32| *to = Some(to.unwrap_or(0).saturating_add(v));
                add32(&mut health.crc_errors, s.crc_errors);
                add32(&mut health.decode_errors, s.decode_errors);
                add32(&mut health.overruns, s.overruns);
                add32(&mut health.pixel_errors, s.pixel_errors);
            }
            health.boards.push(crate::view::BoardHealth {
                name: board.name.clone(),
                load: self.loads.get(b).copied().flatten(),
                frames_done: self.done[b],
                frames_dropped: self.dropped[b],
                error: status.err().map(|e| e.to_string()),
            });
        }
        // The whole camera's digest: each board runs its own part.
        health.config_digest = Some(brightpix_protocol::wire::tables::config_digest(
            &rig.whole.view(),
        ));
        health
    }
}

/// The live view's set-up for a rig: the whole camera, pixels shown, each
/// board's name and sub-apertures.
fn rig_view_setup(rig: &Rig, title: String, source: String) -> crate::view::Setup {
    let mut setup = crate::view::Setup::new(title, source, rig.whole.clone());
    setup.pixels = true;
    setup.boards = rig
        .boards
        .iter()
        .map(|b| (b.name.clone(), b.windows.clone()))
        .collect();
    setup
}
