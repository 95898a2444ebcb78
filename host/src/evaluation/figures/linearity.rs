//! Linearity (paper §2.4, §3.8, Fig. 11): a noiseless, turbulence-free
//! spot moved by a tilt ramp, the engine's slope for each N against its
//! all-pixel slope.

use std::fmt::Write as _;
use std::time::Instant;

use anyhow::{anyhow, Result};

use super::{progress_bar, RunOptions};
use crate::evaluation::plot::{self, Marker, Plot, Series, COLORS};
use crate::evaluation::{Batch, Method};
use crate::simulator::{SimulationParams, Simulator, Source};

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
        (Some(k), _) => k,
        (None, true) => 61,
        (None, false) => 301,
    };
    let params = SimulationParams {
        turbulence: false,
        read_noise_e: 0.0,
        source: Source::Ngs,
        ..SimulationParams::canary()
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
            errors: Vec::new(),
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
    plot::write(&opts.out.join("linearity-a"), &plot_a, (1000, 620))?;
    // (b), (c): residual after subtracting the all-pixel slope.
    let bc_ns = [1, 9, 15, 20, 25, 50, 100];
    for (m, file, title) in [
        (
            Method::SUBTRACT_NEXT,
            "linearity-b",
            "Fig. 11b: residual, subtract-next (traces offset)",
        ),
        (
            Method::THRESHOLD,
            "linearity-c",
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
                errors: Vec::new(),
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
        plot::write(&opts.out.join(file), &plot, (1000, 620))?;
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
