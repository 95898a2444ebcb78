//! `brightpix stream`: send recorded frames to a device whose camera the
//! host emulates, collect its slopes, optionally verify every one.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;

use crate::config_file::ProcessingConfig;
use crate::io::results::{complete_streamed, remove_stale_companions};
use crate::io::{
    check_result_outputs, Appender, FrameSource, IoError, Layout, Provenance, Raw, Results,
    ResultsFormat,
};
use crate::link::verify::Verifier;
use crate::link::{Client, FrameOutcome, PixelSink};
use crate::sil::verify_outcomes;
use crate::sim_device::{catch_interrupts, interrupted};

use super::all_invalid::InvalidFrames;

#[derive(Args)]
#[command(
    about = "Configure a device, stream frames (.npy or FITS) to it, collect its slopes, optionally verify them bit for bit",
    after_help = "Examples:\n  brightpix stream --port /dev/pts/4 --config examples/canary.toml --frames frames.npy --verify\n  brightpix stream --port /dev/ttyACM0 --config examples/canary.toml --frames frames.fits --out slopes.npy\n  brightpix stream --port /dev/ttyACM0 --config examples/canary.toml --frames frames.npy --count 100 --out slopes.fits --layout vector\n  brightpix stream --port /dev/pts/5 --config examples/canary.toml --frames f.npy --verify --pixels-fifo /tmp/bp/pixels.fifo\n\n\
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
    /// Frames: .npy (uint8/uint16, shape (frames, height, width)) or FITS cube (the first HDU
    /// holding an image, tile-compressed included; BSCALE/BZERO applied).
    #[arg(long, value_name = "PATH")]
    frames: PathBuf,
    /// FITS HDU of the frames: an index (0: primary) or EXTNAME (default: the first image).
    #[arg(long, value_name = "HDU")]
    hdu: Option<String>,
    /// Check every result against the reference implementation.
    #[arg(long)]
    verify: bool,
    /// Write slopes, flux, validity and provenance (.npy set, FITS or CSV as `process`; NaN where
    /// dropped). .npy and FITS slopes are written frame by frame as they arrive: after Ctrl-C or a
    /// kill the file holds every frame received; flux, validity and provenance follow at the end.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Slopes layout of --out: pairs (frames, sub-apertures, 2) or vector (frames, 2 x
    /// sub-apertures), [x_0..x_S-1, y_0..y_S-1] as AO codes (DARC, COMPASS, soapy) take them.
    #[arg(long, value_enum, default_value_t = Layout::Pairs, requires = "out")]
    layout: Layout,
    /// Send pixels through this FIFO instead of the link.
    #[arg(long, value_name = "PATH")]
    pixels_fifo: Option<PathBuf>,
    /// Stream only the first N frames of the file.
    #[arg(long, value_name = "N")]
    count: Option<usize>,
    /// Mismatches to print.
    #[arg(long, default_value_t = 10)]
    show: usize,
    /// Do not upload --config: the device already runs it. Its active configuration's digest
    /// must equal --config's (refused otherwise, unless --force).
    #[arg(long)]
    no_configure: bool,
    /// With --no-configure: stream even if the device's configuration differs from --config.
    #[arg(long, requires = "no_configure")]
    force: bool,
    #[command(flatten)]
    live: super::view::ViewFlag,
}

/// Frames read and streamed at a time.
const BATCH: usize = 256;

pub fn run(args: StreamArgs) -> Result<()> {
    if let Some(out) = &args.out {
        check_result_outputs(&[&args.config, &args.frames], &[out])?;
    }
    if args.count == Some(0) {
        bail!("--count must be at least 1");
    }
    let config = ProcessingConfig::load(&args.config)?;
    let view = config.view();
    let mut source = FrameSource::open_hdu(&args.frames, args.hdu.as_deref())?;
    source.set_camera(&view.camera)?;
    let total = args.count.unwrap_or(usize::MAX).min(source.len());
    let subapertures = view.windows.len();
    let mut verifier = Verifier::new(&view, args.show).context("configuration")?;
    let live = args.live.start()?;
    catch_interrupts();
    let mut client = Client::open(&args.port)?;
    client.set_interrupt(Some(interrupted));
    if args.no_configure {
        check_active_configuration(&mut client, &view, &args.config, args.force)?;
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
    if let Some(live) = &live {
        let mut setup = crate::view::Setup::new(
            format!(
                "stream of {} to {}",
                args.frames.display(),
                client.port_name()
            ),
            args.config.display().to_string(),
            config.clone(),
        );
        setup.pixels = true;
        live.hub.set_setup(setup);
    }
    // Slopes go to the file as they arrive: it holds every frame received
    // so far at any moment, even if this process is killed.
    let mut out = match &args.out {
        Some(path) => Some(SlopesFile::create(path, subapertures, args.layout)?),
        None => None,
    };
    let progress = super::progress::Progress::new(total as u64, "frames");
    let mut tally = Tally::default();
    let mut invalid = InvalidFrames::default();
    let mut elapsed = std::time::Duration::ZERO;
    let mut first = 0;
    let mut failure = None;
    // The configuration the device runs as the stream starts (--config's,
    // unless --force streams to another on purpose).
    let expected_digest = client
        .status()
        .context("asking the device for its active configuration")?
        .config_digest;
    // Frames streamed while the device ran this configuration for certain.
    let mut trusted = 0usize;
    let mut taken_over = None;
    while first < total {
        let count = BATCH.min(total - first);
        let mut batch = vec![Vec::new(); count];
        for (k, frame) in batch.iter_mut().enumerate() {
            source.read_frame_into(first + k, frame)?;
        }
        let mut outcomes = Vec::with_capacity(count);
        let mut write_error = None;
        let batch_started = std::time::Instant::now();
        let result = client.stream_frames(first as u32, &batch, |o| {
            if let Some(out) = &mut out {
                if let Err(e) = out.push(&o, subapertures) {
                    write_error.get_or_insert(e);
                }
            }
            progress.inc(1);
            if let Some(live) = &live {
                let k = o.frame().wrapping_sub(first as u32) as usize;
                crate::view::offer_outcome(
                    &live.hub,
                    &o,
                    subapertures,
                    batch.get(k).map(Vec::as_slice),
                );
            }
            outcomes.push(o);
        });
        if let Some(e) = write_error {
            return Err(e.into());
        }
        outcomes.sort_by_key(FrameOutcome::frame);
        for o in &outcomes {
            tally.count(o);
            invalid.outcome(o, subapertures);
        }
        let sent = match &result {
            Ok(report) => report.frames_sent,
            Err(_) => outcomes.len(),
        };
        if args.verify {
            verify_outcomes(&mut verifier, &batch[..sent], first as u32, &outcomes);
        }
        match result {
            Ok(report) => elapsed += report.elapsed,
            Err(e) => {
                elapsed += batch_started.elapsed();
                failure = Some(e);
                break;
            }
        }
        // Another program on the port (one that does not take the lock:
        // pyserial does not) can start a session and upload another
        // configuration: the slopes would then be its configuration's. The
        // digest is checked after every batch, so the frames before the
        // last good check are known to be this configuration's.
        let status = client.status();
        if let (Some(live), Ok(status)) = (&live, &status) {
            live.hub
                .set_health(crate::view::Health::from_status(status));
        }
        match status {
            Ok(status) if status.config_digest == expected_digest => trusted = first + count,
            Ok(status) => {
                let digest = |d: Option<u32>| d.map_or("none".into(), |d| format!("{d:#010x}"));
                taken_over = Some(format!(
                    "the device's configuration changed during the stream (digest {}, was {}): another client took the device over; only the first {trusted} frames written are of the configuration the stream started with",
                    digest(status.config_digest),
                    digest(expected_digest),
                ));
                break;
            }
            Err(e) => {
                failure = Some(e);
                break;
            }
        }
        first += count;
    }
    progress.finish();
    if let Some(live) = &live {
        let ended = match (&failure, &taken_over) {
            (Some(e), _) => format!("the stream stopped: {e}"),
            (None, Some(problem)) => problem.clone(),
            (None, None) => format!(
                "the stream ended after {} frames",
                tally.done + tally.dropped
            ),
        };
        live.hub.set_message(Some(ended));
    }
    if let Some(out) = out {
        let mut provenance = Provenance::of("brightpix stream (device)", &view, Some(&args.config));
        provenance.frames_source = Some(args.frames.display().to_string());
        provenance.config_id = client.status().ok().and_then(|s| s.config_id);
        if taken_over.is_some() {
            provenance.trusted_frames = Some(trusted as u64);
        }
        let path = args.out.as_deref().unwrap_or(Path::new(""));
        let written = out.finish(path, &provenance)?;
        eprintln!(
            "brightpix: {} holds the slopes of {written} frames ({} complete, {} dropped, {} incomplete; NaN where the device sent nothing)",
            args.out.as_deref().unwrap_or(Path::new("")).display(),
            tally.done,
            tally.dropped,
            tally.incomplete
        );
    }
    println!(
        "streamed {} of {total} frames of {} to {} ({} dropped, {} incomplete) in {:.3} s: {:.0} frames/s, {:.0} us/frame",
        tally.done,
        args.frames.display(),
        client.port_name(),
        tally.dropped,
        tally.incomplete,
        elapsed.as_secs_f64(),
        tally.done as f64 / elapsed.as_secs_f64().max(1e-9),
        elapsed.as_secs_f64() * 1e6 / tally.done.max(1) as f64
    );
    invalid.warn();
    if let Some(problem) = taken_over {
        bail!("{problem}");
    }
    if let Some(e) = failure {
        if args.verify {
            print_verification(&verifier, total);
        }
        bail!(
            "streaming stopped after {} of {total} frames: {e}",
            tally.done + tally.dropped
        );
    }
    if let Ok(status) = client.status() {
        println!("{}", super::demo::format_status(&status));
    }
    if args.verify {
        print_verification(&verifier, total);
        if verifier.frames_verified != total as u64 {
            bail!(
                "only {} of the {total} frames requested were verified",
                verifier.frames_verified
            );
        }
        if !verifier.all_match() {
            bail!("the device's results differ from the reference");
        }
    } else if tally.dropped + tally.incomplete > 0 {
        bail!(
            "{} frames were dropped by the device",
            tally.dropped + tally.incomplete
        );
    }
    Ok(())
}

/// `--no-configure`: the device's active configuration must be `--config`'s
/// (their digests, PROTOCOL.md §7, are equal), or every result would differ.
fn check_active_configuration(
    client: &mut Client,
    view: &brightpix_protocol::Config<'_>,
    path: &Path,
    force: bool,
) -> Result<()> {
    let expected = brightpix_protocol::wire::tables::config_digest(view);
    let status = client
        .status()
        .context("asking the device for its active configuration (--no-configure)")?;
    let problem = match status.config_digest {
        Some(digest) if digest == expected => return Ok(()),
        Some(digest) => format!(
            "the device's active configuration (id {:#010x}, digest {digest:#010x}) is not {} (digest {expected:#010x})",
            status.config_id.unwrap_or(0),
            path.display()
        ),
        None => "the device has no active configuration".to_string(),
    };
    if force {
        eprintln!("brightpix: warning: {problem}; streaming anyway (--force)");
        return Ok(());
    }
    bail!(
        "{problem}: drop --no-configure to upload {}, or add --force to stream anyway",
        path.display()
    )
}

pub(super) fn print_verification(verifier: &Verifier, requested: usize) {
    println!(
        "verified {} of {requested} frames, {} sub-aperture results compared with the reference: {} mismatches, {} frames dropped, {} missing",
        verifier.frames_verified,
        verifier.slopes_compared,
        verifier.mismatch_count,
        verifier.frames_dropped,
        verifier.frames_missing
    );
    for m in &verifier.mismatches {
        println!("  mismatch: {m}");
    }
}

/// Frame outcomes by kind.
#[derive(Default)]
struct Tally {
    done: usize,
    dropped: usize,
    incomplete: usize,
}

impl Tally {
    fn count(&mut self, o: &FrameOutcome) {
        match o {
            FrameOutcome::Done(_) => self.done += 1,
            FrameOutcome::Dropped { .. } => self.dropped += 1,
            FrameOutcome::Incomplete(_) => self.incomplete += 1,
        }
    }
}

/// `--out`: one row per frame, in frame order, as each frame's outcome
/// arrives: the slopes appended to the file at once (.npy, FITS), flux and
/// validity kept for the end.
struct SlopesFile {
    /// `None` for CSV, written whole at the end.
    file: Option<Appender>,
    layout: Layout,
    results: Results,
    /// Outcomes that arrived ahead of an earlier frame's.
    waiting: std::collections::BTreeMap<u32, Vec<Option<Raw>>>,
    next: Option<u32>,
}

impl SlopesFile {
    fn create(path: &Path, subapertures: usize, layout: Layout) -> Result<SlopesFile> {
        let row = match layout {
            Layout::Pairs => vec![subapertures, 2],
            Layout::Vector => vec![2 * subapertures],
        };
        // An earlier run's flux, validity and provenance must not stand
        // beside this run's slopes, even if this run is killed.
        remove_stale_companions(path)?;
        let file = match ResultsFormat::from_path(path)? {
            // Written whole at the end: AOT's tables cannot grow in place.
            ResultsFormat::Csv | ResultsFormat::Aot => None,
            _ => Some(Appender::create(path, &row)?),
        };
        Ok(SlopesFile {
            file,
            layout,
            results: Results::new(subapertures),
            waiting: Default::default(),
            next: None,
        })
    }

    fn push(&mut self, o: &FrameOutcome, subapertures: usize) -> Result<(), IoError> {
        let row: Vec<Option<Raw>> = o
            .slopes()
            .by_index(subapertures)
            .into_iter()
            .map(|e| e.map(Raw::from))
            .collect();
        let next = *self.next.get_or_insert(o.frame());
        self.waiting.insert(o.frame(), row);
        let mut next = next;
        while let Some(row) = self.waiting.remove(&next) {
            self.write(row)?;
            next = next.wrapping_add(1);
        }
        self.next = Some(next);
        Ok(())
    }

    fn write(&mut self, row: Vec<Option<Raw>>) -> Result<(), IoError> {
        let before = self.results.slopes.len();
        for raw in row {
            self.results.push(raw);
        }
        match &mut self.file {
            Some(file) => file.append(&self.layout.arrange(&self.results.slopes[before..])),
            None => Ok(()),
        }
    }

    /// Writes what remains; returns the frames the output holds.
    fn finish(mut self, path: &Path, provenance: &Provenance) -> Result<usize, IoError> {
        // Frames whose predecessors never ended (cannot happen: every frame
        // sent gets an outcome), in order.
        for row in std::mem::take(&mut self.waiting).into_values() {
            self.write(row)?;
        }
        if let Some(file) = self.file {
            file.finish()?;
        }
        complete_streamed(path, &self.results, provenance, self.layout)?;
        Ok(self.results.frames())
    }
}
