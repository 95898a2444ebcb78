//! # Evaluation: the paper's metric R with the engine's own arithmetic
//!
//! Basden, Myers & Gendron (2011) eq. 1: `R = sqrt(mean_m (S_true(m) -
//! S_est(m))^2)`, where `S_true` is the centre of gravity of the noiseless
//! image without selection (f64, [`SpotFrame::true_slope`]) and `S_est` the
//! slope the **firmware's streaming engine** computes from the noisy camera
//! image ([`SpotFrame::raw`]) with a selection rule and N: a one-window camera
//! of the sub-aperture's size, the simulator's background subtracted as
//! `round(calibration_background * 16)` (1/16 count), slopes `/ 65536`.
//!
//! Images do not depend on the rule or N, so a [`Batch`] of frames is
//! simulated once and the engine is run on it for every (method, N)
//! ([`evaluate`], in parallel over the combinations). Every combination sees
//! the same frames, so differences between methods are estimated from
//! paired per-frame errors ([`Score::paired_difference`]), far more precisely
//! than from two independent R's.
//!
//! `N >= n` (the window's pixel count) is "all pixels": no selection, no
//! subtraction (SPEC.md §3), whatever the rule: the reference point of every
//! curve.
//!
//! Standard errors: `R^2` is a mean over frames of per-frame squared errors;
//! its standard error is their standard deviation over `sqrt(K)`, and that of
//! `R` follows by the delta method (`se(R) = se(R^2) / (2R)`).

pub mod figures;
pub mod plot;
pub mod recorded;
pub mod stats;
pub mod tune;

use anyhow::{anyhow, Context, Result};
use brightpix_protocol::{Camera, LevelFilter, SelectionRule, SubapertureWindow};
use rayon::prelude::*;

use crate::config_file::{PixelCounts, ProcessingConfig};
use crate::engine_runner::HostEngine;
use crate::simulator::{SimulationParams, Simulator, SpotFrame};

/// A selection rule with an optional level filter (SPEC.md §3-4), and
/// optionally a calibration threshold at 0 counts that clips negative
/// (background-subtracted) pixels to 0 before selection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Method {
    pub rule: SelectionRule,
    /// Gain shift of the temporal level filter, if any.
    pub level_filter: Option<u8>,
    /// Clip pixels below 0 counts to 0 (a threshold of 0, SPEC.md §2).
    pub clip_negative: bool,
}

impl Method {
    /// The paper's "N+1th subtracted algorithm".
    pub const SUBTRACT_NEXT: Method = Method {
        rule: SelectionRule::SubtractNext,
        level_filter: None,
        clip_negative: false,
    };
    /// The paper's selection without subtraction.
    pub const THRESHOLD: Method = Method {
        rule: SelectionRule::Threshold,
        level_filter: None,
        clip_negative: false,
    };
    /// DARC as flown.
    pub const SUBTRACT_NEXT_DISTINCT: Method = Method {
        rule: SelectionRule::SubtractNextDistinct,
        level_filter: None,
        clip_negative: false,
    };

    /// Subtract the mean of the M values below v(N).
    pub const fn subtract_mean(m: u16) -> Method {
        Method {
            rule: SelectionRule::SubtractMean { count: m },
            level_filter: None,
            clip_negative: false,
        }
    }

    /// This rule with a level filter of gain `2^-gain_shift`.
    pub const fn with_level_filter(self, gain_shift: u8) -> Method {
        Method {
            level_filter: Some(gain_shift),
            ..self
        }
    }

    /// This rule after clipping negative pixels to 0.
    pub const fn clipped(self) -> Method {
        Method {
            clip_negative: true,
            ..self
        }
    }

    /// Short name: `subtract-next`, `threshold`, `subtract-mean(M=4)`,
    /// `subtract-next+filter(g=4)`.
    pub fn label(&self) -> String {
        let rule = match self.rule {
            SelectionRule::Threshold => "threshold".to_string(),
            SelectionRule::SubtractNext => "subtract-next".to_string(),
            SelectionRule::SubtractNextDistinct => "subtract-next-distinct".to_string(),
            SelectionRule::SubtractMean { count } => format!("subtract-mean(M={count})"),
        };
        let rule = match self.level_filter {
            Some(g) => format!("{rule}+filter(g={g})"),
            None => rule,
        };
        if self.clip_negative {
            format!("{rule}+clip0")
        } else {
            rule
        }
    }
}

/// A batch of simulated frames of one sub-aperture: what the engine needs
/// (raw images) and what the metric compares against (true slopes).
#[derive(Clone, Debug)]
pub struct Batch {
    /// Side of the images (pixels).
    pub size: usize,
    /// The camera's bit depth.
    pub bit_depth: u8,
    /// Background subtracted by calibration, 1/16 count.
    pub background_q4: i32,
    /// Raw images, `size * size` per frame, one after the other.
    pub raw: Vec<u16>,
    /// Centre of gravity of the noiseless image, pixels `[x, y]`.
    pub true_slopes: Vec<[f64; 2]>,
    /// Pixels clamped at the camera's maximum, over all frames.
    pub saturated: usize,
    /// Unit vector of the LGS elongation on the detector (`[1, 0]` for a
    /// NGS): the direction of [`Axis::Along`].
    pub direction: [f64; 2],
    /// Sum over frames of [`SpotFrame::field_fraction`].
    pub field_fraction_sum: f64,
}

impl Batch {
    /// An empty batch for `sim`'s images.
    pub fn for_simulator(sim: &Simulator) -> Batch {
        Batch {
            size: sim.size(),
            bit_depth: sim.params().bit_depth,
            background_q4: (sim.calibration_background() * 16.0).round() as i32,
            raw: Vec::new(),
            true_slopes: Vec::new(),
            saturated: 0,
            direction: sim.params().source.elongation_direction(),
            field_fraction_sum: 0.0,
        }
    }

    /// Mean fraction of the spot's light on the detector (1: nothing
    /// truncated).
    pub fn field_fraction(&self) -> f64 {
        self.field_fraction_sum / self.len().max(1) as f64
    }

    /// Appends simulated frames (their noiseless images are dropped).
    pub fn push_frames(&mut self, frames: &[SpotFrame]) {
        for f in frames {
            assert_eq!(f.size, self.size, "frame size differs from the batch's");
            self.raw.extend_from_slice(&f.raw);
            self.true_slopes.push(f.true_slope);
            self.saturated += f.saturated;
            self.field_fraction_sum += f.field_fraction;
        }
    }

    /// Simulates frames `0 .. count` of run `seed` in chunks of `chunk`
    /// frames (parallel inside a chunk), calling `progress(frames_done)`
    /// after each chunk.
    pub fn simulate(
        sim: &Simulator,
        seed: u64,
        count: usize,
        chunk: usize,
        progress: &dyn Fn(usize),
    ) -> Batch {
        let mut batch = Batch::for_simulator(sim);
        batch.raw.reserve(count * batch.size * batch.size);
        let chunk = chunk.max(1);
        let mut first = 0;
        while first < count {
            let n = chunk.min(count - first);
            batch.push_frames(&sim.frames(seed, first as u64, n));
            first += n;
            progress(n);
        }
        batch
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.true_slopes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.true_slopes.is_empty()
    }

    /// Pixels per sub-aperture, `n`.
    pub fn pixel_count(&self) -> usize {
        self.size * self.size
    }

    /// Raw image of frame `index`.
    pub fn frame(&self, index: usize) -> &[u16] {
        let n = self.pixel_count();
        &self.raw[index * n..(index + 1) * n]
    }

    /// The one-window configuration that processes this batch with `method`
    /// and `pixels` (clamped to `n`: all pixels).
    pub fn config(&self, method: Method, pixels: usize) -> ProcessingConfig {
        let side = self.size as u16;
        let camera = Camera {
            width: side,
            height: side,
            bit_depth: self.bit_depth,
        };
        let window = SubapertureWindow {
            x: 0,
            y: 0,
            width: side,
            height: side,
        };
        let mut config = ProcessingConfig::new(camera, vec![window]);
        config.background = Some(vec![self.background_q4; self.pixel_count()]);
        config.rule = method.rule;
        config.pixels = PixelCounts::All(pixels.clamp(1, self.pixel_count()) as u16);
        config.level_filter = method
            .level_filter
            .map(|gain_shift| LevelFilter { gain_shift });
        config.threshold = method.clip_negative.then_some(0);
        config
    }

    /// The engine's slopes (pixels) for every frame, and the number of
    /// invalid results (flux <= 0: slope 0).
    pub fn engine_slopes(&self, method: Method, pixels: usize) -> Result<(Vec<[f64; 2]>, usize)> {
        const FRAMES_PER_CALL: usize = 1024;
        let config = self.config(method, pixels);
        let mut engine = HostEngine::new(config.view())
            .map_err(|e| anyhow!("{e:?}"))
            .with_context(|| format!("engine configuration for {} N={pixels}", method.label()))?;
        let mut slopes = Vec::with_capacity(self.len());
        let mut invalid = 0;
        let mut first = 0;
        while first < self.len() {
            let n = FRAMES_PER_CALL.min(self.len() - first);
            let results = engine
                .process((first..first + n).map(|i| self.frame(i)), usize::MAX)
                .map_err(|(k, e)| anyhow!("frame {}: {e:?}", first + k))?;
            for frame in results {
                let r = frame[0];
                invalid += usize::from(!r.valid);
                slopes.push([r.slope_x as f64 / 65536.0, r.slope_y as f64 / 65536.0]);
            }
            first += n;
        }
        Ok((slopes, invalid))
    }

    /// Scores `method` with `pixels`: per-frame errors against the true
    /// slopes.
    pub fn score(&self, method: Method, pixels: usize) -> Result<Score> {
        let (slopes, invalid) = self.engine_slopes(method, pixels)?;
        let errors = slopes
            .iter()
            .zip(&self.true_slopes)
            .map(|(s, t)| [s[0] - t[0], s[1] - t[1]])
            .collect();
        Ok(Score {
            method,
            pixels: pixels.min(self.pixel_count()),
            all_pixels: pixels >= self.pixel_count(),
            invalid,
            errors,
            direction: self.direction,
        })
    }
}

/// Which slope component a number refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    X,
    Y,
    /// Both components pooled (per frame, the mean of the two squared
    /// errors): for a NGS, where x and y have the same statistics.
    Both,
    /// Parallel to the LGS elongation (the paper's worst case; x for a NGS).
    Along,
    /// Perpendicular to the LGS elongation (y for a NGS).
    Across,
}

impl Axis {
    pub fn name(&self) -> &'static str {
        match self {
            Axis::X => "x",
            Axis::Y => "y",
            Axis::Both => "x and y",
            Axis::Along => "along the elongation",
            Axis::Across => "across the elongation",
        }
    }

    /// The squared error on this axis of the error `e = [ex, ey]`, with
    /// `u` the elongation direction.
    pub fn squared(&self, e: &[f64; 2], u: [f64; 2]) -> f64 {
        match self {
            Axis::X => e[0] * e[0],
            Axis::Y => e[1] * e[1],
            Axis::Both => 0.5 * (e[0] * e[0] + e[1] * e[1]),
            Axis::Along => (e[0] * u[0] + e[1] * u[1]).powi(2),
            Axis::Across => (e[1] * u[0] - e[0] * u[1]).powi(2),
        }
    }
}

/// A value with its standard error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    pub value: f64,
    pub se: f64,
}

/// Mean and standard error of the mean.
pub(crate) fn mean_se(values: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let (mut n, mut sum) = (0usize, 0.0);
    for v in values.clone() {
        n += 1;
        sum += v;
    }
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let mean = sum / n as f64;
    let var = if n > 1 {
        values.map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64
    } else {
        f64::NAN
    };
    (mean, (var / n as f64).sqrt())
}

/// The result of one (method, N) on a batch.
#[derive(Clone, Debug)]
pub struct Score {
    pub method: Method,
    /// N, at most `n`.
    pub pixels: usize,
    /// `N >= n`: no selection.
    pub all_pixels: bool,
    /// Frames the engine found invalid (flux <= 0; slope 0).
    pub invalid: usize,
    /// Per frame, `S_est - S_true` for x and y (pixels).
    pub errors: Vec<[f64; 2]>,
    /// Unit vector of the elongation ([`Axis::Along`]).
    pub direction: [f64; 2],
}

impl Score {
    /// Per-frame squared errors on `axis`.
    pub fn squared(&self, axis: Axis) -> impl Iterator<Item = f64> + Clone + '_ {
        let u = self.direction;
        self.errors.iter().map(move |e| axis.squared(e, u))
    }

    /// `R^2` (mean squared error) and its standard error.
    pub fn mse(&self, axis: Axis) -> Estimate {
        let (value, se) = mean_se(self.squared(axis));
        Estimate { value, se }
    }

    /// R (pixels) and its standard error.
    pub fn r(&self, axis: Axis) -> Estimate {
        let m = self.mse(axis);
        let value = m.value.sqrt();
        Estimate {
            value,
            se: m.se / (2.0 * value),
        }
    }

    /// `R(self) - R(other)` on the same frames, with the standard error of
    /// the paired difference (common random numbers): negative means `self`
    /// is better.
    pub fn paired_difference(&self, other: &Score, axis: Axis) -> Estimate {
        assert_eq!(self.errors.len(), other.errors.len());
        // mean(a - b) = R_a^2 - R_b^2 exactly; its spread gives the error.
        let (_, se) = mean_se(
            self.squared(axis)
                .zip(other.squared(axis))
                .map(|(a, b)| a - b),
        );
        let (ra, rb) = (self.r(axis).value, other.r(axis).value);
        // R_a^2 - R_b^2 = (R_a - R_b)(R_a + R_b)
        Estimate {
            value: ra - rb,
            se: se / (ra + rb),
        }
    }
}

/// Scores every `(method, N)` on `batch` in parallel (rayon), calling
/// `progress()` after each. Results are in the order of `methods`, then
/// `pixels`; N values `>= n` collapse to one "all pixels" entry per method.
pub fn evaluate(
    batch: &Batch,
    methods: &[Method],
    pixels: &[usize],
    progress: &(dyn Fn() + Sync),
) -> Result<Vec<Score>> {
    let jobs = jobs(batch.pixel_count(), methods, pixels);
    jobs.par_iter()
        .map(|&(method, n)| {
            let s = batch.score(method, n);
            progress();
            s
        })
        .collect()
}

/// The distinct `(method, N)` combinations [`evaluate`] runs.
pub fn jobs(pixel_count: usize, methods: &[Method], pixels: &[usize]) -> Vec<(Method, usize)> {
    let mut ns: Vec<usize> = pixels.iter().map(|&n| n.clamp(1, pixel_count)).collect();
    ns.sort_unstable();
    ns.dedup();
    methods
        .iter()
        .flat_map(|&m| ns.iter().map(move |&n| (m, n)))
        .collect()
}

/// The N values of the paper's curves for a window of `pixel_count` pixels:
/// roughly logarithmic from 1, ending with `pixel_count` (all pixels).
pub fn default_pixel_grid(pixel_count: usize) -> Vec<usize> {
    const GRID: [usize; 33] = [
        1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 14, 16, 18, 20, 22, 25, 28, 32, 36, 40, 45, 50, 60, 70, 80,
        100, 120, 150, 180, 200, 256, 400, 600,
    ];
    let mut v: Vec<usize> = GRID.iter().copied().filter(|&n| n < pixel_count).collect();
    // Extend beyond 600 for large windows.
    let mut n = 800;
    while n < pixel_count {
        v.push(n);
        n = n * 3 / 2;
    }
    v.push(pixel_count);
    v
}

/// The best (lowest R on `axis`) of `scores`.
pub fn best(scores: &[Score], axis: Axis) -> Option<&Score> {
    scores
        .iter()
        .min_by(|a, b| a.mse(axis).value.total_cmp(&b.mse(axis).value))
}

/// Simulates `frames` frames of `params` and scores `methods` x `pixels`:
/// the whole evaluation of one case, without progress reporting.
pub fn evaluate_case(
    params: SimulationParams,
    seed: u64,
    frames: usize,
    methods: &[Method],
    pixels: &[usize],
) -> Result<(Batch, Vec<Score>)> {
    let sim = Simulator::new(params).map_err(|e| anyhow!("{e}"))?;
    let batch = Batch::simulate(&sim, seed, frames, 1024, &|_| {});
    let scores = evaluate(&batch, methods, pixels, &|| {})?;
    Ok((batch, scores))
}

/// The score of `(method, N)` in `scores` (N clamped to `n` by the caller).
pub fn find(scores: &[Score], method: Method, pixels: usize) -> Option<&Score> {
    scores
        .iter()
        .find(|s| s.method == method && s.pixels == pixels)
}

/// The "all pixels" score of `method` in `scores`.
pub fn all_pixels(scores: &[Score], method: Method) -> Option<&Score> {
    scores.iter().find(|s| s.method == method && s.all_pixels)
}

#[cfg(test)]
mod tests;
