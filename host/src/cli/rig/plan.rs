//! `brightpix rig plan`: a whole-camera configuration split over boards,
//! written as `rig.toml` (and each board's own configuration).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;

use crate::config_file::ProcessingConfig;
use crate::rig::{self, BoardKind, CostModel, Rig};

use super::print_rig;

#[derive(Args)]
pub(super) struct PlanArgs {
    /// The whole camera's configuration (TOML, docs/CONFIG.md).
    #[arg(long, value_name = "C.toml")]
    config: PathBuf,
    /// Boards to split over.
    #[arg(long, value_parser = crate::cli::at_least_one)]
    boards: usize,
    /// The boards: stm32h743 (480 MHz Cortex-M7, DCMI crop), qemu-m4 or qemu-m7.
    #[arg(long, default_value = "stm32h743", value_parser = BoardKind::parse)]
    board: BoardKind,
    /// The camera's frame rate, Hz: each board's load, and the fewest boards whose cores and
    /// links (stm32h743: USB full speed, about 1 MB/s of results) keep up.
    #[arg(long, value_name = "HZ")]
    camera_rate: Option<f64>,
    /// Instructions per pixel measured for this configuration on whole rows (`brightpix bench
    /// --config`) instead of the model fitted to the bench's tables; the board's camera interface
    /// is added (stm32h743: what its camera path adds, from the bench's
    /// `canary-12bit-dcmi` row).
    #[arg(long, value_name = "X")]
    instr_per_px: Option<f64>,
    /// The boards' results link, MB/s, as measured (`brightpix bench --port PORT --link`) instead
    /// of the board's own (stm32h743: USB full speed, about 1 MB/s); kept in the rig file
    /// (`link_mb_per_s`), so `rig check` counts it too.
    #[arg(long, value_name = "MB/S")]
    link_rate: Option<f64>,
    /// Write the rig here (rig.toml); without it the file is printed.
    #[arg(long, value_name = "rig.toml")]
    out: Option<PathBuf>,
    /// Also write each board's own configuration, DIR/<board name>.toml (its rectangle as
    /// [camera.crop]), which `brightpix configure --config` takes for that board alone.
    #[arg(long, value_name = "DIR")]
    board_configs: Option<PathBuf>,
    /// Reach each band of rows one row into the band below, so neighbours share a camera row:
    /// `rig capture` then compares a checksum of it from both boards every frame, an alignment
    /// self-check that needs no wiring (each board captures one more row; loads as planned).
    #[arg(long)]
    shared_rows: bool,
}

fn model_for(
    kind: BoardKind,
    instr_per_px: Option<f64>,
    link_rate: Option<f64>,
) -> Result<CostModel> {
    let model = kind.cost_model();
    let model = match instr_per_px {
        Some(x) if x.is_finite() && x > 0.0 => CostModel::flat(x, &model),
        Some(x) => bail!("--instr-per-px {x}: must be a positive number"),
        None => model,
    };
    match link_rate {
        Some(r) => model
            .with_link_rate(r)
            .map_err(|e| anyhow::anyhow!("--link-rate {r}: {e}")),
        None => Ok(model),
    }
}

pub(super) fn run(args: PlanArgs) -> Result<()> {
    if let Some(rate) = args.camera_rate.filter(|r| !(r.is_finite() && *r > 0.0)) {
        bail!("--camera-rate {rate}: must be a positive number of frames per second");
    }
    if let Some(out) = &args.out {
        if out.extension().and_then(|e| e.to_str()) != Some("toml") {
            bail!(
                "--out {}: a rig file is TOML: name it *.toml",
                out.display()
            );
        }
        let same = |a: &Path, b: &Path| {
            std::fs::canonicalize(a)
                .ok()
                .zip(std::fs::canonicalize(b).ok())
                .is_some_and(|(a, b)| a == b)
        };
        if same(out, &args.config) {
            bail!(
                "--out {} is the configuration itself: write the rig to another file",
                out.display()
            );
        }
    }
    let whole = ProcessingConfig::load(&args.config)?;
    let model = model_for(args.board, args.instr_per_px, args.link_rate)?;
    let (plan, mut loads) =
        rig::plan_keeping_up(&whole, args.boards, args.board, &model, args.camera_rate)?;
    let mut rig = Rig::from_plan(whole, args.board, args.camera_rate, &plan)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    // Checked by `model_for`; kept in the rig file.
    rig.link_mb_per_s = args.link_rate;
    if args.shared_rows {
        if plan.cut != rig::Cut::Rows || rig.boards.len() < 2 {
            bail!("--shared-rows: the plan has no two bands of rows to overlap (it cut column strips or runs of windows, or one board)");
        }
        rig = rig
            .with_shared_rows()
            .map_err(|e| anyhow::anyhow!("--shared-rows: {e}"))?;
        // Each band is a row taller now: its loads again.
        loads = rig::loads(
            &rig.whole,
            &rig.shares(),
            args.board,
            &model,
            args.camera_rate,
            true,
        );
        if !loads.iter().all(rig::BoardLoad::keeps_up) {
            bail!(
                "--shared-rows: with the shared rows {}: plan more boards (--boards {})",
                rig::busiest(&loads, args.board, &model),
                rig.boards.len() + 1
            );
        }
    }
    println!(
        "rig plan: {} sub-apertures of {} over {} {} boards, cut in {}",
        rig.whole.windows.len(),
        args.config.display(),
        rig.boards.len(),
        args.board.name(),
        plan.cut.describe()
    );
    print_rig(&rig, &model, Some(&loads));
    let config_name = match &args.out {
        Some(out) => relative_to(&args.config, out.parent().unwrap_or(Path::new(""))),
        None => args.config.clone(),
    };
    let text = rig.to_toml(&config_name, Some(&loads));
    match &args.out {
        Some(out) => {
            // Whole or not at all: a temporary file beside it, renamed.
            let staged = out.with_extension("toml.partial");
            std::fs::write(&staged, text)
                .and_then(|()| std::fs::rename(&staged, out))
                .with_context(|| format!("writing {}", out.display()))?;
            println!("wrote {}", out.display());
        }
        None => print!("\n{text}"),
    }
    if let Some(dir) = &args.board_configs {
        let mut keep: Vec<&Path> = vec![&args.config];
        if let Some(out) = &args.out {
            keep.push(out);
        }
        write_board_configs(&rig, dir, &keep)?;
    }
    Ok(())
}

/// Writes each board's configuration as `dir/<board name>.toml` (and the
/// sibling `.npy` files it may need): an ordinary configuration file whose
/// camera is the board's rectangle, placed on the sensor by `[camera.crop]`
/// (docs/CONFIG.md). Refuses to overwrite any of `keep` (the whole
/// configuration, the rig file).
pub(super) fn write_board_configs(rig: &Rig, dir: &Path, keep: &[&Path]) -> Result<()> {
    let canonical = |p: &Path| std::fs::canonicalize(p).ok();
    for b in &rig.boards {
        let target = dir.join(format!("{}.toml", b.name));
        if let Some(t) = canonical(&target) {
            if keep.iter().any(|k| canonical(k).as_ref() == Some(&t)) {
                bail!(
                    "--board-configs {}: board {:?}'s configuration would overwrite {}: choose another directory",
                    dir.display(),
                    b.name,
                    target.display()
                );
            }
        }
        let path = b
            .config
            .save(dir, &b.name)
            .with_context(|| format!("board {:?}'s configuration", b.name))?;
        println!(
            "wrote {} (board {:?}: {} sub-apertures, rectangle {})",
            path.display(),
            b.name,
            b.windows.len(),
            b.rectangle.describe()
        );
    }
    Ok(())
}

/// `path` as the rig file in `dir` should name it: its file name when both
/// are in one directory, else absolute.
fn relative_to(path: &Path, dir: &Path) -> PathBuf {
    let canonical = |p: &Path| {
        std::fs::canonicalize(if p.as_os_str().is_empty() {
            Path::new(".")
        } else {
            p
        })
        .ok()
    };
    match (canonical(path), canonical(dir)) {
        (Some(p), Some(d)) if p.parent() == Some(d.as_path()) => {
            PathBuf::from(p.file_name().unwrap_or_default())
        }
        (Some(p), _) => p,
        _ => path.to_path_buf(),
    }
}
