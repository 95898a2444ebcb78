//! `brightpix capture`: record slopes from a device with its own camera,
//! and, for a simulated device's camera, verify every one bit for bit.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use brightpix_protocol::wire::{CameraInterface, DeviceError};
use clap::Args;

use crate::config_file::ProcessingConfig;
use crate::io::{check_result_outputs, write_results, Layout, Provenance, Raw, Results};
use crate::link::verify::Verifier;
use crate::link::{Client, FrameOutcome, LinkError};
use crate::sil::verify_outcomes;
use crate::sim_device::CameraFrames;

#[derive(Args)]
#[command(
    about = "Record the slopes, flux and validity of N frames from a device with its own camera (.npy, FITS or CSV); with --verify, check a simulated camera's frames bit for bit",
    after_help = "Examples:\n  brightpix capture --port /dev/ttyACM0 --count 1000 --out slopes.npy\n  brightpix capture --port /dev/ttyACM0 --config examples/canary.toml --count 100 --out s.fits --layout vector\n\n\
  # a simulated device with its own camera, no hardware:\n  brightpix simulate-device --camera sim:7 &        # prints /dev/pts/N\n  brightpix capture --port /dev/pts/N --config examples/canary.toml --count 200 --verify --seed 7 --out s.npy\n\n\
Written as by `brightpix process` (docs/OUTPUTS.md): slopes float64 pixels, flux counts,\n\
validity 0/1, provenance (the device's configuration id and digest); NaN where a frame was dropped.\n\
--verify regenerates the frames of `simulate-device --camera sim:SEED` (each capture starts at its\n\
frame 0) for --config's camera and compares every sub-aperture's slopes, flux and validity with the\n\
reference implementation; the exit status is non-zero on any mismatch or dropped frame.\n\
A device without a camera of its own (simulate-device without --camera) answers NoCamera: send it\n\
frames with `brightpix stream` instead."
)]
pub struct CaptureArgs {
    /// Serial port of the device (/dev/ttyACM0, /dev/pts/N, COM3) or unix:PATH.
    #[arg(long)]
    port: String,
    /// Frames to record.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    count: u32,
    /// Output: .npy (with .flux.npy, .valid.npy, .json beside it), .fits or .csv.
    #[arg(long, required_unless_present = "verify")]
    out: Option<PathBuf>,
    /// Slopes layout: pairs (frames, sub-apertures, 2) or vector (frames, 2 x sub-apertures).
    #[arg(long, value_enum, default_value_t = Layout::Pairs)]
    layout: Layout,
    /// Upload this configuration first (otherwise the device's active one is used).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Check every result against the reference on the frames of the simulated camera
    /// (simulate-device --camera sim:SEED); needs --config.
    #[arg(long, requires = "config")]
    verify: bool,
    /// Seed of the simulated camera, for --verify (as in --camera sim:SEED).
    #[arg(long, default_value_t = 1, requires = "verify")]
    seed: u64,
    /// Mismatches to print with --verify.
    #[arg(long, default_value_t = 10)]
    show: usize,
    #[command(flatten)]
    live: super::view::ViewFlag,
}

pub fn run(args: CaptureArgs) -> Result<()> {
    let inputs: Vec<&std::path::Path> = args.config.as_deref().into_iter().collect();
    let outputs: Vec<&std::path::Path> = args.out.as_deref().into_iter().collect();
    check_result_outputs(&inputs, &outputs)?;
    let config = args
        .config
        .as_deref()
        .map(ProcessingConfig::load)
        .transpose()?;
    let mut verifier = match &config {
        Some(c) if args.verify => {
            Some(Verifier::new(&c.view(), args.show).context("configuration")?)
        }
        _ => None,
    };
    let live = args.live.start()?;
    let mut client = Client::open(&args.port)?;
    let mut provenance = None;
    if let (Some(path), Some(config)) = (&args.config, &config) {
        let done = client.configure(&config.view())?;
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
    // The view needs the geometry: --config's. A simulated camera's frames
    // (--verify --seed) are remade for display, off the data path.
    let live_n = config.as_ref().map(|c| c.windows.len());
    let _pixel_maker = match (&live, &config) {
        (Some(live), Some(c)) => {
            let mut setup = crate::view::Setup::new(
                format!("capture from the camera of the device at {}", args.port),
                args.config
                    .as_deref()
                    .unwrap_or(std::path::Path::new(""))
                    .display()
                    .to_string(),
                c.clone(),
            );
            // With a crop the frames shown would be the rectangle's own
            // simulation, not the sensor's cut: none shown.
            setup.pixels = args.verify && c.crop.is_none();
            live.hub.set_setup(setup);
            live.hub
                .set_health(crate::view::Health::from_status(&status));
            (args.verify && c.crop.is_none()).then(|| {
                crate::view::device::PixelMaker::start(live.hub.clone(), c.camera, args.seed)
            })
        }
        (Some(live), None) => {
            live.hub.set_message(Some(
                "capture without --config: the view cannot draw the sub-apertures (give --config)"
                    .into(),
            ));
            None
        }
        _ => None,
    };

    let progress = super::progress::Progress::new(u64::from(args.count), "frames");
    let started = Instant::now();
    let mut first_arrival = None;
    let mut last_arrival = started;
    let captured = client.capture_with(args.count, &mut |o| {
        let now = Instant::now();
        first_arrival.get_or_insert(now);
        last_arrival = now;
        if matches!(o, FrameOutcome::Done(_)) {
            progress.inc(1);
        }
        if let (Some(live), Some(n)) = (&live, live_n) {
            crate::view::offer_outcome(&live.hub, o, n, None);
        }
    });
    progress.finish();
    let seconds = started.elapsed().as_secs_f64().max(1e-9);
    let (outcomes, error) = match captured {
        Ok(o) => (o, None),
        Err(i) if i.received.is_empty() => {
            if let LinkError::Device {
                error: DeviceError::NoCamera,
                ..
            } = &i.error
            {
                bail!(
                    "the device at {} has no camera of its own, or its camera refused the configured one ({}): \
                     start a simulated device with `brightpix simulate-device --camera sim`, or send frames with `brightpix stream`",
                    args.port,
                    i.error
                );
            }
            return Err(i.error.into());
        }
        Err(i) => (i.received, Some(i.error)),
    };
    let n = config.as_ref().map_or_else(
        || {
            outcomes
                .iter()
                .flat_map(|o| o.slopes().slopes.iter())
                .map(|s| s.index as usize + 1)
                .max()
                .unwrap_or(0)
        },
        |c| c.windows.len(),
    );
    let mut results = Results::new(n);
    let mut dropped = 0;
    let mut invalid = super::all_invalid::InvalidFrames::default();
    for o in &outcomes {
        dropped += usize::from(!matches!(o, FrameOutcome::Done(_)));
        invalid.outcome(o, n);
        for s in o.slopes().by_index(n) {
            results.push(s.map(Raw::from));
        }
    }
    if let Some(out) = &args.out {
        write_results(out, &results, &provenance, args.layout)?;
    }
    let done = outcomes.len() - dropped;
    // The steady rate: between the first frame's arrival and the last's.
    let steady = match first_arrival {
        Some(first) if done > 1 => {
            let span = (last_arrival - first).as_secs_f64();
            format!(
                ", {:.1} frames/s after the first",
                (outcomes.len() - 1) as f64 / span.max(1e-9)
            )
        }
        _ => String::new(),
    };
    eprintln!(
        "brightpix: {done} frames captured ({dropped} dropped) x {n} sub-apertures in {seconds:.3} s: {:.2} frames/s{steady}{}",
        outcomes.len() as f64 / seconds,
        args.out
            .as_ref()
            .map(|p| format!("; written to {}", p.display()))
            .unwrap_or_default()
    );
    invalid.warn();
    // The board's camera counters run since boot: what this capture added.
    let after = client.status().ok();
    if let (Some(live), Some(after)) = (&live, &after) {
        live.hub.set_health(crate::view::Health::from_status(after));
    }
    if let Some(line) = after.and_then(|a| {
        camera_counters_during(status.health.camera_interface, a.health.camera_interface)
    }) {
        eprintln!("brightpix: {line}");
    }
    if let (Some(verifier), Some(config)) = (&mut verifier, &config) {
        let last = outcomes
            .iter()
            .map(|o| o.frame())
            .max()
            .map_or(0, |f| f + 1);
        let frames = simulated_frames(config, args.seed, last as usize);
        verify_outcomes(verifier, &frames, 0, &outcomes);
        super::stream::print_verification(verifier, args.count as usize);
    }
    if let Some(e) = error {
        bail!("the capture stopped early (the frames received were kept): {e}");
    }
    if let Some(verifier) = &verifier {
        if verifier.mismatch_count > 0 {
            bail!(
                "the device's results differ from the reference on the simulated camera's frames (seed {0}): is the device's camera sim:{0}?",
                args.seed
            );
        }
        if verifier.frames_verified != u64::from(args.count) {
            bail!(
                "only {} of the {} frames requested were verified",
                verifier.frames_verified,
                args.count
            );
        }
        if !verifier.all_match() {
            bail!(
                "the device dropped or lost {} frames: its camera ran faster than it kept up with (a lower --camera-fps on simulate-device helps)",
                verifier.frames_failed
            );
        }
    }
    Ok(())
}

/// The camera interface's counters during a capture (`after - before`),
/// for a board that reports them.
fn camera_counters_during(
    before: Option<CameraInterface>,
    after: Option<CameraInterface>,
) -> Option<String> {
    let (b, a) = (before?, after?);
    Some(format!(
        "camera interface during this capture: overruns {}, sync errors {}, DMA transfer errors {}, DMA FIFO errors {}, FIFO not drained at frame end {}",
        a.overruns.wrapping_sub(b.overruns),
        a.sync_errors.wrapping_sub(b.sync_errors),
        a.dma_transfer_errors.wrapping_sub(b.dma_transfer_errors),
        a.dma_fifo_errors.wrapping_sub(b.dma_fifo_errors),
        a.fifo_not_drained.wrapping_sub(b.fifo_not_drained),
    ))
}

/// The first `count` frames a simulated camera of `seed` gives a device
/// configured with `config`: with a crop (`[camera.crop]`, a board of a
/// rig), the whole sensor's frames cut to the rectangle, as the device's
/// camera interface cuts them (PROTOCOL.md §9).
fn simulated_frames(config: &ProcessingConfig, seed: u64, count: usize) -> Vec<Vec<u16>> {
    let Some(crop) = config.crop else {
        return CameraFrames::new(config.camera, seed).frames(0, count);
    };
    let sensor = crop.sensor(config.camera);
    let rectangle = crate::rig::Rectangle {
        x: crop.x,
        y: crop.y,
        width: config.camera.width,
        height: config.camera.height,
    };
    CameraFrames::new(sensor, seed)
        .frames(0, count)
        .iter()
        .map(|frame| rectangle.crop(frame, usize::from(sensor.width)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_counters_are_the_captures_own() {
        let at = |overruns, fifo| CameraInterface {
            overruns,
            sync_errors: 0,
            dma_transfer_errors: 0,
            dma_fifo_errors: 1,
            fifo_not_drained: fifo,
        };
        let line = camera_counters_during(Some(at(7, 2)), Some(at(9, 2))).unwrap();
        assert!(
            line.contains("overruns 2,")
                && line.contains("DMA FIFO errors 0,")
                && line.ends_with("frame end 0"),
            "{line}"
        );
        assert_eq!(camera_counters_during(None, Some(at(1, 1))), None);
    }
}
