//! `brightpix tune`: the best rule and N for the user's conditions.

use crate::config_file::ProcessingConfig;
use crate::evaluation::tune::{
    candidate_methods, jobs_per_class, plan, pupil_mse, tune, Conditions, Lgs, TuneOptions,
};
use crate::evaluation::Axis;
use crate::simulator::SimulationParams;
use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::fmt::Write as _;
use std::path::PathBuf;

#[derive(Args)]
#[command(
    about = "Simulate your conditions and write a configuration with the best rule and N (per sub-aperture for LGS)",
    after_help = "The configuration gives the windows (their size, and their position in the pupil); the\n\
options give the conditions (CANARY defaults). Candidates: subtract-next, threshold,\n\
subtract-mean M = 2, 4, 8 (and, with --level-filter G, each subtracting rule with that filter),\n\
every N from 1 to all pixels. The rule is one per configuration; N is chosen per class of\n\
sub-apertures (same window size and, for a LGS, similar distance to the launch position).\n\
R is the paper's metric (eq. 1), x and y pooled; for a LGS R_par/R_perp are parallel and\n\
perpendicular to the elongation. Calibration other than the background (flat, threshold) is\n\
kept in the output but not modelled.\n\n\
Examples:\n  brightpix tune --config examples/canary.toml --out tuned\n  brightpix tune --config examples/canary.toml --read-noise 6 --level-filter 4 --out tuned\n  brightpix tune --config examples/canary.toml --lgs rayleigh:1000 --launch 0,0 --out tuned --name lgs"
)]
pub struct TuneArgs {
    /// Processing configuration whose windows are tuned (TOML).
    #[arg(long)]
    config: PathBuf,
    /// Output directory (created).
    #[arg(long)]
    out: PathBuf,
    /// Name of the written configuration (`OUT/NAME.toml`).
    #[arg(long, default_value = "tuned")]
    name: String,
    /// Fried parameter r0 (m) at 500 nm.
    #[arg(long, default_value_t = 0.125)]
    r0: f64,
    /// Outer scale L0 (m); `inf` for Kolmogorov.
    #[arg(long, default_value_t = 30.0)]
    outer_scale: f64,
    /// Detected photons per sub-aperture per frame.
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
    /// Telescope diameter (m).
    #[arg(long, default_value_t = 4.2)]
    telescope: f64,
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
    /// Also try each subtracting rule with a level filter of this gain shift (1..=16).
    #[arg(long, value_name = "G")]
    level_filter: Option<u8>,
    /// Distance classes for a LGS.
    #[arg(long, default_value_t = 4)]
    classes: usize,
    /// Frames simulated per class.
    #[arg(long, default_value_t = 4000)]
    frames: usize,
    /// Seed of the random streams.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

fn parse_launch(text: &str) -> Result<[f64; 2]> {
    let parts: Vec<&str> = text.split(',').collect();
    if parts.len() != 2 {
        bail!("--launch {text:?}: expected X,Y in metres");
    }
    let x: f64 = parts[0].trim().parse().context("--launch X")?;
    let y: f64 = parts[1].trim().parse().context("--launch Y")?;
    Ok([x, y])
}

pub fn run(args: TuneArgs) -> Result<()> {
    let config = ProcessingConfig::load(&args.config)?;
    if let Some(g) = args.level_filter {
        if !(1..=16).contains(&g) {
            bail!("--level-filter must be 1..=16, got {g}");
        }
    }
    let across = args.subapertures_across.unwrap_or_else(|| {
        config
            .grid
            .as_ref()
            .map_or(7, |g| g.grid.columns.max(g.grid.rows) as u32)
    });
    let background = config.background.as_ref().map_or(0.0, |b| {
        b.iter().map(|&v| v as f64).sum::<f64>() / b.len().max(1) as f64 / 16.0
    });
    let params = SimulationParams {
        telescope_diameter_m: args.telescope,
        subapertures_across: across,
        pixel_scale_arcsec: args.pixel_scale,
        wavelength_m: args.wavelength,
        airy_diameter_arcsec: args.airy,
        r0_m: args.r0,
        outer_scale_m: args.outer_scale,
        photons: args.photons,
        read_noise_e: args.read_noise,
        gain_e_per_count: args.gain,
        background,
        background_error: args.background_error,
        ..SimulationParams::canary()
    };
    params
        .validate()
        .map_err(|e| anyhow::anyhow!("conditions: {e}"))?;
    let conditions = Conditions {
        params,
        lgs: args.lgs.as_deref().map(Lgs::parse).transpose()?,
        launch_m: parse_launch(&args.launch)?,
        lgs_spot_fwhm_arcsec: args.lgs_spot,
    };
    let options = TuneOptions {
        frames: args.frames.max(10),
        seed: args.seed,
        classes: args.classes.max(1),
        methods: candidate_methods(args.level_filter),
    };
    let planned = plan(&config, &conditions, options.classes)?;
    let total_jobs: usize = planned
        .iter()
        .map(|c| jobs_per_class(c.size, &options.methods))
        .sum();
    // Progress in frames: simulation counts 1 per frame, the engine the
    // same amount in total.
    let per_job = options.frames as f64 / jobs_per_class(planned[0].size, &options.methods) as f64;
    let bar = ProgressBar::new((options.frames * planned.len() * 2) as u64);
    bar.set_style(
        ProgressStyle::with_template("tune [{elapsed_precise}] {wide_bar} {percent:>3}% eta {eta}")
            .expect("valid template"),
    );
    eprintln!(
        "brightpix: tune: {} sub-apertures in {} class(es), {} candidate rules, {} engine runs of {} frames",
        config.windows.len(),
        planned.len(),
        options.methods.len(),
        total_jobs,
        options.frames
    );
    let result = tune(&config, &conditions, &options, &|frames, jobs| {
        bar.inc(frames as u64 + (jobs as f64 * per_job).round() as u64);
    })?;
    bar.finish_and_clear();

    std::fs::create_dir_all(&args.out).with_context(|| args.out.display().to_string())?;
    let path = result.config.save(&args.out, &args.name)?;

    let lgs = conditions.lgs.is_some();
    let mut report = String::new();
    writeln!(
        report,
        "rule: {} (pupil RMS R at each class's best N: {}; the first (simplest) rule within 1% or 2 paired standard errors of the best is kept)",
        result.method.label(),
        options
            .methods
            .iter()
            .map(|&m| format!("{} {:.4}", m.label(), pupil_mse(&result.classes, m).sqrt()))
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    writeln!(
        report,
        "{:>5} {:>5} {:>13} {:>5} {:>9} {:>10} {:>10} {:>10} {:>10}",
        "class",
        "subap",
        "distance (m)",
        "N",
        "R (px)",
        if lgs { "R_par" } else { "R_x" },
        if lgs { "R_perp" } else { "R_y" },
        "R all px",
        "R current"
    )?;
    let mut csv = String::from(
        "class,subapertures,window,distance_m,min_distance_m,max_distance_m,method,N,R,se,R_x,R_y\n",
    );
    for (k, c) in result.classes.iter().enumerate() {
        let chosen = c.chosen.as_ref().expect("tuned");
        let r = chosen.r(Axis::Both);
        let all = c.all_pixels().map_or(f64::NAN, |s| s.r(Axis::Both).value);
        let current = c
            .current
            .as_ref()
            .map_or("-".to_string(), |s| format!("{:.4}", s.r(Axis::Both).value));
        writeln!(
            report,
            "{:>5} {:>5} {:>13} {:>5} {:>9} {:>10.4} {:>10.4} {:>10.4} {:>10}",
            k,
            c.members.len(),
            format!("{:.2}-{:.2}", c.min_distance_m, c.max_distance_m),
            format!(
                "{}{}",
                chosen.pixels,
                if chosen.all_pixels { "*" } else { "" }
            ),
            format!("{:.4}", r.value),
            chosen.r(Axis::X).value,
            chosen.r(Axis::Y).value,
            all,
            current
        )?;
        for s in &c.scores {
            let rb = s.r(Axis::Both);
            writeln!(
                csv,
                "{k},{},{},{:.3},{:.3},{:.3},{},{},{:.6},{:.6},{:.6},{:.6}",
                c.members.len(),
                c.size,
                c.distance_m,
                c.min_distance_m,
                c.max_distance_m,
                s.method.label(),
                s.pixels,
                rb.value,
                rb.se,
                s.r(Axis::X).value,
                s.r(Axis::Y).value
            )?;
        }
    }
    writeln!(
        report,
        "(R in pixels, {} frames per class; * = all pixels; R current = the input configuration's rule and N)",
        options.frames
    )?;
    let csv_path = args.out.join(format!("{}-tune.csv", args.name));
    std::fs::write(&csv_path, csv)?;
    print!("{report}");
    eprintln!(
        "brightpix: wrote {} and {}",
        path.display(),
        csv_path.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use crate::config_file::{PixelCounts, ProcessingConfig};
    use crate::simulator::{SimulationParams, Simulator};
    use clap::Parser;

    fn run(argv: &[&str]) -> anyhow::Result<()> {
        match Cli::try_parse_from(argv).expect("valid arguments").command {
            Command::Tune(a) => super::run(a),
            Command::Process(a) => super::super::process::run(a),
            #[allow(unreachable_patterns)]
            _ => unreachable!(),
        }
    }

    /// `tune` with a Rayleigh LGS on the CANARY example writes a per-sub-
    /// aperture configuration that loads and that `brightpix process` runs.
    #[test]
    fn tune_writes_a_configuration_that_process_accepts() {
        let dir = std::env::temp_dir().join(format!("brightpix-tune-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let example = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/canary.toml");
        let out = dir.to_str().unwrap();
        run(&[
            "brightpix",
            "tune",
            "--config",
            example,
            "--out",
            out,
            "--name",
            "lgs",
            "--lgs",
            "rayleigh:1500",
            "--launch",
            "0,0",
            "--classes",
            "2",
            "--frames",
            "60",
        ])
        .unwrap();
        let tuned = ProcessingConfig::load(dir.join("lgs.toml")).unwrap();
        let original = ProcessingConfig::load(example).unwrap();
        assert_eq!(tuned.windows, original.windows);
        assert_eq!(tuned.background, original.background);
        assert!(dir.join("lgs-tune.csv").exists());
        if let PixelCounts::PerSubaperture(list) = &tuned.pixels {
            assert_eq!(list.len(), 49);
        }

        // Two frames of the whole 112x112 camera: 7x7 simulated sub-apertures.
        let sim = Simulator::new(SimulationParams::canary()).unwrap();
        let spots = sim.frames(5, 0, 2 * 49);
        let mut data = vec![0u16; 2 * 112 * 112];
        for f in 0..2 {
            for s in 0..49 {
                let (c, r) = (s % 7, s / 7);
                let spot = &spots[f * 49 + s];
                for y in 0..16 {
                    for x in 0..16 {
                        data[f * 112 * 112 + (r * 16 + y) * 112 + c * 16 + x] =
                            spot.raw[y * 16 + x];
                    }
                }
            }
        }
        let frames = dir.join("frames.npy");
        crate::io::write_array(&frames, &[2, 112, 112], &data).unwrap();
        let slopes = dir.join("slopes.npy");
        run(&[
            "brightpix",
            "process",
            "--config",
            dir.join("lgs.toml").to_str().unwrap(),
            "--frames",
            frames.to_str().unwrap(),
            "--out",
            slopes.to_str().unwrap(),
        ])
        .unwrap();
        let out = crate::io::read_array(&slopes).unwrap();
        assert_eq!(out.shape, vec![2, 49, 2]);
        // The slopes are the spots' (within noise).
        for (s, spot) in spots.iter().take(49).enumerate() {
            let t = spot.true_slope;
            let got = [out.data[s * 2], out.data[s * 2 + 1]];
            assert!((got[0] - t[0]).abs() < 1.5 && (got[1] - t[1]).abs() < 1.5);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A tuned per-sub-aperture configuration (here 9 candidates, level
    /// filter included) is accepted by the firmware's device loop (in
    /// process, over a pseudo-terminal), and what it streams back matches the
    /// reference bit for bit.
    #[test]
    fn a_simulated_device_accepts_the_tuned_configuration() {
        let dir = std::env::temp_dir().join(format!("brightpix-tune-dev-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let example = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/canary.toml");
        run(&[
            "brightpix",
            "tune",
            "--config",
            example,
            "--out",
            dir.to_str().unwrap(),
            "--lgs",
            "rayleigh:1500",
            "--classes",
            "3",
            "--level-filter",
            "4",
            "--frames",
            "60",
        ])
        .unwrap();
        let tuned = ProcessingConfig::load(dir.join("tuned.toml")).unwrap();
        let view = tuned.view();
        let device = crate::sim_device::InProcessDevice::start_pty().unwrap();
        let mut client = crate::link::Client::open(device.port()).unwrap();
        client.configure(&view).unwrap();
        let frames = crate::sil::canary_frames(3, 9);
        let run = crate::sil::stream_and_verify(&mut client, &view, &frames, 0, 3);
        assert!(run.error.is_none(), "{:?}", run.error);
        assert!(run.verifier.all_match(), "{:#?}", run.verifier.mismatches);
        assert_eq!(run.verifier.frames_verified, 3);
        drop(client);
        device.stop();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
