//! Recommending the rule and N for a user's instrument (`brightpix tune`).
//!
//! The configuration gives the sub-aperture windows: their size and, from
//! their positions, where each sits in the telescope pupil. The conditions
//! give the optics, atmosphere, detector, pupil and guide star (or, with
//! recorded frames, what [`super::recorded`] measured in them).
//!
//! Each window is placed in the pupil ([`place`]): its lit fraction (the
//! part of its square inside the annulus between the telescope diameter and
//! the central obscuration; below the illumination threshold it is dark and
//! not tuned), and for a LGS its distance from the launch position and the
//! azimuth of its elongation (radial from the launch point). Windows are
//! grouped into classes by size, lit fraction (full or partial bins),
//! distance and azimuth folded into 0-45 degrees (the pixel grid looks the
//! same under 90-degree rotations and mirrors); each class is simulated once
//! at a representative member (its own distance, azimuth and cut pupil,
//! photons scaled by its lit fraction), and every candidate (rule, N) is
//! scored on those frames with the engine ([`super::evaluate`]).
//!
//! The rule is one per configuration (the device applies one rule), chosen
//! on the pupil-summed `R^2` with each class at its best N; N is then per
//! class. R is scored on [`Conditions::score_axis`]: along the elongation
//! (the paper's worst case, the default for a LGS) or x and y pooled.

use anyhow::{anyhow, bail, Result};

pub mod output;
mod request;
pub mod wfe;
pub use request::{parse_score, FittedR0, Prepared, TuneRequest, MIN_FRAMES, SET_BY_TUNE};
pub use wfe::{Criterion, WfePlan, WfeRequest, WfeTuneResult};

use super::{all_pixels, default_pixel_grid, evaluate, jobs, Axis, Batch, Method, Score};
use crate::config_file::{PixelCounts, ProcessingConfig};
use crate::simulator::{SimulationParams, Simulator, Source, SubaperturePupil};

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

    /// A short description for reports.
    pub fn describe(&self) -> String {
        match *self {
            Lgs::Rayleigh {
                gate_depth_m,
                altitude_m,
            } => format!(
                "Rayleigh, gate {gate_depth_m} m deep at {:.1} km",
                altitude_m / 1e3
            ),
            Lgs::Sodium {
                separation_m,
                altitude_m,
            } => format!(
                "sodium, double Gaussian (HWHM 3.5 and 2 km, densities 0.4/0.6) at {:.1} km and {:.1} km above it",
                altitude_m / 1e3,
                separation_m / 1e3
            ),
        }
    }

    /// The simulator's source for a sub-aperture `distance_m` from launch,
    /// elongated along `angle_deg` on the detector.
    pub fn source(&self, distance_m: f64, angle_deg: f64, spot_fwhm_arcsec: f64) -> Source {
        let source = match *self {
            Lgs::Rayleigh {
                gate_depth_m,
                altitude_m,
            } => Source::Rayleigh {
                altitude_m,
                gate_depth_m,
                launch_offset_m: distance_m,
                spot_fwhm_arcsec,
                elongation_angle_deg: 0.0,
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
                    elongation_angle_deg: 0.0,
                },
                _ => unreachable!("Source::sodium is a sodium source"),
            },
        };
        source.with_elongation_angle(angle_deg)
    }
}

/// The telescope pupil beyond its diameter (`params.telescope_diameter_m`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PupilModel {
    /// Central obscuration diameter (m).
    pub obscuration_m: f64,
    /// Sub-apertures lit below this fraction of their area are dark: not
    /// tuned, and left out of the tuned configuration.
    pub illumination_threshold: f64,
}

/// The user's conditions.
#[derive(Clone, Debug)]
pub struct Conditions {
    /// Everything but the sub-aperture size, source and pupil cut:
    /// `pixels_per_subaperture` is set per class from the windows, `photons`
    /// is for a fully lit sub-aperture.
    pub params: SimulationParams,
    pub lgs: Option<Lgs>,
    /// Launch position in pupil coordinates (m), origin at the pupil centre.
    pub launch_m: [f64; 2],
    /// Unelongated LGS spot FWHM (arcsec).
    pub lgs_spot_fwhm_arcsec: f64,
    pub pupil: PupilModel,
    /// What R is scored on: [`Axis::Along`] (the paper's LGS choice) or
    /// [`Axis::Both`].
    pub score_axis: Axis,
    /// Measured photons per window (from recorded frames): replace the
    /// pupil model's lit fraction times `photons`.
    pub measured_photons: Option<Vec<f64>>,
}

/// How hard to look.
#[derive(Clone, Debug)]
pub struct TuneOptions {
    /// Frames simulated per class.
    pub frames: usize,
    pub seed: u64,
    /// Distance classes (LGS only).
    pub classes: usize,
    /// Azimuth classes over 0-45 degrees (LGS only).
    pub angle_classes: usize,
    /// Candidate methods.
    pub methods: Vec<Method>,
    /// Largest acceptable fraction of a spot's light outside its window.
    pub max_truncation: f64,
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

/// Where one window sits in the pupil.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Centre in the pupil (m), origin at the pupil centre.
    pub position_m: [f64; 2],
    /// Fraction of the sub-aperture's square inside the telescope annulus
    /// (or, with recorded frames, its measured signal over the median of
    /// the brightest half).
    pub lit_fraction: f64,
    /// Distance from the launch position (m).
    pub distance_m: f64,
    /// Azimuth of the elongation on the detector (degrees from +x towards
    /// +y): that of the sub-aperture seen from the launch position.
    pub angle_deg: f64,
}

impl Placement {
    /// The azimuth folded into 0..=45 degrees by the pixel grid's symmetry.
    pub fn folded_angle_deg(&self) -> f64 {
        let a = self.angle_deg.rem_euclid(90.0);
        if a > 45.0 {
            90.0 - a
        } else {
            a
        }
    }
}

/// Fraction of the square of side `d` centred at `centre` inside the
/// annulus of outer diameter `outer` and inner diameter `inner` (64x64
/// samples).
pub fn lit_fraction(centre: [f64; 2], d: f64, outer: f64, inner: f64) -> f64 {
    const S: usize = 64;
    let mut inside = 0usize;
    for i in 0..S {
        let x = centre[0] + d * ((i as f64 + 0.5) / S as f64 - 0.5);
        for j in 0..S {
            let y = centre[1] + d * ((j as f64 + 0.5) / S as f64 - 0.5);
            let r = x.hypot(y);
            if r <= outer / 2.0 && r >= inner / 2.0 {
                inside += 1;
            }
        }
    }
    inside as f64 / (S * S) as f64
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

/// Places every window of `config` in the pupil under `conditions`.
pub fn place(config: &ProcessingConfig, conditions: &Conditions) -> Vec<Placement> {
    let p = &conditions.params;
    let d = p.subaperture_diameter_m();
    let positions = pupil_positions(config, d);
    let lit: Vec<f64> = match &conditions.measured_photons {
        Some(photons) => {
            // Relative to the median of the brightest half (fully lit ones).
            let mut sorted = photons.clone();
            sorted.sort_by(f64::total_cmp);
            let top = &sorted[sorted.len() / 2..];
            let reference = top[top.len() / 2].max(f64::MIN_POSITIVE);
            photons
                .iter()
                .map(|&v| (v / reference).clamp(0.0, 1.0))
                .collect()
        }
        None => positions
            .iter()
            .map(|&c| lit_fraction(c, d, p.telescope_diameter_m, conditions.pupil.obscuration_m))
            .collect(),
    };
    positions
        .iter()
        .zip(lit)
        .map(|(&c, lit_fraction)| {
            let v = [c[0] - conditions.launch_m[0], c[1] - conditions.launch_m[1]];
            Placement {
                position_m: c,
                lit_fraction,
                distance_m: v[0].hypot(v[1]),
                angle_deg: if v == [0.0, 0.0] {
                    0.0
                } else {
                    v[1].atan2(v[0]).to_degrees()
                },
            }
        })
        .collect()
}

/// One group of sub-apertures simulated together.
#[derive(Clone, Debug)]
pub struct Class {
    /// Window indices.
    pub members: Vec<usize>,
    /// Window side (pixels).
    pub size: usize,
    /// The member that is simulated.
    pub representative: usize,
    /// Its placement.
    pub placement: Placement,
    /// Photons per frame simulated for it.
    pub photons: f64,
    /// Distance range of the members (m).
    pub min_distance_m: f64,
    pub max_distance_m: f64,
    /// Lit fraction range of the members.
    pub min_lit: f64,
    pub max_lit: f64,
    /// Every candidate's scores on the class's frames.
    pub scores: Vec<Score>,
    /// The current configuration's rule and N on these frames, if that
    /// rule's N is the same for all members.
    pub current: Option<Score>,
    /// The chosen method's best score (set by [`tune`]).
    pub chosen: Option<Score>,
    /// Mean fraction of the spot's light inside the window.
    pub field_fraction: f64,
    /// The simulated parameters.
    pub params: Option<SimulationParams>,
}

impl Class {
    /// The best score of `method` in this class (lowest R on `axis`).
    pub fn best(&self, method: Method, axis: Axis) -> Option<&Score> {
        self.scores
            .iter()
            .filter(|s| s.method == method)
            .min_by(|a, b| a.mse(axis).value.total_cmp(&b.mse(axis).value))
    }

    /// "All pixels" on this class's frames.
    pub fn all_pixels(&self) -> Option<&Score> {
        all_pixels(&self.scores, Method::SUBTRACT_NEXT)
    }
}

/// The plan: the classes and the dark windows.
#[derive(Clone, Debug)]
pub struct Plan {
    pub placements: Vec<Placement>,
    pub classes: Vec<Class>,
    /// Windows lit below the illumination threshold.
    pub dark: Vec<usize>,
}

/// Equal-width bin of `v` in `[lo, hi]` among `bins`.
fn bin(v: f64, lo: f64, hi: f64, bins: usize) -> usize {
    if bins <= 1 || hi <= lo {
        0
    } else {
        (((v - lo) / (hi - lo) * bins as f64) as usize).min(bins - 1)
    }
}

/// The classes `tune` would simulate, without simulating them.
pub fn plan(
    config: &ProcessingConfig,
    conditions: &Conditions,
    options: &TuneOptions,
) -> Result<Plan> {
    for (i, w) in config.windows.iter().enumerate() {
        if w.width != w.height {
            bail!(
                "window {i} is {}x{}: tune simulates square sub-apertures only",
                w.width,
                w.height
            );
        }
    }
    let placements = place(config, conditions);
    let threshold = conditions.pupil.illumination_threshold;
    let dark: Vec<usize> = (0..placements.len())
        .filter(|&i| placements[i].lit_fraction < threshold)
        .collect();
    let lit: Vec<usize> = (0..placements.len())
        .filter(|&i| placements[i].lit_fraction >= threshold)
        .collect();
    if lit.is_empty() {
        bail!(
            "no sub-aperture is lit above the illumination threshold {threshold} (telescope {} m, obscuration {} m)",
            conditions.params.telescope_diameter_m,
            conditions.pupil.obscuration_m
        );
    }
    let lgs = conditions.lgs.is_some();
    let (d_bins, a_bins) = if lgs {
        (options.classes, options.angle_classes)
    } else {
        (1, 1)
    };
    const FULL: f64 = 0.999;
    let partial_bins = 2;
    let mut keys: Vec<((usize, usize, usize, usize), usize)> = Vec::new();
    let mut sizes: Vec<usize> = lit
        .iter()
        .map(|&i| config.windows[i].width as usize)
        .collect();
    sizes.sort_unstable();
    sizes.dedup();
    for &size in &sizes {
        let of_size: Vec<usize> = lit
            .iter()
            .copied()
            .filter(|&i| config.windows[i].width as usize == size)
            .collect();
        let dist = |i: usize| placements[i].distance_m;
        let lo = of_size
            .iter()
            .map(|&i| dist(i))
            .fold(f64::INFINITY, f64::min);
        let hi = of_size
            .iter()
            .map(|&i| dist(i))
            .fold(f64::NEG_INFINITY, f64::max);
        for &i in &of_size {
            let p = &placements[i];
            let lit_bin = if p.lit_fraction >= FULL {
                0
            } else {
                1 + bin(p.lit_fraction, threshold, FULL, partial_bins)
            };
            let key = (
                size,
                lit_bin,
                bin(p.distance_m, lo, hi, d_bins),
                bin(p.folded_angle_deg(), 0.0, 45.0, a_bins),
            );
            keys.push((key, i));
        }
    }
    keys.sort_by_key(|(k, i)| (*k, *i));
    let mut classes = Vec::new();
    let mut start = 0;
    while start < keys.len() {
        let key = keys[start].0;
        let members: Vec<usize> = keys[start..]
            .iter()
            .take_while(|(k, _)| *k == key)
            .map(|(_, i)| *i)
            .collect();
        start += members.len();
        let n = members.len() as f64;
        let mean = |f: &dyn Fn(&Placement) -> f64| {
            members.iter().map(|&i| f(&placements[i])).sum::<f64>() / n
        };
        let (md, ma, ml) = (
            mean(&|p| p.distance_m),
            mean(&|p| p.folded_angle_deg()),
            mean(&|p| p.lit_fraction),
        );
        let representative = *members
            .iter()
            .min_by(|&&a, &&b| {
                let cost = |i: usize| {
                    let p = &placements[i];
                    ((p.distance_m - md) / 0.1).powi(2)
                        + ((p.folded_angle_deg() - ma) / 5.0).powi(2)
                        + ((p.lit_fraction - ml) / 0.05).powi(2)
                };
                cost(a).total_cmp(&cost(b))
            })
            .expect("members is not empty");
        let photons = match &conditions.measured_photons {
            Some(m) => members.iter().map(|&i| m[i]).sum::<f64>() / n,
            None => conditions.params.photons * placements[representative].lit_fraction,
        };
        let fold = |f: fn(f64, f64) -> f64, init: f64, g: &dyn Fn(&Placement) -> f64| {
            members.iter().map(|&i| g(&placements[i])).fold(init, f)
        };
        classes.push(Class {
            size: key.0,
            representative,
            placement: placements[representative],
            photons,
            min_distance_m: fold(f64::min, f64::INFINITY, &|p| p.distance_m),
            max_distance_m: fold(f64::max, f64::NEG_INFINITY, &|p| p.distance_m),
            min_lit: fold(f64::min, f64::INFINITY, &|p| p.lit_fraction),
            max_lit: fold(f64::max, f64::NEG_INFINITY, &|p| p.lit_fraction),
            members,
            scores: Vec::new(),
            current: None,
            chosen: None,
            field_fraction: 1.0,
            params: None,
        });
    }
    // Most-populated first within a size: the report reads better.
    Ok(Plan {
        placements,
        classes,
        dark,
    })
}

/// The simulation parameters of `class`.
pub fn class_params(class: &Class, conditions: &Conditions, bit_depth: u8) -> SimulationParams {
    let mut params = conditions.params.clone();
    params.pixels_per_subaperture = class.size as u32;
    params.bit_depth = bit_depth;
    params.photons = class.photons.max(1e-3);
    let p = class.placement;
    if let Some(lgs) = conditions.lgs {
        params.source = lgs.source(p.distance_m, p.angle_deg, conditions.lgs_spot_fwhm_arcsec);
    }
    if p.lit_fraction < 0.999 && conditions.measured_photons.is_none() {
        params.pupil = Some(SubaperturePupil {
            centre_m: p.position_m,
            obscuration_m: conditions.pupil.obscuration_m,
        });
    }
    params
}

/// Number of engine runs [`tune`] will make per class (for progress bars).
pub fn jobs_per_class(size: usize, methods: &[Method]) -> usize {
    jobs(size * size, methods, &default_pixel_grid(size * size)).len()
}

/// The pupil-averaged `R^2` of `m` with each class at its best N.
pub fn pupil_mse(classes: &[Class], m: Method, axis: Axis) -> f64 {
    let mut value = 0.0;
    let mut count = 0.0;
    for c in classes {
        let Some(s) = c.best(m, axis) else {
            return f64::INFINITY;
        };
        let w = c.members.len() as f64;
        value += w * s.mse(axis).value;
        count += w;
    }
    value / count
}

/// The rule: the least pupil-summed `R^2` with each class at its best N,
/// except that the first candidate (in the order given: simplest first) that
/// is not worse than that by more than two paired standard errors or 1% in
/// R wins, so that a meaningless gain never trades the paper's subtract-next
/// for a more complex rule.
pub fn choose_method(classes: &[Class], methods: &[Method], axis: Axis) -> Method {
    let best = methods
        .iter()
        .copied()
        .min_by(|a, b| pupil_mse(classes, *a, axis).total_cmp(&pupil_mse(classes, *b, axis)))
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
            let (Some(a), Some(b)) = (c.best(m, axis), c.best(best, axis)) else {
                continue;
            };
            let w = c.members.len() as f64;
            let (_, se) = super::mean_se(a.squared(axis).zip(b.squared(axis)).map(|(x, y)| x - y));
            diff += w * (a.mse(axis).value - b.mse(axis).value);
            var += (w * se).powi(2);
        }
        // Also within 1% in R (2% in R^2): not worth a more complex rule.
        let total: f64 = classes
            .iter()
            .filter_map(|c| {
                c.best(best, axis)
                    .map(|s| c.members.len() as f64 * s.mse(axis).value)
            })
            .sum();
        if diff <= (2.0 * var.sqrt()).max(0.02 * total) {
            return m;
        }
    }
    best
}

/// What [`tune`] found.
#[derive(Clone, Debug)]
pub struct TuneResult {
    pub method: Method,
    pub plan: Plan,
    /// The input configuration with the chosen rule, level filter and N,
    /// dark windows left out unless kept.
    pub config: ProcessingConfig,
    /// Classes whose spots lose more than the allowed light outside the
    /// window.
    pub truncated: Vec<usize>,
}

impl TuneResult {
    /// Why the tuned N is not reliable, when some class's spots keep less
    /// than `1 - max_truncation` of their light inside the window; `None`
    /// when every class's do.
    pub fn truncation(&self, max_truncation: f64) -> Option<String> {
        if self.truncated.is_empty() {
            return None;
        }
        let worst = self
            .truncated
            .iter()
            .map(|&k| self.plan.classes[k].field_fraction)
            .fold(1.0, f64::min);
        Some(format!(
            "spots are truncated by the sub-aperture: class(es) {:?} keep only {:.1}% of their light in the window (allowed loss {}%); a larger field of view (pixel scale or window) is needed, and the tuned N is not reliable",
            self.truncated,
            100.0 * worst,
            100.0 * max_truncation
        ))
    }
}

/// Simulates the conditions for every class, scores every candidate and
/// picks the rule and the N per class. `progress(frames, jobs)` is called
/// as work completes. With `keep_dark`, dark windows stay in the output
/// with the median of the chosen N.
pub fn tune(
    config: &ProcessingConfig,
    conditions: &Conditions,
    options: &TuneOptions,
    keep_dark: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<TuneResult> {
    if options.methods.is_empty() {
        bail!("no candidate methods");
    }
    let axis = conditions.score_axis;
    let mut plan = plan(config, conditions, options)?;
    let current_method = Method {
        rule: config.rule,
        level_filter: config.level_filter.map(|f| f.gain_shift),
        clip_negative: false,
    };
    for class in &mut plan.classes {
        let params = class_params(class, conditions, config.camera.bit_depth);
        let sim =
            Simulator::new(params.clone()).map_err(|e| anyhow!("simulation parameters: {e}"))?;
        let batch = Batch::simulate(&sim, options.seed, options.frames, 512, &|n| progress(n, 0));
        class.field_fraction = batch.field_fraction();
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
        class.params = Some(params);
    }
    let method = choose_method(&plan.classes, &options.methods, axis);
    let mut pixels = vec![0u16; config.windows.len()];
    let mut chosen_ns = Vec::new();
    for class in &mut plan.classes {
        let best = class.best(method, axis).expect("scored").clone();
        for &i in &class.members {
            pixels[i] = best.pixels as u16;
        }
        chosen_ns.push(best.pixels as u16);
        class.chosen = Some(best);
    }
    chosen_ns.sort_unstable();
    let median = chosen_ns[chosen_ns.len() / 2];
    for &i in &plan.dark {
        pixels[i] = median;
    }
    let truncated = plan
        .classes
        .iter()
        .enumerate()
        .filter(|(_, c)| c.field_fraction < 1.0 - options.max_truncation)
        .map(|(k, _)| k)
        .collect();
    let mut out = config.clone();
    out.rule = method.rule;
    out.level_filter = method
        .level_filter
        .map(|gain_shift| brightpix_protocol::LevelFilter { gain_shift });
    let keep: Vec<bool> = (0..config.windows.len())
        .map(|i| keep_dark || !plan.dark.contains(&i))
        .collect();
    if !keep.iter().all(|&k| k) {
        drop_windows(&mut out, &keep);
        pixels = pixels
            .iter()
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(&n, _)| n)
            .collect();
    }
    out.pixels = if pixels.iter().all(|&n| n == pixels[0]) {
        PixelCounts::All(pixels[0])
    } else {
        PixelCounts::PerSubaperture(pixels)
    };
    out.validate()
        .map_err(|e| anyhow!("tuned configuration: {e:?}"))?;
    Ok(TuneResult {
        method,
        plan,
        config: out,
        truncated,
    })
}

/// Leaves out the windows whose `keep` is false (and their reference
/// slopes); a grid layout gets them as skipped positions.
fn drop_windows(config: &mut ProcessingConfig, keep: &[bool]) {
    if let Some(layout) = &mut config.grid {
        let positions: Vec<[u16; 2]> = layout.positions().collect();
        if positions.len() == keep.len() {
            for (p, &k) in positions.iter().zip(keep) {
                if !k {
                    layout.skip.push(*p);
                }
            }
            layout.skip.sort_by_key(|p| (p[1], p[0]));
        }
    }
    config.windows = config
        .windows
        .iter()
        .zip(keep)
        .filter(|(_, &k)| k)
        .map(|(w, _)| *w)
        .collect();
    if let Some(refs) = &mut config.reference_slopes {
        *refs = refs
            .iter()
            .zip(keep)
            .filter(|(_, &k)| k)
            .map(|(r, _)| *r)
            .collect();
    }
}
