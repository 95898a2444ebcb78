//! `brightpix endtoend`: the paper's §3.10, residual wavefront error and
//! Strehl against N with the device's own slopes.

use crate::config_file::ProcessingConfig;
use crate::endtoend::least_squares::LeastSquares;
use crate::endtoend::{
    parse_layer_list, parse_stars, report, Conditions, EndToEnd, RunOptions, Scenario,
};
use crate::evaluation::Method;
use crate::simulator::atmosphere::Atmosphere;
use crate::simulator::{SimulationParams, SpotModel};
use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

/// The end-to-end conditions that `tune --criterion wfe` shares
/// ([`Conditions`], whose defaults these are).
#[derive(Args, Clone, Debug)]
pub struct ConditionArgs {
    /// Guide stars (one wavefront sensor each): RADIUS,ANGLE;... (arcsec, degrees from +x
    /// towards +y). Default: the paper's (40.2,26.6;40.2,153.4;19.0,288.4).
    #[arg(long, value_name = "R,A;...", allow_hyphen_values = true)]
    pub asterism: Option<String>,
    /// Science target: RADIUS,ANGLE (arcsec, degrees).
    #[arg(
        long,
        default_value = "0,0",
        value_name = "R,A",
        allow_hyphen_values = true
    )]
    pub science: String,
    /// Layers: ALTITUDE:FRACTION:WIND_SPEED:WIND_DIRECTION,... (m, share of Cn2 (normalised),
    /// m/s, degrees the wind blows towards). Default: 0:0.6:7.5:0,500:0.3:10:90,5000:0.1:15:45.
    #[arg(long, value_name = "LAYERS", allow_hyphen_values = true)]
    pub layers: Option<String>,
    /// Multiply every layer's wind speed.
    #[arg(long, default_value_t = 1.0)]
    pub wind_scale: f64,
    /// Wavefront-sensor frame rate (Hz).
    #[arg(long, default_value_t = 250.0)]
    pub frame_rate: f64,
    /// Loop delay: from the sensors' sampling to the science phase the DM corrects (frames).
    #[arg(long, default_value_t = 2.0)]
    pub delay: f64,
    /// Science wavelength (m) of the Strehl ratio (default: H band).
    #[arg(long, default_value_t = 1.65e-6)]
    pub science_wavelength: f64,
    /// DM actuators across (default: sub-apertures across + 1, Fried geometry).
    #[arg(long)]
    pub dm_actuators: Option<usize>,
    /// DM influence function at the neighbouring actuator.
    #[arg(long, default_value_t = 0.2)]
    pub dm_coupling: f64,
    /// Slope noise the fixed reconstructor assumes (px rms).
    #[arg(long, default_value_t = 0.2)]
    pub fixed_noise: f64,
    /// Independent atmosphere episodes scored (>= 2).
    #[arg(long, default_value_t = 40)]
    pub episodes: usize,
    /// Frames per episode (frozen flow within an episode).
    #[arg(long, default_value_t = 100)]
    pub episode_frames: usize,
    /// Episodes on which each rule and N's slope noise is measured for its matched reconstructor.
    #[arg(long, default_value_t = 1)]
    pub calibration_episodes: usize,
}

impl ConditionArgs {
    /// The conditions these options give, parsed (the library checks
    /// their values).
    pub fn conditions(&self) -> Result<Conditions> {
        let guide_stars = self
            .asterism
            .as_deref()
            .map(parse_stars)
            .transpose()
            .context("--asterism")?;
        let science = parse_stars(&self.science).context("--science")?;
        if science.len() != 1 {
            bail!("--science: one RADIUS,ANGLE");
        }
        let layers = self
            .layers
            .as_deref()
            .map(parse_layer_list)
            .transpose()
            .context("--layers")?;
        Ok(Conditions {
            guide_stars,
            science: science[0],
            layers,
            wind_scale: self.wind_scale,
            frame_rate_hz: self.frame_rate,
            delay_frames: self.delay,
            science_wavelength_m: self.science_wavelength,
            dm_actuators_across: self.dm_actuators,
            dm_coupling: self.dm_coupling,
            fixed_noise_px: self.fixed_noise,
            episodes: self.episodes,
            episode_frames: self.episode_frames,
            calibration_episodes: self.calibration_episodes,
        })
    }
}

#[derive(Args)]
#[command(
    about = "End to end (paper §3.10): on-axis residual wavefront error and Strehl against N, open-loop MOAO through a layered atmosphere, with the engine's own slopes",
    after_help = "Each guide star's wavefront sensor looks through frozen-flow von Kármán layers in its own direction;\n\
its camera frames (the simulator's spots and noise) go through the streaming engine with each rule and N;\n\
a tomographic reconstructor (least squares on the layers, regularised by their von Kármán covariance)\n\
drives a DM on the science path in open loop, `--delay` frames later. Two reconstructors: matched (each\n\
rule and N its own measured slope noise) and fixed (--fixed-noise for all). Writes NAME.csv, NAME.md\n\
(summary, assumptions, error budget), NAME.svg/png (WFE), NAME-strehl.svg/png, NAME-budget.svg/png.\n\
Defaults: the paper's CANARY (examples/canary-vignetted.toml: 36 sub-apertures of 16x16 at 0.22\",\n\
640 nm, 200 photons, 2 e-, 250 Hz; r0 12.5 cm, 60/30/10% at 0/0.5/5 km) and what it leaves open.\n\n\
Examples:\n  brightpix endtoend --out e2e\n  brightpix endtoend --out e2e --quick\n  brightpix endtoend --out e2e --outer-scale 10 --wind-scale 2 --name l0-10\n  brightpix endtoend --out e2e --least-squares tsvd:0.05 --name ls\n  brightpix endtoend --out e2e --model-layers 0:0.5,1000:0.4,8000:0.1 --emccd --noise-weights --name mismatch\n  brightpix endtoend --config my.toml --asterism '30,0;30,120;30,240' --photons 500 --read-noise 0.5 --out mine"
)]
pub struct EndToEndArgs {
    /// Output directory (created).
    #[arg(long)]
    out: PathBuf,
    /// Name of the outputs (`OUT/NAME.csv`, ...).
    #[arg(long, default_value = "endtoend")]
    name: String,
    /// Wavefront-sensor configuration (TOML): camera, windows, background (the rule and N are
    /// varied). Default: examples/canary-vignetted.toml (built in).
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    conditions: ConditionArgs,
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
    /// Detector pixel scale (arcsec/pixel).
    #[arg(long, default_value_t = 0.22)]
    pixel_scale: f64,
    /// WFS wavelength (m).
    #[arg(long, default_value_t = 640e-9)]
    wavelength: f64,
    /// Airy diameter of the lenslet spot (arcsec).
    #[arg(long, default_value_t = 0.7)]
    airy: f64,
    /// effective-wavelength, wfs-wavelength or wfs-wavelength-blurred (see `tune --help`).
    #[arg(long, default_value = "effective-wavelength")]
    spot_model: String,
    /// Telescope diameter (m).
    #[arg(long, default_value_t = 4.2)]
    telescope: f64,
    /// Central obscuration diameter (m).
    #[arg(long, default_value_t = 1.0)]
    obscuration: f64,
    /// Sub-apertures across the pupil (default: the grid's larger side).
    #[arg(long)]
    subapertures_across: Option<usize>,
    /// Rules: comma-separated subtract-next, threshold, subtract-next-distinct, subtract-mean:M.
    #[arg(long, default_value = "subtract-next,threshold")]
    rules: String,
    /// N values, comma-separated (N at or above the window's pixels: all pixels, always added).
    #[arg(
        long,
        default_value = "1,2,3,4,5,6,8,10,12,14,16,18,20,25,30,40,50,60,80,100,128,160,200"
    )]
    pixels: String,
    /// Seed of the random streams (a run is reproducible from it).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// A small smoke run (4 episodes of 20 frames, fewer N).
    #[arg(long)]
    quick: bool,
    /// Replace the fixed reconstructor by plain least squares on the layer nodes (no prior):
    /// tsvd:R (singular values of G below R x the largest discarded) or tikhonov:R (alpha = (R x
    /// the largest singular value)^2). The matched MMSE reconstructor is kept beside it.
    #[arg(long, value_name = "tsvd:R|tikhonov:R")]
    least_squares: Option<String>,
    /// Layer nodes per sub-aperture pitch of the least-squares reconstructor (1: at the lenslet
    /// pitch, a virtual DM per layer; 2: the MMSE reconstructor's d/2 lattice).
    #[arg(long, default_value_t = 1)]
    least_squares_nodes: usize,
    /// The profile the reconstructors assume: ALTITUDE:FRACTION,... (m, share, normalised).
    /// Default: the atmosphere's own (perfectly known).
    #[arg(long, value_name = "ALT:FRAC,...")]
    model_layers: Option<String>,
    /// EMCCD at high gain: multiplication noise doubles the photon noise's variance (excess
    /// noise factor sqrt(2)); --read-noise is then the effective read noise.
    #[arg(long)]
    emccd: bool,
    /// The matched reconstructor weights each sub-aperture by its own measured slope noise.
    #[arg(long)]
    noise_weights: bool,
    /// Per-sub-aperture N: each sub-aperture selects max(1, round(N x its lit fraction)).
    #[arg(long)]
    pixels_by_light: bool,
}

/// Parses `ALT:FRACTION,...` into the reconstructor's profile, fractions
/// normalised.
pub fn parse_model_layers(text: &str) -> Result<Vec<(f64, f64)>> {
    let mut v: Vec<(f64, f64)> = text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            let (h, f) = s
                .split_once(':')
                .with_context(|| format!("{s:?}: expected ALTITUDE:FRACTION"))?;
            let h: f64 = h
                .trim()
                .parse()
                .with_context(|| format!("{s:?}: altitude"))?;
            let f: f64 = f
                .trim()
                .parse()
                .with_context(|| format!("{s:?}: fraction"))?;
            if !(h.is_finite() && h >= 0.0 && f.is_finite() && f > 0.0) {
                bail!("{s:?}: altitude >= 0 and fraction > 0");
            }
            Ok((h, f))
        })
        .collect::<Result<_>>()?;
    if v.is_empty() {
        bail!("no layer given");
    }
    let total: f64 = v.iter().map(|l| l.1).sum();
    v.iter_mut().for_each(|l| l.1 /= total);
    Ok(v)
}

/// Parses a rule list.
pub fn parse_rules(text: &str) -> Result<Vec<Method>> {
    text.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            Ok(match s {
                "subtract-next" => Method::SUBTRACT_NEXT,
                "threshold" => Method::THRESHOLD,
                "subtract-next-distinct" => Method::SUBTRACT_NEXT_DISTINCT,
                _ => match s.strip_prefix("subtract-mean:") {
                    Some(m) => {
                        let m: u16 = m.parse().with_context(|| format!("rule {s:?}"))?;
                        if m == 0 {
                            bail!("rule {s:?}: M must be at least 1");
                        }
                        Method::subtract_mean(m)
                    }
                    None => bail!(
                        "unknown rule {s:?}: one of subtract-next, threshold, subtract-next-distinct, subtract-mean:M"
                    ),
                },
            })
        })
        .collect()
}

fn parse_pixels(text: &str) -> Result<Vec<usize>> {
    let v: Vec<usize> = text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            let n: usize = s.parse().with_context(|| format!("--pixels {s:?}"))?;
            if n == 0 {
                bail!("--pixels: N must be at least 1");
            }
            Ok(n)
        })
        .collect::<Result<_>>()?;
    if v.is_empty() {
        bail!("--pixels: no N given");
    }
    Ok(v)
}

/// Checks an output directory and a name before any work.
pub fn check_out(out: &Path, name: &str) -> Result<()> {
    if out.exists() && !out.is_dir() {
        bail!("--out {}: exists and is not a directory", out.display());
    }
    if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
        bail!("--name {name:?}: must be a plain file name");
    }
    std::fs::create_dir_all(out).with_context(|| format!("--out {}", out.display()))?;
    Ok(())
}

fn scenario(args: &EndToEndArgs) -> Result<Scenario> {
    let mut s = Scenario::canary();
    if let Some(path) = &args.config {
        s.config = ProcessingConfig::load(path)?;
    }
    let background = s.config.background.as_ref().map_or(0.0, |b| {
        b.iter().map(|&v| v as f64).sum::<f64>() / b.len().max(1) as f64 / 16.0
    });
    let spot_model = SpotModel::parse(&args.spot_model).ok_or_else(|| {
        anyhow!(
            "--spot-model {:?}: one of effective-wavelength, wfs-wavelength, wfs-wavelength-blurred",
            args.spot_model
        )
    })?;
    s.wfs = SimulationParams {
        telescope_diameter_m: args.telescope,
        pixel_scale_arcsec: args.pixel_scale,
        wavelength_m: args.wavelength,
        airy_diameter_arcsec: args.airy,
        spot_model,
        photons: args.photons,
        read_noise_e: args.read_noise,
        em_excess_noise: args.emccd,
        gain_e_per_count: args.gain,
        background,
        ..SimulationParams::canary()
    };
    s.obscuration_m = args.obscuration;
    s.across = args.subapertures_across;
    s.atmosphere = Atmosphere {
        r0_m: args.r0,
        outer_scale_m: args.outer_scale,
        ..Atmosphere::canary()
    };
    args.conditions.conditions()?.apply(&mut s)?;
    s.least_squares = args
        .least_squares
        .as_deref()
        .map(LeastSquares::parse)
        .transpose()
        .context("--least-squares")?;
    s.model_layers = args
        .model_layers
        .as_deref()
        .map(parse_model_layers)
        .transpose()
        .context("--model-layers")?;
    s.least_squares_nodes = args.least_squares_nodes;
    s.noise_weights = args.noise_weights;
    s.pixels_by_light = args.pixels_by_light;
    Ok(s)
}

/// Prints what an end-to-end run assumes and how big it is; returns its
/// progress bar (in frames).
pub fn start(e2e: &EndToEnd, options: &RunOptions) -> ProgressBar {
    for l in e2e.scenario.describe(&e2e.lenslets, &e2e.dm) {
        eprintln!("brightpix: endtoend: {l}");
    }
    let combos = e2e.combos(&options.methods, &options.pixels);
    let frames = options.frames_per_episode * (options.episodes + options.calibration_episodes);
    eprintln!(
        "brightpix: endtoend: {} rule/N combinations x {} sensors on {} frames ({} episodes of {}, {} calibration); screens {} samples across",
        combos.len(),
        e2e.scenario.guide_stars.len(),
        frames,
        options.episodes,
        options.frames_per_episode,
        options.calibration_episodes,
        e2e.screen_sides()
            .iter()
            .map(|(n, d)| format!("{n} ({:.1} m)", *n as f64 * d))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let bar = ProgressBar::new(frames as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "endtoend [{elapsed_precise}] {wide_bar} {pos}/{len} frames eta {eta}",
        )
        .expect("valid template"),
    );
    bar
}

/// Prints the files an end-to-end run wrote.
pub fn print_written(written: &report::Written) {
    eprintln!(
        "brightpix: endtoend: wrote {}, {}, {}",
        written.csv.display(),
        written.summary_path.display(),
        written
            .plots
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
}

pub fn run(args: EndToEndArgs) -> Result<()> {
    // Everything checked before any work.
    let methods = parse_rules(&args.rules).context("--rules")?;
    if methods.is_empty() {
        bail!("--rules: no rule given");
    }
    let mut pixels = parse_pixels(&args.pixels)?;
    check_out(&args.out, &args.name)?;
    let scenario = scenario(&args)?;
    let (episodes, frames, calibration) = if args.quick {
        (4, 20, 1)
    } else {
        (
            args.conditions.episodes,
            args.conditions.episode_frames,
            args.conditions.calibration_episodes,
        )
    };
    if args.quick {
        pixels.retain(|n| [1, 4, 10, 20, 50].contains(n));
    }
    let e2e = EndToEnd::new(scenario, frames)?;
    pixels.push(e2e.window_pixels());
    let options = RunOptions {
        seed: args.seed,
        episodes,
        frames_per_episode: frames,
        calibration_episodes: calibration,
        methods,
        pixels,
    };
    let bar = start(&e2e, &options);
    let result = e2e.run(&options, &|n| bar.inc(n as u64))?;
    bar.finish_and_clear();
    let run_line = report::run_line(&options, &result.timing, rayon::current_num_threads());
    let lines = e2e.scenario.describe(&e2e.lenslets, &e2e.dm);
    let written = report::write(
        &args.out,
        &args.name,
        "end to end",
        &result,
        &lines,
        &run_line,
    )?;
    print_written(&written);
    print!("{}", written.summary);
    Ok(())
}

#[cfg(test)]
mod tests;
