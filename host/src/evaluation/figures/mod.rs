//! The paper's §3 results, regenerated with the engine: one CSV, one or
//! more SVG plots and a Markdown summary per figure (`brightpix paper`).
//!
//! Every figure is a list of cases (simulation parameters) and methods; each
//! case is simulated once and the engine run for every (method, N) on its
//! frames (see [`super`]). Cases of one figure share the seed, so they share
//! the turbulence where only noise parameters differ (common random
//! numbers).

mod catalog;
mod charts;
mod linearity;
mod report;
pub mod sensitivity;
mod spots;

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, bail, Result};
use indicatif::{ProgressBar, ProgressStyle};

use super::plot::Marker;
use super::{default_pixel_grid, evaluate, jobs, Axis, Batch, Method, Score};
use crate::simulator::{SimulationParams, Simulator};

pub use catalog::figure;
pub use charts::write_figure;
pub use linearity::{linear_fit, noiseless_batch, run_linearity, LinearityFit, LINEARITY_Y_OFFSET};
pub use report::summary;

/// The all-pixel reference with negative pixels clipped to 0 (a threshold
/// at 0 counts), scored in every case next to the usual all-pixel one.
pub const CLIPPED_ALL: Method = Method::THRESHOLD.clipped();

/// Names of all figures, in the paper's order.
pub const FIGURES: [&str; 14] = [
    "spots",
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
    "sodium-paper",
    "linearity",
    "rules",
];

/// One simulated condition of a figure.
#[derive(Clone, Debug)]
pub struct Case {
    pub label: String,
    /// Added to the run's seed: cases that repeat one condition with other
    /// random numbers.
    pub seed_offset: u64,
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

/// One line of a figure's CSV.
#[derive(Clone, Debug)]
pub struct Row {
    pub case: usize,
    pub score: Score,
    pub frames: usize,
    pub saturated: usize,
    pub pixel_count: usize,
    /// Mean fraction of the spot's light inside the window.
    pub field_fraction: f64,
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

pub(crate) fn progress_bar(total: u64, name: &str) -> ProgressBar {
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
pub(crate) fn frames_for(default: usize, opts: &RunOptions) -> usize {
    match (opts.frames, opts.quick) {
        (Some(k), _) => k,
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
        let batch = Batch::simulate(&sim, opts.seed + c.seed_offset, frames, 512, &|n| {
            bar.inc(n as u64)
        });
        let n = batch.pixel_count();
        zero_r.push(zero_estimate_r(&batch, fig.axis));
        let grid = default_pixel_grid(n);
        let job_count = jobs(n, &fig.methods, &grid).len();
        let done = std::sync::atomic::AtomicUsize::new(0);
        bar.set_message(format!("{}: engine x {job_count}", c.label));
        let mut scores = evaluate(&batch, &fig.methods, &grid, &|| {
            let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let before = frames * k / job_count;
            let after = frames * (k + 1) / job_count;
            bar.inc((after - before) as u64);
        })?;
        scores.push(batch.score(CLIPPED_ALL, n)?);
        for score in scores {
            rows.push(Row {
                case: ci,
                score,
                frames,
                saturated: batch.saturated,
                pixel_count: n,
                field_fraction: batch.field_fraction(),
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
        .map(|t| axis.squared(t, batch.direction))
        .sum();
    (sq / batch.len().max(1) as f64).sqrt()
}

fn axis_words(axis: Axis) -> &'static str {
    match axis {
        Axis::X => "x",
        Axis::Y => "y",
        Axis::Both => "per slope, x and y pooled",
        Axis::Along => "parallel to the elongation",
        Axis::Across => "perpendicular to the elongation",
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
/// summary text.
pub fn run_and_write(name: &str, opts: &RunOptions) -> Result<String> {
    std::fs::create_dir_all(&opts.out).map_err(|e| anyhow!("{}: {e}", opts.out.display()))?;
    match name {
        "linearity" => return run_linearity(opts),
        "spots" => return spots::run_spots(opts),
        "sensitivity" => return sensitivity::run_sensitivity(opts),
        _ => {}
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
