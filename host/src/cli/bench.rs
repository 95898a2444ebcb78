//! `brightpix bench`: every speed figure in one command. The QEMU bench on
//! Cortex-M4 and Cortex-M7 (instructions per pixel, against the honest floor,
//! and the work after the last row) and the host bench (the engine on all
//! cores and on one, against a per-window sort and the best peer); with
//! `--config`, the same for the user's configuration and what it means for
//! their camera and board.

use anyhow::{bail, Context, Result};
use clap::Args;
use std::ffi::OsString;
use std::path::{Path, PathBuf};

use crate::bench::host::{host_table, peer_table};
use crate::bench::qemu::{self, QemuCore, QemuRow};
use crate::bench::workloads::{self, Workload};
use crate::bench::{run_host, HostOptions, HostRow};
use crate::config_file::ProcessingConfig;
use crate::rig::{self, CostModel};

#[derive(Args)]
#[command(
    about = "Measure every speed figure: the engine in QEMU (Cortex-M4, M7) and on this host, against its floor and peers",
    after_help = "Examples:\n  \
brightpix bench                                   # QEMU (M4, M7) and host tables, built-in workloads\n  \
brightpix bench --json figures.json               # the same, and the figures as JSON\n  \
brightpix bench --host-only --quick               # host table only, a short run\n  \
brightpix bench --config my.toml --camera-rate 1000\n                                                    # my configuration on simulated spots: does a 1 kHz camera fit one board?\n  \
brightpix bench --config my.toml --frames run.fits --mhz 400 --camera-size 240x240 --camera-rate 1500\n  \
brightpix bench --port /dev/ttyACM0                # a board's own bench mode: DWT cycles per pixel on the board\n  \
brightpix bench --port /dev/pts/5 --workload canary-subtract-next-n20 --frames 16 --json board.json\n\n\
QEMU counts instructions exactly (-icount); a board's pixel rate assumes one instruction per cycle at --mhz\n\
(Cortex-M7 dual issue can do better, flash and memory wait states worse). Host figures are median [min-max]\n\
over interleaved rounds of runs of at least --min-run-ms; only ratios measured in the same run mean much\n\
on a busy machine. Ratios are taken round by round.\n\
--port asks a device's bench mode (PROTOCOL.md §14): the board measures the engine and the honest floor on its\n\
own generated workloads (the QEMU bench's) and reports counts per frame and after the last row: DWT cycles on\n\
the STM32H743 (and Mpx/s at its clock), instructions on the QEMU board under -icount, 'uncounted' without it.\n\
The QEMU part needs qemu-system-arm and the thumbv7em-none-eabihf target (scripts/setup installs both);\n\
without them the host table is still printed."
)]
pub struct BenchArgs {
    /// Also write the figures as JSON: a list of objects, QEMU rows {workload, core, instr_per_px,
    /// floor_instr_per_px, last_row_instructions, ...} and host rows {workload, mpx_per_s, x_sort, ...}.
    #[arg(long, value_name = "PATH")]
    json: Option<PathBuf>,
    /// Measure this configuration (TOML, see docs/CONFIG.md) instead of the built-in workloads.
    #[arg(long, value_name = "C.toml")]
    config: Option<PathBuf>,
    /// With --config: frames to measure on (.npy or FITS cube); default: simulated spots.
    /// With --port: frames measured per workload (default: each workload's own; the board takes at most 64).
    #[arg(long, value_name = "PATH|K")]
    frames: Option<PathBuf>,
    /// Ask the device on this serial port to measure with its own bench mode (PROTOCOL.md §14) instead of
    /// running the QEMU and host benches here.
    #[arg(long, value_name = "PORT", conflicts_with_all = ["config", "host_only", "qemu_only", "cores"])]
    port: Option<String>,
    /// With --port: the one workload to measure (default: every workload the board has).
    #[arg(long, value_name = "NAME", requires = "port")]
    workload: Option<String>,
    /// With --port: time the device's link to the host instead (PROTOCOL.md §15): the device sends
    /// fill bytes as fast as the link takes them; a board's results take that link, and
    /// `brightpix rig plan --link-rate` takes the rate measured.
    #[arg(long, requires = "port", conflicts_with_all = ["workload", "frames"])]
    link: bool,
    /// With --link: fill bytes, 1 to 16777216 [default: 1000000, about 1 s of USB full speed;
    /// QEMU's UART carries 0.1-0.3 MB/s to the host].
    #[arg(long, value_name = "N", requires = "link")]
    link_bytes: Option<u32>,
    /// With --link: fill bytes a message, 1 to 960 [default: 256].
    #[arg(long, value_name = "N", requires = "link")]
    link_chunk: Option<u16>,
    /// With --port: the longest wait for one workload's report, seconds (the board measures in silence;
    /// QEMU under -icount takes tens of seconds for some).
    #[arg(long, value_name = "S", default_value_t = 600.0, requires = "port")]
    workload_timeout: f64,
    /// With --config: the board's clock, MHz, for its pixel rate and latency.
    #[arg(long, default_value_t = 480.0, value_name = "MHZ")]
    mhz: f64,
    /// With --config: the camera's frame rate, Hz: does it fit one board (and this host)?
    #[arg(long, value_name = "HZ", requires = "config")]
    camera_rate: Option<f64>,
    /// With --camera-rate: the camera's size, WIDTHxHEIGHT (default: the configuration's camera).
    #[arg(long, value_name = "WxH", requires = "camera_rate", value_parser = parse_size)]
    camera_size: Option<(u32, u32)>,
    /// Frames given to the QEMU bench for --config (each takes it a moment in emulation).
    #[arg(long, default_value_t = 4, value_name = "N")]
    qemu_frames: usize,
    /// Only the host bench.
    #[arg(long, conflicts_with = "qemu_only")]
    host_only: bool,
    /// Only the QEMU bench.
    #[arg(long)]
    qemu_only: bool,
    /// QEMU cores to run (default: both).
    #[arg(long = "core", value_name = "m4|m7", value_parser = parse_core)]
    cores: Vec<QemuCore>,
    /// Host threads for the all-cores figure (default: all cores).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Timed host rounds, after a warm-up round (min, median and max reported) [default: 20; 3 with --quick].
    #[arg(long, value_name = "N")]
    rounds: Option<usize>,
    /// Shortest timed host run, milliseconds: each task repeats its work until one run lasts this long
    /// [default: 100; 10 with --quick].
    #[arg(long, value_name = "MS")]
    min_run_ms: Option<f64>,
    /// A short host run (3 rounds of 10 ms runs, fewer frames): for a smoke test, not for figures.
    #[arg(long)]
    quick: bool,
    /// Print every host peer's figures and the QEMU bench's own output.
    #[arg(long, short)]
    verbose: bool,
}

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("{text:?} is not WIDTHxHEIGHT, e.g. 240x240"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|&v| v > 0)
            .ok_or_else(|| format!("{v:?} in {text:?} is not a positive whole number of pixels"))
    };
    Ok((parse(w)?, parse(h)?))
}

fn parse_core(text: &str) -> Result<QemuCore, String> {
    match text.to_ascii_lowercase().as_str() {
        "m4" | "cortex-m4" => Ok(QemuCore::M4),
        "m7" | "cortex-m7" => Ok(QemuCore::M7),
        _ => Err(format!("{text:?} is not a QEMU core: m4 or m7")),
    }
}

pub fn run(args: BenchArgs) -> Result<()> {
    if let (Some(port), true) = (&args.port, args.link) {
        super::bench_link::run(&super::bench_link::LinkBench {
            port,
            bytes: args.link_bytes.unwrap_or(1_000_000),
            chunk: args.link_chunk.unwrap_or(256),
            json: args.json.as_deref(),
        })?;
        return Ok(());
    }
    if let Some(port) = &args.port {
        let frames = match &args.frames {
            None => 0,
            Some(text) => text
                .to_str()
                .and_then(|t| t.parse::<u32>().ok())
                .filter(|&k| k > 0)
                .with_context(|| {
                    format!(
                        "--frames {} with --port is a number of frames per workload",
                        text.display()
                    )
                })?,
        };
        if !(args.workload_timeout.is_finite() && args.workload_timeout > 0.0) {
            bail!(
                "--workload-timeout {} is not a positive number of seconds",
                args.workload_timeout
            );
        }
        super::bench_port::run(&super::bench_port::PortBench {
            port,
            workload: args.workload.as_deref(),
            frames,
            json: args.json.as_deref(),
            per_workload: std::time::Duration::from_secs_f64(args.workload_timeout),
        })?;
        return Ok(());
    }
    if args.frames.is_some() && args.config.is_none() {
        bail!("--frames needs --config (a frame file) or --port (frames per workload)");
    }
    if !(args.mhz.is_finite() && args.mhz > 0.0) {
        bail!("--mhz {} is not a positive clock", args.mhz);
    }
    if let Some(rate) = args.camera_rate {
        if !(rate.is_finite() && rate > 0.0) {
            bail!("--camera-rate {rate} is not a positive frame rate");
        }
    }
    let cores = if args.cores.is_empty() {
        QemuCore::ALL.to_vec()
    } else {
        args.cores.clone()
    };
    let min_run_ms = args
        .min_run_ms
        .unwrap_or(if args.quick { 10.0 } else { 100.0 });
    if !(min_run_ms.is_finite() && min_run_ms >= 0.0) {
        bail!("--min-run-ms {min_run_ms} is not a duration in milliseconds");
    }
    let options = HostOptions {
        rounds: args
            .rounds
            .unwrap_or(if args.quick { 3 } else { 20 })
            .max(1),
        threads: args.threads,
        min_run_seconds: min_run_ms * 1e-3,
    };
    let frame_pixels = if args.quick { 500_000 } else { 4_000_000 };

    // The workloads (and, for a user configuration, its QEMU inputs) first:
    // a bad configuration or frame file is refused before anything runs.
    let user = match &args.config {
        Some(path) => {
            let config = ProcessingConfig::load(path)?;
            let frames = workloads::frames_for(&config.camera, frame_pixels, 8);
            Some(workloads::user(config, args.frames.as_deref(), frames)?)
        }
        None => None,
    };

    // The camera a --camera-rate applies to.
    let camera = match (args.camera_size, &user) {
        (Some((w, h)), _) => Some((w as u64 * h as u64, format!("{w}x{h}"))),
        (None, Some(workload)) => Some((
            workload.shape.pixels_per_frame() as u64,
            format!("{}x{}", workload.shape.width, workload.shape.height),
        )),
        (None, None) => None,
    };

    let mut qemu_rows = Vec::new();
    let mut qemu_problem = None;
    if !args.host_only {
        let repo = qemu::repository_root();
        match qemu::missing(repo.as_deref()) {
            Some(missing) => qemu_problem = Some(missing),
            None => {
                let repo = repo.expect("missing() checked it");
                let scratch =
                    std::env::temp_dir().join(format!("brightpix-bench-{}", std::process::id()));
                let qemu_args = match &user {
                    Some(workload) => qemu_user_args(workload, &scratch, args.qemu_frames)?,
                    None => Vec::new(),
                };
                for &core in &cores {
                    eprintln!(
                        "brightpix bench: QEMU {} (builds the bench the first time)...",
                        core.name()
                    );
                    match qemu::run(&repo, core, &qemu_args) {
                        Ok(run) => {
                            if args.verbose {
                                eprintln!("{}", run.output);
                            }
                            qemu_rows.extend(run.rows);
                        }
                        Err(error) => {
                            qemu_problem = Some(error);
                            break;
                        }
                    }
                }
                let _ = std::fs::remove_dir_all(&scratch);
            }
        }
    }

    let mut host_rows = Vec::new();
    if !args.qemu_only {
        let workloads = match user {
            Some(workload) => vec![workload],
            None => workloads::standard(frame_pixels),
        };
        for workload in &workloads {
            eprintln!(
                "brightpix bench: host, {} ({} frames)...",
                workload.name, workload.shape.frames
            );
            host_rows.push(
                run_host(workload, &options)
                    .with_context(|| format!("host bench of {}", workload.name))?,
            );
        }
    }

    if !args.host_only {
        println!("QEMU (instructions are exact; x floor: the engine over the honest floor in the same bench)");
        if !qemu_rows.is_empty() {
            print!("{}", qemu_table(&qemu_rows));
        }
        if let Some(problem) = &qemu_problem {
            println!("  not measured: {problem}");
        }
        println!();
    }
    if !host_rows.is_empty() {
        let threads = host_rows[0].threads;
        println!(
            "Host ({threads} threads; x sort, x peer: the per-window sort's and the best peer's time over the engine's on the peer's own rule; \
             engine/baseline: the engine's time over the no-selection baseline's; one core each; median [min-max] over the rounds)"
        );
        print!("{}", host_table(&host_rows));
        if args.verbose {
            println!();
            print!("{}", peer_table(&host_rows));
        }
    }
    if let Some(path) = &args.config {
        println!();
        print!(
            "{}",
            capacity_report(path, &args, camera.as_ref(), &qemu_rows, host_rows.first())
        );
    }
    if let Some(path) = &args.json {
        let json = figures_json(&qemu_rows, &host_rows, &args);
        std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("brightpix bench: wrote {}", path.display());
    }
    if qemu_problem.is_some() && args.qemu_only {
        bail!("the QEMU bench did not run");
    }
    Ok(())
}

/// Writes the user's configuration and first frames for the QEMU bench.
fn qemu_user_args(workload: &Workload, dir: &Path, frames: usize) -> Result<Vec<OsString>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let count = frames.clamp(1, workload.shape.frames);
    let pixels = &workload.pixels[..count * workload.shape.pixels_per_frame()];
    let (config, frames) = qemu::write_user_inputs(dir, &workload.config.view(), pixels)
        .with_context(|| format!("cannot write the QEMU bench's inputs in {}", dir.display()))?;
    Ok(vec![
        "--config".into(),
        config.into(),
        "--frames".into(),
        frames.into(),
    ])
}

/// A row per workload: instructions per pixel, x floor and last-row
/// instructions on each core.
fn qemu_table(rows: &[QemuRow]) -> String {
    let mut workloads: Vec<&str> = Vec::new();
    for row in rows {
        if !workloads.contains(&row.workload.as_str()) {
            workloads.push(&row.workload);
        }
    }
    let mut out = format!(
        "{:<34} {:>9} {:>7} {:>10}   {:>9} {:>7} {:>10}\n",
        "workload", "M4 ins/px", "x floor", "last row", "M7 ins/px", "x floor", "last row"
    );
    for workload in workloads {
        out.push_str(&format!("{workload:<34}"));
        for core in QemuCore::ALL {
            match rows
                .iter()
                .find(|r| r.workload == workload && r.core == core.name())
            {
                Some(r) => out.push_str(&format!(
                    " {:>9.2} {:>7} {:>10.0}  ",
                    r.instr_per_px,
                    r.x_floor().map_or("-".into(), |x| format!("{x:.2}")),
                    r.last_row_instructions
                )),
                None => out.push_str(&format!(" {:>9} {:>7} {:>10}  ", "-", "-", "-")),
            }
        }
        out.push('\n');
    }
    out
}

/// Figures for the user's configuration: what one board sustains at
/// `--mhz`, the latency after the last row, and whether the camera fits.
fn capacity_report(
    path: &Path,
    args: &BenchArgs,
    camera: Option<&(u64, String)>,
    qemu_rows: &[QemuRow],
    host: Option<&HostRow>,
) -> String {
    let mut out = format!("Your configuration ({}):\n", path.display());
    for core in QemuCore::ALL {
        let Some(row) = qemu_rows
            .iter()
            .find(|r| r.workload == workloads::USER && r.core == core.name())
        else {
            continue;
        };
        let capacity = Capacity::of(row, args.mhz);
        let floor = row
            .x_floor()
            .map_or(String::new(), |x| format!(" ({x:.2}x the floor)"));
        out.push_str(&format!(
            "  {} at {} MHz: {:.2} instructions/pixel{} -> {:.1} Mpx/s per board; {:.1} us after the last row ({:.0} instructions)\n",
            core.name(),
            args.mhz,
            row.instr_per_px,
            floor,
            capacity.px_per_s * 1e-6,
            capacity.latency_us,
            row.last_row_instructions
        ));
        camera_fit(&mut out, args, camera, &capacity);
        if core == QemuCore::M7 {
            // The whole rows above, plus what the STM32H743's camera path
            // adds (its model's, from the bench's `canary-12bit-dcmi`).
            let board = CostModel::STM32H743;
            let capacity = Capacity {
                px_per_s: args.mhz * 1e6 / (row.instr_per_px + board.camera_per_pixel),
                latency_us: (row.last_row_instructions + board.last_row_per_frame) / args.mhz,
            };
            out.push_str(&format!(
                "  an STM32H743 at {} MHz with its camera path (+{:.2} instructions/pixel, +{:.0} after the last pixel: the DMA ring, its camera source's runs and the bit-depth check, from the bench's canary-12bit-dcmi row): {:.1} Mpx/s per board; {:.1} us after the last row\n",
                args.mhz,
                board.camera_per_pixel,
                board.last_row_per_frame,
                capacity.px_per_s * 1e-6,
                capacity.latency_us,
            ));
            camera_fit(&mut out, args, camera, &capacity);
            link_fit(&mut out, path, args);
        }
    }
    if qemu_rows.iter().all(|r| r.workload != workloads::USER) {
        out.push_str("  (no QEMU figures: the board's rate and latency need the QEMU bench)\n");
    }
    if let Some(host) = host {
        out.push_str(&format!(
            "  this host: {:.1} Mpx/s on {} threads ({:.1} on one core; medians)",
            host.mpx_per_s.median, host.threads, host.mpx_per_s_one_core.median
        ));
        if let (Some(rate), Some((pixels, size))) = (args.camera_rate, camera) {
            let needed = rate * *pixels as f64;
            out.push_str(&format!(
                "; a {size} camera at {rate} Hz ({:.1} Mpx/s) {}",
                needed * 1e-6,
                if needed <= host.mpx_per_s.median * 1e6 {
                    "fits"
                } else {
                    "does not fit"
                }
            ));
        }
        out.push('\n');
    }
    out
}

/// Whether one STM32H743's results at `--camera-rate` fit its link (the
/// configuration's own camera only: another `--camera-size` has other
/// windows).
fn link_fit(out: &mut String, path: &Path, args: &BenchArgs) {
    let (Some(rate), None) = (args.camera_rate, args.camera_size) else {
        return;
    };
    let Ok(config) = ProcessingConfig::load(path) else {
        return;
    };
    let Some(link) = CostModel::STM32H743.link else {
        return;
    };
    let all: Vec<usize> = (0..config.windows.len()).collect();
    let bytes = rig::frame_bytes(&config, &rig::ResultBounds::of(&config), &all, false) as f64;
    let share = bytes * rate / link.bytes_per_s;
    out.push_str(&format!(
        "    its results at {rate} Hz: up to {:.2} MB/s ({bytes:.0} bytes a frame): {} its {} link ({:.0}% of about {:.1} MB/s; `brightpix rig plan` counts the boards both need)\n",
        bytes * rate * 1e-6,
        if share <= 1.0 { "FIT" } else { "do NOT fit" },
        link.name,
        share * 100.0,
        link.bytes_per_s * 1e-6,
    ));
}

/// Whether the camera of `--camera-rate` fits a board of `capacity`.
fn camera_fit(
    out: &mut String,
    args: &BenchArgs,
    camera: Option<&(u64, String)>,
    capacity: &Capacity,
) {
    if let (Some(rate), Some((pixels, size))) = (args.camera_rate, camera) {
        let needed = rate * *pixels as f64;
        let share = needed / capacity.px_per_s;
        out.push_str(&format!(
            "    a {size} camera at {rate} Hz needs {:.1} Mpx/s: {} ({:.0}% of the board's cycles at one instruction per cycle; the frame period is {:.0} us)\n",
            needed * 1e-6,
            if share <= 1.0 { "FITS one board" } else { "does NOT fit one board" },
            share * 100.0,
            1e6 / rate,
        ));
    }
}

/// A board's capacity from a QEMU row.
struct Capacity {
    px_per_s: f64,
    latency_us: f64,
}

impl Capacity {
    fn of(row: &QemuRow, mhz: f64) -> Self {
        Capacity {
            px_per_s: mhz * 1e6 / row.instr_per_px,
            latency_us: row.last_row_instructions / mhz,
        }
    }
}

/// The JSON list: QEMU rows (with `kind: "qemu"`), then host rows (with
/// `kind: "host"`); user rows carry their capacity at `--mhz`.
fn figures_json(
    qemu_rows: &[QemuRow],
    host_rows: &[HostRow],
    args: &BenchArgs,
) -> serde_json::Value {
    let mut list = Vec::new();
    for row in qemu_rows {
        let mut value = serde_json::to_value(row).expect("rows serialise");
        let object = value.as_object_mut().expect("a row is an object");
        object.insert("kind".into(), "qemu".into());
        object.insert("x_floor".into(), row.x_floor().into());
        if row.workload == workloads::USER {
            let capacity = Capacity::of(row, args.mhz);
            object.insert("mhz".into(), args.mhz.into());
            object.insert("px_per_s_per_board".into(), capacity.px_per_s.into());
            object.insert("latency_us".into(), capacity.latency_us.into());
        }
        list.push(value);
    }
    for row in host_rows {
        let mut value = serde_json::to_value(row).expect("rows serialise");
        let object = value.as_object_mut().expect("a row is an object");
        object.insert("kind".into(), "host".into());
        list.push(value);
    }
    serde_json::Value::Array(list)
}
