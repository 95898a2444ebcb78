//! What a tuning run writes: the tuned configuration (with the
//! assumptions as TOML comments and a `[tuned]` table that the loader
//! ignores), every candidate's score as CSV, and R against N of the chosen
//! rule as a plot; on the residual WFE ([`write_wfe`]), the tuned
//! configuration and the end-to-end run's CSV, summary and plots.
//! `brightpix tune` and the Python `TuneResult.save` and
//! `WfeTuneResult.save` write the same files.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, Result};

use super::wfe::WfeTuneResult;
use super::{Prepared, TuneResult};
use crate::endtoend::report;
use crate::evaluation::plot::{self, Marker, Plot, Series, COLORS};
use crate::evaluation::Axis;

/// The files [`write`] wrote.
#[derive(Clone, Debug)]
pub struct Written {
    /// `DIRECTORY/NAME.toml`: the tuned configuration.
    pub config: PathBuf,
    /// `DIRECTORY/NAME-tune.csv`: every candidate's score.
    pub scores: PathBuf,
    /// `DIRECTORY/NAME-tune.svg` and `.png`: R against N.
    pub plots: Vec<PathBuf>,
}

/// Refuses a name that is not a plain file name, before any work.
pub fn check_name(name: &str) -> Result<()> {
    if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
        anyhow::bail!("name {name:?}: must be a plain file name");
    }
    Ok(())
}

/// Writes the tuned configuration, the scores and the plot into
/// `directory` (created). `lines` are the assumptions
/// ([`Prepared::assumptions`]).
pub fn write(
    directory: &Path,
    name: &str,
    prepared: &Prepared,
    result: &TuneResult,
    lines: &[String],
) -> Result<Written> {
    let config = result.config.save(directory, name)?;
    let mut text = std::fs::read_to_string(&config)?;
    text.push_str(&tuned_block(prepared, result, lines)?);
    let tmp = config.with_extension("toml.tmp");
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, &config)?;
    let scores = directory.join(format!("{name}-tune.csv"));
    std::fs::write(&scores, scores_csv(result, prepared.conditions.score_axis)?)?;
    let plots = plot_classes(
        result,
        prepared.conditions.score_axis,
        &directory.join(format!("{name}-tune")),
    )?;
    Ok(Written {
        config,
        scores,
        plots,
    })
}

/// The files [`write_wfe`] wrote.
#[derive(Clone, Debug)]
pub struct WrittenWfe {
    /// `DIRECTORY/NAME.toml`: the tuned configuration.
    pub config: PathBuf,
    /// `DIRECTORY/NAME-endtoend.csv`, `.md`, and the plots.
    pub endtoend: report::Written,
}

impl WrittenWfe {
    /// Every path: the configuration, then the end-to-end files.
    pub fn paths(&self) -> Vec<PathBuf> {
        let mut v = vec![self.config.clone()];
        v.extend(self.endtoend.paths());
        v
    }
}

/// Writes the configuration tuned on the residual WFE (with `lines`, the
/// sensor's assumptions ([`Prepared::assumptions`]), and the end-to-end
/// run's as comments, and its `[tuned]` table) and the end-to-end run's
/// CSV, summary and plots (`NAME-endtoend.*`) into `directory` (created).
pub fn write_wfe(
    directory: &Path,
    name: &str,
    result: &WfeTuneResult,
    lines: &[String],
) -> Result<WrittenWfe> {
    check_name(name)?;
    let config = result.config.save(directory, name)?;
    let mut text = std::fs::read_to_string(&config)?;
    text.push_str(&wfe_block(result, lines)?);
    let tmp = config.with_extension("toml.tmp");
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, &config)?;
    let run_line = report::run_line(&result.options, &result.endtoend.timing, result.threads);
    let endtoend = report::write(
        directory,
        &format!("{name}-endtoend"),
        "tune",
        &result.endtoend,
        &result.scenario,
        &run_line,
    )?;
    Ok(WrittenWfe { config, endtoend })
}

/// The `[tuned]` table and the comment block of a WFE-tuned configuration.
fn wfe_block(result: &WfeTuneResult, lines: &[String]) -> Result<String> {
    let mut t = toml::Table::new();
    t.insert(
        "tool".into(),
        format!("brightpix tune {}", env!("CARGO_PKG_VERSION")).into(),
    );
    t.insert("criterion".into(), "wfe".into());
    t.insert("rule".into(), result.method.label().into());
    t.insert("N".into(), (result.pixels as i64).into());
    t.insert("wfe_nm".into(), toml::Value::Float(result.wfe_nm.value));
    t.insert("wfe_se_nm".into(), toml::Value::Float(result.wfe_nm.se));
    t.insert("strehl".into(), toml::Value::Float(result.strehl.value));
    t.insert(
        "science_wavelength_m".into(),
        toml::Value::Float(result.science_wavelength_m),
    );
    if let Some(all) = result.wfe_all_pixels_nm {
        t.insert("wfe_all_pixels_nm".into(), toml::Value::Float(all));
    }
    t.insert(
        "N_not_resolved_from_best".into(),
        toml::Value::Array(
            result
                .not_resolved
                .iter()
                .map(|&n| (n as i64).into())
                .collect(),
        ),
    );
    t.insert(
        "dark_windows".into(),
        toml::Value::Array(result.dark.iter().map(|&i| (i as i64).into()).collect()),
    );
    t.insert("seed".into(), (result.options.seed as i64).into());
    t.insert("episodes".into(), (result.options.episodes as i64).into());
    t.insert(
        "episode_frames".into(),
        (result.options.frames_per_episode as i64).into(),
    );
    let mut outer = toml::Table::new();
    outer.insert("tuned".into(), toml::Value::Table(t));
    let mut block = String::from(
        "\n# ---- brightpix tune --criterion wfe: what was assumed (the [tuned] table is ignored by the loader) ----\n",
    );
    for l in lines.iter().chain(&result.scenario) {
        let _ = writeln!(block, "# {l}");
    }
    block.push('\n');
    block.push_str(&toml::to_string(&outer).map_err(|e| anyhow!("{e}"))?);
    Ok(block)
}

/// Every class's every candidate, one CSV row each.
pub fn scores_csv(result: &TuneResult, axis: Axis) -> Result<String> {
    let mut csv = String::from(
        "class,subapertures,window,representative,lit_fraction,photons,distance_m,angle_deg,light_in_window,method,N,R,se,R_along,R_across\n",
    );
    for (k, c) in result.plan.classes.iter().enumerate() {
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
    Ok(csv)
}

/// The `[tuned]` table and the comment block appended to the TOML.
fn tuned_block(prepared: &Prepared, result: &TuneResult, lines: &[String]) -> Result<String> {
    let axis = prepared.conditions.score_axis;
    let p = &prepared.conditions.params;
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
        (prepared.options.frames as i64).into(),
    );
    t.insert("seed".into(), (prepared.options.seed as i64).into());
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
        f(prepared.conditions.pupil.obscuration_m),
    );
    t.insert(
        "illumination_threshold".into(),
        f(prepared.conditions.pupil.illumination_threshold),
    );
    t.insert(
        "subapertures_across".into(),
        (p.subapertures_across as i64).into(),
    );
    if let Some(lgs) = &prepared.conditions.lgs {
        t.insert("lgs".into(), lgs.describe().into());
        t.insert(
            "launch_m".into(),
            toml::Value::Array(prepared.conditions.launch_m.iter().map(|&v| f(v)).collect()),
        );
        t.insert(
            "lgs_spot_fwhm_arcsec".into(),
            f(prepared.conditions.lgs_spot_fwhm_arcsec),
        );
    }
    t.insert(
        "measured_from_frames".into(),
        prepared.measured.is_some().into(),
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
