//! What an end-to-end run simulates: the instrument, the atmosphere, the
//! asterism, the loop; with the paper's CANARY setup as the default.

use anyhow::{bail, Context, Result};

use super::conditions::normalise_layers;
use super::geometry::{DeformableMirror, Lenslets};
use super::least_squares::LeastSquares;
use crate::config_file::ProcessingConfig;
use crate::simulator::atmosphere::{Atmosphere, Layer};
use crate::simulator::{SimulationParams, ARCSEC_PER_RAD};

/// A star's position from the axis: `radius_arcsec` at `angle_deg` from +x
/// towards +y.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuideStar {
    pub radius_arcsec: f64,
    pub angle_deg: f64,
}

impl GuideStar {
    pub const ON_AXIS: GuideStar = GuideStar {
        radius_arcsec: 0.0,
        angle_deg: 0.0,
    };

    /// Direction `[x, y]` (radians).
    pub fn direction_rad(&self) -> [f64; 2] {
        let a = self.angle_deg.to_radians();
        let r = self.radius_arcsec / ARCSEC_PER_RAD;
        [r * a.cos(), r * a.sin()]
    }

    /// The paper's asterism (its table 2).
    pub fn canary_asterism() -> Vec<GuideStar> {
        [(40.2, 26.6), (40.2, 153.4), (19.0, 288.4)]
            .iter()
            .map(|&(radius_arcsec, angle_deg)| GuideStar {
                radius_arcsec,
                angle_deg,
            })
            .collect()
    }
}

/// Everything an end-to-end run simulates.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// Every wavefront sensor's camera and windows (one window per
    /// sub-aperture) and its calibration; the rule and N are set per run.
    pub config: ProcessingConfig,
    /// Sub-apertures across the pupil (`None`: the grid's larger side).
    pub across: Option<usize>,
    /// The spot and detector of a fully lit sub-aperture: telescope
    /// diameter, pixel scale, WFS wavelength, spot model, photons, read
    /// noise, gain, background (its r0 and outer scale are the
    /// atmosphere's, its turbulence switch is ignored).
    pub wfs: SimulationParams,
    /// Central obscuration diameter (m).
    pub obscuration_m: f64,
    pub atmosphere: Atmosphere,
    /// One wavefront sensor per guide star.
    pub guide_stars: Vec<GuideStar>,
    /// The science target's direction.
    pub science: GuideStar,
    pub science_wavelength_m: f64,
    pub frame_rate_hz: f64,
    /// From the wavefront sensors' sampling to the DM's shape being
    /// compared with the science phase (frames).
    pub delay_frames: f64,
    /// DM actuators across (`None`: sub-apertures across + 1, Fried).
    pub dm_actuators_across: Option<usize>,
    /// Influence function at the neighbouring actuator.
    pub dm_coupling: f64,
    /// The slope noise the fixed reconstructor assumes (px rms).
    pub fixed_noise_px: f64,
    /// Spacing of the science grid (m).
    pub science_spacing_m: f64,
    /// The profile the reconstructor assumes, `(altitude m, fraction)` per
    /// layer (`None`: the atmosphere's own, perfectly known). A different
    /// one is a profile mismatch, as on sky where the profile is measured.
    pub model_layers: Option<Vec<(f64, f64)>>,
    /// Replace the fixed MMSE reconstructor by plain least squares
    /// (`None`: the fixed MMSE one with `fixed_noise_px`).
    pub least_squares: Option<LeastSquares>,
    /// Layer nodes per sub-aperture pitch of the least-squares
    /// reconstructor (1: nodes at the lenslet pitch, a virtual DM per
    /// layer; 2: the MMSE reconstructor's lattice).
    pub least_squares_nodes: usize,
    /// The matched reconstructor weights each sub-aperture by its own
    /// measured slope noise (`false`: one variance for all).
    pub noise_weights: bool,
    /// Each sub-aperture selects `max(1, round(N x lit fraction))` pixels
    /// (`false`: N for all): partly lit sub-apertures have fewer photons.
    pub pixels_by_light: bool,
}

/// The CANARY wavefront sensor of the paper: `examples/canary-vignetted.toml`
/// (7x7 windows of 16x16 on a 112x112 camera, the 36 sub-apertures CANARY
/// uses: corners and the centre skipped).
pub fn canary_config() -> ProcessingConfig {
    ProcessingConfig::from_toml_str(
        include_str!("../../../examples/canary-vignetted.toml"),
        std::path::Path::new("examples/canary-vignetted.toml"),
    )
    .expect("the bundled example configuration is valid")
}

impl Scenario {
    /// The paper's §3.10 setup, and where it is silent: the WHT's 1.0 m
    /// central obscuration (its secondary), CANARY's 8x8 DM (52 actuators,
    /// Fried geometry, 20% coupling), a 2-frame delay, H band (1.65 um),
    /// the winds and outer scale of [`Atmosphere::canary`], a fixed
    /// reconstructor assuming 0.2 px of slope noise.
    pub fn canary() -> Scenario {
        Scenario {
            config: canary_config(),
            across: None,
            wfs: SimulationParams::canary(),
            obscuration_m: 1.0,
            atmosphere: Atmosphere::canary(),
            guide_stars: GuideStar::canary_asterism(),
            science: GuideStar::ON_AXIS,
            science_wavelength_m: 1.65e-6,
            frame_rate_hz: 250.0,
            delay_frames: 2.0,
            dm_actuators_across: None,
            dm_coupling: 0.2,
            fixed_noise_px: 0.2,
            science_spacing_m: 0.075,
            model_layers: None,
            least_squares: None,
            least_squares_nodes: 1,
            noise_weights: false,
            pixels_by_light: false,
        }
    }

    /// The reconstructor's profile: `model_layers`, or the atmosphere's.
    pub fn model_profile(&self) -> Vec<(f64, f64)> {
        self.model_layers.clone().unwrap_or_else(|| {
            self.atmosphere
                .layers
                .iter()
                .map(|l| (l.altitude_m, l.fraction))
                .collect()
        })
    }

    /// What the run assumes, one line each.
    pub fn describe(&self, lenslets: &Lenslets, dm: &DeformableMirror) -> Vec<String> {
        let p = &self.wfs;
        let a = &self.atmosphere;
        vec![
            format!(
                "telescope {} m, central obscuration {} m; {} sub-apertures across (d = {:.3} m), {} windows used",
                p.telescope_diameter_m,
                self.obscuration_m,
                lenslets.across,
                lenslets.pitch_m,
                lenslets.subapertures.len()
            ),
            format!(
                "wavefront sensors: {} NGS at {} (radius\", angle deg); {} px of {}\", {} nm, Airy {}\" ({}); {} photons per fully lit sub-aperture and frame (partly lit: in proportion), read noise {} e-, background {} counts subtracted",
                self.guide_stars.len(),
                self.guide_stars
                    .iter()
                    .map(|g| format!("({}, {})", g.radius_arcsec, g.angle_deg))
                    .collect::<Vec<_>>()
                    .join(" "),
                p.pixels_per_subaperture,
                p.pixel_scale_arcsec,
                p.wavelength_m * 1e9,
                p.airy_diameter_arcsec,
                p.spot_model.name(),
                p.photons,
                p.read_noise_e,
                p.background
            ),
            format!(
                "atmosphere: r0 {} m at {} nm, L0 {} m; layers (altitude m, fraction, wind m/s towards deg): {}; effective wind {:.1} m/s",
                a.r0_m,
                a.r0_wavelength_m * 1e9,
                a.outer_scale_m,
                a.layers
                    .iter()
                    .map(|l| format!(
                        "({}, {}, {}, {})",
                        l.altitude_m, l.fraction, l.wind_speed_m_s, l.wind_direction_deg
                    ))
                    .collect::<Vec<_>>()
                    .join(" "),
                a.effective_wind_m_s()
            ),
            format!(
                "loop: open-loop MOAO at {} Hz, the DM's shape compared with the science phase {} frames ({:.1} ms) after the sensors sampled the atmosphere",
                self.frame_rate_hz,
                self.delay_frames,
                1e3 * self.delay_frames / self.frame_rate_hz
            ),
            format!(
                "DM: {} actuators ({}x{} lattice of pitch {:.3} m within D/2 + pitch/2), Gaussian influence functions, {}% coupling",
                dm.actuators.len(),
                self.dm_actuators_across.unwrap_or(lenslets.across + 1),
                self.dm_actuators_across.unwrap_or(lenslets.across + 1),
                dm.pitch_m,
                100.0 * dm.coupling
            ),
            format!(
                "reconstructor: least squares on layer phases (bilinear nodes of pitch d/2 at {}), regularised by the layers' von Kármán covariance and slope noise: matched (each rule and N its own measured noise, {}) and {}",
                match &self.model_layers {
                    None => "the true altitudes (the profile known)".to_string(),
                    Some(m) => format!(
                        "a profile unlike the atmosphere's: (altitude m, fraction) {}",
                        m.iter()
                            .map(|(h, f)| format!("({h}, {f:.3})"))
                            .collect::<Vec<_>>()
                            .join(" ")
                    ),
                },
                if self.noise_weights {
                    "each sub-aperture weighted by its own measured noise"
                } else {
                    "one variance for every slope"
                },
                match self.least_squares {
                    None => format!("fixed ({} px rms for all)", self.fixed_noise_px),
                    Some(ls) => format!(
                        "{}: plain least squares on nodes of pitch d/{} at the same altitudes, without the prior, {}",
                        ls.label(),
                        self.least_squares_nodes,
                        match ls {
                            LeastSquares::TruncatedSvd(r) =>
                                format!("singular values of G below {r} of the largest discarded"),
                            LeastSquares::Tikhonov(r) => format!(
                                "Tikhonov alpha = ({r} x the largest singular value of G)^2"
                            ),
                        }
                    ),
                }
            ),
            format!(
                "selection: {}; camera: {}",
                if self.pixels_by_light {
                    "per sub-aperture, N x its lit fraction (rounded, at least 1)"
                } else {
                    "the same N in every sub-aperture"
                },
                if p.em_excess_noise {
                    "EMCCD at high gain (multiplication noise: photon-noise variance doubled, excess noise factor sqrt(2))"
                } else {
                    "no multiplication noise (Poisson and read noise)"
                }
            ),
            format!(
                "science: at ({}\", {} deg), {} nm, residual on a {} m grid over the pupil, piston removed",
                self.science.radius_arcsec,
                self.science.angle_deg,
                self.science_wavelength_m * 1e9,
                self.science_spacing_m
            ),
        ]
    }
}

/// Parses `r,a;r,a;...` (arcsec, degrees) into guide stars.
pub fn parse_stars(text: &str) -> Result<Vec<GuideStar>> {
    text.split(';')
        .filter(|s| !s.trim().is_empty())
        .map(|s| {
            let parts: Vec<&str> = s.split(',').map(str::trim).collect();
            if parts.len() != 2 {
                bail!("{s:?}: expected RADIUS,ANGLE (arcsec, degrees)");
            }
            let radius_arcsec: f64 = parts[0].parse().with_context(|| format!("{s:?}: radius"))?;
            let angle_deg: f64 = parts[1].parse().with_context(|| format!("{s:?}: angle"))?;
            if !(radius_arcsec.is_finite() && radius_arcsec >= 0.0 && angle_deg.is_finite()) {
                bail!("{s:?}: the radius must be >= 0 and both finite");
            }
            Ok(GuideStar {
                radius_arcsec,
                angle_deg,
            })
        })
        .collect()
}

/// Parses `ALT:FRACTION:SPEED:DIRECTION,...` (m, share, m/s, degrees) into
/// layers; the fractions are normalised to sum to 1.
pub fn parse_layers(text: &str) -> Result<Vec<Layer>> {
    normalise_layers(parse_layer_list(text)?)
}

/// Parses `ALT:FRACTION:SPEED:DIRECTION,...` into layers as written (the
/// fractions not normalised: [`normalise_layers`] does it, once).
pub fn parse_layer_list(text: &str) -> Result<Vec<Layer>> {
    text.split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| {
            let parts: Vec<&str> = s.split(':').map(str::trim).collect();
            if parts.len() != 4 {
                bail!("{s:?}: expected ALTITUDE:FRACTION:WIND_SPEED:WIND_DIRECTION");
            }
            let v: Vec<f64> = parts
                .iter()
                .map(|p| p.parse::<f64>().with_context(|| format!("{s:?}: {p:?}")))
                .collect::<Result<_>>()?;
            Ok(Layer {
                altitude_m: v[0],
                fraction: v[1],
                wind_speed_m_s: v[2],
                wind_direction_deg: v[3],
            })
        })
        .collect()
}
