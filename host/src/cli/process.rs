//! `brightpix process`: slopes from recorded frames, by the engine or the reference.

use crate::config_file::ProcessingConfig;
use crate::engine_runner::HostEngine;
use crate::io::{write_array, FrameSource};
use crate::reference::Reference;
use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
#[command(
    about = "Compute slopes from recorded frames (.npy or FITS cube) into a .npy of shape (frames, sub-apertures, 2)",
    after_help = "Examples:\n  brightpix process --config examples/canary.toml --frames frames.fits --out slopes.npy\n  brightpix process --config examples/canary.toml --frames frames.npy --out ref.npy --reference\n\n\
Slopes are float64 pixels, [x, y], reference slopes subtracted, 0.0 for invalid sub-apertures\n\
(flux at or below min_flux). Engine and reference give identical numbers (see shared/SPEC.md)."
)]
pub struct ProcessArgs {
    /// Processing configuration (TOML, see docs/CONFIG.md).
    #[arg(long)]
    config: PathBuf,
    /// Frames: .npy (uint8/uint16, shape (frames, height, width)) or FITS cube.
    #[arg(long)]
    frames: PathBuf,
    /// Output slopes (.npy, float64, shape (frames, sub-apertures, 2), pixels).
    #[arg(long)]
    out: PathBuf,
    /// Use the reference implementation (full sort per sub-aperture) instead of the streaming engine.
    #[arg(long)]
    reference: bool,
    /// Feed the engine this many pixels at a time, as a camera link's DMA would (default: whole frames).
    #[arg(long, value_name = "PIXELS")]
    chunk: Option<usize>,
    /// Also write the validity of each sub-aperture (uint8 0/1, shape (frames, sub-apertures)).
    #[arg(long, value_name = "FILE")]
    valid_out: Option<PathBuf>,
}

/// Frames are read and processed in batches of this many.
const BATCH: usize = 64;

pub fn run(args: ProcessArgs) -> Result<()> {
    let config = ProcessingConfig::load(&args.config)?;
    let view = config.view();
    let mut source = FrameSource::open_for_camera(&args.frames, &view.camera)?;
    let frames = source.len();
    let subapertures = view.windows.len();
    let mut slopes = Vec::with_capacity(frames * subapertures * 2);
    let mut valid = Vec::with_capacity(frames * subapertures);
    let started = Instant::now();
    let mut push = |x: i32, y: i32, ok: bool| {
        slopes.push(x as f64 / 65536.0);
        slopes.push(y as f64 / 65536.0);
        valid.push(ok as u8);
    };
    if args.reference {
        let mut reference = Reference::new(&view).context("configuration")?;
        let mut frame = Vec::new();
        for index in 0..frames {
            source.read_frame_into(index, &mut frame)?;
            let outputs = reference
                .process_frame(&frame)
                .with_context(|| format!("frame {index}"))?;
            for o in outputs {
                push(o.slope_x, o.slope_y, o.valid);
            }
        }
    } else {
        let mut engine = HostEngine::new(view).context("configuration")?;
        let chunk = args.chunk.unwrap_or(usize::MAX);
        let mut batch: Vec<Vec<u16>> = Vec::with_capacity(BATCH);
        let mut first = 0;
        while first < frames {
            let count = BATCH.min(frames - first);
            batch.resize_with(count, Vec::new);
            for (k, frame) in batch.iter_mut().enumerate() {
                source.read_frame_into(first + k, frame)?;
            }
            let results = engine
                .process(batch.iter().map(Vec::as_slice), chunk)
                .map_err(|(k, e)| anyhow::anyhow!("frame {}: {e}", first + k))?;
            for r in results.iter().flatten() {
                push(r.slope_x, r.slope_y, r.valid);
            }
            first += count;
        }
    }
    let elapsed = started.elapsed();
    write_array(&args.out, &[frames, subapertures, 2], &slopes)?;
    if let Some(path) = &args.valid_out {
        write_array(path, &[frames, subapertures], &valid)?;
    }
    let invalid = valid.iter().filter(|&&v| v == 0).count();
    eprintln!(
        "brightpix: {frames} frames x {subapertures} sub-apertures by the {} in {:.3} s ({:.0} frames/s); {invalid} invalid; wrote {}",
        if args.reference { "reference" } else { "streaming engine" },
        elapsed.as_secs_f64(),
        frames as f64 / elapsed.as_secs_f64().max(1e-9),
        args.out.display()
    );
    Ok(())
}
