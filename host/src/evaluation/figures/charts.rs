//! A figure's files: the CSV and the plots (SVG and PNG).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use super::report::summary;
use super::{axis_words, best_row, method_marker, FigureResult};
use crate::evaluation::plot::{self, Marker, Plot, Series, COLORS};
use crate::evaluation::{Axis, Method};

fn fmt_value(v: f64) -> String {
    if v.is_infinite() {
        "inf".into()
    } else {
        format!("{v}")
    }
}

/// Writes `<name>.csv`, the panels' SVGs and `<name>.md` (a summary) under
/// `out`; returns the files written.
pub fn write_figure(result: &FigureResult, out: &Path) -> Result<Vec<PathBuf>> {
    let fig = &result.figure;
    let mut written = Vec::new();
    // CSV
    let mut csv = String::from(
        "figure,case,value,seed,method,N,pixels_in_window,all_pixels,frames,R_x,se_x,R_y,se_y,R_xy,se_xy,R_along,se_along,R_across,se_across,pixel_scale_arcsec,invalid,saturated_pixels,light_in_window\n",
    );
    for row in &result.rows {
        let c = &fig.cases[row.case];
        let s = &row.score;
        let (x, y, b) = (s.r(Axis::X), s.r(Axis::Y), s.r(Axis::Both));
        let (al, ac) = (s.r(Axis::Along), s.r(Axis::Across));
        writeln!(
            csv,
            "{},\"{}\",{},{},{},{},{},{},{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{},{:.5}",
            fig.name,
            c.label.replace('"', "\"\""),
            fmt_value(c.value),
            c.seed_offset,
            s.method.label(),
            s.pixels,
            row.pixel_count,
            s.all_pixels,
            row.frames,
            x.value,
            x.se,
            y.value,
            y.se,
            b.value,
            b.se,
            al.value,
            al.se,
            ac.value,
            ac.se,
            c.params.pixel_scale_arcsec,
            s.invalid,
            row.saturated,
            row.field_fraction
        )?;
    }
    let path = out.join(format!("{}.csv", fig.name));
    std::fs::write(&path, csv).with_context(|| path.display().to_string())?;
    written.push(path);

    // Plots
    let y_desc = format!("R, {} (pixels)", axis_words(fig.axis));
    for p in &fig.panels {
        let cases: Vec<usize> = p
            .cases
            .clone()
            .unwrap_or_else(|| (0..fig.cases.len()).collect());
        let mut series = Vec::new();
        for (k, &ci) in cases.iter().enumerate() {
            for &m in &p.methods {
                let mut pts: Vec<(f64, f64, f64)> = result
                    .rows
                    .iter()
                    .filter(|r| r.case == ci && r.score.method == m)
                    .map(|r| {
                        let e = r.score.r(fig.axis);
                        (r.score.pixels as f64, e.value, e.se)
                    })
                    .collect();
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                let errors = pts.iter().map(|p| p.2).collect();
                let pts: Vec<(f64, f64)> = pts.iter().map(|p| (p.0, p.1)).collect();
                if pts.is_empty() {
                    continue;
                }
                let label = if p.methods.len() > 1 {
                    format!("{} ({})", fig.cases[ci].label, m.label())
                } else {
                    fig.cases[ci].label.clone()
                };
                series.push(Series {
                    label,
                    color: COLORS[k % COLORS.len()],
                    marker: method_marker(m),
                    dashed: m == Method::THRESHOLD,
                    points: pts,
                    errors,
                    ring_last: true,
                });
            }
        }
        let plot = Plot {
            title: p.title.clone(),
            x_desc: "N, brightest pixels selected (ringed: all pixels, no selection)".into(),
            y_desc: y_desc.clone(),
            x_log: true,
            series,
            y_range: None,
        };
        let name = if p.suffix.is_empty() {
            fig.name.to_string()
        } else {
            format!("{}-{}", fig.name, p.suffix)
        };
        written.extend(plot::write(&out.join(name), &plot, (1000, 560))?);
    }
    if let Some(x_desc) = fig.best_vs_value {
        let mut series = Vec::new();
        for (k, &m) in fig.methods.iter().enumerate() {
            let est: Vec<(f64, f64, f64)> = (0..fig.cases.len())
                .filter_map(|ci| {
                    best_row(result, ci, m, fig.axis).map(|r| {
                        let e = r.score.r(fig.axis);
                        (fig.cases[ci].value, e.value, e.se)
                    })
                })
                .collect();
            series.push(Series {
                label: format!("{}, best N", m.label()),
                color: COLORS[k % COLORS.len()],
                marker: method_marker(m),
                dashed: m == Method::THRESHOLD,
                points: est.iter().map(|p| (p.0, p.1)).collect(),
                errors: est.iter().map(|p| p.2).collect(),
                ring_last: false,
            });
        }
        let pts = (0..fig.cases.len())
            .filter_map(|ci| {
                result
                    .rows
                    .iter()
                    .find(|r| r.case == ci && r.score.all_pixels)
                    .map(|r| (fig.cases[ci].value, r.score.r(fig.axis).value))
            })
            .collect();
        let top = series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.1))
            .chain(result.zero_r.iter().copied())
            .fold(0.0f64, f64::max);
        series.push(Series {
            label: "all pixels (no selection)".into(),
            color: COLORS[7],
            marker: Marker::Square,
            dashed: true,
            points: pts,
            errors: Vec::new(),
            ring_last: false,
        });
        series.push(Series {
            label: "slope always 0 (no information)".into(),
            color: COLORS[6],
            marker: Marker::None,
            dashed: true,
            points: fig
                .cases
                .iter()
                .zip(&result.zero_r)
                .map(|(c, &r)| (c.value, r))
                .collect(),
            errors: Vec::new(),
            ring_last: false,
        });
        let plot = Plot {
            title: format!("{}: R at the best N of each rule", fig.title),
            x_desc: x_desc.into(),
            y_desc: y_desc.clone(),
            x_log: false,
            series,
            y_range: Some(0.0..1.1 * top),
        };
        written.extend(plot::write(
            &out.join(format!("{}-best", fig.name)),
            &plot,
            (1000, 560),
        )?);
    }
    let path = out.join(format!("{}.md", fig.name));
    std::fs::write(&path, summary(result)).with_context(|| path.display().to_string())?;
    written.push(path);
    Ok(written)
}
