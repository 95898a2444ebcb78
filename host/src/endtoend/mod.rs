//! # End to end: the corrected wavefront that each N buys
//!
//! Basden, Myers & Gendron (2011) §3.10 simulated CANARY end to end (open
//! loop MOAO, three off-axis NGS, least-squares tomography) and found a
//! residual wavefront error of about 550 nm with all pixels and 280 nm
//! with N = 20. This module does the same with **the device's own
//! slopes**: every wavefront-sensor frame goes through the firmware's
//! streaming engine ([`HostEngine`]) with the rule and N under test.
//!
//! ## The loop, one frame
//! 1. **Atmosphere** ([`crate::simulator::atmosphere`]): von Kármán layers
//!    moved by their wind (frozen flow), in independent episodes.
//! 2. **Wavefront sensors**: each guide star's sensor looks through the
//!    layers in its own direction (NGS: no cone); each of its sub-apertures
//!    gets its lenslet's optical path difference cut from the layers, and
//!    the existing image formation and noise
//!    ([`CameraSimulator::frame_from_opds`]) make the camera frame: one
//!    Shack-Hartmann camera per star, the configuration's windows on it,
//!    partly lit sub-apertures with their cut pupils and fewer photons.
//! 3. **Slopes**: the engine, with the configuration and the rule and N,
//!    on every camera frame: the integers `brightpix process` gives.
//! 4. **Reconstruction** ([`reconstructor`]): regularised least squares on
//!    the layers' phases, projected on the on-axis direction and fitted by
//!    the DM: one matrix from slopes to DM commands.
//! 5. **Correction**: open loop (MOAO): the DM takes the commands of the
//!    frame's slopes `delay` frames after the wavefront sensors sampled the
//!    atmosphere (the sensors see the atmosphere at an instant, the middle
//!    of their exposure; the DM's shape is compared with the science path's
//!    phase at that instant plus the delay).
//! 6. **Residual**: on-axis phase minus DM, piston removed, on the science
//!    grid; its variance and the on-axis intensity of its PSF at the
//!    science wavelength (the Strehl ratio: `|mean exp(i 2 pi r /
//!    lambda)|^2` per frame, averaged: the long-exposure PSF's peak).
//!
//! ## Two reconstructors
//! Every rule and N is scored with two reconstructors that differ only in
//! the slope noise `sigma^2` they assume: **matched** (each rule and N with
//! its own slope-noise variance, measured on calibration episodes
//! independent of the scored ones: what Learn & Apply does with on-sky
//! covariances) and **fixed** (one `sigma` for every rule and N, the same
//! matrix for all, like a reconstructor built once for the system). With
//! `Scenario::least_squares` the fixed one gives way to a plain
//! least-squares tomography like the paper's ([`least_squares`]), scored on
//! the same frames beside the matched MMSE one.
//!
//! ## Error budget
//! The residual of a frame is split exactly, by linearity, into
//! `phi(t+tau) - H M s = [phi(t+tau) - H c_fit(t+tau)]` (fitting)
//! `+ H [c_fit(t+tau) - c_fit(t)]` (temporal: the delay)
//! `+ H [c_fit(t) - M s_low]` (tomography: the on-axis phase that perfect
//! slopes of the sensor-visible turbulence do not give)
//! `- H M s_high` (aliasing: the slopes of the turbulence above the
//! lenslets' Nyquist frequency `1/(2d)`)
//! `- H M (s_cog - s_gtilt)` (the spot's own bias: noiseless centre of
//! gravity of the pixelated, truncated spot against the G-tilt)
//! `- H M (s - s_cog)` (noise: the engine's slopes against the noiseless
//! centre of gravity; what the selection changes),
//! with `c_fit` the DM's best fit of the on-axis phase, `s_low` and
//! `s_high` the G-tilts of the low- and high-pass parts of the layers. Each
//! term's mean square is reported; fitting is orthogonal to the others, the
//! rest may correlate a little (the report gives the sum of squares and
//! the total).
//!
//! ## Statistics
//! Every rule and N sees the same frames. Frames within an episode are
//! correlated (the same screens); episodes are independent, so standard
//! errors come from the spread of the per-episode means (batch means).
//!
//! [`HostEngine`]: crate::engine_runner::HostEngine
//! [`CameraSimulator::frame_from_opds`]: crate::simulator::camera::CameraSimulator::frame_from_opds

pub mod conditions;
pub mod covariance;
pub mod geometry;
pub mod least_squares;
pub mod reconstructor;
pub mod report;
mod results;
mod run;
mod scenario;

pub use conditions::{normalise_layers, Conditions};
pub use results::{
    estimate, rms_nm, Combo, ComboResult, EndToEndResult, Reconstruction, RunOptions, Terms, Timing,
};
pub use scenario::{
    canary_config, parse_layer_list, parse_layers, parse_stars, GuideStar, Scenario,
};

#[cfg(test)]
mod tests;
#[cfg(test)]
mod variant_tests;

use anyhow::{anyhow, bail, Result};
use nalgebra::DMatrix;
use rayon::prelude::*;

use crate::config_file::{PixelCounts, ProcessingConfig};
use crate::engine_runner::HostEngine;
use crate::evaluation::Method;
use crate::simulator::atmosphere::{Coverage, LayeredScreens, Part, SampleGrid};
use crate::simulator::camera::{CameraSimulator, CameraWindow};
use crate::simulator::{SimulationParams, SubaperturePupil};
use brightpix_protocol::LevelFilter;
use geometry::{DeformableMirror, Lenslets, Pupil, ScienceGrid};
use reconstructor::{ModelGeometry, Science, Tomography};

/// One episode's simulated data, shared by every rule and N.
pub struct EpisodeData {
    pub frames: usize,
    /// Per wavefront sensor, its camera frames one after the other.
    pub raw: Vec<Vec<u16>>,
    /// Slopes x frames (px): the noiseless centres of gravity, the G-tilts,
    /// and the G-tilts of the low-pass layers.
    pub s_cog: DMatrix<f64>,
    pub s_gtilt: DMatrix<f64>,
    pub s_low: DMatrix<f64>,
    /// Science points x frames: the on-axis OPD (m, piston removed) when the
    /// sensors sample and `delay` later.
    pub phi_now: DMatrix<f64>,
    pub phi_later: DMatrix<f64>,
    /// Wall time (s): the screens, the sensors' frames, the science phase.
    pub timing: [f64; 3],
}

/// Everything built once for a scenario.
pub struct EndToEnd {
    pub scenario: Scenario,
    pub pupil: Pupil,
    pub lenslets: Lenslets,
    pub grid: ScienceGrid,
    pub dm: DeformableMirror,
    pub science: Science,
    pub tomography: Tomography,
    /// The plain least-squares reconstructor's layer model, when the run
    /// has one (`Scenario::least_squares`).
    pub ls_tomography: Option<Tomography>,
    camera: CameraSimulator,
    screens: LayeredScreens,
    directions: Vec<[f64; 2]>,
    frames_per_episode: usize,
    /// The lenslet phase grid: samples across, spacing (m).
    phase_grid: (usize, f64),
    window_pixels: usize,
}

/// Index offset of the calibration episodes (their frames and screens are
/// drawn from streams no scored episode uses).
const CALIBRATION_EPISODE: u64 = 1 << 40;

impl EndToEnd {
    /// Checks the scenario and builds the cameras, the screens' generators
    /// for episodes of `frames_per_episode` frames, and the reconstructor.
    pub fn new(scenario: Scenario, frames_per_episode: usize) -> Result<EndToEnd> {
        let s = &scenario;
        if frames_per_episode == 0 {
            bail!("an episode needs at least one frame");
        }
        if s.guide_stars.is_empty() {
            bail!("at least one guide star is needed");
        }
        for (k, g) in s.guide_stars.iter().chain([&s.science]).enumerate() {
            if !(g.radius_arcsec.is_finite() && g.radius_arcsec >= 0.0 && g.angle_deg.is_finite()) {
                bail!("star {k}: radius must be >= 0 and finite, angle finite");
            }
        }
        let positive = |name: &str, v: f64| -> Result<()> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                bail!("{name} must be positive and finite, got {v}")
            }
        };
        positive("science wavelength", s.science_wavelength_m)?;
        positive("frame rate", s.frame_rate_hz)?;
        positive("fixed reconstructor noise", s.fixed_noise_px)?;
        positive("science grid spacing", s.science_spacing_m)?;
        if !(s.delay_frames.is_finite() && s.delay_frames >= 0.0) {
            bail!("the delay must be >= 0 frames, got {}", s.delay_frames);
        }
        if !(s.obscuration_m.is_finite()
            && s.obscuration_m >= 0.0
            && s.obscuration_m < s.wfs.telescope_diameter_m)
        {
            bail!(
                "the obscuration must be in [0, telescope diameter), got {}",
                s.obscuration_m
            );
        }
        s.atmosphere.validate().map_err(|e| anyhow!("{e}"))?;
        s.config
            .validate()
            .map_err(|e| anyhow!("configuration: {e:?}"))?;
        let pupil = Pupil {
            diameter_m: s.wfs.telescope_diameter_m,
            obscuration_m: s.obscuration_m,
        };
        let lenslets = Lenslets::from_config(&s.config, &pupil, s.across)?;
        let first = s.config.windows[0];
        if s.config
            .windows
            .iter()
            .any(|w| w.width != first.width || w.height != first.height)
            || first.width != first.height
        {
            bail!("the end-to-end simulation needs square windows, all of one size");
        }
        let wfs = SimulationParams {
            subapertures_across: lenslets.across as u32,
            pixels_per_subaperture: first.width as u32,
            bit_depth: s.config.camera.bit_depth,
            r0_m: s.atmosphere.r0_m,
            r0_wavelength_m: s.atmosphere.r0_wavelength_m,
            outer_scale_m: s.atmosphere.outer_scale_m,
            turbulence: false,
            ..s.wfs.clone()
        };
        wfs.validate()
            .map_err(|e| anyhow!("wavefront sensor: {e}"))?;
        let windows: Vec<CameraWindow> = s
            .config
            .windows
            .iter()
            .zip(&lenslets.subapertures)
            .map(|(w, sub)| CameraWindow {
                x: w.x as usize,
                y: w.y as usize,
                params: SimulationParams {
                    photons: wfs.photons * sub.lit,
                    pupil: Some(SubaperturePupil {
                        centre_m: sub.centre_m,
                        obscuration_m: s.obscuration_m,
                    }),
                    ..wfs.clone()
                },
            })
            .collect();
        let camera = CameraSimulator::new(
            s.config.camera.width as usize,
            s.config.camera.height as usize,
            windows,
        )
        .map_err(|e| anyhow!("wavefront sensor: {e}"))?;
        let (_, _, sim0) = camera.windows().next().expect("at least one window");
        let phase_grid = sim0.phase_sampling();
        let directions: Vec<[f64; 2]> = s.guide_stars.iter().map(|g| g.direction_rad()).collect();
        let science_dir = s.science.direction_rad();
        let reach = lenslets
            .subapertures
            .iter()
            .map(|sub| sub.centre_m[0].abs().max(sub.centre_m[1].abs()))
            .fold(0.0, f64::max)
            + (phase_grid.0 as f64 / 2.0 + 1.0) * phase_grid.1;
        let dt = 1.0 / s.frame_rate_hz;
        let coverage = Coverage {
            half_width_m: reach.max(pupil.diameter_m / 2.0 + s.science_spacing_m),
            directions_rad: directions.iter().copied().chain([science_dir]).collect(),
            duration_s: (frames_per_episode as f64 - 1.0 + s.delay_frames) * dt,
        };
        let screens = LayeredScreens::new(
            &s.atmosphere,
            phase_grid.1,
            &coverage,
            Some(1.0 / (2.0 * lenslets.pitch_m)),
        )
        .map_err(|e| anyhow!("{e}"))?;
        let grid = ScienceGrid::new(&pupil, s.science_spacing_m);
        let dm = DeformableMirror::new(
            &pupil,
            s.dm_actuators_across.unwrap_or(lenslets.across + 1),
            lenslets.pitch_m * lenslets.across as f64
                / (s.dm_actuators_across.unwrap_or(lenslets.across + 1) as f64 - 1.0),
            s.dm_coupling,
        )?;
        let science = Science::new(&dm, &grid);
        let layers = s.model_profile();
        if layers.is_empty()
            || layers
                .iter()
                .any(|&(h, f)| !(h.is_finite() && h >= 0.0 && f.is_finite() && f > 0.0))
        {
            bail!("the reconstructor's profile needs layers at altitudes >= 0 with positive fractions");
        }
        let model = |nodes_per_subaperture: usize| ModelGeometry {
            pupil: &pupil,
            lenslets: &lenslets,
            wfs_directions: &directions,
            science_direction: science_dir,
            layers: &layers,
            r0_m: s.atmosphere.r0_m,
            r0_wavelength_m: s.atmosphere.r0_wavelength_m,
            outer_scale_m: s.atmosphere.outer_scale_m,
            pixel_scale_arcsec: wfs.pixel_scale_arcsec,
            dm: &dm,
            science: &grid,
            nodes_per_subaperture,
        };
        let tomography = Tomography::new(&model(reconstructor::NODES_PER_SUBAPERTURE), &science)?;
        // The least-squares reconstructor's own lattice: without a prior,
        // nodes finer than the slopes can resolve are left to the minimum
        // norm, so its pitch is a choice of its own.
        let ls_tomography = match s.least_squares {
            Some(_) => Some(Tomography::new(&model(s.least_squares_nodes), &science)?),
            None => None,
        };
        let window_pixels = first.width as usize * first.height as usize;
        let scenario = Scenario { wfs, ..scenario };
        Ok(EndToEnd {
            scenario,
            pupil,
            lenslets,
            grid,
            dm,
            science,
            tomography,
            ls_tomography,
            camera,
            screens,
            directions,
            frames_per_episode,
            phase_grid,
            window_pixels,
        })
    }

    pub fn frames_per_episode(&self) -> usize {
        self.frames_per_episode
    }

    /// Pixels of one window (N at or above it: all pixels).
    pub fn window_pixels(&self) -> usize {
        self.window_pixels
    }

    /// Side (samples) and spacing (m) of each layer's screen.
    pub fn screen_sides(&self) -> Vec<(usize, f64)> {
        self.screens
            .patch_sides()
            .iter()
            .map(|&n| (n, self.phase_grid.1))
            .collect()
    }

    /// The engine configuration of every wavefront sensor for `method` and
    /// N: the scenario's configuration with the rule, N (at most the
    /// window's pixels; with `pixels_by_light`, scaled per sub-aperture by
    /// its lit fraction) and level filter set, and a threshold of 0 for a
    /// clipping method.
    pub fn engine_config(&self, method: Method, pixels: usize) -> ProcessingConfig {
        let mut config = self.scenario.config.clone();
        config.rule = method.rule;
        let n = pixels.clamp(1, self.window_pixels);
        config.pixels = if self.scenario.pixels_by_light && n < self.window_pixels {
            PixelCounts::PerSubaperture(
                self.lenslets
                    .subapertures
                    .iter()
                    .map(|sub| ((n as f64 * sub.lit).round() as u16).max(1))
                    .collect(),
            )
        } else {
            PixelCounts::All(n as u16)
        };
        config.level_filter = method
            .level_filter
            .map(|gain_shift| LevelFilter { gain_shift });
        if method.clip_negative {
            config.threshold = Some(0);
        }
        config
    }

    /// Simulates episode `episode` (its screens, every sensor's frames,
    /// the science phase) of run `seed`. Frame `t` of the episode is frame
    /// `first_frame + t` of the run for the noise streams.
    pub fn simulate_episode(&self, seed: u64, episode: u64, first_frame: u64) -> EpisodeData {
        let started = std::time::Instant::now();
        let screens = self.screens.episode(seed, episode);
        let t_screens = started.elapsed().as_secs_f64();
        let f = self.frames_per_episode;
        let nw = self.directions.len();
        let n_sub = self.lenslets.subapertures.len();
        let dt = 1.0 / self.scenario.frame_rate_hz;
        let (n, delta) = self.phase_grid;
        let frames: Vec<(crate::simulator::camera::CameraFrame, Vec<[f64; 2]>)> = (0..f * nw)
            .into_par_iter()
            .map(|i| {
                let (t, w) = (i / nw, i % nw);
                let time = t as f64 * dt;
                let dir = self.directions[w];
                let mut low = Vec::with_capacity(n_sub);
                let mut low_opd = vec![0.0; n * n];
                let frame = self.camera.frame_from_opds(
                    seed,
                    (first_frame + t as u64) * nw as u64 + w as u64,
                    &mut |k, sim, buffer| {
                        let grid = SampleGrid {
                            centre_m: self.lenslets.subapertures[k].centre_m,
                            n,
                            spacing_m: delta,
                        };
                        screens.add_grid(&grid, dir, time, Part::Full, buffer);
                        low_opd.iter_mut().for_each(|v| *v = 0.0);
                        screens.add_grid(&grid, dir, time, Part::Low, &mut low_opd);
                        low.push(sim.opd_gtilt_px(&low_opd));
                    },
                );
                (frame, low)
            })
            .collect();
        let n_s = 2 * n_sub * nw;
        let mut s_cog = DMatrix::zeros(n_s, f);
        let mut s_gtilt = DMatrix::zeros(n_s, f);
        let mut s_low = DMatrix::zeros(n_s, f);
        let pixels = self.scenario.config.camera.pixel_count();
        let mut raw = vec![Vec::with_capacity(f * pixels); nw];
        for (i, (frame, low)) in frames.into_iter().enumerate() {
            let (t, w) = (i / nw, i % nw);
            raw[w].extend_from_slice(&frame.raw);
            let per_window = frame.true_slopes.iter().zip(&frame.phase_slopes).zip(&low);
            for (k, ((cog, gtilt), low)) in per_window.enumerate() {
                for a in 0..2 {
                    let row = (w * n_sub + k) * 2 + a;
                    s_cog[(row, t)] = cog[a];
                    s_gtilt[(row, t)] = gtilt[a];
                    s_low[(row, t)] = low[a];
                }
            }
        }
        let t_frames = started.elapsed().as_secs_f64() - t_screens;
        let sci_dir = self.scenario.science.direction_rad();
        let delay = self.scenario.delay_frames * dt;
        let np = self.grid.points.len();
        let columns: Vec<(Vec<f64>, Vec<f64>)> = (0..f)
            .into_par_iter()
            .map(|t| {
                let time = t as f64 * dt;
                let sample = |at: f64| {
                    let mut v: Vec<f64> = self
                        .grid
                        .points
                        .iter()
                        .map(|&p| screens.opd(p, sci_dir, at, Part::Full))
                        .collect();
                    let mean = v.iter().sum::<f64>() / np as f64;
                    v.iter_mut().for_each(|x| *x -= mean);
                    v
                };
                (sample(time), sample(time + delay))
            })
            .collect();
        let mut phi_now = DMatrix::zeros(np, f);
        let mut phi_later = DMatrix::zeros(np, f);
        for (t, (now, later)) in columns.into_iter().enumerate() {
            phi_now.column_mut(t).copy_from_slice(&now);
            phi_later.column_mut(t).copy_from_slice(&later);
        }
        let t_science = started.elapsed().as_secs_f64() - t_screens - t_frames;
        EpisodeData {
            frames: f,
            raw,
            s_cog,
            s_gtilt,
            s_low,
            phi_now,
            phi_later,
            timing: [t_screens, t_frames, t_science],
        }
    }

    /// The engine's slopes of every sensor's frames with `method` and N:
    /// per sensor, frame-major (`frame * windows + window`), `[x, y]` in
    /// 2^-16 px, exactly as `brightpix process` computes them.
    pub fn engine_slopes(
        &self,
        data: &EpisodeData,
        method: Method,
        pixels: usize,
    ) -> Result<Vec<Vec<[i32; 2]>>> {
        let config = self.engine_config(method, pixels);
        let frame_pixels = self.scenario.config.camera.pixel_count();
        data.raw
            .iter()
            .map(|raw| {
                let mut engine = HostEngine::new(config.view())
                    .map_err(|e| anyhow!("engine configuration: {e:?}"))?;
                let results = engine
                    .process(raw.chunks_exact(frame_pixels), usize::MAX)
                    .map_err(|(k, e)| anyhow!("frame {k}: {e:?}"))?;
                Ok(results
                    .iter()
                    .flat_map(|frame| frame.iter().map(|r| [r.slope_x, r.slope_y]))
                    .collect())
            })
            .collect()
    }

    /// [`EndToEnd::engine_slopes`] as the reconstructor's slope vectors
    /// (slopes x frames, px).
    pub fn slope_matrix(&self, ints: &[Vec<[i32; 2]>], frames: usize) -> DMatrix<f64> {
        let n_sub = self.lenslets.subapertures.len();
        let mut s = DMatrix::zeros(2 * n_sub * ints.len(), frames);
        for (w, per) in ints.iter().enumerate() {
            for t in 0..frames {
                for k in 0..n_sub {
                    let v = per[t * n_sub + k];
                    s[((w * n_sub + k) * 2, t)] = v[0] as f64 / 65536.0;
                    s[((w * n_sub + k) * 2 + 1, t)] = v[1] as f64 / 65536.0;
                }
            }
        }
        s
    }

    /// The rule-and-N combinations a run scores.
    pub fn combos(&self, methods: &[Method], pixels: &[usize]) -> Vec<Combo> {
        crate::evaluation::jobs(self.window_pixels, methods, pixels)
            .into_iter()
            .map(|(method, n)| Combo {
                method,
                pixels: n,
                all_pixels: n >= self.window_pixels,
            })
            .collect()
    }
}
