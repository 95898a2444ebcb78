//! `brightpix capture`: record slopes from a device with its own camera.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;

use crate::config_file::ProcessingConfig;
use crate::io::{check_result_outputs, write_results, Layout, Provenance, Raw, Results};
use crate::link::{Client, FrameOutcome};

#[derive(Args)]
#[command(
    about = "Record the slopes, flux and validity of N frames from a device with its own camera (.npy, FITS or CSV)",
    after_help = "Examples:\n  brightpix capture --port /dev/ttyACM0 --count 1000 --out slopes.npy\n  brightpix capture --port /dev/ttyACM0 --config examples/canary.toml --count 100 --out s.npy\n\n\
Written as by `brightpix process` (docs/OUTPUTS.md): slopes float64 pixels, flux counts,\n\
validity 0/1, provenance (the device's configuration id and digest); NaN where a frame was dropped. Devices whose camera the host emulates\n\
(simulate-device) answer NoCamera: use `brightpix stream` for them."
)]
pub struct CaptureArgs {
    /// Serial port of the device (/dev/ttyACM0, /dev/pts/N, COM3) or unix:PATH.
    #[arg(long)]
    port: String,
    /// Frames to record.
    #[arg(long, value_name = "N")]
    count: u32,
    /// Output: .npy (with .flux.npy, .valid.npy, .json beside it), .fits or .csv.
    #[arg(long)]
    out: PathBuf,
    /// Slopes layout: pairs (frames, sub-apertures, 2) or vector (frames, 2 x sub-apertures).
    #[arg(long, value_enum, default_value_t = Layout::Pairs)]
    layout: Layout,
    /// Upload this configuration first (otherwise the device's active one is used).
    #[arg(long)]
    config: Option<PathBuf>,
}

pub fn run(args: CaptureArgs) -> Result<()> {
    let inputs: Vec<&std::path::Path> = args.config.as_deref().into_iter().collect();
    check_result_outputs(&inputs, &[&args.out])?;
    if args.count == 0 {
        bail!("--count must be at least 1");
    }
    let mut client = Client::open(&args.port)?;
    let mut subapertures = None;
    let mut provenance = None;
    if let Some(path) = &args.config {
        let config = ProcessingConfig::load(path)?;
        let done = client.configure(&config.view())?;
        subapertures = Some(config.windows.len());
        let mut p = Provenance::of("brightpix capture (device)", &config.view(), Some(path));
        p.config_id = Some(done.config_id);
        provenance = Some(p);
    }
    let status = client.status()?;
    let mut provenance = provenance.unwrap_or_else(|| {
        let mut p = Provenance::unknown_config("brightpix capture (device)", status.config_id);
        p.config_digest = status.config_digest;
        p
    });
    provenance.frames_source = Some(format!("the camera of the device at {}", args.port));
    let started = std::time::Instant::now();
    let (outcomes, error) = match client.capture(args.count) {
        Ok(o) => (o, None),
        Err(i) if i.received.is_empty() => return Err(i.error.into()),
        Err(i) => (i.received, Some(i.error)),
    };
    let n = subapertures.unwrap_or_else(|| {
        outcomes
            .iter()
            .flat_map(|o| o.slopes().slopes.iter())
            .map(|s| s.index as usize + 1)
            .max()
            .unwrap_or(0)
    });
    let seconds = started.elapsed().as_secs_f64().max(1e-9);
    let mut results = Results::new(n);
    let mut dropped = 0;
    for o in &outcomes {
        let complete = matches!(o, FrameOutcome::Done(_));
        dropped += usize::from(!complete);
        for s in o.slopes().by_index(n) {
            results.push(s.map(|s| Raw {
                slope_x: s.slope_x,
                slope_y: s.slope_y,
                flux: s.flux,
                valid: s.valid,
            }));
        }
    }
    write_results(&args.out, &results, &provenance, args.layout)?;
    eprintln!(
        "brightpix: {} frames ({} dropped) x {n} sub-apertures in {seconds:.3} s ({:.1} frames/s) written to {}",
        outcomes.len(),
        dropped,
        outcomes.len() as f64 / seconds,
        args.out.display()
    );
    if let Some(e) = error {
        bail!("the capture stopped early (the frames received were written): {e}");
    }
    Ok(())
}
