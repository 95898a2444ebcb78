//! Recommending the rule and N for a user's conditions (`brightpix tune`).
//!
//! The configuration gives the sub-aperture windows (their size and, from
//! their positions, where each sits in the pupil); the conditions give the
//! optics, atmosphere, detector and guide star. With a laser guide star the
//! spot elongation grows with the sub-aperture's distance from the launch
//! position, so sub-apertures are grouped by window size and by that
//! distance into a few classes; each class is simulated once (its mean
//! distance) and every candidate (rule, N) is scored on it with the engine
//! ([`super::evaluate`]).
//!
//! The rule is one per configuration (the device applies one rule), so the
//! chosen rule minimises the pupil-summed `R^2` with each class at its best
//! N; N is then per class. R is scored on both axes pooled (`R^2 = (R_x^2 +
//! R_y^2) / 2`), which does not depend on the direction of elongation in the
//! detector; the simulator elongates along x, so `R_x` is the error parallel
//! to the elongation and `R_y` perpendicular to it.

use anyhow::{anyhow, bail, Result};

use super::{all_pixels, default_pixel_grid, evaluate, jobs, Axis, Batch, Method, Score};
use crate::config_file::{PixelCounts, ProcessingConfig};
use crate::simulator::{SimulationParams, Simulator, Source};

/// A laser guide star.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lgs {
    /// Range-gated Rayleigh beacon: gate depth and gate-centre altitude (m).
    Rayleigh { gate_depth_m: f64, altitude_m: f64 },
    /// Sodium beacon: the paper's double-Gaussian profile with peak
    /// separation `s` above a lower peak at `altitude_m`.
    Sodium { separation_m: f64, altitude_m: f64 },
}

impl Lgs {
    /// Parses `rayleigh:DEPTH[:ALTITUDE]` or `sodium:SEPARATION[:ALTITUDE]`
    /// (metres; defaults 20 km and 90 km).
    pub fn parse(text: &str) -> Result<Lgs> {
        let parts: Vec<&str> = text.split(':').collect();
        let num = |s: &str| -> Result<f64> {
            let v: f64 = s
                .trim()
                .parse()
                .map_err(|_| anyhow!("--lgs {text:?}: {s:?} is not a number (metres)"))?;
            if !(v.is_finite() && v >= 0.0) {
                bail!("--lgs {text:?}: {s:?} must be >= 0");
            }
            Ok(v)
        };
        match parts.as_slice() {
            ["rayleigh", d] => Ok(Lgs::Rayleigh {
                gate_depth_m: num(d)?,
                altitude_m: 20e3,
            }),
            ["rayleigh", d, h] => Ok(Lgs::Rayleigh {
                gate_depth_m: num(d)?,
                altitude_m: num(h)?,
            }),
            ["sodium", s] => Ok(Lgs::Sodium {
                separation_m: num(s)?,
                altitude_m: 90e3,
            }),
            ["sodium", s, h] => Ok(Lgs::Sodium {
                separation_m: num(s)?,
                altitude_m: num(h)?,
            }),
            _ => bail!(
                "--lgs {text:?}: expected rayleigh:DEPTH[:ALTITUDE] or sodium:SEPARATION[:ALTITUDE] (metres)"
            ),
        }
    }

    /// The simulator's source for a sub-aperture `distance_m` from launch.
    pub fn source(&self, distance_m: f64, spot_fwhm_arcsec: f64) -> Source {
        match *self {
            Lgs::Rayleigh {
                gate_depth_m,
                altitude_m,
            } => Source::Rayleigh {
                altitude_m,
                gate_depth_m,
                launch_offset_m: distance_m,
                spot_fwhm_arcsec,
            },
            Lgs::Sodium {
                separation_m,
                altitude_m,
            } => match Source::sodium(separation_m) {
                Source::Sodium {
                    peak_densities,
                    half_widths_m,
                    ..
                } => Source::Sodium {
                    lower_peak_altitude_m: altitude_m,
                    separation_m,
                    peak_densities,
                    half_widths_m,
                    launch_offset_m: distance_m,
                    spot_fwhm_arcsec,
                },
                _ => unreachable!("Source::sodium is a sodium source"),
            },
        }
    }
}

/// The user's conditions.
#[derive(Clone, Debug)]
pub struct Conditions {
    /// Everything but the sub-aperture size and the source:
    /// `pixels_per_subaperture` is set per class from the windows.
    pub params: SimulationParams,
    pub lgs: Option<Lgs>,
    /// Launch position in pupil coordinates (m), origin at the pupil centre.
    pub launch_m: [f64; 2],
    /// Unelongated LGS spot FWHM (arcsec).
    pub lgs_spot_fwhm_arcsec: f64,
}

/// How hard to look.
#[derive(Clone, Debug)]
pub struct TuneOptions {
    /// Frames simulated per class.
    pub frames: usize,
    pub seed: u64,
    /// Distance classes (LGS only).
    pub classes: usize,
    /// Candidate methods.
    pub methods: Vec<Method>,
}

/// The candidate methods of `brightpix tune`: subtract-next, threshold,
/// subtract-mean with M = 2, 4, 8, and with `level_filter` each subtracting
/// rule also with that filter.
pub fn candidate_methods(level_filter: Option<u8>) -> Vec<Method> {
    let mut m = vec![
        Method::SUBTRACT_NEXT,
        Method::THRESHOLD,
        Method::subtract_mean(2),
        Method::subtract_mean(4),
        Method::subtract_mean(8),
    ];
    if let Some(g) = level_filter {
        let filtered: Vec<Method> = m
            .iter()
            .filter(|x| x.rule.subtracts())
            .map(|x| x.with_level_filter(g))
            .collect();
        m.extend(filtered);
    }
    m
}

/// One group of sub-apertures simulated together.
#[derive(Clone, Debug)]
pub struct Class {
    /// Window indices.
    pub members: Vec<usize>,
    /// Window side (pixels).
    pub size: usize,
    /// Distance from the launch (m): simulated (mean of members), min, max.
    pub distance_m: f64,
    pub min_distance_m: f64,
    pub max_distance_m: f64,
    /// Every candidate's scores on the class's frames.
    pub scores: Vec<Score>,
    /// The current configuration's rule and N on these frames, if that
    /// rule's N is the same for all members.
    pub current: Option<Score>,
    /// The chosen method's best score (set by [`tune`]).
    pub chosen: Option<Score>,
}

impl Class {
    /// The best score of `method` in this class (lowest pooled R).
    pub fn best(&self, method: Method) -> Option<&Score> {
        self.scores
            .iter()
            .filter(|s| s.method == method)
            .min_by(|a, b| a.mse(Axis::Both).value.total_cmp(&b.mse(Axis::Both).value))
    }

    /// "All pixels" on this class's frames.
    pub fn all_pixels(&self) -> Option<&Score> {
        all_pixels(&self.scores, Method::SUBTRACT_NEXT)
    }
}

/// What [`tune`] found.
#[derive(Clone, Debug)]
pub struct TuneResult {
    pub method: Method,
    pub classes: Vec<Class>,
    /// The input configuration with the chosen rule, level filter and N.
    pub config: ProcessingConfig,
    /// Pupil position (m) of every window.
    pub positions_m: Vec<[f64; 2]>,
}

/// Pupil position (m, origin at the centre of the windows' bounding box) of
/// each window: its centre over the window pitch (the grid's, or the window
/// width) times the sub-aperture diameter `d`.
pub fn pupil_positions(config: &ProcessingConfig, d: f64) -> Vec<[f64; 2]> {
    let centres: Vec<[f64; 2]> = config
        .windows
        .iter()
        .map(|w| {
            [
                w.x as f64 + w.width as f64 / 2.0,
                w.y as f64 + w.height as f64 / 2.0,
            ]
        })
        .collect();
    let (pitch_x, pitch_y) = match &config.grid {
        Some(g) => (g.grid.pitch_x as f64, g.grid.pitch_y as f64),
        None => {
            let w = config.windows.first().map_or(1.0, |w| w.width as f64);
            let h = config.windows.first().map_or(1.0, |w| w.height as f64);
            (w, h)
        }
    };
    let lo = |k: usize| centres.iter().map(|c| c[k]).fold(f64::INFINITY, f64::min);
    let hi = |k: usize| {
        centres
            .iter()
            .map(|c| c[k])
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let mid = [(lo(0) + hi(0)) / 2.0, (lo(1) + hi(1)) / 2.0];
    centres
        .iter()
        .map(|c| [(c[0] - mid[0]) / pitch_x * d, (c[1] - mid[1]) / pitch_y * d])
        .collect()
}

/// Groups windows by size, then (LGS) by distance into at most `classes`
/// equal-width distance bins.
fn make_classes(
    config: &ProcessingConfig,
    distances: &[f64],
    classes: usize,
    lgs: bool,
) -> Result<Vec<Class>> {
    let mut sizes: Vec<usize> = Vec::new();
    for (i, w) in config.windows.iter().enumerate() {
        if w.width != w.height {
            bail!(
                "window {i} is {}x{}: tune simulates square sub-apertures only",
                w.width,
                w.height
            );
        }
        if !sizes.contains(&(w.width as usize)) {
            sizes.push(w.width as usize);
        }
    }
    let bins = if lgs { classes.max(1) } else { 1 };
    let mut out = Vec::new();
    for &size in &sizes {
        let members: Vec<usize> = (0..config.windows.len())
            .filter(|&i| config.windows[i].width as usize == size)
            .collect();
        let lo = members
            .iter()
            .map(|&i| distances[i])
            .fold(f64::INFINITY, f64::min);
        let hi = members
            .iter()
            .map(|&i| distances[i])
            .fold(f64::NEG_INFINITY, f64::max);
        let width = (hi - lo) / bins as f64;
        for b in 0..bins {
            let in_bin: Vec<usize> = members
                .iter()
                .copied()
                .filter(|&i| {
                    let k = if width > 0.0 {
                        (((distances[i] - lo) / width) as usize).min(bins - 1)
                    } else {
                        0
                    };
                    k == b
                })
                .collect();
            if in_bin.is_empty() {
                continue;
            }
            let ds: Vec<f64> = in_bin.iter().map(|&i| distances[i]).collect();
            out.push(Class {
                size,
                distance_m: ds.iter().sum::<f64>() / ds.len() as f64,
                min_distance_m: ds.iter().copied().fold(f64::INFINITY, f64::min),
                max_distance_m: ds.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                members: in_bin,
                scores: Vec::new(),
                current: None,
                chosen: None,
            });
        }
    }
    Ok(out)
}

/// Number of engine runs [`tune`] will make per class (for progress bars).
pub fn jobs_per_class(size: usize, methods: &[Method]) -> usize {
    jobs(size * size, methods, &default_pixel_grid(size * size)).len()
}

/// The classes `tune` would simulate, without simulating them.
pub fn plan(
    config: &ProcessingConfig,
    conditions: &Conditions,
    classes: usize,
) -> Result<Vec<Class>> {
    let d = conditions.params.subaperture_diameter_m();
    let positions = pupil_positions(config, d);
    let distances: Vec<f64> = positions
        .iter()
        .map(|p| {
            ((p[0] - conditions.launch_m[0]).powi(2) + (p[1] - conditions.launch_m[1]).powi(2))
                .sqrt()
        })
        .collect();
    make_classes(config, &distances, classes, conditions.lgs.is_some())
}

/// The pupil-averaged `R^2` of `m` with each class at its best N.
pub fn pupil_mse(classes: &[Class], m: Method) -> f64 {
    let mut value = 0.0;
    let mut count = 0.0;
    for c in classes {
        let Some(s) = c.best(m) else {
            return f64::INFINITY;
        };
        let w = c.members.len() as f64;
        value += w * s.mse(Axis::Both).value;
        count += w;
    }
    value / count
}

/// The rule: the least pupil-summed `R^2` with each class at its best N,
/// except that the first candidate (in the order given: simplest first) that
/// is not worse than that by more than two paired standard errors or 1% in
/// R wins, so that a meaningless gain never trades the paper's subtract-next
/// for a more complex rule.
pub fn choose_method(classes: &[Class], methods: &[Method]) -> Method {
    let best = methods
        .iter()
        .copied()
        .min_by(|a, b| pupil_mse(classes, *a).total_cmp(&pupil_mse(classes, *b)))
        .expect("methods is not empty");
    for &m in methods {
        if m == best {
            return m;
        }
        // Paired standard error of the difference, class by class (same
        // frames): sum of w^2 var(per-frame difference) / K.
        let mut var = 0.0;
        let mut diff = 0.0;
        for c in classes {
            let (Some(a), Some(b)) = (c.best(m), c.best(best)) else {
                continue;
            };
            let w = c.members.len() as f64;
            let (_, se) = super::mean_se(
                a.squared_errors
                    .iter()
                    .zip(&b.squared_errors)
                    .map(|(x, y)| 0.5 * (x[0] + x[1]) - 0.5 * (y[0] + y[1])),
            );
            diff += w * (a.mse(Axis::Both).value - b.mse(Axis::Both).value);
            var += (w * se).powi(2);
        }
        // Also within 1% in R (2% in R^2): not worth a more complex rule.
        let total: f64 = classes
            .iter()
            .filter_map(|c| {
                c.best(best)
                    .map(|s| c.members.len() as f64 * s.mse(Axis::Both).value)
            })
            .sum();
        if diff <= (2.0 * var.sqrt()).max(0.02 * total) {
            return m;
        }
    }
    best
}

/// Simulates the conditions for every class, scores every candidate and
/// picks the rule and the N per class. `progress(frames, jobs)` is called
/// as work completes.
pub fn tune(
    config: &ProcessingConfig,
    conditions: &Conditions,
    options: &TuneOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<TuneResult> {
    if options.methods.is_empty() {
        bail!("no candidate methods");
    }
    let d = conditions.params.subaperture_diameter_m();
    let positions = pupil_positions(config, d);
    let mut classes = plan(config, conditions, options.classes)?;
    let current_method = Method {
        rule: config.rule,
        level_filter: config.level_filter.map(|f| f.gain_shift),
    };
    for class in &mut classes {
        let mut params = conditions.params.clone();
        params.pixels_per_subaperture = class.size as u32;
        params.bit_depth = config.camera.bit_depth;
        if let Some(lgs) = conditions.lgs {
            params.source = lgs.source(class.distance_m, conditions.lgs_spot_fwhm_arcsec);
        }
        let sim = Simulator::new(params).map_err(|e| anyhow!("simulation parameters: {e}"))?;
        let batch = Batch::simulate(&sim, options.seed, options.frames, 512, &|n| progress(n, 0));
        let grid = default_pixel_grid(class.size * class.size);
        class.scores = evaluate(&batch, &options.methods, &grid, &|| progress(0, 1))?;
        let current_n: Vec<u16> = class
            .members
            .iter()
            .map(|&i| config.view().selection.count.for_subaperture(i))
            .collect();
        if current_n.iter().all(|&n| n == current_n[0]) {
            class.current = Some(batch.score(current_method, current_n[0] as usize)?);
        }
    }
    let method = choose_method(&classes, &options.methods);
    let mut pixels = vec![0u16; config.windows.len()];
    for class in &mut classes {
        let best = class.best(method).expect("scored").clone();
        for &i in &class.members {
            pixels[i] = best.pixels as u16;
        }
        class.chosen = Some(best);
    }
    let mut out = config.clone();
    out.rule = method.rule;
    out.level_filter = method
        .level_filter
        .map(|gain_shift| brightpix_protocol::LevelFilter { gain_shift });
    out.pixels = if pixels.iter().all(|&n| n == pixels[0]) {
        PixelCounts::All(pixels[0])
    } else {
        PixelCounts::PerSubaperture(pixels)
    };
    out.validate()
        .map_err(|e| anyhow!("tuned configuration: {e:?}"))?;
    Ok(TuneResult {
        method,
        classes,
        config: out,
        positions_m: positions,
    })
}
