//! The paper's §3 results, regenerated with the engine: one CSV, one or
//! more SVG plots and a Markdown summary per figure (`brightpix paper`).
//!
//! Every figure is a list of cases (simulation parameters) and methods; each
//! case is simulated once and the engine run for every (method, N) on its
//! frames (see [`super`]). Cases of one figure share the seed, so they share
//! the turbulence where only noise parameters differ (common random
//! numbers).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};

use super::plot::{self, Marker, Plot, Series, COLORS};
use super::{default_pixel_grid, evaluate, jobs, Axis, Batch, Method, Score};
use crate::simulator::{SimulationParams, Simulator, Source};

/// Names of all figures, in the paper's order.
pub const FIGURES: [&str; 12] = [
    "spot-size",
    "signal",
    "background-error",
    "read-noise",
    "outer-scale",
    "seeing",
    "rayleigh",
    "sodium",
    "subaperture-size",
    "subaperture-size-fov",
    "linearity",
    "rules",
];

/// One simulated condition of a figure.
#[derive(Clone, Debug)]
pub struct Case {
    pub label: String,
    /// The varied parameter's value (for CSV and summary plots).
    pub value: f64,
    pub params: SimulationParams,
}

/// One plot of a figure: a subset of its cases and methods.
#[derive(Clone, Debug)]
pub struct Panel {
    /// File name suffix (`""`: `<figure>.svg`, `"ext"`: `<figure>-ext.svg`).
    pub suffix: &'static str,
    pub title: String,
    /// Indices into the figure's cases; `None`: all.
    pub cases: Option<Vec<usize>>,
    pub methods: Vec<Method>,
}

/// A figure of the paper's §3 (other than linearity).
#[derive(Clone, Debug)]
pub struct Figure {
    pub name: &'static str,
    /// What the paper's figure shows, with its number.
    pub title: String,
    /// Name of the varied parameter (CSV column `value`).
    pub parameter: &'static str,
    pub cases: Vec<Case>,
    pub methods: Vec<Method>,
    /// The slope component R is plotted for.
    pub axis: Axis,
    /// Default frames per case.
    pub frames: usize,
    pub panels: Vec<Panel>,
    /// Also plot the best R over N against the parameter (x label).
    pub best_vs_value: Option<&'static str>,
}

/// Options of a `brightpix paper` run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    pub out: PathBuf,
    /// Frames per case (`None`: the figure's default, or the quick size).
    pub frames: Option<usize>,
    pub seed: u64,
    pub quick: bool,
}

const MEAN4: Method = Method::subtract_mean(4);
const FILTER4: Method = Method::SUBTRACT_NEXT.with_level_filter(4);

fn canary() -> SimulationParams {
    SimulationParams::canary()
}

fn case(label: impl Into<String>, value: f64, params: SimulationParams) -> Case {
    Case {
        label: label.into(),
        value,
        params,
    }
}

fn panel(title: impl Into<String>, methods: &[Method]) -> Panel {
    Panel {
        suffix: "",
        title: title.into(),
        cases: None,
        methods: methods.to_vec(),
    }
}

fn snr(params: &SimulationParams) -> f64 {
    let n = params.photons;
    let npix = (params.pixels_per_subaperture as f64).powi(2);
    n / (n + params.read_noise_e.powi(2) * npix).sqrt()
}

/// The figure called `name` (not `linearity`, see [`run_linearity`]).
pub fn figure(name: &str) -> Option<Figure> {
    const NGS_FRAMES: usize = 20_000;
    let sn = Method::SUBTRACT_NEXT;
    let th = Method::THRESHOLD;
    let f = match name {
        "spot-size" => Figure {
            name: "spot-size",
            title: "Fig. 3c: spot size (Airy diameter)".into(),
            parameter: "airy_diameter_arcsec",
            cases: [0.35, 0.7, 1.4, 2.1]
                .iter()
                .map(|&a| {
                    case(
                        format!("Airy {a}\""),
                        a,
                        SimulationParams {
                            airy_diameter_arcsec: a,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![th, sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 3c: spot size, with (circles) and without (triangles, dashed) subtraction",
                &[th, sn],
            )],
            best_vs_value: None,
        },
        "signal" => Figure {
            name: "signal",
            title: "Fig. 4: signal level".into(),
            parameter: "photons",
            cases: [100.0, 150.0, 200.0, 500.0, 1e6]
                .iter()
                .map(|&n| {
                    // 1e6 photons would saturate a 16-bit camera at 1 e-/count
                    // (peak pixel ~1e5 e-): 16 e-/count keeps every pixel
                    // below 2^16 (the read noise is then below one count,
                    // irrelevant at this flux).
                    let gain = if n > 2e5 { 16.0 } else { 1.0 };
                    let p = SimulationParams {
                        photons: n,
                        gain_e_per_count: gain,
                        ..canary()
                    };
                    case(format!("{n} ph (SNR {:.1})", snr(&p)), n, p)
                })
                .collect(),
            methods: vec![sn, th],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel("Fig. 4: signal level (subtract-next)", &[sn])],
            best_vs_value: None,
        },
        "background-error" => Figure {
            name: "background-error",
            title: "Fig. 5: background subtraction error".into(),
            parameter: "background_error_counts",
            cases: [0.0, 1.0, 2.0, 10.0]
                .iter()
                .map(|&b| {
                    case(
                        format!("bg error {b}"),
                        b,
                        SimulationParams {
                            background_error: b,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![th, sn, MEAN4],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 5: background error, with (circles) and without (triangles, dashed) subtraction",
                &[th, sn],
            )],
            best_vs_value: Some("background error (counts)"),
        },
        "read-noise" => {
            let values = [0.1, 1.0, 2.0, 3.0, 5.0, 7.0, 10.0];
            let cases: Vec<Case> = values
                .iter()
                .map(|&r| {
                    let p = SimulationParams {
                        read_noise_e: r,
                        ..canary()
                    };
                    case(format!("{r} e- (SNR {:.1})", snr(&p)), r, p)
                })
                .collect();
            Figure {
                name: "read-noise",
                title: "Fig. 6: read noise".into(),
                parameter: "read_noise_e",
                cases,
                methods: vec![th, sn, MEAN4, FILTER4],
                axis: Axis::Both,
                frames: NGS_FRAMES,
                panels: vec![
                    Panel {
                        suffix: "",
                        title: "Fig. 6: read noise, with (circles) and without (triangles, dashed) subtraction".into(),
                        cases: Some(vec![0, 1, 2, 4, 6]),
                        methods: vec![th, sn],
                    },
                    Panel {
                        suffix: "ext",
                        title: "Read noise 5 and 10 e-: the paper's suggested fixes (subtract-mean M=4, level filter)".into(),
                        cases: Some(vec![4, 6]),
                        methods: vec![th, sn, MEAN4, FILTER4],
                    },
                ],
                best_vs_value: Some("read noise (e- rms)"),
            }
        }
        "outer-scale" => Figure {
            name: "outer-scale",
            title: "Fig. 7a: outer scale".into(),
            parameter: "outer_scale_m",
            cases: [5.0, 10.0, 30.0, 100.0, f64::INFINITY]
                .iter()
                .map(|&l0| {
                    case(
                        if l0.is_finite() {
                            format!("L0 {l0} m")
                        } else {
                            "L0 inf (Kolmogorov)".into()
                        },
                        l0,
                        SimulationParams {
                            outer_scale_m: l0,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel("Fig. 7a: outer scale (subtract-next)", &[sn])],
            best_vs_value: None,
        },
        "seeing" => Figure {
            name: "seeing",
            title: "Fig. 7b: seeing (d/r0, d = 0.6 m)".into(),
            parameter: "d_over_r0",
            cases: [2.0, 3.0, 4.0, 4.8, 6.0, 8.0, 10.0]
                .iter()
                .map(|&dr| {
                    let r0 = 0.6 / dr;
                    case(
                        format!("d/r0 {dr} (r0 {:.1} cm)", r0 * 100.0),
                        dr,
                        SimulationParams { r0_m: r0, ..canary() },
                    )
                })
                .collect(),
            methods: vec![sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel("Fig. 7b: seeing (subtract-next)", &[sn])],
            best_vs_value: None,
        },
        "rayleigh" => Figure {
            name: "rayleigh",
            title: "Fig. 8b: Rayleigh LGS, x parallel to elongation".into(),
            parameter: "gate_depth_m",
            cases: [0.0, 500.0, 1000.0, 1500.0]
                .iter()
                .map(|&g| {
                    case(
                        format!("gate {g} m"),
                        g,
                        SimulationParams::canary_rayleigh(g),
                    )
                })
                .collect(),
            methods: vec![sn, th],
            axis: Axis::X,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 8b: Rayleigh LGS, 20 km, edge sub-aperture (R parallel to elongation, subtract-next)",
                &[sn],
            )],
            best_vs_value: None,
        },
        "sodium" => Figure {
            name: "sodium",
            title: "Fig. 9b: sodium LGS, x parallel to elongation".into(),
            parameter: "separation_m",
            cases: [0.0, 8e3, 14e3]
                .iter()
                .map(|&s| {
                    case(
                        format!("s = {} km", s / 1e3),
                        s,
                        SimulationParams::sodium(s),
                    )
                })
                .collect(),
            methods: vec![sn, th],
            axis: Axis::X,
            frames: 8_000,
            panels: vec![panel(
                "Fig. 9b: sodium LGS, 21 m from launch, 24\" FOV, 1000 ph (R parallel, subtract-next)",
                &[sn],
            )],
            best_vs_value: None,
        },
        "subaperture-size" => Figure {
            name: "subaperture-size",
            title: "Fig. 10: pixels per sub-aperture at a fixed 0.22\"/pixel".into(),
            parameter: "pixels_across",
            cases: [6u32, 8, 10, 12, 16, 20, 24]
                .iter()
                .map(|&n| {
                    case(
                        format!("{n}x{n} ({:.2}\" FOV)", n as f64 * 0.22),
                        n as f64,
                        SimulationParams {
                            pixels_per_subaperture: n,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 10: sub-aperture size at 0.22\"/pixel (subtract-next)",
                &[sn],
            )],
            best_vs_value: None,
        },
        "subaperture-size-fov" => Figure {
            name: "subaperture-size-fov",
            title: "Fig. 10 (variant): pixels per sub-aperture at a fixed 3.52\" field".into(),
            parameter: "pixels_across",
            cases: [6u32, 8, 10, 12, 16, 20, 24]
                .iter()
                .map(|&n| {
                    let scale = 3.52 / n as f64;
                    case(
                        format!("{n}x{n} ({scale:.3}\"/px)"),
                        n as f64,
                        SimulationParams {
                            pixels_per_subaperture: n,
                            pixel_scale_arcsec: scale,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 10 variant: sub-aperture size at a fixed 3.52\" field (R in each case's pixels)",
                &[sn],
            )],
            best_vs_value: None,
        },
        "rules" => {
            let methods = vec![
                th,
                sn,
                Method::SUBTRACT_NEXT_DISTINCT,
                Method::subtract_mean(2),
                MEAN4,
                Method::subtract_mean(8),
                FILTER4,
                MEAN4.with_level_filter(4),
            ];
            Figure {
                name: "rules",
                title: "All rules at the paper's defaults".into(),
                parameter: "defaults",
                cases: vec![case("defaults", 0.0, canary())],
                methods: methods.clone(),
                axis: Axis::Both,
                frames: NGS_FRAMES,
                panels: vec![panel(
                    "All brightpix rules at the paper's defaults (200 ph, 2 e-)",
                    &methods,
                )],
                best_vs_value: None,
            }
        }
        _ => return None,
    };
    Some(f)
}

/// One line of a figure's CSV.
#[derive(Clone, Debug)]
pub struct Row {
    pub case: usize,
    pub score: Score,
    pub frames: usize,
    pub saturated: usize,
    pub pixel_count: usize,
}

/// A figure's results.
#[derive(Clone, Debug)]
pub struct FigureResult {
    pub figure: Figure,
    pub rows: Vec<Row>,
    /// Per case, R of a slope that is always 0 (the RMS of the true slope on
    /// the figure's axis): an estimator with no information.
    pub zero_r: Vec<f64>,
    pub seconds: f64,
}

fn progress_bar(total: u64, name: &str) -> ProgressBar {
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template(
            "{prefix:>22} [{elapsed_precise}] {wide_bar} {percent:>3}% eta {eta} {msg}",
        )
        .expect("valid template"),
    );
    bar.set_prefix(name.to_string());
    bar
}

/// Frames per case for a figure under `opts`.
fn frames_for(default: usize, opts: &RunOptions) -> usize {
    match (opts.frames, opts.quick) {
        (Some(k), _) => k.max(2),
        (None, true) => (default / 25).max(200),
        (None, false) => default,
    }
}

/// Runs one figure (simulation and engine), without writing anything.
pub fn run_figure(fig: Figure, opts: &RunOptions) -> Result<FigureResult> {
    let started = Instant::now();
    let frames = frames_for(fig.frames, opts);
    let bar = progress_bar((2 * frames * fig.cases.len()) as u64, fig.name);
    let mut rows = Vec::new();
    let mut zero_r = Vec::new();
    for (ci, c) in fig.cases.iter().enumerate() {
        bar.set_message(format!("{}: simulating", c.label));
        let sim = Simulator::new(c.params.clone())
            .map_err(|e| anyhow!("{}: {}: {e}", fig.name, c.label))?;
        let batch = Batch::simulate(&sim, opts.seed, frames, 512, &|n| bar.inc(n as u64));
        let n = batch.pixel_count();
        zero_r.push(zero_estimate_r(&batch, fig.axis));
        let grid = default_pixel_grid(n);
        let job_count = jobs(n, &fig.methods, &grid).len();
        let done = std::sync::atomic::AtomicUsize::new(0);
        bar.set_message(format!("{}: engine x {job_count}", c.label));
        let scores = evaluate(&batch, &fig.methods, &grid, &|| {
            let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let before = frames * k / job_count;
            let after = frames * (k + 1) / job_count;
            bar.inc((after - before) as u64);
        })?;
        for score in scores {
            rows.push(Row {
                case: ci,
                score,
                frames,
                saturated: batch.saturated,
                pixel_count: n,
            });
        }
    }
    bar.finish_and_clear();
    Ok(FigureResult {
        figure: fig,
        rows,
        zero_r,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// R of the estimate "slope = 0": the RMS of the true slopes on `axis`.
pub fn zero_estimate_r(batch: &Batch, axis: Axis) -> f64 {
    let sq: f64 = batch
        .true_slopes
        .iter()
        .map(|t| match axis {
            Axis::X => t[0] * t[0],
            Axis::Y => t[1] * t[1],
            Axis::Both => 0.5 * (t[0] * t[0] + t[1] * t[1]),
        })
        .sum();
    (sq / batch.len().max(1) as f64).sqrt()
}

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
        "figure,case,value,method,N,pixels_in_window,all_pixels,frames,R_x,se_x,R_y,se_y,R_xy,se_xy,pixel_scale_arcsec,invalid,saturated_pixels\n",
    );
    for row in &result.rows {
        let c = &fig.cases[row.case];
        let s = &row.score;
        let (x, y, b) = (s.r(Axis::X), s.r(Axis::Y), s.r(Axis::Both));
        writeln!(
            csv,
            "{},\"{}\",{},{},{},{},{},{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{}",
            fig.name,
            c.label.replace('"', "\"\""),
            fmt_value(c.value),
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
            c.params.pixel_scale_arcsec,
            s.invalid,
            row.saturated
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
                let mut pts: Vec<(f64, f64)> = result
                    .rows
                    .iter()
                    .filter(|r| r.case == ci && r.score.method == m)
                    .map(|r| (r.score.pixels as f64, r.score.r(fig.axis).value))
                    .collect();
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
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
            format!("{}.svg", fig.name)
        } else {
            format!("{}-{}.svg", fig.name, p.suffix)
        };
        let path = out.join(name);
        plot::write_svg(&path, &plot, (1000, 560))?;
        written.push(path);
    }
    if let Some(x_desc) = fig.best_vs_value {
        let mut series = Vec::new();
        for (k, &m) in fig.methods.iter().enumerate() {
            let pts = (0..fig.cases.len())
                .filter_map(|ci| {
                    best_row(result, ci, m, fig.axis)
                        .map(|r| (fig.cases[ci].value, r.score.r(fig.axis).value))
                })
                .collect();
            series.push(Series {
                label: format!("{}, best N", m.label()),
                color: COLORS[k % COLORS.len()],
                marker: method_marker(m),
                dashed: m == Method::THRESHOLD,
                points: pts,
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
        let path = out.join(format!("{}-best.svg", fig.name));
        plot::write_svg(&path, &plot, (1000, 560))?;
        written.push(path);
    }
    let path = out.join(format!("{}.md", fig.name));
    std::fs::write(&path, summary(result)).with_context(|| path.display().to_string())?;
    written.push(path);
    Ok(written)
}

fn axis_words(axis: Axis) -> &'static str {
    match axis {
        Axis::X => "x, parallel to elongation",
        Axis::Y => "y",
        Axis::Both => "per slope, x and y pooled",
    }
}

fn method_marker(m: Method) -> Marker {
    if m == Method::SUBTRACT_NEXT {
        Marker::Circle
    } else if m == Method::THRESHOLD {
        Marker::Triangle
    } else if m.level_filter.is_some() {
        Marker::Cross
    } else {
        Marker::Square
    }
}

/// The row with the lowest R of `method` in case `ci` (any N, including all
/// pixels).
pub fn best_row(result: &FigureResult, ci: usize, method: Method, axis: Axis) -> Option<&Row> {
    result
        .rows
        .iter()
        .filter(|r| r.case == ci && r.score.method == method)
        .min_by(|a, b| a.score.mse(axis).value.total_cmp(&b.score.mse(axis).value))
}

/// Markdown summary: per case and method, the best N, R there, R at N = 20
/// and with all pixels, the N range within 5% of the best R, and the paired
/// gain over all pixels.
pub fn summary(result: &FigureResult) -> String {
    let fig = &result.figure;
    let axis = fig.axis;
    let frames = result.rows.first().map_or(0, |r| r.frames);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "### {} (`{}`)\n\n{} frames per case, R {} in pixels, +- one standard error; {:.0} s.\n",
        fig.title,
        fig.name,
        frames,
        axis_words(axis),
        result.seconds
    );
    let _ = writeln!(
        s,
        "| case | method | best N | R(best) | R(N=20) | R(all) | N with R within 5% of best | R(all) - R(best), paired | R(slope 0) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    for (ci, c) in fig.cases.iter().enumerate() {
        for &m in &fig.methods {
            let rows: Vec<&Row> = result
                .rows
                .iter()
                .filter(|r| r.case == ci && r.score.method == m)
                .collect();
            let Some(best) = best_row(result, ci, m, axis) else {
                continue;
            };
            let rb = best.score.r(axis);
            let at = |n: usize| rows.iter().find(|r| r.score.pixels == n);
            let all = rows.iter().find(|r| r.score.all_pixels);
            let near: Vec<usize> = rows
                .iter()
                .filter(|r| r.score.r(axis).value <= 1.05 * rb.value)
                .map(|r| r.score.pixels)
                .collect();
            let fmt = |r: Option<&Row>| {
                r.map_or("-".into(), |r| {
                    let e = r.score.r(axis);
                    format!("{:.4} ± {:.4}", e.value, e.se)
                })
            };
            let gain = all.map_or("-".into(), |a| {
                let d = a.score.paired_difference(&best.score, axis);
                format!("{:.4} ± {:.4}", d.value, d.se)
            });
            let _ = writeln!(
                s,
                "| {} | {} | {}{} | {:.4} ± {:.4} | {} | {} | {}..{} | {} | {:.3} |",
                c.label,
                m.label(),
                best.score.pixels,
                if best.score.all_pixels { " (all)" } else { "" },
                rb.value,
                rb.se,
                fmt(at(20).copied()),
                fmt(all.copied()),
                near.iter().min().copied().unwrap_or(0),
                near.iter().max().copied().unwrap_or(0),
                gain,
                result.zero_r.get(ci).copied().unwrap_or(f64::NAN)
            );
        }
    }
    let invalid: usize = result.rows.iter().map(|r| r.score.invalid).sum();
    let saturated: usize = result
        .rows
        .iter()
        .filter(|r| r.score.all_pixels)
        .map(|r| r.saturated)
        .sum();
    let _ = writeln!(
        s,
        "\nInvalid engine results (flux <= 0): {invalid}; saturated pixels: {saturated}."
    );
    s
}

/// Runs `name` (a figure or `linearity`) and writes its files; returns the
/// summary text.
pub fn run_and_write(name: &str, opts: &RunOptions) -> Result<String> {
    std::fs::create_dir_all(&opts.out).with_context(|| opts.out.display().to_string())?;
    if name == "linearity" {
        return run_linearity(opts);
    }
    let Some(fig) = figure(name) else {
        bail!(
            "unknown figure {name:?}; one of: {}, all",
            FIGURES.join(", ")
        );
    };
    let result = run_figure(fig, opts)?;
    write_figure(&result, &opts.out)?;
    Ok(summary(&result))
}

// ---------------------------------------------------------------------------
// Linearity (paper §2.4, §3.8, Fig. 11)
// ---------------------------------------------------------------------------

/// The linearity ramp's constant y position (pixels).
pub const LINEARITY_Y_OFFSET: f64 = 0.2;

/// N values of the linearity study: the union of the paper's Fig. 11a-c.
const LINEARITY_N: [usize; 13] = [1, 3, 4, 5, 7, 9, 10, 13, 15, 20, 25, 50, 100];

/// Per (method, N): linear fit of the measured slope against the all-pixel
/// slope.
#[derive(Clone, Debug)]
pub struct LinearityFit {
    pub method: Method,
    pub pixels: usize,
    /// Fitted gain (d measured / d all-pixel).
    pub gain: f64,
    /// RMS of the residual from the fitted line (pixels).
    pub rms_nonlinearity: f64,
    /// Largest absolute residual from the fitted line (pixels).
    pub max_nonlinearity: f64,
}

/// Fits `y = a + b x`; returns `(b, rms residual, max |residual|)`.
pub fn linear_fit(x: &[f64], y: &[f64]) -> (f64, f64, f64) {
    let n = x.len() as f64;
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    let b = sxy / sxx;
    let a = my - b * mx;
    let res: Vec<f64> = x.iter().zip(y).map(|(xi, yi)| yi - a - b * xi).collect();
    let rms = (res.iter().map(|r| r * r).sum::<f64>() / n).sqrt();
    let max = res.iter().fold(0.0f64, |m, r| m.max(r.abs()));
    (b, rms, max)
}

/// The noiseless camera of the linearity study: each noiseless image scaled
/// so the brightest pixel of the ramp is 50000 counts, plus a 50-count
/// background, rounded (no photon or read noise: the paper's "noiseless"
/// WFS, digitised for the engine).
pub fn noiseless_batch(sim: &Simulator, tilts: &[[f64; 2]], seed: u64) -> Batch {
    let frames = sim.frames_with_tilts(seed, 0, tilts);
    let peak = frames
        .iter()
        .flat_map(|f| f.noiseless.iter().copied())
        .fold(0.0f64, f64::max);
    let scale = 50_000.0 / peak;
    let background = 50.0;
    let mut batch = Batch::for_simulator(sim);
    batch.background_q4 = (background * 16.0) as i32;
    batch.bit_depth = 16;
    for f in &frames {
        batch.raw.extend(
            f.noiseless
                .iter()
                .map(|&v| (v * scale + background).round() as u16),
        );
        batch.true_slopes.push(f.true_slope);
    }
    batch
}

/// The linearity study: a noiseless, turbulence-free spot (defaults
/// otherwise) moved along x by a tilt ramp; the engine's slope for each N
/// against its all-pixel slope, with and without subtraction.
pub fn run_linearity(opts: &RunOptions) -> Result<String> {
    let started = Instant::now();
    let steps = match (opts.frames, opts.quick) {
        (Some(k), _) => k.max(3),
        (None, true) => 61,
        (None, false) => 301,
    };
    let params = SimulationParams {
        turbulence: false,
        read_noise_e: 0.0,
        source: Source::Ngs,
        ..canary()
    };
    let sim = Simulator::new(params).map_err(|e| anyhow!("linearity: {e}"))?;
    let max_tilt = 3.0;
    // A small constant y offset: with the spot exactly centred in y, pairs of
    // pixels tie exactly (noiseless, integer counts), and subtract-next with
    // N = 1, 3, ... then weighs them all 0 (SPEC §3; the paper's float images
    // never tie exactly).
    let tilts: Vec<[f64; 2]> = (0..steps)
        .map(|i| [max_tilt * i as f64 / (steps - 1) as f64, LINEARITY_Y_OFFSET])
        .collect();
    let methods = [Method::SUBTRACT_NEXT, Method::THRESHOLD];
    let n = sim.size() * sim.size();
    let bar = progress_bar(
        (1 + methods.len() * (LINEARITY_N.len() + 1)) as u64,
        "linearity",
    );
    let batch = noiseless_batch(&sim, &tilts, opts.seed);
    bar.inc(1);
    let (all, _) = batch.engine_slopes(Method::SUBTRACT_NEXT, n)?;
    let all_x: Vec<f64> = all.iter().map(|s| s[0]).collect();
    let mut ns: Vec<usize> = LINEARITY_N.to_vec();
    ns.push(n);
    let mut curves: Vec<(Method, usize, Vec<f64>)> = Vec::new();
    for &m in &methods {
        for &k in &ns {
            let (s, _) = batch.engine_slopes(m, k)?;
            curves.push((m, k, s.iter().map(|v| v[0]).collect()));
            bar.inc(1);
        }
    }
    bar.finish_and_clear();

    let mut csv =
        String::from("tilt_px,true_slope_x,all_pixels_slope_x,method,N,slope_x,residual_x\n");
    for (m, k, xs) in &curves {
        for (i, &v) in xs.iter().enumerate() {
            writeln!(
                csv,
                "{:.4},{:.6},{:.6},{},{},{:.6},{:.6}",
                tilts[i][0],
                batch.true_slopes[i][0],
                all_x[i],
                m.label(),
                k,
                v,
                v - all_x[i]
            )?;
        }
    }
    std::fs::write(opts.out.join("linearity.csv"), csv)?;

    let fits: Vec<LinearityFit> = curves
        .iter()
        .map(|(m, k, xs)| {
            let (gain, rms, max) = linear_fit(&all_x, xs);
            LinearityFit {
                method: *m,
                pixels: *k,
                gain,
                rms_nonlinearity: rms,
                max_nonlinearity: max,
            }
        })
        .collect();

    let label = |k: usize| {
        if k >= n {
            format!("all ({n})")
        } else {
            format!("N={k}")
        }
    };
    // (a) measured vs all-pixel slope, subtract-next, offset for clarity.
    let a_ns = [1, 3, 5, 9, 20, 50, n];
    let step_a = 0.75;
    let mut series = Vec::new();
    for (j, &k) in a_ns.iter().enumerate() {
        let (_, _, xs) = curves
            .iter()
            .find(|(m, kk, _)| *m == Method::SUBTRACT_NEXT && *kk == k)
            .expect("computed");
        let off = step_a * (a_ns.len() - 1 - j) as f64;
        series.push(Series {
            label: format!("{} (+{off:.2})", label(k)),
            color: COLORS[j % COLORS.len()],
            marker: Marker::None,
            dashed: false,
            points: all_x.iter().zip(xs).map(|(&x, &y)| (x, y + off)).collect(),
            ring_last: false,
        });
    }
    let plot_a = Plot {
        title: "Fig. 11a: linearity, subtract-next (noiseless; traces offset)".into(),
        x_desc: "slope with all pixels (pixels)".into(),
        y_desc: "slope with N brightest pixels + offset (pixels)".into(),
        x_log: false,
        series,
        y_range: None,
    };
    plot::write_svg(&opts.out.join("linearity-a.svg"), &plot_a, (1000, 620))?;
    // (b), (c): residual after subtracting the all-pixel slope.
    let bc_ns = [1, 9, 15, 20, 25, 50, 100];
    for (m, file, title) in [
        (
            Method::SUBTRACT_NEXT,
            "linearity-b.svg",
            "Fig. 11b: residual, subtract-next (traces offset)",
        ),
        (
            Method::THRESHOLD,
            "linearity-c.svg",
            "Fig. 11c: residual, threshold only (traces offset)",
        ),
    ] {
        let step = 0.2;
        let mut series = Vec::new();
        for (j, &k) in bc_ns.iter().enumerate() {
            let (_, _, xs) = curves
                .iter()
                .find(|(mm, kk, _)| *mm == m && *kk == k)
                .expect("computed");
            let off = step * (bc_ns.len() - 1 - j) as f64;
            series.push(Series {
                label: format!("{} (+{off:.1})", label(k)),
                color: COLORS[j % COLORS.len()],
                marker: Marker::None,
                dashed: false,
                points: all_x
                    .iter()
                    .zip(xs)
                    .map(|(&x, &y)| (x, y - x + off))
                    .collect(),
                ring_last: false,
            });
        }
        let plot = Plot {
            title: title.into(),
            x_desc: "slope with all pixels (pixels)".into(),
            y_desc: "slope(N) - slope(all) + offset (pixels)".into(),
            x_log: false,
            series,
            y_range: Some(-0.6..(step * bc_ns.len() as f64 + 0.6)),
        };
        plot::write_svg(&opts.out.join(file), &plot, (1000, 620))?;
    }

    let mut s = String::new();
    let _ = writeln!(
        s,
        "### Fig. 11: linearity (`linearity`)\n\n{steps} tilts from 0 to {max_tilt} px along x (y = {LINEARITY_Y_OFFSET} px), no turbulence, no noise (image scaled to a 50000-count peak); linear fit of the engine's slope against its all-pixel slope; {:.0} s.\n",
        started.elapsed().as_secs_f64()
    );
    let _ = writeln!(
        s,
        "| N | subtract-next gain | subtract-next RMS / max nonlinearity (px) | threshold gain | threshold RMS / max nonlinearity (px) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|");
    for &k in &ns {
        let f = |m: Method| {
            fits.iter()
                .find(|f| f.method == m && f.pixels == k)
                .expect("computed")
        };
        let (a, b) = (f(Method::SUBTRACT_NEXT), f(Method::THRESHOLD));
        let _ = writeln!(
            s,
            "| {} | {:.4} | {:.4} / {:.4} | {:.4} | {:.4} / {:.4} |",
            label(k),
            a.gain,
            a.rms_nonlinearity,
            a.max_nonlinearity,
            b.gain,
            b.rms_nonlinearity,
            b.max_nonlinearity
        );
    }
    std::fs::write(opts.out.join("linearity.md"), &s)?;
    Ok(s)
}
