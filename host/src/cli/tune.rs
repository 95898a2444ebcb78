//! `brightpix tune`: the best rule and N for the user's instrument.

use crate::config_file::ProcessingConfig;
use crate::evaluation::tune::{
    jobs_per_class, output, parse_score, plan, pupil_mse, tune, Criterion, Lgs, Prepared,
    PupilModel, TuneRequest, WfeRequest,
};
use crate::evaluation::Axis;
use crate::simulator::{SimulationParams, SpotModel};
use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(Args)]
#[command(
    about = "Simulate your instrument and write a configuration with the best rule and N (per class of sub-apertures)",
    after_help = "The configuration gives the windows (their size, and their position in the pupil); the\n\
options give the conditions (CANARY defaults), or --frames measures them in recorded frames.\n\
Candidates: subtract-next, threshold, subtract-mean M = 2, 4, 8 (and, with --level-filter G, each\n\
subtracting rule with that filter), every N from 1 to all pixels. The rule is one per\n\
configuration; N is chosen per class of sub-apertures (same window size, lit fraction and, for a\n\
LGS, similar distance to the launch position and elongation azimuth). Sub-apertures lit below\n\
--illumination-threshold are dark: left out of the output (--keep-dark keeps them).\n\
R is the paper's metric (eq. 1): for a LGS along the elongation (the paper's choice; --score\n\
pooled for x and y pooled). Everything assumed is printed and written into the output TOML\n\
(a comment block and a [tuned] table that the loader ignores). Spots that lose more than\n\
--max-truncation of their light outside the window make tune exit non-zero (after writing).\n\n\
Examples:\n  brightpix tune --config examples/canary.toml --out tuned\n  brightpix tune --config examples/canary.toml --obscuration 1.2 --read-noise 6 --level-filter 4 --out tuned\n  brightpix tune --config examples/canary.toml --lgs rayleigh:1000 --launch 0,0 --out tuned --name lgs\n  brightpix tune --config examples/canary.toml --pixel-scale 1.5 --photons 1000 --lgs sodium:8000 --launch 21,0 --out na\n  brightpix tune --config examples/canary.toml --frames recorded.fits --out tuned"
)]
pub struct TuneArgs {
    /// Processing configuration whose windows are tuned (TOML).
    #[arg(long)]
    config: PathBuf,
    /// Output directory (created; must not be an existing file).
    #[arg(long)]
    out: PathBuf,
    /// Name of the written configuration (`OUT/NAME.toml`).
    #[arg(long, default_value = "tuned")]
    name: String,
    /// Recorded frames (.npy, FITS cube or AOT file of the configured camera): estimate signal per
    /// sub-aperture, background, read noise and spot size (r0) from them instead of the
    /// --photons, --read-noise, --background-error and --r0 options.
    #[arg(long, value_name = "PATH")]
    frames: Option<PathBuf>,
    /// With --frames of an AOT file (.aot.fits): the UID of the Shack-Hartmann sensor whose
    /// detector pixel intensities to read (default: the file's only sensor).
    #[arg(long, value_name = "NAME", requires = "frames")]
    sensor: Option<String>,
    /// Fried parameter r0 (m) at 500 nm.
    #[arg(long, default_value_t = 0.125)]
    r0: f64,
    /// Outer scale L0 (m); `inf` for Kolmogorov.
    #[arg(long, default_value_t = 30.0)]
    outer_scale: f64,
    /// Detected photons per fully lit sub-aperture per frame.
    #[arg(long, default_value_t = 200.0)]
    photons: f64,
    /// Read noise (e- rms).
    #[arg(long, default_value_t = 2.0)]
    read_noise: f64,
    /// Camera gain (e- per count).
    #[arg(long, default_value_t = 1.0)]
    gain: f64,
    /// Error of the background subtraction (counts): a constant left after calibration.
    #[arg(long, default_value_t = 0.0)]
    background_error: f64,
    /// Detector pixel scale (arcsec/pixel).
    #[arg(long, default_value_t = 0.22)]
    pixel_scale: f64,
    /// WFS wavelength (m).
    #[arg(long, default_value_t = 640e-9)]
    wavelength: f64,
    /// Airy diameter (to the first dark ring) of the lenslet spot (arcsec).
    #[arg(long, default_value_t = 0.7)]
    airy: f64,
    /// How the Airy diameter and the wavelength are reconciled: effective-wavelength (the
    /// paper's stated spot), wfs-wavelength (diffraction at the WFS wavelength, --airy
    /// ignored), wfs-wavelength-blurred (WFS wavelength plus an optics blur up to --airy).
    #[arg(long, default_value = "effective-wavelength")]
    spot_model: String,
    /// Telescope diameter (m).
    #[arg(long, default_value_t = 4.2)]
    telescope: f64,
    /// Central obscuration diameter (m).
    #[arg(long, default_value_t = 0.0)]
    obscuration: f64,
    /// Sub-apertures lit below this fraction of their area are dark (not tuned, left out).
    #[arg(long, default_value_t = 0.5)]
    illumination_threshold: f64,
    /// Keep dark sub-apertures in the output (with the median tuned N).
    #[arg(long)]
    keep_dark: bool,
    /// Sub-apertures across the pupil (default: the grid's columns, else 7).
    #[arg(long)]
    subapertures_across: Option<u32>,
    /// Laser guide star: rayleigh:DEPTH[:ALTITUDE] or sodium:SEPARATION[:ALTITUDE] (metres).
    #[arg(long)]
    lgs: Option<String>,
    /// Launch position in pupil coordinates (m, from the pupil centre), X,Y.
    #[arg(long, default_value = "0,0", allow_hyphen_values = true)]
    launch: String,
    /// Unelongated LGS spot FWHM (arcsec).
    #[arg(long, default_value_t = 0.28)]
    lgs_spot: f64,
    /// What R is scored on: along (the elongation; default for a LGS) or pooled (x and y; default
    /// for a NGS).
    #[arg(long)]
    score: Option<String>,
    /// Also try each subtracting rule with a level filter of this gain shift (1..=16).
    #[arg(long, value_name = "G")]
    level_filter: Option<u8>,
    /// Distance classes for a LGS (>= 1).
    #[arg(long, default_value_t = 4)]
    classes: usize,
    /// Elongation azimuth classes over 0-45 degrees for a LGS (>= 1).
    #[arg(long, default_value_t = 2)]
    angle_classes: usize,
    /// Frames simulated per class (>= 20).
    #[arg(long, value_name = "N", default_value_t = 4000)]
    count: usize,
    /// Largest fraction of a spot's light allowed outside its window (a NGS spot at the
    /// paper's defaults loses 2.6% in Airy rings and seeing halo).
    #[arg(long, default_value_t = 0.05)]
    max_truncation: f64,
    /// Exit 0 even when spots are truncated by their window.
    #[arg(long)]
    allow_truncation: bool,
    /// Seed of the random streams.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// What the tuned N minimises: r (the paper's slope error R, per class of sub-apertures) or
    /// wfe (the on-axis residual wavefront error of an end-to-end open-loop MOAO simulation
    /// through a layered atmosphere, one N for every window; NGS only; see `brightpix endtoend`
    /// and the options below). An option that only the other criterion uses is refused: with
    /// wfe, --count, --score, --classes, --angle-classes, --launch, --lgs-spot, --keep-dark,
    /// --max-truncation and --allow-truncation; with r, the end-to-end options below.
    #[arg(long, default_value = "r")]
    criterion: String,
    #[command(flatten)]
    endtoend: super::endtoend::ConditionArgs,
}

fn parse_launch(text: &str) -> Result<[f64; 2]> {
    let parts: Vec<&str> = text.split(',').collect();
    if parts.len() != 2 {
        bail!("--launch {text:?}: expected X,Y in metres");
    }
    let x: f64 = parts[0].trim().parse().context("--launch X")?;
    let y: f64 = parts[1].trim().parse().context("--launch Y")?;
    if !(x.is_finite() && y.is_finite()) {
        bail!("--launch {text:?}: X and Y must be finite");
    }
    Ok([x, y])
}

/// Checks the output location before any work.
fn check_out(out: &Path, name: &str) -> Result<()> {
    if out.exists() && !out.is_dir() {
        bail!(
            "--out {}: exists and is not a directory (tune writes several files into a directory)",
            out.display()
        );
    }
    output::check_name(name).context("--name")?;
    std::fs::create_dir_all(out).with_context(|| format!("--out {}", out.display()))?;
    let probe = out.join(format!(".{name}.write-test"));
    std::fs::write(&probe, b"")
        .with_context(|| format!("--out {}: not writable", out.display()))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

/// Everything checked and derived before the simulation starts.
struct Setup {
    config: ProcessingConfig,
    prepared: Prepared,
}

/// The request the options make; refused, like the rest, before any work.
fn request(args: &TuneArgs) -> Result<TuneRequest> {
    let spot_model = SpotModel::parse(&args.spot_model).ok_or_else(|| {
        anyhow!(
            "--spot-model {:?}: one of effective-wavelength, wfs-wavelength, wfs-wavelength-blurred",
            args.spot_model
        )
    })?;
    let lgs = args.lgs.as_deref().map(Lgs::parse).transpose()?;
    let score = args
        .score
        .as_deref()
        .map(parse_score)
        .transpose()
        .context("--score")?;
    let request = TuneRequest {
        params: SimulationParams {
            telescope_diameter_m: args.telescope,
            pixel_scale_arcsec: args.pixel_scale,
            wavelength_m: args.wavelength,
            airy_diameter_arcsec: args.airy,
            spot_model,
            r0_m: args.r0,
            outer_scale_m: args.outer_scale,
            photons: args.photons,
            read_noise_e: args.read_noise,
            gain_e_per_count: args.gain,
            background_error: args.background_error,
            ..SimulationParams::canary()
        },
        subapertures_across: args.subapertures_across,
        lgs,
        launch_m: parse_launch(&args.launch)?,
        lgs_spot_fwhm_arcsec: args.lgs_spot,
        pupil: PupilModel {
            obscuration_m: args.obscuration,
            illumination_threshold: args.illumination_threshold,
        },
        score,
        level_filter: args.level_filter,
        frames: args.count,
        seed: args.seed,
        classes: args.classes,
        angle_classes: args.angle_classes,
        max_truncation: args.max_truncation,
    };
    request.check()?;
    Ok(request)
}

fn setup(args: &TuneArgs, request: &TuneRequest) -> Result<Setup> {
    if let Some(path) = &args.frames {
        if !path.is_file() {
            bail!(
                "--frames {}: no such file (recorded frames, .npy or FITS; the number of simulated frames per class is --count)",
                path.display()
            );
        }
    }
    check_out(&args.out, &args.name)?;
    let config = ProcessingConfig::load(&args.config)?;
    let recorded = match &args.frames {
        Some(path) => Some(
            crate::io::FrameSource::open_sensor(path, None, args.sensor.as_deref())
                .and_then(|mut source| {
                    source.set_camera(&config.camera)?;
                    source.read_all()
                })
                .with_context(|| format!("--frames {}", path.display()))?,
        ),
        None => None,
    };
    let prepared = request.prepare(&config, recorded.as_ref())?;
    Ok(Setup { config, prepared })
}

/// Refuses an option of the other criterion among those `given` on the
/// command line (clap's ids), which that criterion would ignore.
fn refuse_other_criterion(criterion: Criterion, given: &[String]) -> Result<()> {
    for id in given {
        let flag = format!("--{}", id.replace('_', "-"));
        if id == "allow_truncation" && criterion == Criterion::Wfe {
            bail!("{flag}: criterion wfe does not check the spots' truncation");
        }
        // The library names the simulated frames per class `frames`; here
        // `--frames` is the recorded frames, which both criteria use.
        let name = match id.as_str() {
            "count" => "frames",
            "frames" => continue,
            other => other,
        };
        criterion.check_given(&[name]).context(flag)?;
    }
    Ok(())
}

/// `given`: the ids of the options given on the command line (the others
/// took their defaults).
pub fn run(args: TuneArgs, given: &[String]) -> Result<()> {
    let criterion = Criterion::parse(&args.criterion)?;
    refuse_other_criterion(criterion, given)?;
    let request = request(&args)?;
    // The end-to-end conditions, checked with the rest before any work.
    let endtoend = match criterion {
        Criterion::R => None,
        Criterion::Wfe => {
            let wfe = WfeRequest {
                tune: request.clone(),
                endtoend: args.endtoend.conditions()?,
            };
            wfe.check()?;
            Some(wfe.endtoend)
        }
    };
    let setup = setup(&args, &request)?;
    let recorded_from = args
        .frames
        .as_ref()
        .map_or(String::new(), |p| p.display().to_string());
    let lines = setup.prepared.assumptions(&recorded_from, criterion);
    for l in &lines {
        eprintln!("brightpix: tune: {l}");
    }
    if let Some(conditions) = &endtoend {
        return wfe_tune::run(&args, &setup, &lines, conditions);
    }
    let planned = plan(
        &setup.config,
        &setup.prepared.conditions,
        &setup.prepared.options,
    )?;
    let total_jobs: usize = planned
        .classes
        .iter()
        .map(|c| jobs_per_class(c.size, &setup.prepared.options.methods))
        .sum();
    let frames = setup.prepared.options.frames;
    let per_job = frames as f64
        / jobs_per_class(planned.classes[0].size, &setup.prepared.options.methods) as f64;
    let bar = ProgressBar::new((frames * planned.classes.len() * 2) as u64);
    bar.set_style(
        ProgressStyle::with_template("tune [{elapsed_precise}] {wide_bar} {percent:>3}% eta {eta}")
            .expect("valid template"),
    );
    eprintln!(
        "brightpix: tune: {} sub-apertures ({} dark) in {} class(es), {} candidate rules, {} engine runs of {} frames",
        setup.config.windows.len(),
        planned.dark.len(),
        planned.classes.len(),
        setup.prepared.options.methods.len(),
        total_jobs,
        frames
    );
    let result = tune(
        &setup.config,
        &setup.prepared.conditions,
        &setup.prepared.options,
        args.keep_dark,
        &|frames, jobs| {
            bar.inc(frames as u64 + (jobs as f64 * per_job).round() as u64);
        },
    )?;
    bar.finish_and_clear();

    let written = output::write(&args.out, &args.name, &setup.prepared, &result, &lines)?;

    let axis = setup.prepared.conditions.score_axis;
    let classes = &result.plan.classes;
    let mut report = String::new();
    writeln!(
        report,
        "rule: {} (pupil RMS R {} at each class's best N: {}; the first (simplest) rule within 1% or 2 paired standard errors of the best is kept)",
        result.method.label(),
        axis.name(),
        setup
            .prepared
            .options
            .methods
            .iter()
            .map(|&m| format!("{} {:.4}", m.label(), pupil_mse(classes, m, axis).sqrt()))
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    writeln!(
        report,
        "{:>5} {:>5} {:>5} {:>13} {:>7} {:>5} {:>9} {:>9} {:>9} {:>9} {:>9} {:>7}",
        "class",
        "subap",
        "lit",
        "distance (m)",
        "angle",
        "N",
        "R",
        "R_along",
        "R_across",
        "R all px",
        "R current",
        "in win"
    )?;
    for (k, c) in classes.iter().enumerate() {
        let chosen = c.chosen.as_ref().expect("tuned");
        let r = chosen.r(axis);
        let all = c.all_pixels().map_or(f64::NAN, |s| s.r(axis).value);
        let current = c
            .current
            .as_ref()
            .map_or("-".to_string(), |s| format!("{:.4}", s.r(axis).value));
        writeln!(
            report,
            "{:>5} {:>5} {:>5} {:>13} {:>7.1} {:>5} {:>9.4} {:>9.4} {:>9.4} {:>9.4} {:>9} {:>7.3}",
            k,
            c.members.len(),
            format!("{:.2}", c.placement.lit_fraction),
            format!("{:.2}-{:.2}", c.min_distance_m, c.max_distance_m),
            c.placement.angle_deg,
            format!(
                "{}{}",
                chosen.pixels,
                if chosen.all_pixels { "*" } else { "" }
            ),
            r.value,
            chosen.r(Axis::Along).value,
            chosen.r(Axis::Across).value,
            all,
            current,
            c.field_fraction
        )?;
    }
    writeln!(
        report,
        "(R in pixels, {} frames per class; * = all pixels; angle = elongation azimuth of the simulated member; in win = light inside the window; R current = the input configuration's rule and N)",
        frames
    )?;
    if !result.plan.dark.is_empty() {
        writeln!(
            report,
            "dark sub-apertures (lit below {}): windows {:?}: {}",
            setup.prepared.conditions.pupil.illumination_threshold,
            result.plan.dark,
            if args.keep_dark {
                "kept with the median N"
            } else {
                "left out of the tuned configuration"
            }
        )?;
    }
    print!("{report}");
    eprintln!(
        "brightpix: wrote {}, {} and {}",
        written.config.display(),
        written.scores.display(),
        written
            .plots
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    if let Some(msg) = result.truncation(setup.prepared.options.max_truncation) {
        if args.allow_truncation {
            eprintln!("brightpix: tune: warning: {msg}");
        } else {
            bail!("{msg} (files written; --allow-truncation to accept)");
        }
    }
    Ok(())
}

mod wfe_tune;

#[cfg(test)]
mod tests;
