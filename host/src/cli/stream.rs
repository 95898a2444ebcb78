//! `brightpix stream`: send recorded frames to a device whose camera the
//! host emulates, collect its slopes, optionally verify every one.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;

use crate::config_file::ProcessingConfig;
use crate::io::{write_array, FrameSource};
use crate::link::verify::Verifier;
use crate::link::{Client, FrameOutcome, PixelSink};
use crate::sil::verify_outcomes;

#[derive(Args)]
#[command(
    about = "Configure a device, stream frames (.npy or FITS) to it, collect its slopes, optionally verify them bit for bit",
    after_help = "Examples:\n  brightpix stream --port /dev/pts/4 --config examples/canary.toml --frames frames.npy --verify\n  brightpix stream --port /dev/ttyACM0 --config examples/canary.toml --frames frames.fits --out slopes.npy\n  brightpix stream --port /dev/pts/5 --config examples/canary.toml --frames f.npy --verify --pixels-fifo /tmp/bp/pixels.fifo\n\n\
With --verify every sub-aperture's slopes, flux and validity are compared with the reference\n\
implementation (host/src/reference); the first mismatches are printed (frame, sub-aperture,\n\
both values) and the exit status is non-zero on any mismatch or dropped frame.\n\
--pixels-fifo writes the pixels into the FIFO the device reads (simulate-device --pixels-fifo,\n\
the QEMU board's --pixels) instead of the link; slopes still come over the link."
)]
pub struct StreamArgs {
    /// Serial port of the device (/dev/ttyACM0, /dev/pts/N, COM3) or unix:PATH.
    #[arg(long)]
    port: String,
    /// Processing configuration (TOML, see docs/CONFIG.md), uploaded first.
    #[arg(long)]
    config: PathBuf,
    /// Frames: .npy (uint8/uint16, shape (frames, height, width)) or FITS cube.
    #[arg(long)]
    frames: PathBuf,
    /// Check every result against the reference implementation.
    #[arg(long)]
    verify: bool,
    /// Write the slopes (.npy, float64, shape (frames, sub-apertures, 2), pixels; NaN where dropped).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Send pixels through this FIFO instead of the link.
    #[arg(long, value_name = "PATH")]
    pixels_fifo: Option<PathBuf>,
    /// Stream only the first N frames of the file.
    #[arg(long, value_name = "N")]
    count: Option<usize>,
    /// Mismatches to print.
    #[arg(long, default_value_t = 10)]
    show: usize,
    /// Do not upload --config (the device already has it; --config is still used to verify).
    #[arg(long)]
    no_configure: bool,
}

/// Frames read and streamed at a time.
const BATCH: usize = 256;

pub fn run(args: StreamArgs) -> Result<()> {
    let config = ProcessingConfig::load(&args.config)?;
    let view = config.view();
    let mut source = FrameSource::open_for_camera(&args.frames, &view.camera)?;
    let total = args.count.unwrap_or(usize::MAX).min(source.len());
    let subapertures = view.windows.len();
    let mut client = Client::open(&args.port)?;
    if args.no_configure {
        client.assume_configured(&view);
    } else {
        let done = client.configure(&view)?;
        eprintln!(
            "brightpix: configuration {:#010x} applied ({} messages, {:.1} ms)",
            done.config_id,
            done.messages,
            done.elapsed.as_secs_f64() * 1e3
        );
    }
    if let Some(fifo) = &args.pixels_fifo {
        client.set_pixel_sink(PixelSink::Fifo(fifo.clone()));
    }
    let mut verifier = Verifier::new(&view, args.show).context("configuration")?;
    let mut slopes = Vec::with_capacity(if args.out.is_some() {
        total * subapertures * 2
    } else {
        0
    });
    let mut elapsed = std::time::Duration::ZERO;
    let (mut done, mut dropped) = (0usize, 0usize);
    let mut first = 0;
    let mut failure = None;
    while first < total {
        let count = BATCH.min(total - first);
        let mut batch = vec![Vec::new(); count];
        for (k, frame) in batch.iter_mut().enumerate() {
            source.read_frame_into(first + k, frame)?;
        }
        let mut outcomes = Vec::with_capacity(count);
        let result = client.stream_frames(first as u32, &batch, |o| outcomes.push(o));
        outcomes.sort_by_key(FrameOutcome::frame);
        if args.verify {
            verify_outcomes(&mut verifier, &batch, first as u32, &outcomes);
        }
        if args.out.is_some() {
            let mut by_frame = vec![None; count];
            for o in &outcomes {
                if let Some(slot) = by_frame.get_mut((o.frame() as usize).wrapping_sub(first)) {
                    *slot = Some(o);
                }
            }
            for o in by_frame {
                let entries = match o {
                    Some(FrameOutcome::Done(s)) => s.by_index(subapertures),
                    _ => vec![None; subapertures],
                };
                for e in entries {
                    match e {
                        Some(e) => {
                            slopes.extend([e.slope_x as f64 / 65536.0, e.slope_y as f64 / 65536.0])
                        }
                        None => slopes.extend([f64::NAN, f64::NAN]),
                    }
                }
            }
        }
        match result {
            Ok(report) => {
                elapsed += report.elapsed;
                done += report.frames_done;
                dropped += report.frames_dropped;
            }
            Err(e) => {
                failure = Some(e);
                break;
            }
        }
        first += count;
    }
    let streamed = first.min(total);
    if let Some(out) = &args.out {
        let frames = slopes.len() / (2 * subapertures.max(1));
        write_array(out, &[frames, subapertures, 2], &slopes)?;
        eprintln!(
            "brightpix: slopes of {frames} frames written to {}",
            out.display()
        );
    }
    println!(
        "streamed {done} frames ({dropped} dropped) of {} to {} in {:.3} s: {:.0} frames/s, {:.0} us/frame",
        args.frames.display(),
        client.port_name(),
        elapsed.as_secs_f64(),
        done as f64 / elapsed.as_secs_f64().max(1e-9),
        elapsed.as_secs_f64() * 1e6 / done.max(1) as f64
    );
    if let Some(e) = failure {
        bail!("streaming stopped after {streamed} frames: {e}");
    }
    if let Ok(status) = client.status() {
        println!("{}", super::demo::format_status(&status));
    }
    if args.verify {
        println!(
            "verified {} frames, {} sub-aperture results compared with the reference: {} mismatches, {} frames dropped",
            verifier.frames_verified, verifier.slopes_compared, verifier.mismatch_count, verifier.frames_dropped
        );
        for m in &verifier.mismatches {
            println!("  mismatch: {m}");
        }
        if !verifier.all_match() {
            bail!("the device's results differ from the reference");
        }
    } else if dropped > 0 {
        bail!("{dropped} frames were dropped by the device");
    }
    Ok(())
}
