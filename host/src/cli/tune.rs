//! `brightpix tune`: the best rule and N for the user's instrument.

use crate::config_file::ProcessingConfig;
use crate::evaluation::plot::{self, Marker, Plot, Series, COLORS};
use crate::evaluation::recorded::{measure, shift_and_add_fwhm, Measured};
use crate::evaluation::tune::{
    candidate_methods, jobs_per_class, plan, pupil_mse, tune, Conditions, Lgs, PupilModel,
    TuneOptions, TuneResult,
};
use crate::evaluation::Axis;
use crate::simulator::{SimulationParams, Simulator, SpotModel};
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
    /// and the options below).
    #[arg(long, default_value = "r")]
    criterion: String,
    #[command(flatten)]
    endtoend: super::endtoend::EndToEndConditions,
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
    if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
        bail!("--name {name:?}: must be a plain file name");
    }
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
    conditions: Conditions,
    options: TuneOptions,
    measured: Option<Measured>,
    fitted_r0: Option<(f64, f64, f64)>,
}

fn setup(args: &TuneArgs) -> Result<Setup> {
    if args.count < 20 {
        bail!(
            "--count {}: at least 20 frames per class are needed for a standard error",
            args.count
        );
    }
    if args.classes == 0 {
        bail!("--classes 0: at least one distance class is needed");
    }
    if args.angle_classes == 0 {
        bail!("--angle-classes 0: at least one azimuth class is needed");
    }
    if !(0.0..1.0).contains(&args.max_truncation) {
        bail!(
            "--max-truncation must be in 0..1, got {}",
            args.max_truncation
        );
    }
    if !(0.0..=1.0).contains(&args.illumination_threshold) || args.illumination_threshold == 0.0 {
        bail!(
            "--illumination-threshold must be in (0, 1], got {}",
            args.illumination_threshold
        );
    }
    if let Some(g) = args.level_filter {
        if !(1..=16).contains(&g) {
            bail!("--level-filter must be 1..=16, got {g}");
        }
    }
    let spot_model = SpotModel::parse(&args.spot_model).ok_or_else(|| {
        anyhow!(
            "--spot-model {:?}: one of effective-wavelength, wfs-wavelength, wfs-wavelength-blurred",
            args.spot_model
        )
    })?;
    let lgs = args.lgs.as_deref().map(Lgs::parse).transpose()?;
    let score_axis = match (args.score.as_deref(), lgs.is_some()) {
        (None, true) | (Some("along"), _) => Axis::Along,
        (None, false) | (Some("pooled"), _) => Axis::Both,
        (Some(other), _) => bail!("--score {other:?}: one of along, pooled"),
    };
    let launch_m = parse_launch(&args.launch)?;
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
    let across = args.subapertures_across.unwrap_or_else(|| {
        config
            .grid
            .as_ref()
            .map_or(7, |g| g.grid.columns.max(g.grid.rows) as u32)
    });
    let background = config.background.as_ref().map_or(0.0, |b| {
        b.iter().map(|&v| v as f64).sum::<f64>() / b.len().max(1) as f64 / 16.0
    });
    let mut params = SimulationParams {
        telescope_diameter_m: args.telescope,
        subapertures_across: across,
        pixel_scale_arcsec: args.pixel_scale,
        wavelength_m: args.wavelength,
        airy_diameter_arcsec: args.airy,
        spot_model,
        r0_m: args.r0,
        outer_scale_m: args.outer_scale,
        photons: args.photons,
        read_noise_e: args.read_noise,
        gain_e_per_count: args.gain,
        background,
        background_error: args.background_error,
        bit_depth: config.camera.bit_depth,
        ..SimulationParams::canary()
    };
    params.validate().map_err(|e| anyhow!("conditions: {e}"))?;
    if !(args.lgs_spot.is_finite() && args.lgs_spot >= 0.0) {
        bail!("--lgs-spot must be >= 0, got {}", args.lgs_spot);
    }
    let mut measured_photons = None;
    let mut measured = None;
    let mut fitted_r0 = None;
    if let Some(path) = &args.frames {
        let cube = crate::io::FrameSource::open_sensor(path, None, args.sensor.as_deref())
            .and_then(|mut source| {
                source.set_camera(&config.camera)?;
                source.read_all()
            })
            .with_context(|| format!("--frames {}", path.display()))?;
        let m = measure(&config, &cube, args.gain)?;
        params.read_noise_e = m.read_noise_e;
        params.background_error = m.background_error_counts;
        let mut sorted = m.photons.clone();
        sorted.sort_by(f64::total_cmp);
        params.photons = sorted[sorted.len() * 3 / 4].max(1.0);
        if lgs.is_none() && m.spot_fwhm_px.is_finite() {
            fitted_r0 = Some(fit_r0(&params, &config, &m)?);
            params.r0_m = fitted_r0.expect("just set").0;
        }
        measured_photons = Some(m.photons.clone());
        measured = Some(m);
    }
    let conditions = Conditions {
        params,
        lgs,
        launch_m,
        lgs_spot_fwhm_arcsec: args.lgs_spot,
        pupil: PupilModel {
            obscuration_m: args.obscuration,
            illumination_threshold: args.illumination_threshold,
        },
        score_axis,
        measured_photons,
    };
    let options = TuneOptions {
        frames: args.count,
        seed: args.seed,
        classes: args.classes,
        angle_classes: args.angle_classes,
        methods: candidate_methods(args.level_filter),
        max_truncation: args.max_truncation,
    };
    Ok(Setup {
        config,
        conditions,
        options,
        measured,
        fitted_r0,
    })
}

/// r0 (m, at 500 nm) whose simulated shift-and-add spot (same photons,
/// noise and measure) has the measured FWHM: bisection in log r0 between
/// 2 cm and 1 m, 300 frames per step. Returns (r0, measured FWHM, FWHM of
/// the fit).
fn fit_r0(
    params: &SimulationParams,
    config: &ProcessingConfig,
    m: &Measured,
) -> Result<(f64, f64, f64)> {
    let size = config.windows.first().map_or(16, |w| w.width as usize);
    let fwhm_for = |r0: f64| -> Result<f64> {
        let sim = Simulator::new(SimulationParams {
            r0_m: r0,
            pixels_per_subaperture: size as u32,
            ..params.clone()
        })
        .map_err(|e| anyhow!("{e}"))?;
        let bg = sim.calibration_background() + params.background_error;
        let images: Vec<Vec<f64>> = sim
            .frames(7, 0, 300)
            .iter()
            .map(|f| f.raw.iter().map(|&v| v as f64 - bg).collect())
            .collect();
        Ok(shift_and_add_fwhm(
            images.iter().map(|v| v.as_slice()),
            size,
        ))
    };
    let (mut lo, mut hi) = (0.02f64.ln(), 1.0f64.ln());
    let target = m.spot_fwhm_px;
    let mut best = (params.r0_m, f64::NAN);
    for _ in 0..8 {
        let mid = 0.5 * (lo + hi);
        let f = fwhm_for(mid.exp())?;
        best = (mid.exp(), f);
        // Larger r0, smaller spot.
        if f > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok((best.0, target, best.1))
}

/// The assumptions, one per line (printed and written as TOML comments).
fn assumptions(setup: &Setup, args: &TuneArgs) -> Vec<String> {
    let p = &setup.conditions.params;
    let c = &setup.conditions;
    let mut v = vec![
        format!(
            "telescope {} m, central obscuration {} m, {} sub-apertures across (d = {:.3} m); illumination threshold {}",
            p.telescope_diameter_m,
            c.pupil.obscuration_m,
            p.subapertures_across,
            p.subaperture_diameter_m(),
            c.pupil.illumination_threshold
        ),
        format!(
            "atmosphere: r0 {:.4} m at 500 nm{}, L0 {} m",
            p.r0_m,
            match &setup.fitted_r0 {
                Some((_, measured, fit)) => format!(
                    " (fitted: shift-and-add spot FWHM {measured:.2} px measured, {fit:.2} px simulated)"
                ),
                None => String::new(),
            },
            p.outer_scale_m
        ),
        format!(
            "optics: {} arcsec/pixel, WFS wavelength {} nm, Airy diameter {}\" ({})",
            p.pixel_scale_arcsec,
            p.wavelength_m * 1e9,
            p.airy_diameter_arcsec,
            p.spot_model.name()
        ),
        format!(
            "detector: {} photons per fully lit sub-aperture and frame, read noise {:.3} e-, gain {} e-/count, background {} counts subtracted with an error of {:.3} counts, {} bits",
            p.photons, p.read_noise_e, p.gain_e_per_count, p.background, p.background_error, p.bit_depth
        ),
        match &c.lgs {
            Some(lgs) => format!(
                "guide star: {}, launched at ({}, {}) m in the pupil, unelongated spot FWHM {}\"; elongation radial from the launch position",
                lgs.describe(),
                c.launch_m[0],
                c.launch_m[1],
                c.lgs_spot_fwhm_arcsec
            ),
            None => "guide star: natural (point source)".to_string(),
        },
        format!(
            "scoring: R {}; {} frames per class, seed {}; candidates {}",
            c.score_axis.name(),
            setup.options.frames,
            setup.options.seed,
            setup
                .options
                .methods
                .iter()
                .map(|m| m.label())
                .collect::<Vec<_>>()
                .join(", ")
        ),
        "not modelled: flat field, threshold, lenslet aberrations beyond the spot model; each class is one representative sub-aperture".to_string(),
    ];
    if let Some(m) = &setup.measured {
        v.push(format!(
            "measured from {} ({} frames): read noise {:.3} e- from {} dark pixels ({}); residual background {:.3} counts; signal per sub-aperture {:.1}..{:.1} e- (fully lit: {:.1}); shift-and-add spot FWHM {:.2} px",
            args.frames.as_ref().map_or(String::new(), |p| p.display().to_string()),
            m.frames,
            m.read_noise_e,
            m.dark_pixels,
            m.dark_source,
            m.background_error_counts,
            m.photons.iter().copied().fold(f64::INFINITY, f64::min),
            m.photons.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            p.photons,
            m.spot_fwhm_px
        ));
    }
    v
}

/// The `[tuned]` table and the comment block appended to the TOML.
fn tuned_block(setup: &Setup, result: &TuneResult, lines: &[String]) -> Result<String> {
    let axis = setup.conditions.score_axis;
    let p = &setup.conditions.params;
    let mut t = toml::Table::new();
    let f = |v: f64| toml::Value::Float(v);
    t.insert(
        "tool".into(),
        format!("brightpix tune {}", env!("CARGO_PKG_VERSION")).into(),
    );
    t.insert("rule".into(), result.method.label().into());
    t.insert("score".into(), axis.name().into());
    t.insert(
        "frames_per_class".into(),
        (setup.options.frames as i64).into(),
    );
    t.insert("seed".into(), (setup.options.seed as i64).into());
    t.insert("r0_m".into(), f(p.r0_m));
    t.insert("r0_wavelength_m".into(), f(p.r0_wavelength_m));
    t.insert("outer_scale_m".into(), f(p.outer_scale_m));
    t.insert("photons_fully_lit".into(), f(p.photons));
    t.insert("read_noise_e".into(), f(p.read_noise_e));
    t.insert("gain_e_per_count".into(), f(p.gain_e_per_count));
    t.insert("background_error_counts".into(), f(p.background_error));
    t.insert("pixel_scale_arcsec".into(), f(p.pixel_scale_arcsec));
    t.insert("wavelength_m".into(), f(p.wavelength_m));
    t.insert("airy_diameter_arcsec".into(), f(p.airy_diameter_arcsec));
    t.insert("spot_model".into(), p.spot_model.name().into());
    t.insert("telescope_diameter_m".into(), f(p.telescope_diameter_m));
    t.insert(
        "obscuration_m".into(),
        f(setup.conditions.pupil.obscuration_m),
    );
    t.insert(
        "illumination_threshold".into(),
        f(setup.conditions.pupil.illumination_threshold),
    );
    t.insert(
        "subapertures_across".into(),
        (p.subapertures_across as i64).into(),
    );
    if let Some(lgs) = &setup.conditions.lgs {
        t.insert("lgs".into(), lgs.describe().into());
        t.insert(
            "launch_m".into(),
            toml::Value::Array(setup.conditions.launch_m.iter().map(|&v| f(v)).collect()),
        );
        t.insert(
            "lgs_spot_fwhm_arcsec".into(),
            f(setup.conditions.lgs_spot_fwhm_arcsec),
        );
    }
    t.insert(
        "measured_from_frames".into(),
        setup.measured.is_some().into(),
    );
    t.insert(
        "dark_windows".into(),
        toml::Value::Array(
            result
                .plan
                .dark
                .iter()
                .map(|&i| (i as i64).into())
                .collect(),
        ),
    );
    t.insert("truncated".into(), (!result.truncated.is_empty()).into());
    let classes: Vec<toml::Value> = result
        .plan
        .classes
        .iter()
        .map(|c| {
            let chosen = c.chosen.as_ref().expect("tuned");
            let mut ct = toml::Table::new();
            ct.insert(
                "windows".into(),
                toml::Value::Array(c.members.iter().map(|&i| (i as i64).into()).collect()),
            );
            ct.insert("representative".into(), (c.representative as i64).into());
            ct.insert("N".into(), (chosen.pixels as i64).into());
            ct.insert("R".into(), f(chosen.r(axis).value));
            ct.insert("R_along".into(), f(chosen.r(Axis::Along).value));
            ct.insert("R_across".into(), f(chosen.r(Axis::Across).value));
            ct.insert("lit_fraction".into(), f(c.placement.lit_fraction));
            ct.insert("photons".into(), f(c.photons));
            ct.insert("distance_m".into(), f(c.placement.distance_m));
            ct.insert("elongation_angle_deg".into(), f(c.placement.angle_deg));
            ct.insert("light_in_window".into(), f(c.field_fraction));
            toml::Value::Table(ct)
        })
        .collect();
    t.insert("class".into(), toml::Value::Array(classes));
    let mut outer = toml::Table::new();
    outer.insert("tuned".into(), toml::Value::Table(t));
    let mut s = String::from("\n# ---- brightpix tune: what was assumed (the [tuned] table is ignored by the loader) ----\n");
    for l in lines {
        s.push_str(&format!("# {l}\n"));
    }
    s.push('\n');
    s.push_str(&toml::to_string(&outer).map_err(|e| anyhow!("{e}"))?);
    Ok(s)
}

pub fn run(args: TuneArgs) -> Result<()> {
    let wfe = match args.criterion.as_str() {
        "r" => false,
        "wfe" => true,
        other => bail!("--criterion {other:?}: one of r, wfe"),
    };
    if wfe && args.lgs.is_some() {
        bail!("--criterion wfe: the end-to-end simulation models natural guide stars only (drop --lgs)");
    }
    let setup = setup(&args)?;
    let lines = assumptions(&setup, &args);
    for l in &lines {
        eprintln!("brightpix: tune: {l}");
    }
    if wfe {
        return wfe_tune::run(&args, &setup, &lines);
    }
    let planned = plan(&setup.config, &setup.conditions, &setup.options)?;
    let total_jobs: usize = planned
        .classes
        .iter()
        .map(|c| jobs_per_class(c.size, &setup.options.methods))
        .sum();
    let frames = setup.options.frames;
    let per_job =
        frames as f64 / jobs_per_class(planned.classes[0].size, &setup.options.methods) as f64;
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
        setup.options.methods.len(),
        total_jobs,
        frames
    );
    let result = tune(
        &setup.config,
        &setup.conditions,
        &setup.options,
        args.keep_dark,
        &|frames, jobs| {
            bar.inc(frames as u64 + (jobs as f64 * per_job).round() as u64);
        },
    )?;
    bar.finish_and_clear();

    let path = result.config.save(&args.out, &args.name)?;
    let mut text = std::fs::read_to_string(&path)?;
    text.push_str(&tuned_block(&setup, &result, &lines)?);
    let tmp = path.with_extension("toml.tmp");
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, &path)?;

    let axis = setup.conditions.score_axis;
    let classes = &result.plan.classes;
    let mut report = String::new();
    writeln!(
        report,
        "rule: {} (pupil RMS R {} at each class's best N: {}; the first (simplest) rule within 1% or 2 paired standard errors of the best is kept)",
        result.method.label(),
        axis.name(),
        setup
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
    let mut csv = String::from(
        "class,subapertures,window,representative,lit_fraction,photons,distance_m,angle_deg,light_in_window,method,N,R,se,R_along,R_across\n",
    );
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
        for s in &c.scores {
            let rb = s.r(axis);
            writeln!(
                csv,
                "{k},{},{},{},{:.4},{:.3},{:.3},{:.2},{:.5},{},{},{:.6},{:.6},{:.6},{:.6}",
                c.members.len(),
                c.size,
                c.representative,
                c.placement.lit_fraction,
                c.photons,
                c.placement.distance_m,
                c.placement.angle_deg,
                c.field_fraction,
                s.method.label(),
                s.pixels,
                rb.value,
                rb.se,
                s.r(Axis::Along).value,
                s.r(Axis::Across).value
            )?;
        }
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
            setup.conditions.pupil.illumination_threshold,
            result.plan.dark,
            if args.keep_dark {
                "kept with the median N"
            } else {
                "left out of the tuned configuration"
            }
        )?;
    }
    let csv_path = args.out.join(format!("{}-tune.csv", args.name));
    std::fs::write(&csv_path, csv)?;
    let plots = plot_classes(&result, axis, &args.out.join(format!("{}-tune", args.name)))?;
    print!("{report}");
    eprintln!(
        "brightpix: wrote {}, {} and {}",
        path.display(),
        csv_path.display(),
        plots
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    if !result.truncated.is_empty() {
        let worst = result
            .truncated
            .iter()
            .map(|&k| classes[k].field_fraction)
            .fold(1.0, f64::min);
        let msg = format!(
            "spots are truncated by the sub-aperture: class(es) {:?} keep only {:.1}% of their light in the window (allowed loss {}%); a larger field of view (pixel scale or window) is needed, and the tuned N is not reliable",
            result.truncated,
            100.0 * worst,
            100.0 * setup.options.max_truncation
        );
        if args.allow_truncation {
            eprintln!("brightpix: tune: warning: {msg}");
        } else {
            bail!("{msg} (files written; --allow-truncation to accept)");
        }
    }
    Ok(())
}

/// R against N of the chosen rule, one curve per class.
fn plot_classes(result: &TuneResult, axis: Axis, stem: &Path) -> Result<Vec<PathBuf>> {
    let series = result
        .plan
        .classes
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let mut scores: Vec<_> = c
                .scores
                .iter()
                .filter(|s| s.method == result.method)
                .collect();
            scores.sort_by_key(|s| s.pixels);
            Series {
                label: format!(
                    "class {k}: {} subap, lit {:.2}, {:.1} m (N={})",
                    c.members.len(),
                    c.placement.lit_fraction,
                    c.placement.distance_m,
                    c.chosen.as_ref().map_or(0, |s| s.pixels)
                ),
                color: COLORS[k % COLORS.len()],
                marker: Marker::Circle,
                dashed: false,
                points: scores
                    .iter()
                    .map(|s| (s.pixels as f64, s.r(axis).value))
                    .collect(),
                errors: scores.iter().map(|s| s.r(axis).se).collect(),
                ring_last: true,
            }
        })
        .collect();
    plot::write(
        stem,
        &Plot {
            title: format!(
                "tune: R {} against N, {}",
                axis.name(),
                result.method.label()
            ),
            x_desc: "N, brightest pixels selected (ringed: all pixels)".into(),
            y_desc: "R (pixels)".into(),
            x_log: true,
            series,
            y_range: None,
        },
        (1000, 560),
    )
}

mod wfe_tune;

#[cfg(test)]
mod tests;
