//! `brightpix paper`: regenerate the seed paper's §3 figures with the engine.

use crate::evaluation::figures::{run_and_write, RunOptions, FIGURES};
use anyhow::{bail, Result};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
#[command(
    about = "Regenerate the paper's figures (Basden, Myers & Gendron 2011, §3) with the engine's arithmetic: CSV + SVG + summary per figure",
    after_help = "Figures: spot-size, signal, background-error, read-noise, outer-scale, seeing, rayleigh,\n\
sodium, subaperture-size, subaperture-size-fov, linearity, rules (all brightpix rules at the\n\
defaults), or all.\n\n\
R is the paper's eq. 1: RMS over independent turbulence realisations of (centre of gravity of\n\
the noiseless image, all pixels, f64) minus (the engine's slope from the noisy image with the\n\
rule and N). Each case is simulated once and the engine run for every (rule, N) on the same\n\
frames. Default sizes take a minute or two per figure on 2 cores; --quick is a smoke run.\n\n\
Examples:\n  brightpix paper all --out paper-run\n  brightpix paper read-noise --out out --frames 5000 --seed 3\n  brightpix paper spot-size --out /tmp/smoke --quick"
)]
pub struct PaperArgs {
    /// A figure name, or `all`.
    figure: String,
    /// Output directory (created).
    #[arg(long)]
    out: PathBuf,
    /// Frames per case (default: 20000; sodium 8000; linearity: tilt steps, 301).
    #[arg(long)]
    frames: Option<usize>,
    /// Seed of the random streams.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Small smoke run (1/25 of the frames, at least 200).
    #[arg(long)]
    quick: bool,
}

pub fn run(args: PaperArgs) -> Result<()> {
    let names: Vec<&str> = if args.figure == "all" {
        FIGURES.to_vec()
    } else if FIGURES.contains(&args.figure.as_str()) {
        vec![args.figure.as_str()]
    } else {
        bail!(
            "unknown figure {:?}; one of: {}, all",
            args.figure,
            FIGURES.join(", ")
        );
    };
    let opts = RunOptions {
        out: args.out.clone(),
        frames: args.frames,
        seed: args.seed,
        quick: args.quick,
    };
    let started = Instant::now();
    let mut all = String::new();
    for name in names {
        let t = Instant::now();
        let summary = run_and_write(name, &opts)?;
        eprintln!(
            "brightpix: {name}: {:.1} s, written to {}",
            t.elapsed().as_secs_f64(),
            args.out.display()
        );
        println!("{summary}");
        all.push_str(&summary);
        all.push('\n');
    }
    if args.figure == "all" {
        std::fs::write(args.out.join("summary.md"), all)?;
    }
    eprintln!("brightpix: total {:.1} s", started.elapsed().as_secs_f64());
    Ok(())
}
