//! `brightpix tune --criterion wfe`: the rule and N that minimise the
//! on-axis residual wavefront error of an end-to-end simulation
//! (`brightpix endtoend`) of the user's sensor and conditions.

use super::{Setup, TuneArgs};
use crate::cli::endtoend::run_and_write;
use crate::config_file::{PixelCounts, ProcessingConfig};
use crate::endtoend::{EndToEnd, Reconstruction, RunOptions, Scenario};
use crate::evaluation::tune::place;
use crate::simulator::atmosphere::Atmosphere;
use anyhow::{anyhow, Result};
use brightpix_protocol::LevelFilter;
use std::fmt::Write as _;

/// The N values scored (all pixels added).
const PIXELS: [usize; 23] = [
    1, 2, 3, 4, 5, 6, 8, 10, 12, 14, 16, 18, 20, 25, 30, 40, 50, 60, 80, 100, 128, 160, 200,
];

/// `config` without the windows `dark` (indices): a grid keeps its grid
/// with them skipped; a list loses them (and its per-window N and reference
/// slopes, which tune rewrites anyway).
fn without(config: &ProcessingConfig, dark: &[usize]) -> ProcessingConfig {
    let mut out = config.clone();
    if dark.is_empty() {
        return out;
    }
    if let Some(layout) = &config.grid {
        let mut skip = layout.skip.clone();
        for (k, pos) in layout.positions().enumerate() {
            if dark.contains(&k) {
                skip.push(pos);
            }
        }
        let fresh = ProcessingConfig::from_grid(config.camera, layout.grid, &skip);
        out.windows = fresh.windows;
        out.grid = fresh.grid;
    } else {
        out.windows = config
            .windows
            .iter()
            .enumerate()
            .filter(|(k, _)| !dark.contains(k))
            .map(|(_, w)| *w)
            .collect();
    }
    out.reference_slopes = None;
    out.pixels = PixelCounts::All(20);
    out
}

pub(super) fn run(args: &TuneArgs, setup: &Setup, lines: &[String]) -> Result<()> {
    let p = &setup.prepared.conditions.params;
    let threshold = setup.prepared.conditions.pupil.illumination_threshold;
    let dark: Vec<usize> = place(&setup.config, &setup.prepared.conditions)
        .iter()
        .enumerate()
        .filter(|(_, pl)| pl.lit_fraction < threshold)
        .map(|(k, _)| k)
        .collect();
    let config = without(&setup.config, &dark);
    let mut scenario = Scenario {
        config: config.clone(),
        across: Some(p.subapertures_across as usize),
        wfs: p.clone(),
        obscuration_m: setup.prepared.conditions.pupil.obscuration_m,
        atmosphere: Atmosphere {
            r0_m: p.r0_m,
            r0_wavelength_m: p.r0_wavelength_m,
            outer_scale_m: p.outer_scale_m,
            ..Atmosphere::canary()
        },
        ..Scenario::canary()
    };
    args.endtoend.apply(&mut scenario)?;
    let e2e = EndToEnd::new(scenario, args.endtoend.episode_frames)?;
    let mut pixels = PIXELS.to_vec();
    pixels.push(e2e.window_pixels());
    let options = RunOptions {
        seed: args.seed,
        episodes: args.endtoend.episodes,
        frames_per_episode: args.endtoend.episode_frames,
        calibration_episodes: args.endtoend.calibration_episodes,
        methods: setup.prepared.options.methods.clone(),
        pixels,
    };
    let stem = format!("{}-endtoend", args.name);
    let (result, summary) = run_and_write(&e2e, &options, &args.out, &stem, "tune")?;
    let r = Reconstruction::Matched;
    let best = result
        .combos
        .iter()
        .min_by(|a, b| {
            result
                .wfe_nm(a, r)
                .value
                .total_cmp(&result.wfe_nm(b, r).value)
        })
        .ok_or_else(|| anyhow!("nothing was scored"))?;
    // The N range the run cannot tell from the best (2 paired standard
    // errors), for the chosen rule.
    let flat: Vec<usize> = result
        .combos
        .iter()
        .filter(|c| c.combo.method == best.combo.method)
        .filter(|c| {
            let d = result.paired_difference_nm(c, best, r);
            d.value <= 2.0 * d.se || std::ptr::eq(*c, best)
        })
        .map(|c| c.combo.pixels)
        .collect();
    let mut tuned = config;
    tuned.rule = best.combo.method.rule;
    tuned.pixels = PixelCounts::All(best.combo.pixels as u16);
    tuned.level_filter = best
        .combo
        .method
        .level_filter
        .map(|gain_shift| LevelFilter { gain_shift });
    if best.combo.method.clip_negative {
        tuned.threshold = Some(0);
    }
    let path = tuned.save(&args.out, &args.name)?;
    let wfe = result.wfe_nm(best, r);
    let strehl = result.strehl(best, r);
    let all = result.combos.iter().find(|c| c.combo.all_pixels);
    let mut t = toml::Table::new();
    t.insert(
        "tool".into(),
        format!("brightpix tune {}", env!("CARGO_PKG_VERSION")).into(),
    );
    t.insert("criterion".into(), "wfe".into());
    t.insert("rule".into(), best.combo.method.label().into());
    t.insert("N".into(), (best.combo.pixels as i64).into());
    t.insert("wfe_nm".into(), toml::Value::Float(wfe.value));
    t.insert("wfe_se_nm".into(), toml::Value::Float(wfe.se));
    t.insert("strehl".into(), toml::Value::Float(strehl.value));
    t.insert(
        "science_wavelength_m".into(),
        toml::Value::Float(e2e.scenario.science_wavelength_m),
    );
    if let Some(all) = all {
        t.insert(
            "wfe_all_pixels_nm".into(),
            toml::Value::Float(result.wfe_nm(all, r).value),
        );
    }
    t.insert(
        "N_not_resolved_from_best".into(),
        toml::Value::Array(flat.iter().map(|&n| (n as i64).into()).collect()),
    );
    t.insert(
        "dark_windows".into(),
        toml::Value::Array(dark.iter().map(|&i| (i as i64).into()).collect()),
    );
    t.insert("seed".into(), (args.seed as i64).into());
    t.insert("episodes".into(), (args.endtoend.episodes as i64).into());
    t.insert(
        "episode_frames".into(),
        (args.endtoend.episode_frames as i64).into(),
    );
    let mut outer = toml::Table::new();
    outer.insert("tuned".into(), toml::Value::Table(t));
    let mut block = String::from(
        "\n# ---- brightpix tune --criterion wfe: what was assumed (the [tuned] table is ignored by the loader) ----\n",
    );
    for l in lines
        .iter()
        .chain(&e2e.scenario.describe(&e2e.lenslets, &e2e.dm))
    {
        let _ = writeln!(block, "# {l}");
    }
    block.push('\n');
    block.push_str(&toml::to_string(&outer).map_err(|e| anyhow!("{e}"))?);
    let mut text = std::fs::read_to_string(&path)?;
    text.push_str(&block);
    let tmp = path.with_extension("toml.tmp");
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, &path)?;
    print!("{summary}");
    println!(
        "\ntuned (minimum residual WFE, matched reconstructor): {} N = {}: {:.1} ± {:.1} nm, Strehl {:.3} at {:.0} nm{}; N not resolved from it: {:?}",
        best.combo.method.label(),
        best.combo.pixels,
        wfe.value,
        wfe.se,
        strehl.value,
        e2e.scenario.science_wavelength_m * 1e9,
        all.map_or(String::new(), |a| format!(
            " (all pixels: {:.1} nm)",
            result.wfe_nm(a, r).value
        )),
        flat
    );
    if !dark.is_empty() {
        println!(
            "dark sub-apertures (lit below {threshold}): windows {dark:?}, left out of the simulation and of the tuned configuration"
        );
    }
    eprintln!("brightpix: wrote {}", path.display());
    Ok(())
}
