//! What a user asks [`super::tune`] for, checked and turned into its
//! [`Conditions`] and [`TuneOptions`]: the one set-up behind `brightpix
//! tune` and the Python `brightpix.tune`.
//!
//! A [`TuneRequest`] holds the user's choices with the command line's
//! defaults (the paper's CANARY NGS conditions). [`TuneRequest::check`]
//! refuses a bad value before any file is read or written;
//! [`TuneRequest::prepare`] takes the configuration's camera, background
//! and grid, and with recorded frames measures the signal, noise,
//! background error and spot size (r0) in them ([`super::super::recorded`]).

use anyhow::{anyhow, bail, Result};

use super::{candidate_methods, Conditions, Criterion, Lgs, PupilModel, TuneOptions};
use crate::config_file::ProcessingConfig;
use crate::evaluation::recorded::{measure, shift_and_add_fwhm, Measured};
use crate::evaluation::Axis;
use crate::io::FrameCube;
use crate::simulator::{SimulationParams, Simulator};

/// Simulator parameters that tune sets itself, and from what: a user's
/// conditions may not give them.
pub const SET_BY_TUNE: [(&str, &str); 4] = [
    (
        "source",
        "the guide star is the `lgs` option (a natural guide star without it)",
    ),
    (
        "pixels_per_subaperture",
        "each class of sub-apertures is simulated at its window's size",
    ),
    ("bit_depth", "the configuration's camera gives it"),
    ("background", "the configuration's background gives it"),
];

/// Fewest frames per class: a standard error needs them.
pub const MIN_FRAMES: usize = 20;

/// A tuning run as the user asks for it.
#[derive(Clone, Debug)]
pub struct TuneRequest {
    /// The simulator's conditions: optics, atmosphere, detector. Those of
    /// [`SET_BY_TUNE`] are replaced; `subapertures_across` only when
    /// [`TuneRequest::subapertures_across`] is `None` and the configuration
    /// has a grid (its columns or rows, the larger).
    pub params: SimulationParams,
    /// Sub-apertures across the pupil: `None` takes the configuration's
    /// grid, else `params.subapertures_across`.
    pub subapertures_across: Option<u32>,
    pub lgs: Option<Lgs>,
    /// Launch position in pupil coordinates (m), from the pupil centre.
    pub launch_m: [f64; 2],
    /// Unelongated LGS spot FWHM (arcsec).
    pub lgs_spot_fwhm_arcsec: f64,
    pub pupil: PupilModel,
    /// What R is scored on; `None`: along the elongation for a LGS, x and
    /// y pooled for a NGS.
    pub score: Option<Axis>,
    /// Also try each subtracting rule with this level filter (1..=16).
    pub level_filter: Option<u8>,
    /// Frames simulated per class (at least [`MIN_FRAMES`]).
    pub frames: usize,
    pub seed: u64,
    /// Distance classes (LGS only, at least 1).
    pub classes: usize,
    /// Azimuth classes over 0-45 degrees (LGS only, at least 1).
    pub angle_classes: usize,
    /// Largest fraction of a spot's light allowed outside its window.
    pub max_truncation: f64,
}

impl Default for TuneRequest {
    fn default() -> Self {
        TuneRequest {
            params: SimulationParams::canary(),
            subapertures_across: None,
            lgs: None,
            launch_m: [0.0, 0.0],
            lgs_spot_fwhm_arcsec: 0.28,
            pupil: PupilModel {
                obscuration_m: 0.0,
                illumination_threshold: 0.5,
            },
            score: None,
            level_filter: None,
            frames: 4000,
            seed: 1,
            classes: 4,
            angle_classes: 2,
            max_truncation: 0.05,
        }
    }
}

/// r0 fitted to recorded frames' spot size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FittedR0 {
    /// r0 (m at 500 nm).
    pub r0_m: f64,
    /// The recorded frames' shift-and-add spot FWHM (pixels).
    pub measured_fwhm_px: f64,
    /// The simulated spot's at `r0_m`.
    pub fitted_fwhm_px: f64,
}

/// A checked request for one configuration: what [`super::tune`] takes.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub conditions: Conditions,
    pub options: TuneOptions,
    /// What recorded frames gave, if any.
    pub measured: Option<Measured>,
    pub fitted_r0: Option<FittedR0>,
}

impl TuneRequest {
    /// Refuses a value out of range, before any file is read or written.
    pub fn check(&self) -> Result<()> {
        if self.frames < MIN_FRAMES {
            bail!(
                "{} frames per class: at least {MIN_FRAMES} are needed for a standard error",
                self.frames
            );
        }
        if self.classes == 0 {
            bail!("0 classes: at least one distance class is needed");
        }
        if self.angle_classes == 0 {
            bail!("0 angle classes: at least one azimuth class is needed");
        }
        if !(0.0..1.0).contains(&self.max_truncation) {
            bail!(
                "max truncation must be in 0..1, got {}",
                self.max_truncation
            );
        }
        let threshold = self.pupil.illumination_threshold;
        if !(threshold > 0.0 && threshold <= 1.0) {
            bail!("illumination threshold must be in (0, 1], got {threshold}");
        }
        let obscuration = self.pupil.obscuration_m;
        if !(obscuration.is_finite() && obscuration >= 0.0) {
            bail!("central obscuration must be >= 0 m, got {obscuration}");
        }
        if let Some(g) = self.level_filter {
            if !(1..=16).contains(&g) {
                bail!("level filter gain shift must be 1..=16, got {g}");
            }
        }
        if !(self.lgs_spot_fwhm_arcsec.is_finite() && self.lgs_spot_fwhm_arcsec >= 0.0) {
            bail!(
                "LGS spot FWHM must be >= 0 arcsec, got {}",
                self.lgs_spot_fwhm_arcsec
            );
        }
        if !self.launch_m.iter().all(|v| v.is_finite()) {
            bail!(
                "launch position {:?}: X and Y must be finite",
                self.launch_m
            );
        }
        if self.subapertures_across == Some(0) {
            bail!("0 sub-apertures across: at least 1 is needed");
        }
        Ok(())
    }

    /// The conditions and options for `config`. With `recorded` frames of
    /// its camera, the read noise, background error and photons (the
    /// upper quartile of the windows' signal as a fully lit one's) are
    /// measured in them, and for a NGS r0 is fitted to their spot size.
    pub fn prepare(
        &self,
        config: &ProcessingConfig,
        recorded: Option<&FrameCube>,
    ) -> Result<Prepared> {
        self.check()?;
        let mut params = self.params.clone();
        params.subapertures_across = self.subapertures_across.unwrap_or_else(|| {
            config
                .grid
                .as_ref()
                .map_or(params.subapertures_across, |g| {
                    g.grid.columns.max(g.grid.rows) as u32
                })
        });
        params.background = config.background.as_ref().map_or(0.0, |b| {
            b.iter().map(|&v| v as f64).sum::<f64>() / b.len().max(1) as f64 / 16.0
        });
        params.bit_depth = config.camera.bit_depth;
        params.validate().map_err(|e| anyhow!("conditions: {e}"))?;
        let mut measured_photons = None;
        let mut measured = None;
        let mut fitted_r0 = None;
        if let Some(cube) = recorded {
            let m = measure(config, cube, params.gain_e_per_count)?;
            params.read_noise_e = m.read_noise_e;
            params.background_error = m.background_error_counts;
            let mut sorted = m.photons.clone();
            sorted.sort_by(f64::total_cmp);
            params.photons = sorted[sorted.len() * 3 / 4].max(1.0);
            if self.lgs.is_none() && m.spot_fwhm_px.is_finite() {
                let fit = fit_r0(&params, config, &m)?;
                params.r0_m = fit.r0_m;
                fitted_r0 = Some(fit);
            }
            measured_photons = Some(m.photons.clone());
            measured = Some(m);
        }
        let score_axis = self.score.unwrap_or(if self.lgs.is_some() {
            Axis::Along
        } else {
            Axis::Both
        });
        Ok(Prepared {
            conditions: Conditions {
                params,
                lgs: self.lgs,
                launch_m: self.launch_m,
                lgs_spot_fwhm_arcsec: self.lgs_spot_fwhm_arcsec,
                pupil: self.pupil,
                score_axis,
                measured_photons,
            },
            options: TuneOptions {
                frames: self.frames,
                seed: self.seed,
                classes: self.classes,
                angle_classes: self.angle_classes,
                methods: candidate_methods(self.level_filter),
                max_truncation: self.max_truncation,
            },
            measured,
            fitted_r0,
        })
    }
}

/// The score axis a user names: `along` (the elongation) or `pooled` (x
/// and y).
pub fn parse_score(text: &str) -> Result<Axis> {
    match text {
        "along" => Ok(Axis::Along),
        "pooled" => Ok(Axis::Both),
        other => bail!("score {other:?}: one of along, pooled"),
    }
}

/// r0 (m, at 500 nm) whose simulated shift-and-add spot (same photons,
/// noise and measure) has the measured FWHM: bisection in log r0 between
/// 2 cm and 1 m, 300 frames per step.
fn fit_r0(params: &SimulationParams, config: &ProcessingConfig, m: &Measured) -> Result<FittedR0> {
    let size = config.windows.first().map_or(16, |w| w.width as usize);
    let fwhm_for = |r0: f64| -> Result<f64> {
        let sim = Simulator::new(SimulationParams {
            r0_m: r0,
            pixels_per_subaperture: size as u32,
            ..params.clone()
        })
        .map_err(|e| anyhow!("{e}"))?;
        let bg = sim.calibration_background() + params.background_error;
        let images: Vec<Vec<f64>> = sim
            .frames(7, 0, 300)
            .iter()
            .map(|f| f.raw.iter().map(|&v| v as f64 - bg).collect())
            .collect();
        Ok(shift_and_add_fwhm(
            images.iter().map(|v| v.as_slice()),
            size,
        ))
    };
    let (mut lo, mut hi) = (0.02f64.ln(), 1.0f64.ln());
    let target = m.spot_fwhm_px;
    let mut best = (params.r0_m, f64::NAN);
    for _ in 0..8 {
        let mid = 0.5 * (lo + hi);
        let f = fwhm_for(mid.exp())?;
        best = (mid.exp(), f);
        // Larger r0, smaller spot.
        if f > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(FittedR0 {
        r0_m: best.0,
        measured_fwhm_px: target,
        fitted_fwhm_px: best.1,
    })
}

impl Prepared {
    /// What was assumed, one line each (the command line prints them and
    /// both write them into the tuned TOML). `recorded_from` names the
    /// recorded frames, if any; `criterion` says what is scored (with
    /// [`Criterion::Wfe`] the classes, their frames and R do not apply: the
    /// end-to-end run's own description follows these lines).
    pub fn assumptions(&self, recorded_from: &str, criterion: Criterion) -> Vec<String> {
        let p = &self.conditions.params;
        let c = &self.conditions;
        let candidates = self
            .options
            .methods
            .iter()
            .map(|m| m.label())
            .collect::<Vec<_>>()
            .join(", ");
        let mut v = vec![
            format!(
                "telescope {} m, central obscuration {} m, {} sub-apertures across (d = {:.3} m); illumination threshold {}",
                p.telescope_diameter_m,
                c.pupil.obscuration_m,
                p.subapertures_across,
                p.subaperture_diameter_m(),
                c.pupil.illumination_threshold
            ),
            format!(
                "atmosphere: r0 {:.4} m at 500 nm{}, L0 {} m",
                p.r0_m,
                match &self.fitted_r0 {
                    Some(fit) => format!(
                        " (fitted: shift-and-add spot FWHM {:.2} px measured, {:.2} px simulated)",
                        fit.measured_fwhm_px, fit.fitted_fwhm_px
                    ),
                    None => String::new(),
                },
                p.outer_scale_m
            ),
            format!(
                "optics: {} arcsec/pixel, WFS wavelength {} nm, Airy diameter {}\" ({})",
                p.pixel_scale_arcsec,
                p.wavelength_m * 1e9,
                p.airy_diameter_arcsec,
                p.spot_model.name()
            ),
            format!(
                "detector: {} photons per fully lit sub-aperture and frame, read noise {:.3} e-, gain {} e-/count, background {} counts subtracted with an error of {:.3} counts, {} bits",
                p.photons, p.read_noise_e, p.gain_e_per_count, p.background, p.background_error, p.bit_depth
            ),
            match &c.lgs {
                Some(lgs) => format!(
                    "guide star: {}, launched at ({}, {}) m in the pupil, unelongated spot FWHM {}\"; elongation radial from the launch position",
                    lgs.describe(),
                    c.launch_m[0],
                    c.launch_m[1],
                    c.lgs_spot_fwhm_arcsec
                ),
                None => "guide star: natural (point source)".to_string(),
            },
            match criterion {
                Criterion::R => format!(
                    "scoring: R {}; {} frames per class, seed {}; candidates {}",
                    c.score_axis.name(),
                    self.options.frames,
                    self.options.seed,
                    candidates
                ),
                Criterion::Wfe => format!(
                    "scoring: on-axis residual wavefront error of the end-to-end simulation described below (matched reconstructor), one N for every sub-aperture; seed {}; candidates {}",
                    self.options.seed, candidates
                ),
            },
            match criterion {
                Criterion::R => "not modelled: flat field, threshold, lenslet aberrations beyond the spot model; each class is one representative sub-aperture",
                Criterion::Wfe => "not modelled: flat field, threshold, lenslet aberrations beyond the spot model",
            }
            .to_string(),
        ];
        if let Some(m) = &self.measured {
            v.push(format!(
                "measured from {} ({} frames): read noise {:.3} e- from {} dark pixels ({}); residual background {:.3} counts; signal per sub-aperture {:.1}..{:.1} e- (fully lit: {:.1}); shift-and-add spot FWHM {:.2} px",
                recorded_from,
                m.frames,
                m.read_noise_e,
                m.dark_pixels,
                m.dark_source,
                m.background_error_counts,
                m.photons.iter().copied().fold(f64::INFINITY, f64::min),
                m.photons.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                p.photons,
                m.spot_fwhm_px
            ));
        }
        v
    }
}

impl TuneRequest {
    /// A request with the default options whose conditions a user gave as
    /// named simulator parameters (`given`: the names they gave): those
    /// that tune sets itself ([`SET_BY_TUNE`]) are refused;
    /// `subapertures_across`, if given, is kept over the configuration's
    /// grid.
    pub fn with_conditions(params: SimulationParams, given: &[&str]) -> Result<TuneRequest> {
        for (name, why) in SET_BY_TUNE {
            if given.contains(&name) {
                bail!("conditions: {name:?} is set by tune itself: {why}");
            }
        }
        Ok(TuneRequest {
            subapertures_across: given
                .contains(&"subapertures_across")
                .then_some(params.subapertures_across),
            params,
            ..TuneRequest::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sil::canary_config;

    #[test]
    fn conditions_that_tune_sets_are_refused_and_the_grid_gives_the_pupil() {
        for (name, _) in SET_BY_TUNE {
            let e = TuneRequest::with_conditions(SimulationParams::canary(), &[name]).unwrap_err();
            assert!(e.to_string().contains(name), "{e}");
        }
        // Not given: the configuration's 7x7 grid sets the sub-apertures
        // across, whatever the parameters hold; given, it is kept.
        let params = SimulationParams {
            subapertures_across: 12,
            r0_m: 0.1,
            ..SimulationParams::canary()
        };
        let config = canary_config();
        let mut request = TuneRequest::with_conditions(params.clone(), &["r0_m"]).unwrap();
        request.frames = MIN_FRAMES;
        let prepared = request.prepare(&config, None).unwrap();
        let p = &prepared.conditions.params;
        assert_eq!((p.subapertures_across, p.r0_m), (7, 0.1));
        assert_eq!((p.background, p.bit_depth), (50.0, config.camera.bit_depth));
        assert_eq!(prepared.conditions.score_axis, Axis::Both);
        let mut request =
            TuneRequest::with_conditions(params, &["r0_m", "subapertures_across"]).unwrap();
        request.frames = MIN_FRAMES;
        request.lgs = Some(Lgs::parse("rayleigh:1000").unwrap());
        let prepared = request.prepare(&config, None).unwrap();
        assert_eq!(prepared.conditions.params.subapertures_across, 12);
        assert_eq!(prepared.conditions.score_axis, Axis::Along);
        assert!(prepared.fitted_r0.is_none() && prepared.measured.is_none());
    }

    #[test]
    fn out_of_range_values_are_refused() {
        let refused = |change: &dyn Fn(&mut TuneRequest), expected: &str| {
            let mut request = TuneRequest::default();
            change(&mut request);
            let e = request.check().unwrap_err().to_string();
            assert!(e.contains(expected), "{expected}: {e}");
        };
        refused(&|r| r.frames = MIN_FRAMES - 1, "at least 20");
        refused(&|r| r.classes = 0, "distance class");
        refused(&|r| r.angle_classes = 0, "azimuth class");
        refused(&|r| r.max_truncation = 1.0, "max truncation");
        refused(&|r| r.pupil.illumination_threshold = 0.0, "illumination");
        refused(&|r| r.pupil.obscuration_m = f64::NAN, "obscuration");
        refused(&|r| r.level_filter = Some(17), "1..=16");
        refused(&|r| r.lgs_spot_fwhm_arcsec = -1.0, "LGS spot");
        refused(&|r| r.launch_m = [f64::INFINITY, 0.0], "finite");
        refused(&|r| r.subapertures_across = Some(0), "across");
        assert!(TuneRequest::default().check().is_ok());
        assert!(parse_score("sideways").is_err());
    }
}
