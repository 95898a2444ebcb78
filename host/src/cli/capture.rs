//! `brightpix capture`: record slopes from a device with its own camera.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;

use crate::config_file::ProcessingConfig;
use crate::io::{check_outputs, write_array};
use crate::link::{Client, FrameOutcome};

#[derive(Args)]
#[command(
    about = "Record the slopes of K frames from a device with its own camera into a .npy",
    after_help = "Examples:\n  brightpix capture --port /dev/ttyACM0 --frames-count 1000 --out slopes.npy\n  brightpix capture --port /dev/ttyACM0 --config examples/canary.toml --frames-count 100 --out s.npy\n\n\
Slopes are float64 pixels, shape (frames, sub-apertures, 2), [x, y]; 0.0 for invalid\n\
sub-apertures, NaN where a frame was dropped. Devices whose camera the host emulates\n\
(simulate-device) answer NoCamera: use `brightpix stream` for them."
)]
pub struct CaptureArgs {
    /// Serial port of the device (/dev/ttyACM0, /dev/pts/N, COM3) or unix:PATH.
    #[arg(long)]
    port: String,
    /// Frames to record.
    #[arg(long)]
    frames_count: u32,
    /// Output slopes (.npy).
    #[arg(long)]
    out: PathBuf,
    /// Upload this configuration first (otherwise the device's active one is used).
    #[arg(long)]
    config: Option<PathBuf>,
}

pub fn run(args: CaptureArgs) -> Result<()> {
    let inputs: Vec<&std::path::Path> = args.config.as_deref().into_iter().collect();
    check_outputs(&inputs, &[&args.out])?;
    if args.frames_count == 0 {
        bail!("--frames-count must be at least 1");
    }
    let mut client = Client::open(&args.port)?;
    let mut subapertures = None;
    if let Some(path) = &args.config {
        let config = ProcessingConfig::load(path)?;
        client.configure(&config.view())?;
        subapertures = Some(config.windows.len());
    }
    let (outcomes, error) = match client.capture(args.frames_count) {
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
    let mut data = Vec::with_capacity(outcomes.len() * n * 2);
    let mut dropped = 0;
    for o in &outcomes {
        let complete = matches!(o, FrameOutcome::Done(_));
        dropped += usize::from(!complete);
        for s in o.slopes().by_index(n) {
            match s {
                Some(s) => {
                    data.push(s.slope_x as f64 / 65536.0);
                    data.push(s.slope_y as f64 / 65536.0);
                }
                None => data.extend([f64::NAN, f64::NAN]),
            }
        }
    }
    write_array(&args.out, &[outcomes.len(), n, 2], &data)?;
    eprintln!(
        "brightpix: {} frames ({} dropped) x {n} sub-apertures written to {}",
        outcomes.len(),
        dropped,
        args.out.display()
    );
    if let Some(e) = error {
        bail!("the capture stopped early (the frames received were written): {e}");
    }
    Ok(())
}
