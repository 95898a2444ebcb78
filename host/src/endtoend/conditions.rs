//! The end-to-end conditions a user chooses beyond the wavefront sensor:
//! the asterism, the science target, the layers and their winds, the loop,
//! the DM, the fixed reconstructor's noise, and how long to run. One set-up
//! behind `brightpix endtoend`, `brightpix tune --criterion wfe` and the
//! Python `brightpix.tune(..., criterion="wfe")`, with the command line's
//! defaults; a bad value is refused before any work, its message naming the
//! quantity (each front end names its own option or keyword for it).

use anyhow::{bail, Result};

use super::{GuideStar, Scenario};
use crate::simulator::atmosphere::Layer;

/// The end-to-end conditions.
#[derive(Clone, Debug, PartialEq)]
pub struct Conditions {
    /// One wavefront sensor per guide star (`None`: the paper's asterism).
    pub guide_stars: Option<Vec<GuideStar>>,
    /// The science target's direction.
    pub science: GuideStar,
    /// The layers, fractions as shares of `Cn^2` (normalised here; `None`:
    /// the paper's three layers of [`crate::simulator::atmosphere::Atmosphere::canary`]).
    pub layers: Option<Vec<Layer>>,
    /// Every layer's wind speed is multiplied by it.
    pub wind_scale: f64,
    pub frame_rate_hz: f64,
    /// From the sensors' sampling to the science phase the DM corrects
    /// (frames).
    pub delay_frames: f64,
    /// Wavelength of the Strehl ratio (m).
    pub science_wavelength_m: f64,
    /// DM actuators across (`None`: sub-apertures across + 1, Fried).
    pub dm_actuators_across: Option<usize>,
    /// The DM's influence function at the neighbouring actuator.
    pub dm_coupling: f64,
    /// Slope noise the fixed reconstructor assumes (px rms).
    pub fixed_noise_px: f64,
    /// Independent atmosphere episodes scored (at least 2).
    pub episodes: usize,
    /// Frames per episode (frozen flow within an episode).
    pub episode_frames: usize,
    /// Episodes on which each rule and N's slope noise is measured for its
    /// matched reconstructor.
    pub calibration_episodes: usize,
}

impl Default for Conditions {
    /// The command line's defaults (those of [`Scenario::canary`]).
    fn default() -> Self {
        Conditions {
            guide_stars: None,
            science: GuideStar::ON_AXIS,
            layers: None,
            wind_scale: 1.0,
            frame_rate_hz: 250.0,
            delay_frames: 2.0,
            science_wavelength_m: 1.65e-6,
            dm_actuators_across: None,
            dm_coupling: 0.2,
            fixed_noise_px: 0.2,
            episodes: 40,
            episode_frames: 100,
            calibration_episodes: 1,
        }
    }
}

/// Refuses a star whose direction is not a finite radius >= 0 and angle.
fn check_star(what: &str, g: &GuideStar) -> Result<()> {
    if !(g.radius_arcsec.is_finite() && g.radius_arcsec >= 0.0 && g.angle_deg.is_finite()) {
        bail!(
            "{what} ({}, {}): the radius must be >= 0 (arcsec) and both finite",
            g.radius_arcsec,
            g.angle_deg
        );
    }
    Ok(())
}

/// `layers` with their fractions normalised to sum to 1, every value
/// checked.
pub fn normalise_layers(mut layers: Vec<Layer>) -> Result<Vec<Layer>> {
    if layers.is_empty() {
        bail!("no layer given");
    }
    for (k, l) in layers.iter().enumerate() {
        if !(l.altitude_m.is_finite() && l.altitude_m >= 0.0) {
            bail!(
                "layer {k}: the altitude must be >= 0 m, got {}",
                l.altitude_m
            );
        }
        if !(l.wind_speed_m_s.is_finite() && l.wind_speed_m_s >= 0.0) {
            bail!(
                "layer {k}: the wind speed must be >= 0 m/s, got {}",
                l.wind_speed_m_s
            );
        }
        if !l.wind_direction_deg.is_finite() {
            bail!("layer {k}: the wind direction must be finite");
        }
    }
    let total: f64 = layers.iter().map(|l| l.fraction).sum();
    if !(total.is_finite() && total > 0.0)
        || layers
            .iter()
            .any(|l| l.fraction.is_nan() || l.fraction <= 0.0)
    {
        bail!("every layer's fraction must be positive");
    }
    for l in &mut layers {
        l.fraction /= total;
    }
    Ok(layers)
}

impl Conditions {
    /// Refuses a value out of range, before any work.
    pub fn check(&self) -> Result<()> {
        if let Some(stars) = &self.guide_stars {
            if stars.is_empty() {
                bail!("asterism: at least one guide star");
            }
            for (k, g) in stars.iter().enumerate() {
                check_star(&format!("asterism: guide star {k}"), g)?;
            }
        }
        check_star("science target", &self.science)?;
        if let Some(layers) = &self.layers {
            normalise_layers(layers.clone()).map_err(|e| e.context("layers"))?;
        }
        if !(self.wind_scale.is_finite() && self.wind_scale >= 0.0) {
            bail!("wind scale must be >= 0, got {}", self.wind_scale);
        }
        let positive = |name: &str, v: f64| -> Result<()> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                bail!("{name} must be positive and finite, got {v}")
            }
        };
        positive("frame rate (Hz)", self.frame_rate_hz)?;
        if !(self.delay_frames.is_finite() && self.delay_frames >= 0.0) {
            bail!("the delay must be >= 0 frames, got {}", self.delay_frames);
        }
        positive("science wavelength (m)", self.science_wavelength_m)?;
        if let Some(n) = self.dm_actuators_across {
            if n < 2 {
                bail!("DM actuators across: at least 2, got {n}");
            }
        }
        if !(self.dm_coupling > 0.0 && self.dm_coupling < 1.0) {
            bail!("DM coupling must be in (0, 1), got {}", self.dm_coupling);
        }
        positive("fixed reconstructor noise (px)", self.fixed_noise_px)?;
        if self.episodes < 2 {
            bail!(
                "episodes {}: at least 2 for a standard error",
                self.episodes
            );
        }
        if self.episode_frames == 0 {
            bail!("episode frames must be at least 1");
        }
        if self.calibration_episodes == 0 {
            bail!("calibration episodes must be at least 1");
        }
        Ok(())
    }

    /// Checks, then fills `scenario` with these conditions (its
    /// atmosphere's r0 and outer scale are kept; its layers unless given).
    pub fn apply(&self, scenario: &mut Scenario) -> Result<()> {
        self.check()?;
        if let Some(stars) = &self.guide_stars {
            scenario.guide_stars = stars.clone();
        }
        scenario.science = self.science;
        if let Some(layers) = &self.layers {
            scenario.atmosphere.layers = normalise_layers(layers.clone())?;
        }
        scenario.atmosphere = scenario
            .atmosphere
            .clone()
            .with_wind_scaled(self.wind_scale);
        scenario.frame_rate_hz = self.frame_rate_hz;
        scenario.delay_frames = self.delay_frames;
        scenario.science_wavelength_m = self.science_wavelength_m;
        scenario.dm_actuators_across = self.dm_actuators_across;
        scenario.dm_coupling = self.dm_coupling;
        scenario.fixed_noise_px = self.fixed_noise_px;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layer(altitude_m: f64, fraction: f64, wind_speed_m_s: f64) -> Layer {
        Layer {
            altitude_m,
            fraction,
            wind_speed_m_s,
            wind_direction_deg: 0.0,
        }
    }

    #[test]
    fn the_defaults_are_the_papers_scenario() {
        let c = Conditions::default();
        c.check().unwrap();
        let mut s = Scenario::canary();
        c.apply(&mut s).unwrap();
        let paper = Scenario::canary();
        assert_eq!(s.guide_stars, paper.guide_stars);
        assert_eq!(s.science, paper.science);
        assert_eq!(s.atmosphere, paper.atmosphere);
        assert_eq!(
            (
                s.frame_rate_hz,
                s.delay_frames,
                s.science_wavelength_m,
                s.dm_actuators_across,
                s.dm_coupling,
                s.fixed_noise_px
            ),
            (
                paper.frame_rate_hz,
                paper.delay_frames,
                paper.science_wavelength_m,
                paper.dm_actuators_across,
                paper.dm_coupling,
                paper.fixed_noise_px
            )
        );
    }

    #[test]
    fn given_conditions_fill_the_scenario() {
        let c = Conditions {
            guide_stars: Some(vec![GuideStar {
                radius_arcsec: 30.0,
                angle_deg: 10.0,
            }]),
            science: GuideStar {
                radius_arcsec: 5.0,
                angle_deg: 90.0,
            },
            layers: Some(vec![layer(0.0, 3.0, 5.0), layer(1000.0, 1.0, 10.0)]),
            wind_scale: 2.0,
            frame_rate_hz: 500.0,
            delay_frames: 1.5,
            science_wavelength_m: 2.2e-6,
            dm_actuators_across: Some(9),
            dm_coupling: 0.3,
            fixed_noise_px: 0.1,
            ..Conditions::default()
        };
        let mut s = Scenario::canary();
        c.apply(&mut s).unwrap();
        assert_eq!(s.guide_stars, c.guide_stars.clone().unwrap());
        assert_eq!(s.science, c.science);
        // Fractions normalised once, winds scaled.
        let l = &s.atmosphere.layers;
        assert_eq!((l[0].fraction, l[1].fraction), (0.75, 0.25));
        assert_eq!((l[0].wind_speed_m_s, l[1].wind_speed_m_s), (10.0, 20.0));
        assert_eq!(s.atmosphere.r0_m, Scenario::canary().atmosphere.r0_m);
        assert_eq!(
            (s.frame_rate_hz, s.delay_frames, s.science_wavelength_m),
            (500.0, 1.5, 2.2e-6)
        );
        assert_eq!(
            (s.dm_actuators_across, s.dm_coupling, s.fixed_noise_px),
            (Some(9), 0.3, 0.1)
        );
    }

    #[test]
    fn out_of_range_values_are_refused_naming_the_quantity() {
        let refused = |change: &dyn Fn(&mut Conditions), expected: &str| {
            let mut c = Conditions::default();
            change(&mut c);
            let e = format!("{:#}", c.check().unwrap_err());
            assert!(e.contains(expected), "{expected}: {e}");
            // apply refuses it too, the scenario untouched.
            let mut s = Scenario::canary();
            assert!(c.apply(&mut s).is_err());
            assert_eq!(s.atmosphere, Scenario::canary().atmosphere);
        };
        let star = |radius_arcsec, angle_deg| GuideStar {
            radius_arcsec,
            angle_deg,
        };
        refused(&|c| c.guide_stars = Some(vec![]), "at least one guide star");
        refused(
            &|c| c.guide_stars = Some(vec![star(10.0, 0.0), star(-1.0, 0.0)]),
            "asterism: guide star 1",
        );
        refused(&|c| c.science = star(0.0, f64::NAN), "science target");
        refused(&|c| c.layers = Some(vec![]), "layers: no layer given");
        refused(
            &|c| c.layers = Some(vec![layer(0.0, -1.0, 5.0)]),
            "layers: every layer's fraction must be positive",
        );
        refused(
            &|c| c.layers = Some(vec![layer(-5.0, 1.0, 5.0)]),
            "layer 0: the altitude",
        );
        refused(
            &|c| c.layers = Some(vec![layer(0.0, 1.0, 5.0), layer(0.0, 1.0, -5.0)]),
            "layer 1: the wind speed",
        );
        refused(&|c| c.wind_scale = -1.0, "wind scale");
        refused(&|c| c.frame_rate_hz = 0.0, "frame rate");
        refused(&|c| c.delay_frames = -1.0, "delay");
        refused(
            &|c| c.science_wavelength_m = f64::INFINITY,
            "science wavelength",
        );
        refused(&|c| c.dm_actuators_across = Some(1), "DM actuators across");
        refused(&|c| c.dm_coupling = 1.0, "DM coupling");
        refused(&|c| c.fixed_noise_px = 0.0, "fixed reconstructor noise");
        refused(&|c| c.episodes = 1, "at least 2");
        refused(&|c| c.episode_frames = 0, "episode frames");
        refused(&|c| c.calibration_episodes = 0, "calibration episodes");
    }
}
