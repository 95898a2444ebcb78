//! `brightpix paper`: regenerate the seed paper's §3 figures with the engine.

use crate::evaluation::figures::{run_and_write, RunOptions, FIGURES};
use anyhow::{bail, Context, Result};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
#[command(
    about = "Regenerate the paper's figures (Basden, Myers & Gendron 2011, §3) with the engine's arithmetic: CSV + SVG + summary per figure",
    after_help = "Figures: spots (the spot-image panels), spot-size, signal, background-error, read-noise,\n\
outer-scale, seeing, rayleigh, sodium, subaperture-size, subaperture-size-fov, sodium-paper (Fig. 9b\n\
with the beacon width that gives the paper's optimum), linearity, rules (all brightpix rules at\n\
the defaults, 4 seeds), or all; and sensitivity (how the model's own choices move the\n\
conclusions: spot and seeing, sodium beacon, profile and direction, clipped all-pixel reference).\n\n\
R is the paper's eq. 1: RMS over independent turbulence realisations of (centre of gravity of\n\
the noiseless image, all pixels, f64) minus (the engine's slope from the noisy image with the\n\
rule and N). Each case is simulated once and the engine run for every (rule, N) on the same\n\
frames. Default sizes take a minute or two per figure on 2 cores; --quick is a smoke run.\n\n\
Examples:\n  brightpix paper all --out paper-run\n  brightpix paper read-noise --out out --count 5000 --seed 3\n  brightpix paper spot-size --out /tmp/smoke --quick"
)]
pub struct PaperArgs {
    /// A figure name, or `all`.
    figure: String,
    /// Output directory (created).
    #[arg(long)]
    out: PathBuf,
    /// Frames per case, >= 20 (default: 20000; sodium 8000; sensitivity 8000/4000; linearity:
    /// tilt steps, 301).
    #[arg(long, value_name = "N")]
    count: Option<usize>,
    /// Seed of the random streams.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Small smoke run (1/25 of the frames, at least 200).
    #[arg(long)]
    quick: bool,
}

/// The figures `args` names, with every argument checked before any work.
fn check(args: &PaperArgs) -> Result<Vec<&str>> {
    let names: Vec<&str> = if args.figure == "all" {
        FIGURES.to_vec()
    } else if FIGURES.contains(&args.figure.as_str()) || args.figure == "sensitivity" {
        vec![args.figure.as_str()]
    } else {
        bail!(
            "unknown figure {:?}; one of: {}, all, sensitivity",
            args.figure,
            FIGURES.join(", ")
        );
    };
    if let Some(k) = args.count {
        if k < 20 {
            bail!("--count {k}: at least 20 frames per case (or tilt steps) are needed");
        }
        if args.quick {
            bail!("--count and --quick both set the number of frames: give one");
        }
    }
    if args.out.exists() && !args.out.is_dir() {
        bail!(
            "--out {}: exists and is not a directory",
            args.out.display()
        );
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("--out {}", args.out.display()))?;
    Ok(names)
}

pub fn run(args: PaperArgs) -> Result<()> {
    let names = check(&args)?;
    let opts = RunOptions {
        out: args.out.clone(),
        frames: args.count,
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

#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use clap::Parser;

    fn run(argv: &[&str]) -> anyhow::Result<()> {
        match Cli::try_parse_from(argv).expect("valid arguments").command {
            Command::Paper(a) => super::run(a),
            _ => unreachable!(),
        }
    }

    #[test]
    fn bad_arguments_fail_before_any_work() {
        let dir = std::env::temp_dir().join(format!("brightpix-paper-args-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let out = dir.join("out");
        let o = out.to_str().unwrap();
        let started = std::time::Instant::now();
        let e = run(&["brightpix", "paper", "all", "--out", o, "--count", "0"]).unwrap_err();
        assert!(e.to_string().contains("at least 20"), "{e}");
        let e = run(&["brightpix", "paper", "nope", "--out", o]).unwrap_err();
        assert!(e.to_string().contains("unknown figure"), "{e}");
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("file");
        std::fs::write(&file, "x").unwrap();
        let e = run(&[
            "brightpix",
            "paper",
            "signal",
            "--out",
            file.to_str().unwrap(),
        ])
        .unwrap_err();
        assert!(e.to_string().contains("not a directory"), "{e}");
        // Nothing was simulated: no output was written.
        assert!(!out.exists() || std::fs::read_dir(&out).unwrap().next().is_none());
        assert!(started.elapsed().as_secs() < 5);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
