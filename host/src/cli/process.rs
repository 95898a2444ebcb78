//! `brightpix process`: slopes from recorded frames, by the engine or the reference.

use crate::config_file::ProcessingConfig;
use crate::engine_runner::HostEngine;
use crate::io::results::stage_results;
use crate::io::{
    check_result_outputs, stage_array, FrameShape, FrameSource, Layout, Provenance, Raw, Results,
    ResultsFormat, Staged,
};
use crate::parallel::ParallelEngine;
use crate::reference::Reference;
use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
#[command(
    about = "Compute slopes, flux and validity from recorded frames (.npy or FITS cube) into .npy, FITS or CSV",
    after_help = "Examples:\n  brightpix process --config examples/canary.toml --frames frames.fits --out slopes.npy\n  brightpix process --config examples/canary.toml --frames frames.npy --out ref.fits --reference\n  brightpix process --config examples/canary.toml --frames frames.npy --out slopes.npy --layout vector\n  brightpix process --config examples/canary.toml --frames frames.npy --out slopes.csv\n  brightpix process --config examples/canary.toml --frames telemetry.aot.fits --sensor WFS1 --out slopes.aot.fits\n\n\
Slopes are float64 pixels, [x, y], reference slopes subtracted, 0.0 for invalid sub-apertures\n\
(flux at or below min_flux); flux is float64 counts; validity 0/1. --out x.npy writes x.npy,\n\
x.flux.npy, x.valid.npy and x.json (provenance); x.fits one file with SLOPES, FLUX and VALID\n\
extensions and provenance keywords; x.csv one row per frame and sub-aperture; x.aot.fits\n\
Adaptive Optics Telemetry (docs/OUTPUTS.md).\n\
Engine and reference give identical numbers (see shared/SPEC.md)."
)]
pub struct ProcessArgs {
    /// Processing configuration (TOML, see docs/CONFIG.md).
    #[arg(long)]
    config: PathBuf,
    /// Frames: .npy (uint8/uint16, shape (frames, height, width)), FITS cube (the first HDU
    /// holding an image, tile-compressed included; BSCALE/BZERO applied) or AOT file (the
    /// detector pixel intensities of its Shack-Hartmann sensor, see --sensor).
    #[arg(long, value_name = "PATH")]
    frames: PathBuf,
    /// FITS HDU of the frames: an index (0: primary) or EXTNAME (default: the first image).
    #[arg(long, value_name = "HDU")]
    hdu: Option<String>,
    /// AOT file (.aot.fits) of several wavefront sensors: the UID of the Shack-Hartmann sensor
    /// whose detector pixel intensities are the frames (default: the file's only sensor).
    #[arg(long, value_name = "NAME", conflicts_with = "hdu")]
    sensor: Option<String>,
    /// With --out x.aot.fits: also write the frames as the detector's PIXEL_INTENSITIES.
    #[arg(long)]
    aot_pixels: bool,
    /// Output: .npy (with .flux.npy, .valid.npy, .json beside it), .fits, .aot.fits (Adaptive
    /// Optics Telemetry) or .csv.
    #[arg(long)]
    out: PathBuf,
    /// Slopes layout: pairs (frames, sub-apertures, 2) or vector (frames, 2 x sub-apertures),
    /// [x_0..x_S-1, y_0..y_S-1] as AO codes (DARC, COMPASS, soapy) take them.
    #[arg(long, value_enum, default_value_t = Layout::Pairs)]
    layout: Layout,
    /// Use the reference implementation (full sort per sub-aperture) instead of the streaming engine.
    #[arg(long)]
    reference: bool,
    /// Feed the engine this many pixels at a time, as a camera link's DMA would (default: whole
    /// frames). Runs on one core.
    #[arg(long, value_name = "PIXELS", conflicts_with = "reference", value_parser = super::at_least_one)]
    chunk: Option<usize>,
    /// Worker threads for the engine (default: all cores). Results do not depend on it.
    #[arg(long, value_name = "N", conflicts_with_all = ["reference", "chunk"])]
    threads: Option<usize>,
    /// Also write the validity alone to this .npy or FITS (uint8 0/1, shape (frames, sub-apertures)).
    #[arg(long, value_name = "FILE")]
    valid_out: Option<PathBuf>,
}

/// Frames are read and processed in batches of about this many pixels (and
/// at least 64 frames), so a cube of any size streams through in bounded
/// memory; a batch of 4 MiB mostly stays in the cache between its read and
/// its processing.
const BATCH_PIXELS: usize = 1 << 21;

pub fn run(args: ProcessArgs) -> Result<()> {
    // Before any work: no output may replace an input, or another output.
    let outputs: Vec<&std::path::Path> = [Some(args.out.as_path()), args.valid_out.as_deref()]
        .into_iter()
        .flatten()
        .collect();
    check_result_outputs(&[&args.config, &args.frames], &outputs)?;
    if let Some(valid_out) = &args.valid_out {
        crate::io::FileFormat::from_path(valid_out)?;
    }
    let aot_out = ResultsFormat::from_path(&args.out)? == ResultsFormat::Aot;
    if args.aot_pixels && !aot_out {
        anyhow::bail!(
            "--aot-pixels: --out {} is not an AOT file (a name ending in .aot.fits)",
            args.out.display()
        );
    }
    let config = ProcessingConfig::load(&args.config)?;
    let view = config.view();
    let mut source =
        FrameSource::open_sensor(&args.frames, args.hdu.as_deref(), args.sensor.as_deref())?;
    source.set_camera(&view.camera)?;
    let frames = source.len();
    let subapertures = view.windows.len();
    let mut results = Results::new(subapertures);
    let started = Instant::now();
    let mut threads = 1;
    let progress = super::progress::Progress::new(frames as u64, "frames");
    let mut push = |slope_x: i32, slope_y: i32, flux: i64, valid: bool| {
        results.push(Some(Raw {
            slope_x,
            slope_y,
            flux,
            valid,
        }));
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
                push(o.slope_x, o.slope_y, o.flux, o.valid);
            }
            progress.inc(1);
        }
    } else if let Some(chunk) = args.chunk {
        let mut engine = HostEngine::new(view).context("configuration")?;
        let mut frame = Vec::new();
        for index in 0..frames {
            source.read_frame_into(index, &mut frame)?;
            let results = engine
                .process([frame.as_slice()], chunk)
                .map_err(|(_, e)| anyhow::anyhow!("frame {index}: {e}"))?;
            for r in results.iter().flatten() {
                push(r.slope_x, r.slope_y, r.flux, r.valid);
            }
            progress.inc(1);
        }
    } else {
        let mut engine = ParallelEngine::new(&view, args.threads).context("configuration")?;
        threads = engine.threads();
        let shape = source.shape();
        let batch_frames = (BATCH_PIXELS / shape.pixels_per_frame().max(1)).max(64);
        let mut pixels = Vec::new();
        let mut first = 0;
        while first < frames {
            let count = batch_frames.min(frames - first);
            // Zeroed only as it grows: each batch is read over the last.
            pixels.resize(count * shape.pixels_per_frame(), 0);
            source.read_frames_to(first, &mut pixels)?;
            let batch = FrameShape {
                frames: count,
                ..shape
            };
            let results = engine.process(&pixels, batch).map_err(|e| match e {
                crate::parallel::BatchError::Pixel { frame, error } => {
                    anyhow::anyhow!("frame {}: {error}", first + frame)
                }
                other => anyhow::Error::new(other),
            })?;
            for ((slope, flux), valid) in
                results.slopes.iter().zip(&results.flux).zip(&results.valid)
            {
                push(slope[0], slope[1], *flux, *valid);
            }
            progress.inc(count as u64);
            first += count;
        }
    }
    let elapsed = started.elapsed();
    progress.finish();
    let producer = if args.reference {
        "brightpix process (reference)"
    } else {
        "brightpix process (streaming engine)"
    };
    let mut provenance = Provenance::of(producer, &view, Some(&args.config));
    provenance.frames_source = Some(args.frames.display().to_string());
    // Every output whole, or none: stage them all, then move them in place.
    let mut staged = if args.aot_pixels {
        // Read again rather than kept: only this option pays for the memory.
        let cube = source.read_all()?;
        vec![crate::io::aot::stage(
            &args.out,
            &results,
            &provenance,
            Some(&cube),
        )?]
    } else {
        stage_results(&args.out, &results, &provenance, args.layout)?
    };
    if let Some(path) = &args.valid_out {
        staged.push(stage_array(path, &[frames, subapertures], &results.valid)?);
    }
    Staged::commit_all(staged)?;
    let invalid = results.valid.iter().filter(|&&v| v == 0).count();
    super::all_invalid::InvalidFrames::of_results(&results).warn();
    let seconds = elapsed.as_secs_f64().max(1e-9);
    let pixels = (frames * view.camera.pixel_count()) as f64;
    eprintln!(
        "brightpix: {frames} frames x {subapertures} sub-apertures by the {} in {:.3} s ({:.0} frames/s, {:.1} Mpx/s, reading included); {invalid} invalid; wrote {}",
        if args.reference {
            "reference".to_string()
        } else if args.chunk.is_some() {
            "streaming engine (one core, chunked)".to_string()
        } else {
            format!("streaming engine on {threads} thread(s)")
        },
        seconds,
        frames as f64 / seconds,
        pixels / seconds * 1e-6,
        args.out.display()
    );
    Ok(())
}
