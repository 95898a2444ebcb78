//! The end-to-end run's outputs: CSV, plots (SVG and PNG) and a summary;
//! [`write`] writes them all, as `brightpix endtoend`, `brightpix tune
//! --criterion wfe` and the Python `WfeTuneResult.save` do.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use super::{estimate, rms_nm, ComboResult, EndToEndResult, Reconstruction, RunOptions, Timing};
use crate::evaluation::plot::{self, Marker, Plot, Series, COLORS};
use crate::evaluation::Method;

/// The paper's §3.10 numbers: all pixels 550 nm (Strehl 6%), N = 20
/// 280 nm (33%).
pub const PAPER_ALL_PIXELS_NM: f64 = 550.0;
pub const PAPER_N20_NM: f64 = 280.0;

const RECONSTRUCTIONS: [Reconstruction; 2] = [Reconstruction::Matched, Reconstruction::Fixed];

/// The CSV: one row per rule, N and reconstructor.
pub fn csv(result: &EndToEndResult) -> String {
    let mut s = String::from(
        "method,N,all_pixels,reconstructor,assumed_noise_px,slope_noise_px,wfe_nm,wfe_se_nm,strehl,strehl_se,strehl_marechal,noise_nm,tomography_nm,aliasing_nm,spot_bias_nm,fitting_nm,temporal_nm,budget_rss_nm\n",
    );
    let fitting = estimate(&result.fitting).value;
    let temporal = estimate(&result.temporal).value;
    for c in &result.combos {
        for r in RECONSTRUCTIONS {
            let t = c.terms(r);
            let wfe = result.wfe_nm(c, r);
            let st = result.strehl(c, r);
            let terms = [
                estimate(&t.noise).value,
                estimate(&t.tomography).value,
                estimate(&t.aliasing).value,
                estimate(&t.spot_bias).value,
                fitting,
                temporal,
            ];
            let rss: f64 = terms.iter().sum();
            let nm = |v: f64| v.max(0.0).sqrt() * 1e9;
            let _ = writeln!(
                s,
                "{},{},{},{},{:.5},{:.5},{:.2},{:.2},{:.5},{:.5},{:.5},{:.2},{:.2},{:.2},{:.2},{:.2},{:.2},{:.2}",
                c.combo.method.label(),
                c.combo.pixels,
                c.combo.all_pixels,
                result.label(r),
                c.sigma2_px2(r).sqrt(),
                estimate(&c.slope_noise_px2).value.sqrt(),
                wfe.value,
                wfe.se,
                st.value,
                st.se,
                result.marechal(c, r),
                nm(terms[0]),
                nm(terms[1]),
                nm(terms[2]),
                nm(terms[3]),
                nm(terms[4]),
                nm(terms[5]),
                nm(rss),
            );
        }
    }
    s
}

fn sorted(result: &EndToEndResult, method: Method) -> Vec<&ComboResult> {
    let mut v: Vec<&ComboResult> = result
        .combos
        .iter()
        .filter(|c| c.combo.method == method)
        .collect();
    v.sort_by_key(|c| c.combo.pixels);
    v
}

fn methods(result: &EndToEndResult) -> Vec<Method> {
    let mut m: Vec<Method> = Vec::new();
    for c in &result.combos {
        if !m.contains(&c.combo.method) {
            m.push(c.combo.method);
        }
    }
    m
}

/// Writes `{stem}.svg/png` (WFE against N), `{stem}-strehl` and
/// `{stem}-budget` (the matched reconstructor's budget for the first
/// method); returns the paths.
pub fn plots(result: &EndToEndResult, stem: &Path, title: &str) -> Result<Vec<PathBuf>> {
    let methods = methods(result);
    let markers = [
        Marker::Circle,
        Marker::Triangle,
        Marker::Square,
        Marker::Cross,
    ];
    let curve = |value: &dyn Fn(&ComboResult, Reconstruction) -> (f64, f64)| {
        let mut series = Vec::new();
        for r in RECONSTRUCTIONS {
            for (k, &m) in methods.iter().enumerate() {
                let cs = sorted(result, m);
                let (points, errors): (Vec<(f64, f64)>, Vec<f64>) = cs
                    .iter()
                    .map(|c| {
                        let (v, e) = value(c, r);
                        ((c.combo.pixels as f64, v), e)
                    })
                    .unzip();
                series.push(Series {
                    label: format!("{} ({})", m.label(), result.label(r)),
                    color: COLORS[k % COLORS.len()],
                    marker: markers[k % markers.len()],
                    dashed: r == Reconstruction::Fixed,
                    points,
                    errors,
                    ring_last: true,
                });
            }
        }
        series
    };
    let mut wfe = curve(&|c, r| {
        let e = result.wfe_nm(c, r);
        (e.value, e.se)
    });
    let n_all = result
        .combos
        .iter()
        .map(|c| c.combo.pixels)
        .max()
        .unwrap_or(256) as f64;
    for (label, point, color) in [
        (
            "paper (DASP): all pixels, 550 nm",
            (n_all, PAPER_ALL_PIXELS_NM),
            COLORS[6],
        ),
        (
            "paper (DASP): N = 20, 280 nm",
            (20.0, PAPER_N20_NM),
            COLORS[6],
        ),
    ] {
        let mut s = Series::line(label, color, Marker::Cross);
        s.points = vec![point];
        wfe.push(s);
    }
    let lambda_nm = result.science_wavelength_m * 1e9;
    let mut paths = plot::write(
        stem,
        &Plot {
            title: format!("{title}: on-axis residual wavefront error"),
            x_desc: "N, brightest pixels selected (ringed: all pixels)".into(),
            y_desc: "residual WFE (nm rms)".into(),
            x_log: true,
            series: wfe,
            y_range: None,
        },
        (1100, 600),
    )?;
    let strehl = curve(&|c, r| {
        let e = result.strehl(c, r);
        (e.value, e.se)
    });
    paths.extend(plot::write(
        &stem.with_file_name(format!(
            "{}-strehl",
            stem.file_name().unwrap_or_default().to_string_lossy()
        )),
        &Plot {
            title: format!("{title}: Strehl ratio at {lambda_nm:.0} nm"),
            x_desc: "N, brightest pixels selected (ringed: all pixels)".into(),
            y_desc: "Strehl ratio (long-exposure PSF peak)".into(),
            x_log: true,
            series: strehl,
            y_range: Some(0.0..1.0),
        },
        (1100, 600),
    )?);
    if let Some(&m) = methods.first() {
        let cs = sorted(result, m);
        let r = Reconstruction::Matched;
        let fitting = rms_nm(estimate(&result.fitting)).value;
        let temporal = rms_nm(estimate(&result.temporal)).value;
        type Term = fn(&ComboResult) -> &Vec<f64>;
        let terms: [(&str, Term); 5] = [
            ("total", |c| &c.matched.total),
            ("noise", |c| &c.matched.noise),
            ("tomography", |c| &c.matched.tomography),
            ("aliasing", |c| &c.matched.aliasing),
            ("spot bias", |c| &c.matched.spot_bias),
        ];
        let mut series: Vec<Series> = terms
            .iter()
            .enumerate()
            .map(|(k, (name, f))| {
                let (points, errors): (Vec<(f64, f64)>, Vec<f64>) = cs
                    .iter()
                    .map(|c| {
                        let e = rms_nm(estimate(f(c)));
                        ((c.combo.pixels as f64, e.value), e.se)
                    })
                    .unzip();
                Series {
                    label: (*name).to_string(),
                    color: COLORS[k % COLORS.len()],
                    marker: Marker::Circle,
                    dashed: false,
                    points,
                    errors,
                    ring_last: true,
                }
            })
            .collect();
        let (lo, hi) = (
            cs.first().map_or(1.0, |c| c.combo.pixels as f64),
            cs.last().map_or(256.0, |c| c.combo.pixels as f64),
        );
        for (k, (name, v)) in [("fitting", fitting), ("temporal (delay)", temporal)]
            .into_iter()
            .enumerate()
        {
            let mut s = Series::line(name, COLORS[5 + k], Marker::None);
            s.dashed = true;
            s.points = vec![(lo, v), (hi, v)];
            series.push(s);
        }
        paths.extend(plot::write(
            &stem.with_file_name(format!(
                "{}-budget",
                stem.file_name().unwrap_or_default().to_string_lossy()
            )),
            &Plot {
                title: format!("{title}: error budget, {} ({})", m.label(), result.label(r)),
                x_desc: "N, brightest pixels selected (ringed: all pixels)".into(),
                y_desc: "nm rms".into(),
                x_log: true,
                series,
                y_range: None,
            },
            (1100, 600),
        )?);
    }
    Ok(paths)
}

/// A short text summary: per reconstructor, all pixels, N = 20 and the
/// best N of each method, with paired differences, the Strehl ratios and
/// the budget.
pub fn summary(result: &EndToEndResult, assumptions: &[String], run_line: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# End to end (paper §3.10)\n");
    let _ = writeln!(s, "{run_line}\n");
    for a in assumptions {
        let _ = writeln!(s, "- {a}");
    }
    let lambda = result.science_wavelength_m * 1e9;
    let _ = writeln!(
        s,
        "\nUncorrected on-axis WFE (piston removed): {:.0} nm; DM fitting error {:.1} nm; delay (temporal) error {:.1} nm.\n",
        rms_nm(estimate(&result.uncorrected)).value,
        rms_nm(estimate(&result.fitting)).value,
        rms_nm(estimate(&result.temporal)).value
    );
    if let Some((kept, total)) = result.modes_kept {
        let _ = writeln!(
            s,
            "The least-squares reconstructor keeps {kept} of the {total} singular modes of G.\n"
        );
    }
    let nm = |v: &Vec<f64>| rms_nm(estimate(v)).value;
    for r in RECONSTRUCTIONS {
        let _ = writeln!(s, "## Reconstructor: {}\n", result.label(r));
        let _ = writeln!(
            s,
            "| rule | N | WFE (nm) | Strehl at {lambda:.0} nm | Maréchal | slope noise (px) | noise | tomography | aliasing | spot bias (nm) |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|");
        let mut rows: Vec<&ComboResult> = Vec::new();
        for m in methods(result) {
            let cs = sorted(result, m);
            if let Some(all) = cs.iter().find(|c| c.combo.all_pixels) {
                if !rows.iter().any(|c| c.combo.all_pixels) {
                    rows.push(all);
                }
            }
            if let Some(c20) = cs.iter().find(|c| c.combo.pixels == 20) {
                rows.push(c20);
            }
            if let Some(best) = result.best(m, r) {
                if !rows.iter().any(|c| std::ptr::eq(*c, best)) {
                    rows.push(best);
                }
            }
        }
        for c in &rows {
            let w = result.wfe_nm(c, r);
            let st = result.strehl(c, r);
            let t = c.terms(r);
            let best = result
                .best(c.combo.method, r)
                .is_some_and(|b| std::ptr::eq(b, *c));
            let _ = writeln!(
                s,
                "| {} | {}{} | {:.1} ± {:.1} | {:.3} ± {:.3} | {:.3} | {:.3} | {:.0} | {:.0} | {:.0} | {:.0} |",
                if c.combo.all_pixels {
                    "all pixels".to_string()
                } else {
                    c.combo.method.label()
                },
                c.combo.pixels,
                if best { " (best)" } else { "" },
                w.value,
                w.se,
                st.value,
                st.se,
                result.marechal(c, r),
                estimate(&c.slope_noise_px2).value.sqrt(),
                nm(&t.noise),
                nm(&t.tomography),
                nm(&t.aliasing),
                nm(&t.spot_bias),
            );
        }
        if let (Some(all), Some(n20)) = (
            rows.iter().find(|c| c.combo.all_pixels),
            result.find(Method::SUBTRACT_NEXT, 20),
        ) {
            let d = result.paired_difference_nm(n20, all, r);
            let _ = writeln!(
                s,
                "\nsubtract-next N = 20 against all pixels: {:+.1} ± {:.1} nm (paired over episodes).",
                d.value, d.se
            );
        }
        let _ = writeln!(s);
    }
    s
}

/// The summary's run line: the seed, the episodes and where the time went
/// (wall-clock seconds: the one line that differs between two runs of the
/// same seed).
pub fn run_line(options: &RunOptions, timing: &Timing, threads: usize) -> String {
    let t = timing;
    format!(
        "seed {}, {} episodes of {} frames + {} calibration; {:.0} s: screens {:.0} s, sensor frames {:.0} s, science path {:.0} s, scoring {:.0} s (thread time: engine {:.0} s, reconstruction and residuals {:.0} s) on {} threads",
        options.seed,
        options.episodes,
        options.frames_per_episode,
        options.calibration_episodes,
        t.total,
        t.screens,
        t.wfs_frames,
        t.science,
        t.scoring,
        t.engine_cpu,
        t.reconstruction_cpu,
        threads
    )
}

/// The files [`write`] wrote, and the summary.
#[derive(Clone, Debug)]
pub struct Written {
    /// `DIRECTORY/NAME.csv`: every rule, N and reconstructor.
    pub csv: PathBuf,
    /// `DIRECTORY/NAME.md`: the summary.
    pub summary_path: PathBuf,
    /// `NAME.svg/png`, `NAME-strehl.svg/png`, `NAME-budget.svg/png`.
    pub plots: Vec<PathBuf>,
    /// The summary's text (what `NAME.md` holds).
    pub summary: String,
}

impl Written {
    /// Every path, in the order written.
    pub fn paths(&self) -> Vec<PathBuf> {
        let mut v = vec![self.csv.clone(), self.summary_path.clone()];
        v.extend(self.plots.iter().cloned());
        v
    }
}

/// Writes the CSV, the summary (with `assumptions`, one line each, and
/// `run_line`) and the plots (titled `title`) into `directory` (which must
/// exist) as `NAME.*`.
pub fn write(
    directory: &Path,
    name: &str,
    title: &str,
    result: &EndToEndResult,
    assumptions: &[String],
    run_line: &str,
) -> Result<Written> {
    let summary = summary(result, assumptions, run_line);
    let csv_path = directory.join(format!("{name}.csv"));
    std::fs::write(&csv_path, csv(result)).with_context(|| csv_path.display().to_string())?;
    let summary_path = directory.join(format!("{name}.md"));
    std::fs::write(&summary_path, &summary).with_context(|| summary_path.display().to_string())?;
    let plots = plots(result, &directory.join(name), title)?;
    Ok(Written {
        csv: csv_path,
        summary_path,
        plots,
        summary,
    })
}
