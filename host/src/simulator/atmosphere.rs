//! # Layered frozen-flow atmosphere
//!
//! Thin turbulent layers at given altitudes, each a von Kármán phase screen
//! of its share of the turbulence (`r0_l = r0 f_l^(-3/5)`, `f_l` its
//! fraction of `Cn^2 dh`), translated by its wind (Taylor's frozen flow).
//! A point `x` of the pupil looking in direction `theta` (radians, small
//! angles; a natural guide star, so no cone effect) at time `t` sees the
//! optical path difference
//!
//! `OPD(x, theta, t) = sum_l S_l(x + h_l theta - v_l t)`
//!
//! with `S_l` the layer's screen. Values between screen samples are
//! interpolated bilinearly (as DASP, COMPASS and YAO ray-trace their
//! screens).
//!
//! ## Episodes
//! A run is a sequence of independent **episodes**: each draws fresh
//! screens and then lets them flow for `duration` seconds. One long
//! frozen-flow sequence would need screens of hundreds of metres and would
//! average over few independent realisations of the large scales (the
//! tomographic error's); many short episodes give independent samples, and
//! each still has the frozen flow that a loop delay needs. A layer's screen
//! is a square patch large enough for every point the episode samples:
//! the pupil (its `half_width`), shifted by `h_l theta` for every direction,
//! swept by the wind over the episode. It is cut from one corner of a
//! periodic FFT screen at least twice its side, plus subharmonics down to
//! below `1/(5 L0)` ([`super::turbulence`]'s generator, with the sample
//! spacing of the wavefront sensor's lenslet phase so that a sub-aperture's
//! samples fall on screen samples up to a constant fraction).
//!
//! ## Low-pass twin
//! With a cutoff (cycles per metre, e.g. `1/(2d)`: a Shack-Hartmann's
//! Nyquist frequency), each screen also comes with its low-pass part from
//! the same random numbers (FFT cells with `|f_x|, |f_y|` below the cutoff,
//! and every subharmonic). The high-pass remainder is what a Shack-Hartmann
//! aliases: the end-to-end error budget uses it.
//!
//! ## Random numbers
//! Layer `l` of episode `e` of run `seed` draws from the ChaCha8 stream
//! `(seed, e, 16 + l)`, apart from the image streams (0-2) of
//! [`super::Simulator`] and [`super::camera::CameraSimulator`].

use rayon::prelude::*;
use rustfft::FftPlanner;
use serde::{Deserialize, Serialize};

use super::optics::nice_fft_size;
use super::turbulence::{ScreenBuffers, ScreenGenerator};
use super::{stream_rng, SimError};

/// One turbulent layer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Layer {
    /// Altitude above the telescope (m).
    pub altitude_m: f64,
    /// Fraction of the integrated turbulence strength (`Cn^2 dh`) in this
    /// layer; the fractions of an atmosphere sum to 1.
    pub fraction: f64,
    /// Wind speed (m/s).
    pub wind_speed_m_s: f64,
    /// Direction the layer moves towards, degrees from +x towards +y.
    pub wind_direction_deg: f64,
}

/// A layered atmosphere.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Atmosphere {
    /// Fried parameter of the whole atmosphere (m) at `r0_wavelength_m`.
    pub r0_m: f64,
    /// Wavelength of `r0_m` (m).
    pub r0_wavelength_m: f64,
    /// von Kármán outer scale (m), the same for every layer; `inf` for
    /// Kolmogorov.
    pub outer_scale_m: f64,
    pub layers: Vec<Layer>,
}

impl Atmosphere {
    /// The paper's CANARY atmosphere (§3.10): r0 = 12.5 cm at 500 nm, 60% at
    /// 0 m, 30% at 500 m, 10% at 5 km, and what the paper leaves open: an
    /// outer scale of 30 m (the paper's value elsewhere) and winds of 7.5,
    /// 10 and 15 m/s towards 0°, 90° and 45° (effective speed 9.2 m/s,
    /// `tau0 = 0.314 r0 / v` = 4.3 ms at 500 nm: ordinary La Palma values).
    pub fn canary() -> Self {
        let layer = |altitude_m, fraction, wind_speed_m_s, wind_direction_deg| Layer {
            altitude_m,
            fraction,
            wind_speed_m_s,
            wind_direction_deg,
        };
        Atmosphere {
            r0_m: 0.125,
            r0_wavelength_m: 500e-9,
            outer_scale_m: 30.0,
            layers: vec![
                layer(0.0, 0.6, 7.5, 0.0),
                layer(500.0, 0.3, 10.0, 90.0),
                layer(5000.0, 0.1, 15.0, 45.0),
            ],
        }
    }

    /// Checks every value; the fractions must sum to 1 (within 1e-6).
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |m: String| Err(SimError::Invalid(m));
        if !(self.r0_m.is_finite() && self.r0_m > 0.0) {
            return bad(format!("r0 must be positive, got {}", self.r0_m));
        }
        if !(self.r0_wavelength_m.is_finite() && self.r0_wavelength_m > 0.0) {
            return bad(format!(
                "r0 wavelength must be positive, got {}",
                self.r0_wavelength_m
            ));
        }
        if self.outer_scale_m.is_nan() || self.outer_scale_m <= 0.0 {
            return bad(format!(
                "outer scale must be positive (inf allowed), got {}",
                self.outer_scale_m
            ));
        }
        if self.layers.is_empty() {
            return bad("the atmosphere needs at least one layer".into());
        }
        for (k, l) in self.layers.iter().enumerate() {
            if !(l.altitude_m.is_finite() && l.altitude_m >= 0.0) {
                return bad(format!(
                    "layer {k}: altitude must be >= 0, got {}",
                    l.altitude_m
                ));
            }
            if !(l.fraction.is_finite() && l.fraction > 0.0) {
                return bad(format!(
                    "layer {k}: fraction must be positive, got {}",
                    l.fraction
                ));
            }
            if !(l.wind_speed_m_s.is_finite() && l.wind_speed_m_s >= 0.0) {
                return bad(format!(
                    "layer {k}: wind speed must be >= 0, got {}",
                    l.wind_speed_m_s
                ));
            }
            if !l.wind_direction_deg.is_finite() {
                return bad(format!("layer {k}: wind direction must be finite"));
            }
        }
        let total: f64 = self.layers.iter().map(|l| l.fraction).sum();
        if (total - 1.0).abs() > 1e-6 {
            return bad(format!(
                "layer fractions must sum to 1, they sum to {total}"
            ));
        }
        Ok(())
    }

    /// Fried parameter of layer `l` alone (m, at `r0_wavelength_m`).
    pub fn layer_r0_m(&self, l: usize) -> f64 {
        self.r0_m * self.layers[l].fraction.powf(-0.6)
    }

    /// Wind velocity of layer `l`, `[vx, vy]` (m/s).
    pub fn velocity(&self, l: usize) -> [f64; 2] {
        let layer = &self.layers[l];
        let a = layer.wind_direction_deg.to_radians();
        [
            layer.wind_speed_m_s * a.cos(),
            layer.wind_speed_m_s * a.sin(),
        ]
    }

    /// The effective wind speed `(sum f_l v_l^(5/3))^(3/5)` (m/s).
    pub fn effective_wind_m_s(&self) -> f64 {
        self.layers
            .iter()
            .map(|l| l.fraction * l.wind_speed_m_s.powf(5.0 / 3.0))
            .sum::<f64>()
            .powf(0.6)
    }

    /// The same atmosphere with every wind speed multiplied by `factor`.
    pub fn with_wind_scaled(mut self, factor: f64) -> Self {
        for l in &mut self.layers {
            l.wind_speed_m_s *= factor;
        }
        self
    }
}

/// What an episode samples: pupil points within `half_width_m` of the axis
/// (a square), seen in each of `directions_rad` (`[x, y]` radians), at times
/// `0 ..= duration_s`.
#[derive(Clone, Debug, PartialEq)]
pub struct Coverage {
    pub half_width_m: f64,
    pub directions_rad: Vec<[f64; 2]>,
    pub duration_s: f64,
}

/// Largest screen patch side (samples): beyond it an episode is too long
/// for its screens (FFT screens of twice the side would take gigabytes).
pub const MAX_PATCH: usize = 2048;

/// One layer's screen geometry and generator.
struct LayerPlan {
    altitude_m: f64,
    velocity: [f64; 2],
    /// Pupil-plane position (m) of sample `[0][0]` at time 0.
    origin: [f64; 2],
    generator: ScreenGenerator,
}

/// The screen generators of a layered atmosphere for one kind of episode
/// (immutable and `Sync`: one instance serves every episode and thread).
pub struct LayeredScreens {
    atmosphere: Atmosphere,
    delta_m: f64,
    patch: Vec<usize>,
    plans: Vec<LayerPlan>,
    low_pass_cycles_per_sample: Option<f64>,
}

impl LayeredScreens {
    /// Screens with sample spacing `delta_m` (m) covering `coverage`; with
    /// `low_pass_cutoff` (cycles/m) each screen also has its low-pass twin.
    pub fn new(
        atmosphere: &Atmosphere,
        delta_m: f64,
        coverage: &Coverage,
        low_pass_cutoff: Option<f64>,
    ) -> Result<Self, SimError> {
        atmosphere.validate()?;
        if !(delta_m.is_finite() && delta_m > 0.0) {
            return Err(SimError::Invalid(format!(
                "screen sample spacing must be positive, got {delta_m}"
            )));
        }
        if coverage.directions_rad.is_empty() {
            return Err(SimError::Invalid("no viewing direction".into()));
        }
        let mut planner = FftPlanner::new();
        let mut plans = Vec::with_capacity(atmosphere.layers.len());
        let mut patches = Vec::with_capacity(atmosphere.layers.len());
        for (l, layer) in atmosphere.layers.iter().enumerate() {
            let h = layer.altitude_m;
            let v = atmosphere.velocity(l);
            let hw = coverage.half_width_m;
            let mut lo = [f64::INFINITY; 2];
            let mut hi = [f64::NEG_INFINITY; 2];
            for d in &coverage.directions_rad {
                for a in 0..2 {
                    let sweep = -v[a] * coverage.duration_s;
                    lo[a] = lo[a].min(-hw + h * d[a] + sweep.min(0.0));
                    hi[a] = hi[a].max(hw + h * d[a] + sweep.max(0.0));
                }
            }
            let side = (hi[0] - lo[0]).max(hi[1] - lo[1]);
            // Two samples of margin on each side for the interpolation.
            let patch = (side / delta_m).ceil() as usize + 5;
            if patch > MAX_PATCH {
                return Err(SimError::Invalid(format!(
                    "layer {l} ({h} m, {} m/s): an episode of {} s needs a screen of {patch} samples across (at most {MAX_PATCH}): use shorter episodes",
                    layer.wind_speed_m_s, coverage.duration_s
                )));
            }
            let n = nice_fft_size(2 * patch);
            let l0 = atmosphere.outer_scale_m;
            let mut levels = 0usize;
            while levels < 12
                && (!l0.is_finite() || n as f64 * delta_m * 3f64.powi(levels as i32) < 5.0 * l0)
            {
                levels += 1;
            }
            let generator = ScreenGenerator::new(
                n,
                patch,
                delta_m,
                atmosphere.layer_r0_m(l),
                l0,
                levels,
                &mut planner,
            );
            plans.push(LayerPlan {
                altitude_m: h,
                velocity: v,
                origin: [lo[0] - 2.0 * delta_m, lo[1] - 2.0 * delta_m],
                generator,
            });
            patches.push(patch);
        }
        Ok(LayeredScreens {
            atmosphere: atmosphere.clone(),
            delta_m,
            patch: patches,
            plans,
            low_pass_cycles_per_sample: low_pass_cutoff.map(|f| f * delta_m),
        })
    }

    pub fn atmosphere(&self) -> &Atmosphere {
        &self.atmosphere
    }

    /// Side (samples) of each layer's screen patch.
    pub fn patch_sides(&self) -> &[usize] {
        &self.patch
    }

    /// The screens of episode `episode` of run `seed` (layers in parallel).
    pub fn episode(&self, seed: u64, episode: u64) -> Episode {
        let layers = self
            .plans
            .par_iter()
            .enumerate()
            .map(|(l, plan)| {
                let p = self.patch[l];
                let mut rng = stream_rng(seed, episode, 16 + l as u64);
                let mut bufs = ScreenBuffers::default();
                let mut phase = vec![0.0; p * p];
                let mut low = self.low_pass_cycles_per_sample.map(|_| vec![0.0; p * p]);
                plan.generator.generate_split(
                    &mut rng,
                    &mut bufs,
                    &mut phase,
                    low.as_mut().map(|b| {
                        (
                            b.as_mut_slice(),
                            self.low_pass_cycles_per_sample.unwrap_or(0.0),
                        )
                    }),
                );
                // Phase at the r0 wavelength -> optical path difference.
                let to_m = self.atmosphere.r0_wavelength_m / (2.0 * std::f64::consts::PI);
                phase.iter_mut().for_each(|v| *v *= to_m);
                if let Some(b) = low.as_mut() {
                    b.iter_mut().for_each(|v| *v *= to_m);
                }
                EpisodeLayer {
                    altitude_m: plan.altitude_m,
                    velocity: plan.velocity,
                    origin: plan.origin,
                    delta_m: self.delta_m,
                    side: p,
                    opd: phase,
                    low,
                }
            })
            .collect();
        Episode { layers }
    }
}

/// Which part of the turbulence to sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// Everything.
    Full,
    /// The low-pass twin (needs a cutoff in [`LayeredScreens::new`]).
    Low,
}

struct EpisodeLayer {
    altitude_m: f64,
    velocity: [f64; 2],
    origin: [f64; 2],
    delta_m: f64,
    side: usize,
    /// OPD (m), `side x side`, row-major `[y][x]`.
    opd: Vec<f64>,
    low: Option<Vec<f64>>,
}

impl EpisodeLayer {
    /// Screen coordinates (samples) of pupil point `x` in direction `dir`
    /// at time `t`.
    #[inline]
    fn coordinates(&self, x: [f64; 2], dir: [f64; 2], t: f64) -> [f64; 2] {
        let h = self.altitude_m;
        [
            (x[0] + h * dir[0] - self.velocity[0] * t - self.origin[0]) / self.delta_m,
            (x[1] + h * dir[1] - self.velocity[1] * t - self.origin[1]) / self.delta_m,
        ]
    }

    fn screen(&self, part: Part) -> &[f64] {
        match part {
            Part::Full => &self.opd,
            Part::Low => self
                .low
                .as_deref()
                .expect("the low-pass twin was asked for without a cutoff"),
        }
    }
}

/// A square grid of `n x n` pupil samples of spacing `spacing_m` centred
/// on `centre_m`: sample `(i, j)` at `centre + ((i + 0.5) - n/2, (j + 0.5)
/// - n/2) * spacing` (the lenslet phase grid of [`super::Simulator`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleGrid {
    pub centre_m: [f64; 2],
    pub n: usize,
    pub spacing_m: f64,
}

/// The screens of one episode.
pub struct Episode {
    layers: Vec<EpisodeLayer>,
}

impl Episode {
    /// OPD (m) at pupil point `x` (m) in direction `dir` (radians) at time
    /// `t` (s), summed over the layers.
    pub fn opd(&self, x: [f64; 2], dir: [f64; 2], t: f64, part: Part) -> f64 {
        self.layers
            .iter()
            .map(|layer| {
                let u = layer.coordinates(x, dir, t);
                bilinear(layer.screen(part), layer.side, u)
            })
            .sum()
    }

    /// Adds to `out` (row-major `[y][x]`, `n x n`) the OPD (m) on `grid` in
    /// direction `dir` at time `t`.
    pub fn add_grid(&self, grid: &SampleGrid, dir: [f64; 2], t: f64, part: Part, out: &mut [f64]) {
        let SampleGrid {
            centre_m: centre,
            n,
            spacing_m: spacing,
        } = *grid;
        assert_eq!(out.len(), n * n);
        let c = n as f64 / 2.0 - 0.5;
        for layer in &self.layers {
            let screen = layer.screen(part);
            let u0 = layer.coordinates([centre[0] - c * spacing, centre[1] - c * spacing], dir, t);
            let step = spacing / layer.delta_m;
            for j in 0..n {
                let row = &mut out[j * n..(j + 1) * n];
                let v = u0[1] + j as f64 * step;
                for (i, o) in row.iter_mut().enumerate() {
                    *o += bilinear(screen, layer.side, [u0[0] + i as f64 * step, v]);
                }
            }
        }
    }
}

/// Bilinear interpolation of a `side x side` row-major screen at `u`
/// (samples, `[x, y]`). Points outside the screen are a bug of the caller
/// (the coverage was computed wrongly).
#[inline]
fn bilinear(screen: &[f64], side: usize, u: [f64; 2]) -> f64 {
    let (fx, fy) = (u[0].floor(), u[1].floor());
    let (i, j) = (fx as isize, fy as isize);
    assert!(
        i >= 0 && j >= 0 && (i as usize) + 1 < side && (j as usize) + 1 < side,
        "atmosphere sampled outside its screen at ({:.2}, {:.2}) of {side}",
        u[0],
        u[1]
    );
    let (i, j) = (i as usize, j as usize);
    let (ax, ay) = (u[0] - fx, u[1] - fy);
    let k = j * side + i;
    let top = screen[k] + ax * (screen[k + 1] - screen[k]);
    let bottom = screen[k + side] + ax * (screen[k + side + 1] - screen[k + side]);
    top + ay * (bottom - top)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn coverage(duration_s: f64) -> Coverage {
        Coverage {
            half_width_m: 2.2,
            directions_rad: vec![[0.0, 0.0], [1.9e-4, 0.9e-4]],
            duration_s,
        }
    }

    #[test]
    fn frozen_flow_translates_each_layer_by_its_wind() {
        let atmosphere = Atmosphere {
            layers: vec![Layer {
                altitude_m: 5000.0,
                fraction: 1.0,
                wind_speed_m_s: 10.0,
                wind_direction_deg: 30.0,
            }],
            ..Atmosphere::canary()
        };
        let screens = LayeredScreens::new(&atmosphere, 0.05, &coverage(0.2), None).unwrap();
        let ep = screens.episode(1, 0);
        let v = atmosphere.velocity(0);
        let dir = [1.9e-4, 0.9e-4];
        for &x in &[[0.0, 0.0], [1.3, -0.7], [-2.0, 2.0]] {
            let t = 0.1;
            // What x sees at t, x - v t saw at 0.
            let later = ep.opd(x, dir, t, Part::Full);
            let earlier = ep.opd([x[0] - v[0] * t, x[1] - v[1] * t], dir, 0.0, Part::Full);
            assert!((later - earlier).abs() < 1e-12 * later.abs().max(1e-9));
            // Direction: x in direction dir sees what x + h dir sees on axis.
            let h = 5000.0;
            let on_axis = ep.opd(
                [x[0] + h * dir[0], x[1] + h * dir[1]],
                [0.0, 0.0],
                t,
                Part::Full,
            );
            assert!((later - on_axis).abs() < 1e-12 * later.abs().max(1e-9));
        }
        // A grid sample is the point sample.
        let mut grid = vec![0.0; 9];
        let sample = SampleGrid {
            centre_m: [0.3, -0.2],
            n: 3,
            spacing_m: 0.05,
        };
        ep.add_grid(&sample, dir, 0.05, Part::Full, &mut grid);
        let p = ep.opd([0.35, -0.2], dir, 0.05, Part::Full);
        assert!((grid[5] - p).abs() < 1e-15, "{} {p}", grid[5]);
    }

    #[test]
    fn layers_add_up_to_the_von_karman_structure_function_and_low_pass_splits_it() {
        // The phase structure function of the summed layers follows the
        // whole atmosphere's r0 and L0 (von Kármán, from the covariance the
        // reconstructor uses: an independent formula), within the sampling
        // error of the screens; the low-pass twin removes power only at
        // small scales.
        let atmosphere = Atmosphere::canary();
        let cov = Coverage {
            half_width_m: 3.5,
            directions_rad: vec![[0.0, 0.0]],
            duration_s: 0.0,
        };
        let screens = LayeredScreens::new(&atmosphere, 0.04, &cov, Some(1.0 / 1.2)).unwrap();
        let k = 2.0 * std::f64::consts::PI / 500e-9;
        let theory = |r: f64| {
            use crate::endtoend::covariance::phase_covariance;
            2.0 * (phase_covariance(0.0, 0.125, 30.0) - phase_covariance(r, 0.125, 30.0))
        };
        for (r, tolerance) in [(0.32, 0.15), (1.28, 0.25)] {
            let (mut d, mut d_low, mut n) = (0.0, 0.0, 0usize);
            for e in 0..24 {
                let ep = screens.episode(9, e);
                for i in 0..20 {
                    for j in 0..20 {
                        let x = [-2.8 + 0.27 * i as f64 - r / 2.0, -2.8 + 0.28 * j as f64];
                        let y = [x[0] + r, x[1]];
                        let o = [0.0, 0.0];
                        d +=
                            (ep.opd(x, o, 0.0, Part::Full) - ep.opd(y, o, 0.0, Part::Full)).powi(2);
                        d_low +=
                            (ep.opd(x, o, 0.0, Part::Low) - ep.opd(y, o, 0.0, Part::Low)).powi(2);
                        n += 1;
                    }
                }
            }
            let measured = d / n as f64 * k * k;
            assert!(
                (measured / theory(r) - 1.0).abs() < tolerance,
                "D({r}) = {measured:.2} rad^2, von Kármán {:.2}",
                theory(r)
            );
            let low = d_low / n as f64 * k * k;
            if r < 0.5 {
                assert!(
                    low < 0.8 * measured && low > 0.2 * measured,
                    "{low} {measured}"
                );
            } else {
                assert!(low < measured && low > 0.7 * measured, "{low} {measured}");
            }
        }
    }

    #[test]
    fn bad_atmospheres_and_long_episodes_are_refused() {
        let mut a = Atmosphere::canary();
        a.layers[0].fraction = 0.5;
        assert!(a.validate().unwrap_err().to_string().contains("sum to 1"));
        let a = Atmosphere::canary();
        let e = LayeredScreens::new(&a, 0.0245, &coverage(100.0), None)
            .err()
            .unwrap();
        assert!(e.to_string().contains("shorter episodes"), "{e}");
    }
}
